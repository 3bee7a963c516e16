"""Uniform (helical) actuation: Section II and Table I of the paper.

Notation as in the paper: theta is the drawn angle of the actuator, lam its contraction ratio lambda, D the tube
diameter. Curvatures and torsions are per unit of *actuated* length of the line they belong to; ``lambda_c`` is actuated
over unactuated center-line length. Everything here accepts numpy arrays (broadcast elementwise) or CasADi symbols."""

from __future__ import annotations

import math
from typing import NamedTuple

from vine_nlp.model.ops import lib


class Helix(NamedTuple):
    """Shape of a uniformly actuated tube (Table I)."""

    R_o: object  # outer (unwrinkled) line radius
    R_i: object  # inner (actuator) line radius, negative when lam > cos(2 theta)
    R_c: object  # center line radius, eq. (Rc)
    b: object  # shared pitch parameter: 2 pi b per turn
    kappa_o: object
    tau_o: object
    kappa_i: object
    tau_i: object
    kappa_c: object
    tau_c: object
    lambda_c: object  # center compression ratio v_z


def _den_minus(theta, lam):
    L = lib(theta, lam)
    return lam**2 - 2 * lam * L.cos(2 * theta) + 1


def _den_plus(theta, lam):
    L = lib(theta, lam)
    return lam**2 + 2 * lam * L.cos(2 * theta) + 1


def center_rates(theta, lam, D):
    """Singularity-free center-line quantities (model notes, 'Numerically safe form').

    Returns (kappa_c, tau_c, lambda_c): curvature and torsion of the center line per unit of actuated length and the
    compression ratio lambda_c (paper eq. for v_z). Finite with finite derivatives over |theta| < 90 deg, lam > 0,
    including the straight tube lam = 1, theta = 0 where the R, b form is 0/0."""
    L = lib(theta, lam, D)
    dp = _den_plus(theta, lam)
    kappa_c = 2 * (1 - lam**2) / (D * dp)
    tau_c = 4 * lam * L.sin(2 * theta) / (D * dp)
    # 2 (1 + cos 2theta) = 4 cos^2 theta; the cos form keeps the sqrt argument away from 0.
    lambda_c = L.sqrt(dp) / (2 * L.cos(theta))
    return kappa_c, tau_c, lambda_c


def helix_forward(theta, lam, D) -> Helix:
    """Forward solution of Table I: (theta, lambda, D) -> radii, pitch, curvatures, torsions.

    R_o, R_i, R_c and b are infinite for the straight tube (lam = 1, theta = 0);
    use :func:`center_rates` inside optimization."""
    L = lib(theta, lam, D)
    c2, s2 = L.cos(2 * theta), L.sin(2 * theta)
    dm = _den_minus(theta, lam)
    R_o = D * (1 - lam * c2) / dm
    R_i = D * lam * (c2 - lam) / dm
    R_c = D * (1 - lam**2) / (2 * dm)
    b = D * lam * s2 / dm
    kappa_c, tau_c, lambda_c = center_rates(theta, lam, D)
    return Helix(R_o=R_o, R_i=R_i, R_c=R_c, b=b, kappa_o=(1 - lam * c2) / D, tau_o=lam * s2 / D, kappa_i=(c2 - lam) / (D * lam),
                 tau_i=s2 / (D * lam), kappa_c=kappa_c, tau_c=tau_c, lambda_c=lambda_c)


def helix_inverse(R_o, R_i, b):
    """Inverse solution of Table I: (R_o, R_i, b) -> (theta, lam, D).

    theta takes the sign of the pitch b. The angle is computed as 2 theta = atan2(b D, R_i R_o + b^2), the same angle as
    the paper's arccos form but accurate near 0 and carrying the sign."""
    L = lib(R_o, R_i, b)
    D = R_o - R_i
    lam = L.sqrt((b**2 + R_i**2) / (b**2 + R_o**2))
    theta = 0.5 * L.arctan2(b * D, R_i * R_o + b**2)
    return theta, lam, D


def helix_from_curvature(kappa_c, tau_c, D):
    """Actuator (theta, lam) whose center helix has curvature kappa_c and torsion tau_c.

    Table I's inverse written in kappa_c, tau_c (R_c = kappa/q, b = tau/q, q = kappa^2 + tau^2, R_o,i = R_c +- D/2) and
    divided through by q so that the straight tube (q = 0 -> theta = 0, lam = 1) is not 0/0. Used for initial guesses."""
    L = lib(kappa_c, tau_c, D)
    q = kappa_c**2 + tau_c**2
    theta = 0.5 * L.arctan2(tau_c * D, 1 - D**2 * q / 4)
    lam = L.sqrt((1 - kappa_c * D + D**2 * q / 4) / (1 + kappa_c * D + D**2 * q / 4))
    return theta, lam


def helix_turns(theta, lam, D, length):
    """Number of turns around the helix axis of a uniform section of unactuated length ``length``."""
    L = lib(theta, lam, D, length)
    kappa_c, tau_c, lambda_c = center_rates(theta, lam, D)
    return length * lambda_c * L.sqrt(kappa_c**2 + tau_c**2) / (2 * math.pi)


def helix_self_collides(theta, lam, D, length=None):
    """The paper's self-collision condition (Sec. VI-A): 2 pi |b| < D with at least one turn.

    Written as pi |sin 2theta| + cos 2theta < (lam^2 + 1) / (2 lam), which needs no R, b (and is false for the straight
    tube). With ``length`` None the section is taken as long enough for a full turn. numpy only (returns booleans)."""
    import numpy as np
    theta, lam = np.asarray(theta, float), np.asarray(lam, float)
    tight = math.pi * np.abs(np.sin(2 * theta)) + np.cos(2 * theta) < (lam**2 + 1) / (2 * lam)
    if length is None:
        return tight
    return tight & (helix_turns(theta, lam, D, np.asarray(length, float)) >= 1.0)
