"""Layer 1: the geometric model of Blumenschein et al. (IEEE T-RO 2021).

Pure functions on numpy arrays (vectorized over segments or designs) and, where the NLP needs them, CasADi SX/MX symbols; and
the pure value types they take and give (Routing, Shape, Pairing, Sigmas), and the one table of length units. No I/O."""

from vine_nlp.model.chain import chain_frames, chain_points, phi_from_theta, shape_lines  # noqa: F401
from vine_nlp.model.helix import center_rates, helix_forward, helix_inverse, helix_self_collides  # noqa: F401
from vine_nlp.model.pairing import Pairing, pair_points  # noqa: F401
from vine_nlp.model.routing import MEASURED_LINES, Routing, Sigmas  # noqa: F401
from vine_nlp.model.segment import segment_function, segment_point, segment_transform  # noqa: F401
from vine_nlp.model.shape import Shape, error_metrics, forward_shape, routing_metrics, total_variation  # noqa: F401
from vine_nlp.model.units import MM_PER_UNIT, mm_per_unit  # noqa: F401
