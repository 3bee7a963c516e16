"""As-built correction: estimate what was built from measured points, then correct it (spec/formats.md,
"As-built correction"). Both steps are formulations on the one multiple-shooting transcription.

- ``deviations``: the contract's rule, what stays with a robot from build to build;
- ``pairing``: measurements and their pairing with the model lines (point-to-line, ICP-style);
- ``estimate``: the MAP estimate of the as-built robot, its ICP loop on the drive;
- ``laplace``: the estimate's uncertainty (Laplace approximation);
- ``correction``: the nominal to build next, and :func:`correct`, estimate and correction together.
"""

from vine_nlp.methods.correct.correction import ADJUST, THETA_TRUST, CorrectionResult, correct, correct_routing, lambda_bounds
from vine_nlp.methods.correct.deviations import Deviations, apply_deviations, deviations_of, remove_deviations
from vine_nlp.methods.correct.estimate import Estimate, combine_systematic, estimate_as_built
from vine_nlp.methods.correct.pairing import LINE_SIDE, Measurement

__all__ = ["ADJUST", "THETA_TRUST", "CorrectionResult", "correct", "correct_routing", "lambda_bounds", "Deviations", "apply_deviations", "deviations_of",
           "remove_deviations", "Estimate", "combine_systematic", "estimate_as_built", "LINE_SIDE", "Measurement"]
