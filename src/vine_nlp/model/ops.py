"""One formula, two backends: numpy for numbers, CasADi for symbols.

Every model formula is written once against this tiny namespace. ``lib(*args)`` returns the casadi module when any
argument is a CasADi object and numpy otherwise, so the same function evaluates numbers (vectorized over arrays) and
builds SX/MX expressions for the optimizer."""

from __future__ import annotations

from types import SimpleNamespace

import casadi as ca
import numpy as np

_CASADI_TYPES = (ca.SX, ca.MX, ca.DM)


def is_symbolic(*args) -> bool:
    return any(isinstance(a, _CASADI_TYPES) for a in args)


NUMPY = SimpleNamespace(sin=np.sin, cos=np.cos, tan=np.tan, sqrt=np.sqrt, arctan2=np.arctan2, arccos=np.arccos, fabs=np.abs,
                        fmax=np.maximum, fmin=np.minimum, where=np.where)
# if_else evaluates both branches: callers keep both finite (casadi #1805)
CASADI = SimpleNamespace(sin=ca.sin, cos=ca.cos, tan=ca.tan, sqrt=ca.sqrt, arctan2=ca.atan2, arccos=ca.acos, fabs=ca.fabs,
                         fmax=ca.fmax, fmin=ca.fmin, where=ca.if_else)


def lib(*args):
    return CASADI if is_symbolic(*args) else NUMPY


def safe_series(x, exact, coeffs, threshold):
    """Evaluate f(x) = exact(x) away from 0 and its Taylor series sum(c_k x^k) near 0.

    Both branches are finite everywhere: the exact formula is evaluated at max(x, threshold), so neither values nor
    derivatives of the branch not taken can be NaN (CasADi's if_else differentiates both)."""
    L = lib(x)
    series = 0.0 * x
    power = 1.0 + 0.0 * x
    for c in coeffs:
        series = series + c * power
        power = power * x
    return L.where(x < threshold, series, exact(L.fmax(x, threshold)))
