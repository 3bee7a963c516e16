"""One helical segment's rigid motion T^{j+1}_j (paper eqs. transformationCC-positionCC).

The frame is the Frenet frame of the center helix: x = tangent T, y = normal N (toward the actuator), z = binormal B. A
segment of unactuated length dl moves the frame by exp(sigma xi), sigma = dl lambda_c, twist xi = (v = (1, 0, 0), omega
= (tau_c, 0, kappa_c)) (Frenet-Serret). Written with the SE(3) exponential so the straight tube needs no special case;
the series branches keep values and derivatives finite at phi = 0 (model notes)."""

from __future__ import annotations

import math
from functools import lru_cache

import casadi as ca
import numpy as np

from vine_nlp.model.helix import center_rates
from vine_nlp.model.ops import is_symbolic, lib, safe_series

# Taylor coefficients in x = phi^2 of sin(phi)/phi, (1 - cos phi)/phi^2, (phi - sin phi)/phi^3.
_N_TERMS = 6
_A = [(-1) ** k / math.factorial(2 * k + 1) for k in range(_N_TERMS)]
_B = [(-1) ** k / math.factorial(2 * k + 2) for k in range(_N_TERMS)]
_C = [(-1) ** k / math.factorial(2 * k + 3) for k in range(_N_TERMS)]
# Below this phi^2 the 6-term series is exact to round-off (next term < 1e-17 relative);
# above it the closed forms lose at most ~1e-14 to cancellation.
_X_SWITCH = 0.1


def _exp_coefficients(x):
    L = lib(x)

    def a(x):
        r = L.sqrt(x)
        return L.sin(r) / r

    def b(x):
        return (1 - L.cos(L.sqrt(x))) / x

    def c(x):
        r = L.sqrt(x)
        return (r - L.sin(r)) / (x * r)

    return safe_series(x, a, _A, _X_SWITCH), safe_series(x, b, _B, _X_SWITCH), safe_series(x, c, _C, _X_SWITCH)


def segment_parts(theta, lam, length, D):
    """Entries of T^{j+1}_j as a 3x3 nested list R and a 3-list p (numpy arrays or SX).

    See :func:`twist_parts`; against the paper this is its rotation matrix and its
    position vector with the erratum corrected (y = R (1 - cos(dl/L)), model notes)."""
    kappa_c, tau_c, lambda_c = center_rates(theta, lam, D)
    return twist_parts(kappa_c, tau_c, length * lambda_c)


def twist_parts(kappa_c, tau_c, sigma):
    """exp(sigma xi) for the Frenet twist xi = (v = (1,0,0), omega = (tau_c, 0, kappa_c)).

    With rotation vector sigma * (tau_c, 0, kappa_c) =: (c, 0, a), x = a^2 + c^2 and A, B, C the exp coefficients: R =
    [[1 - B a^2, -A a, B a c], [A a, 1 - B x, -A c], [B a c, A c, 1 - B c^2]], p = sigma (1 - C a^2, B a, C a c).
    Several points of one segment share kappa_c, tau_c: only sigma changes."""
    a = sigma * kappa_c
    c = sigma * tau_c
    x = a * a + c * c
    A, B, C = _exp_coefficients(x)
    R = [
        [1 - B * a * a, -A * a, B * a * c],
        [A * a, 1 - B * x, -A * c],
        [B * a * c, A * c, 1 - B * c * c],
    ]
    p = [sigma * (1 - C * a * a), sigma * B * a, sigma * C * a * c]
    return R, p


def assemble(R, p):
    """4x4 homogeneous transform from nested entries: SX/MX matrix, or numpy (..., 4, 4)."""
    entries = [R[0] + [p[0]], R[1] + [p[1]], R[2] + [p[2]]]
    if is_symbolic(*[e for row in entries for e in row]):
        top = ca.vertcat(*[ca.horzcat(*row) for row in entries])
        return ca.vertcat(top, ca.horzcat(0, 0, 0, 1))
    arrays = np.broadcast_arrays(*[np.asarray(e, dtype=float) for row in entries for e in row])
    shape = arrays[0].shape
    T = np.zeros(shape + (4, 4))
    for k, arr in enumerate(arrays):
        T[..., k // 4, k % 4] = arr
    T[..., 3, 3] = 1.0
    return T


def segment_transform(theta, lam, length, D):
    """T^{j+1}_j of one segment (numpy: vectorized, returns (..., 4, 4); CasADi: 4x4)."""
    return assemble(*segment_parts(theta, lam, length, D))


def segment_point(theta, lam, length, D, u):
    """Center-line point at fraction u of the segment, in the segment's start frame.

    Same as the translation of segment_transform(theta, lam, u * length, D)."""
    _, p = segment_parts(theta, lam, u * length, D)
    return p


def so3_exp(w):
    """Rotation matrix exp([w]x) (Rodrigues), finite with finite derivatives at w = 0.

    numpy: w of shape (3,) -> (3, 3); CasADi: 3-vector -> 3x3 SX/MX."""
    x = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    A, B, _ = _exp_coefficients(x)
    K = [[0 * x, -w[2], w[1]], [w[2], 0 * x, -w[0]], [-w[1], w[0], 0 * x]]
    K2 = [[sum(K[i][k] * K[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    R = [[(1.0 if i == j else 0.0) + A * K[i][j] + B * K2[i][j] for j in range(3)] for i in range(3)]
    if isinstance(w, (ca.SX, ca.MX)) or is_symbolic(*w):
        return ca.vertcat(*[ca.horzcat(*row) for row in R])
    return np.array(R, dtype=float)


@lru_cache(maxsize=8)
def segment_function(n: int) -> ca.Function:
    """One segment as a CasADi SX function of ``n`` points inside it, in units of the tube diameter (D = 1):
    ``(X (12), theta, lam, dl, u (n)) -> (Xn (12), pts (3 x n))``: the frame at the segment's start (rotation
    column-major, then position), the routing parameters and segment length dl (in D), the fractions u of the
    segment where points are wanted; the frame at its end and the center-line points at the fractions. Cached:
    one function per n, shared by every formulation and analysis."""
    X = ca.SX.sym("X", 12)  # rotation column-major (9), then position (3)
    theta, lam, dl = ca.SX.sym("theta"), ca.SX.sym("lam"), ca.SX.sym("dl")
    u = ca.SX.sym("u", n)
    R = ca.reshape(X[:9], 3, 3)
    p = X[9:]
    kappa_c, tau_c, lambda_c = center_rates(theta, lam, 1.0)
    sigma = dl * lambda_c
    Rs, ps = twist_parts(kappa_c, tau_c, sigma)
    Rstep = ca.vertcat(*[ca.horzcat(*row) for row in Rs])
    Xn = ca.vertcat(ca.vec(ca.mtimes(R, Rstep)), p + ca.mtimes(R, ca.vertcat(*ps)))
    pts = []
    for i in range(n):
        # point positions only: the rotation entries of the partial motion are not needed
        _, q = twist_parts(kappa_c, tau_c, u[i] * sigma)
        pts.append(p + ca.mtimes(R, ca.vertcat(*q)))
    return ca.Function("segment", [X, theta, lam, dl, u], [Xn, ca.horzcat(*pts)], ["X", "theta", "lam", "dl", "u"], ["Xn", "pts"])
