"""Analysis of designs: self-collision (collision) and manufacturing tolerance (tolerance).

Pure functions on routings, shapes and results (numpy; CasADi only for Jacobians). No I/O.
"""

from vine_nlp.analysis.collision import (  # noqa: F401
    collision_metrics,
    growth_contacts,
    helix_collisions,
    min_clearance,
    routing_clearance,
    sample_routing,
    uniform_sections,
)
from vine_nlp.analysis.tolerance import (  # noqa: F401
    Sigmas,
    point_jacobian,
    tolerance_metrics,
    tolerance_report,
)
