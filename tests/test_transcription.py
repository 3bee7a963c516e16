"""The one transcription: its hand-assembled derivatives equal CasADi's automatic ones for every formulation."""

import casadi as ca
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vine_nlp.methods.clearance import ClearancePairs
from vine_nlp.methods.drive import pick_best
from vine_nlp.methods.multishape import multishape_spec
from vine_nlp.methods.nlp import nlp_spec
from vine_nlp.methods.robust import RobustTerm
from vine_nlp.methods.structure import Structure
from vine_nlp.methods.tip import tip_spec
from vine_nlp.methods.transcription import Solver, Spec
from vine_nlp.model.routing import Routing


def _automatic(solver):
    """CasADi's own MX Jacobian of g and Hessian of the Lagrangian of a solver's f and g."""
    nx, npar, ng = solver.layout.size, solver.nlpsol.size_in("p")[0], solver.nlpsol.size_out("g")[0]
    x, p, sigma, lam_g = ca.MX.sym("x", nx), ca.MX.sym("p", npar), ca.MX.sym("s"), ca.MX.sym("l", ng)
    q = solver.problem
    f, g = ca.Function("nlp", [q["x"], q["p"]], [q["f"], q["g"]])(x, p)
    H = ca.triu(ca.hessian(sigma * f + ca.dot(lam_g, g), x)[0])
    return ca.Function("auto", [x, p, sigma, lam_g], [ca.jacobian(g, x), H])


def _with(spec, **structure):
    import dataclasses

    return dataclasses.replace(spec, structure=dataclasses.replace(spec.structure, **structure))


SPECS = {
    "nlp M=1": nlp_spec(1, 3, False),
    "nlp M=2 shared": nlp_spec(2, 3, True),
    "nlp M=6": nlp_spec(6, 3, False),
    "multishape shared pose": multishape_spec(4, 2, 3, True),
    "multishape pose per level": multishape_spec(3, 2, 2, False),
    "tip": tip_spec(5, False, True, "turns"),
    "tip closest": tip_spec(4, True, True, "contraction", closest=True),
    "clearance": _with(nlp_spec(6, 2, False, terms=(ClearancePairs(((0, 4), (1, 5))),)), extra=0),
    # rows of one segment pair share a block (pair_block(k)): two groups of different sizes, interleaved
    "clearance grouped": _with(nlp_spec(6, 2, False, terms=(ClearancePairs(((0, 4), (1, 5), (0, 4), (2, 5), (0, 4))),)), extra=0),
    "robust": _with(nlp_spec(5, 2, False, terms=(RobustTerm(),)), extra=9),
}


@pytest.mark.parametrize("name", list(SPECS))
def test_separable_derivatives_equal_casadi_automatic_ones(name):
    s = Solver(SPECS[name])
    rng = np.random.default_rng(len(name))
    nx, npar, ng = s.layout.size, s.nlpsol.size_in("p")[0], s.nlpsol.size_out("g")[0]
    x, p, lam_g = rng.normal(size=nx) * 0.5, rng.uniform(0.1, 1.0, npar), rng.normal(size=ng)
    if "R0g" in s._param_shapes:  # the guess rotations must be rotations
        sl = s.param_slice("R0g")
        p[sl] = np.concatenate([Rotation.random(random_state=k).as_matrix().ravel(order="F") for k in range((sl.stop - sl.start) // 9)])
    J_auto, H_auto = (np.array(v) for v in _automatic(s)(x, p, 0.7, lam_g))
    J = np.array(s.nlpsol.get_function("nlp_jac_g")(x, p)[1])
    H = np.array(s.nlpsol.get_function("nlp_hess_l")(x, p, 0.7, lam_g))
    np.testing.assert_allclose(J, J_auto, atol=1e-12 * np.abs(J_auto).max())
    np.testing.assert_allclose(H, H_auto, atol=1e-11 * np.abs(H_auto).max())
    assert np.abs(H).max() > 1.0  # a real curvature, not two zero matrices


def test_layout_is_in_stage_order_and_fixes_what_it_should():
    s = Solver(Spec(Structure(3, 2, 2, "level", "fixed", extra=1)))
    lay = s.layout
    # every variable has one place; stage j's variables come after stage j-1's
    assert lay.size == 2 + 12 * 2 + 3 * (1 + 1 + 1 + 12 * 2)
    assert np.all(np.diff(lay.theta) > 0) and np.all(lay.X[1:, :, 0].min(axis=1) > lay.theta)
    X0 = np.arange(24.0).reshape(2, 12)
    lbx, ubx = s.bounds(X0=X0, theta=(-1, 1), lam=(np.array([0.5, 0.6]), np.array([1.0, 0.6])), length=(0.1, 2))
    np.testing.assert_array_equal(lbx[lay.X[0].ravel()], X0.ravel())
    np.testing.assert_array_equal(ubx[lay.X[0].ravel()], X0.ravel())
    assert lbx[lay.lam_global[1]] == ubx[lay.lam_global[1]] == 0.6


class _R:
    def __init__(self, objective, converged=True):
        self.objective, self.converged = objective, converged


def test_one_tie_rule_picks_the_first_of_equal_objectives():
    assert pick_best([_R(2.0), _R(1.0), _R(1.0 * (1 + 1e-9))]) == 1
    assert pick_best([_R(1.0 + 1e-9), _R(1.0)]) == 0  # within the tie tolerance: the earlier start
    assert pick_best([_R(0.5, converged=False), _R(3.0)]) == 1  # converged first


def test_a_declared_variable_gets_its_place_bounds_and_round_trip():
    """One more per-segment variable is one declaration: the layout, packing, unpacking and bounds follow from it."""
    from vine_nlp.methods.variables import ROUTING, Var, box, slots

    phi0 = Var("phi0", lambda a, ref: (-1.0, 2.0), size=2)
    s = Solver(Spec(Structure(3, 1, variables=ROUTING + (phi0,))))
    lay = s.layout
    assert lay.size == 6 + 12 + 3 * (3 + 2 + 12)
    assert lay.var["phi0"].shape == (3, 2) and np.all(lay.var["phi0"][:, 0] == lay.dl + 1)  # after the routing's, stage by stage
    assert slots(s.structure.variables).size == 5
    rng = np.random.default_rng(0)
    values = {"theta": rng.normal(size=3), "lam": rng.uniform(0.5, 1, 3), "length": rng.uniform(1, 2, 3), "phi0": rng.normal(size=(3, 2))}
    v = s.unpack(s.pack_x(rng.normal(size=(1, 12, 4)), **values))
    for name, val in values.items():
        np.testing.assert_array_equal(v[name].reshape(np.shape(val)), val)
    a = type("A", (), {"theta_max": 0.5, "lambda_min": 0.4})()
    lbx, ubx = s.bounds(**box(a, np.ones(3), s.structure.variables))
    assert np.all(lbx[lay.var["phi0"]] == -1.0) and np.all(ubx[lay.var["phi0"]] == 2.0)
    assert np.all(lbx[lay.theta] == -0.5) and np.all(ubx[lay.dl] == 5.0)


def test_a_routing_is_built_by_name_only():
    with pytest.raises(TypeError):
        Routing(np.zeros(2), np.ones(2), np.ones(2))  # the positional form is refused
    r = Routing(theta=np.zeros(2), lam=0.5, length=np.ones(2))
    assert r.lam.tolist() == [0.5, 0.5] and r.segments == 2
