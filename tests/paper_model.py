"""The paper's printed segment transform, the independent reference the model is checked against (docs/model.md,
"The erratum")."""

import numpy as np

from vine_nlp.model import helix_forward
from vine_nlp.model.segment import assemble


def paper_segment_transform(theta, lam, length, D):
    """The paper's printed T^{j+1}_j in R_c, b, L form, with the erratum corrected (numpy only).

    The independent reference the chain is checked against; 0/0 on a straight tube (lam = 1, theta = 0)."""
    h = helix_forward(np.asarray(theta, float), np.asarray(lam, float), D)
    R, b = h.R_c, h.b
    Lh = np.sqrt(R**2 + b**2)
    dl = np.asarray(length, float) * h.lambda_c
    a = dl / Lh
    ca_, sa = np.cos(a), np.sin(a)
    Rm = [
        [R**2 / Lh**2 * ca_ + b**2 / Lh**2, -R / Lh * sa, R * b / Lh**2 * (1 - ca_)],
        [R / Lh * sa, ca_, -b / Lh * sa],
        [R * b / Lh**2 * (1 - ca_), b / Lh * sa, b**2 / Lh**2 * ca_ + R**2 / Lh**2],
    ]
    p = [R**2 / Lh * sa + b**2 / Lh * a, R * (1 - ca_), R * b / Lh * (a - sa)]
    return assemble(Rm, p)
