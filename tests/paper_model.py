"""Paper formulas the model is checked against: the printed segment transform (docs/model.md, "The erratum") and the
angles between the lines' tangents."""

import numpy as np

from vine_nlp.model import helix_forward
from vine_nlp.model.ops import lib
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


def line_offset_angles(theta, lam):
    """Angles alpha_{c,i}, alpha_{c,o} between the center tangent and the inner/outer tangents.

    The paper's alpha_{c,i} = atan(b/R_i) - atan(b/R_c) and alpha_{c,o} = atan(b/R_c) - atan(b/R_o), taken with
    quadrant-correct angles and simplified (the common factor lam^2 - 2 lam cos 2theta + 1 > 0 cancels): alpha_{c,i} =
    atan2(sin 2theta, lam + cos 2theta), alpha_{c,o} = atan2(lam sin 2theta, 1 + lam cos 2theta). They add up to 2 theta
    (eq. tangent_dot) and equal theta each on a straight tube."""
    L = lib(theta, lam)
    c2, s2 = L.cos(2 * theta), L.sin(2 * theta)
    return L.arctan2(s2, lam + c2), L.arctan2(lam * s2, 1 + lam * c2)
