"""Layer 1: the geometric model of Blumenschein et al. (IEEE T-RO 2021).

Pure functions; each works on numpy arrays (vectorized over segments or designs)
and on CasADi SX/MX symbols alike. No I/O.
"""

from vine_nlp.model.helix import (  # noqa: F401
    center_rates,
    cosserat,
    helix_forward,
    helix_inverse,
    helix_self_collides,
    line_offset_angles,
)
from vine_nlp.model.segment import segment_transform, segment_point, paper_segment_transform, line_transform  # noqa: F401
from vine_nlp.model.chain import chain_frames, chain_points, phi_from_theta, theta_from_phi, shape_lines  # noqa: F401
