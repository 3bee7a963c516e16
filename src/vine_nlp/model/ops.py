"""One formula, two backends: numpy for numbers, CasADi for symbols.

Every model formula is written once against this tiny namespace. ``lib(*args)`` returns the casadi module when any
argument is a CasADi object and numpy otherwise, so the same function evaluates numbers (vectorized over arrays) and
builds SX/MX expressions for the optimizer."""

from __future__ import annotations

import casadi as ca
import numpy as np

_CASADI_TYPES = (ca.SX, ca.MX, ca.DM)


def is_symbolic(*args) -> bool:
    return any(isinstance(a, _CASADI_TYPES) for a in args)


class _Numpy:
    sin = staticmethod(np.sin)
    cos = staticmethod(np.cos)
    tan = staticmethod(np.tan)
    sqrt = staticmethod(np.sqrt)
    arctan2 = staticmethod(np.arctan2)
    arccos = staticmethod(np.arccos)
    fabs = staticmethod(np.abs)
    fmax = staticmethod(np.maximum)
    fmin = staticmethod(np.minimum)
    where = staticmethod(np.where)


class _Casadi:
    sin = staticmethod(ca.sin)
    cos = staticmethod(ca.cos)
    tan = staticmethod(ca.tan)
    sqrt = staticmethod(ca.sqrt)
    arctan2 = staticmethod(ca.atan2)
    arccos = staticmethod(ca.acos)
    fabs = staticmethod(ca.fabs)
    fmax = staticmethod(ca.fmax)
    fmin = staticmethod(ca.fmin)

    @staticmethod
    def where(cond, a, b):
        # if_else evaluates both branches: callers keep both finite (casadi #1805).
        return ca.if_else(cond, a, b)


NUMPY = _Numpy()
CASADI = _Casadi()


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
