"""The model of several actuators on one tube (model.actuators): one actuator is today's chain; a uniform helix
against the closed form; a two-actuator state against single-actuator chains composed by hand."""

from pathlib import Path

import numpy as np
import pytest
from paper_model import paper_segment_transform

from vine_nlp.io.problems import load_problem
from vine_nlp.model import chain_frames, forward_shape, phi_from_theta
from vine_nlp.model.actuators import Lines, TwoLines, actuator_lines, forward_states, owners, roll, state_shape, too_close
from vine_nlp.model.chain import segment_end_samples

PROBLEMS = Path(__file__).resolve().parents[1] / "problems"
FORWARD = [p for p in sorted(PROBLEMS.glob("*.toml")) if load_problem(p).kind == "forward"]


def _one(r, phi0=0.0):
    return Lines(("a",), r.theta[None], r.lam[None], [phi0], r.length, r.initial_pose)


@pytest.mark.parametrize("path", FORWARD, ids=lambda p: p.stem)
def test_one_actuator_is_todays_chain(path):
    r = load_problem(path).problem.routing
    D = load_problem(path).problem.diameter
    for lam in (r.lam, np.where(np.arange(r.segments) % 5 < 2, 1.0, r.lam)):  # as given; with unactuated runs
        rr = type(r)(theta=r.theta, lam=lam, length=r.length, initial_pose=r.initial_pose)
        want = forward_shape(rr, D)
        got = forward_states(_one(rr), D, {"s": ["a"]})["s"]
        scale = np.abs(want.center).max() + D
        for line in ("center", "inner", "outer"):
            assert np.abs(getattr(got, line) - getattr(want, line)).max() <= 1e-12 * scale


def test_one_actuator_rolled_base_is_phi0():
    rng = np.random.default_rng(1)
    M, D = 12, 2.0
    th, lam, length = rng.uniform(-0.5, 0.5, M), np.where(rng.random(M) < 0.5, 1.0, rng.uniform(0.5, 0.9, M)), rng.uniform(0.5, 1.5, M)
    lines = Lines(("a", "b"), [np.zeros(M), th], [np.ones(M), lam], [0.0, 0.7], length)
    seg, frac = segment_end_samples(length, 3)
    got = state_shape(lines, D, ["b"], seg, frac).center
    want = forward_shape(lines.routing(1), D, 3).center
    assert np.abs(got - want).max() < 1e-12
    assert np.allclose(lines.phi(D)[1], 0.7 + phi_from_theta(th, length, D))


def test_uniform_helix_against_closed_form():
    """Segments 3..8 shaped by line b (uniform theta, lambda); lines a (inactive) and b elsewhere unactuated:
    the shaped run is the closed-form helix (paper form) started from the frame rolled to phi_b."""
    M, D, th, lam = 10, 2.4, 0.3, 0.6
    length = np.full(M, 1.5)
    lam_b = np.where((np.arange(M) >= 3) & (np.arange(M) < 9), lam, 1.0)
    lines = Lines(("a", "b"), [np.full(M, 0.2), np.full(M, th)], [np.full(M, 0.5), lam_b], [0.0, 1.1], length)
    seg, frac = np.array([3] * 5), np.linspace(0, 1, 6)[:5]
    got = state_shape(lines, D, ["b"], np.r_[seg, 8], np.r_[frac + 0.0, 1.0]).center
    phi_b = lines.phi(D)[1]
    start = np.eye(4)
    start[0, 3] = 3 * 1.5  # three straight segments, no turn
    start = start @ roll(phi_b[3])
    arcs = np.r_[frac * 1.5, 6 * 1.5]
    want = (start @ paper_segment_transform(th, lam, arcs, D))[:, :3, 3]
    assert np.abs(got - want).max() < 1e-12


def test_two_actuators_composed_by_hand():
    rng = np.random.default_rng(7)
    M, D = 20, 3.0
    length = rng.uniform(0.8, 1.2, M)
    th = rng.uniform(-0.6, 0.6, (2, M))
    lam = np.ones((2, M))
    lam[0, :10] = rng.uniform(0.5, 0.95, 10)
    lam[1, 12:] = rng.uniform(0.5, 0.95, 8)
    lines = Lines(("A", "B"), th, lam, [0.0, 2.0], length, roll(0.3) @ np.diag([1.0, 1, 1, 1]))
    phi = lines.phi(D)
    # by hand: A's chain over 0..9 from the base rolled to phi_A[0]; straight 10, 11; B's chain from 12 rolled to phi_B[12]
    F = chain_frames(th[0, :10], lam[0, :10], length[:10], D, lines.initial_pose @ roll(phi[0, 0]))
    G = F[-1] @ roll(-phi[0, 10])
    G[:3, 3] += G[:3, 0] * (length[10] + length[11])
    H = chain_frames(th[1, 12:], lam[1, 12:], length[12:], D, G @ roll(phi[1, 12]))
    want = np.r_[F[:, :3, 3], H[:, :3, 3]]
    ends = state_shape(lines, D, ["A", "B"], np.r_[np.arange(M), M - 1], np.r_[np.zeros(M), 1.0]).center
    got = np.r_[ends[:11], ends[12:]]
    assert np.abs(got - want).max() < 1e-12
    # state {A}: B's actuation ignored; {B} alone equals B's one-actuator routing
    assert np.abs(state_shape(lines, D, ["B"], np.arange(M), np.zeros(M)).center
                  - forward_shape(lines.routing(1), D, 1).center[:M]).max() < 1e-12


def test_two_active_lines_on_one_segment_refused():
    M = 4
    lines = Lines(("A", "B", "C"), np.zeros((3, M)), [[1, 0.8, 1, 1], [1, 0.7, 0.9, 1], [0.5, 1, 1, 1]], [0, 0, 0], np.ones(M))
    assert list(owners(lines, ["A", "C"])) == [2, 0, -1, -1]
    with pytest.raises(TwoLines, match=r"state 'both': segment 2 has 2 active lines \(A, B\); the model allows one per segment"):
        owners(lines, ["A", "B"], "both")


def test_widths_apart():
    M, D = 3, 2.0
    lines = Lines(("A", "B"), np.zeros((2, M)), [[0.8, 0.8, 1.0], [0.8, 1.0, 0.7]], [0.0, 0.5], np.ones(M))
    # 0.5 rad apart = 0.5 length units around the circumference (D/2 = 1)
    assert too_close(lines, D, [0.4, 0.4]) == []
    assert too_close(lines, D, [0.6, 0.6]) == [(0, 0, 1)]


def test_actuator_lines_are_on_the_tube_and_the_shaping_line_is_inner():
    rng = np.random.default_rng(3)
    M, D = 10, 2.0
    lam = np.ones((2, M))
    lam[0, :5], lam[1, 6:] = 0.7, 0.8
    lines = Lines(("A", "B"), rng.uniform(-0.4, 0.4, (2, M)), lam, [0.0, 2.0], np.ones(M))
    seg, frac = segment_end_samples(lines.length, 4)
    shape = state_shape(lines, D, ["A", "B"], seg, frac)
    got = actuator_lines(lines, D, ["A", "B"], seg, frac)
    for pts in got.values():  # D/2 from the center line
        assert np.allclose(np.linalg.norm(pts - shape.center, axis=1), D / 2)
    shaped_by = np.where(seg < 5, "A", np.where(seg >= 6, "B", "A"))  # segment 5: none shapes it; A is the state's first
    for name in ("A", "B"):
        assert np.allclose(got[name][shaped_by == name], shape.inner[shaped_by == name], atol=1e-12)
