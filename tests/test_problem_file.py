"""Problem, sweep and fit files (spec/formats.md) -> typed problems, and their error messages."""

from __future__ import annotations

import math
import textwrap

import numpy as np
import pytest
from conftest import mutate
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vine_nlp import targets
from vine_nlp.errors import InputError
from vine_nlp.io.problem_file import (
    apply_override,
    load_problem,
    load_sweep,
    parse_problem,
)
from vine_nlp.problem import Actuator, DesignOptions, DesignProblem, FitProblem, ForwardProblem, Routing

TUBE = "[tube]\ndiameter = 2.0\n"


def write(directory, name, text):
    path = directory / name
    path.write_text(textwrap.dedent(text))
    return path


def forward(tmp_path, routing):
    return load_problem(write(tmp_path, "fwd.toml", TUBE + "[routing]\n" + textwrap.dedent(routing)))


# ------------------------------------------------------------------ forward problems


def test_forward_number_form(tmp_path):
    pf = forward(tmp_path, "length = 5.0\nsegment_length = 1.0\ntheta = 0.1\nlambda = 0.8\n")
    assert pf.kind == "forward" and pf.name == "fwd" and pf.units == "cm"
    assert isinstance(pf.problem, ForwardProblem) and pf.problem.diameter == 2.0
    r = pf.problem.routing
    assert r.segments == 5
    np.testing.assert_array_equal(r.theta, 0.1)
    np.testing.assert_array_equal(r.lam, 0.8)
    np.testing.assert_array_equal(r.length, 1.0)
    np.testing.assert_array_equal(r.initial_pose, np.eye(4))
    assert "theta = 0.1" in pf.source


def test_forward_array_form(tmp_path):
    r = forward(tmp_path, "length = 3\nsegment_length = 1\ntheta = [0.1, -0.2, 0.3]\nlambda = [1, 0.9, 0.5]\n").problem.routing
    np.testing.assert_array_equal(r.theta, [0.1, -0.2, 0.3])
    np.testing.assert_array_equal(r.lam, [1, 0.9, 0.5])


def test_forward_expression_form_is_taken_at_segment_starts(tmp_path):
    r = forward(
        tmp_path,
        'length = 100.0\nsegment_length = 1.0\ntheta = "pi/12 * sin(0.1 * s)"\nlambda = "0.9 - 0.001 * s"\n',
    ).problem.routing
    s = np.arange(100.0)
    np.testing.assert_allclose(r.theta, np.pi / 12 * np.sin(0.1 * s), atol=1e-15)
    np.testing.assert_allclose(r.lam, 0.9 - 0.001 * s, atol=1e-15)


def test_forward_phi_form_inverts_eq_phi(tmp_path):
    r = forward(tmp_path, 'length = 4\nsegment_length = 1\nphi = "0.5 * s**2"\nlambda = 1\n').problem.routing
    ends = np.arange(5.0)
    dphi = np.diff(0.5 * ends**2)
    np.testing.assert_allclose(r.theta, np.arctan((2.0 / 2) * dphi / 1.0))
    # and eq. (phi(s_j)) gives phi back from theta
    np.testing.assert_allclose(np.cumsum((2 / 2.0) * np.tan(r.theta) * r.length), 0.5 * ends[1:] ** 2)


@pytest.mark.parametrize("value, expected", [("4.0", [4.0] * 3), ("[1, 2, -3]", [1, 2, -3])])
def test_forward_theta_deg_form(tmp_path, value, expected):
    r = forward(tmp_path, f"length = 3\nsegment_length = 1\ntheta_deg = {value}\nlambda = 0.9\n").problem.routing
    np.testing.assert_allclose(r.theta, np.radians(expected))


def test_forward_last_segment_is_shorter_when_the_length_does_not_divide(tmp_path):
    r = forward(tmp_path, "length = 10.5\nsegment_length = 1.0\ntheta = 0\nlambda = 1\n").problem.routing
    assert r.segments == 11 and r.length[-1] == pytest.approx(0.5) and r.length.sum() == pytest.approx(10.5)
    r = forward(tmp_path, "length = 0.3\nsegment_length = 0.1\ntheta = 0\nlambda = 1\n").problem.routing
    assert r.segments == 3  # 0.3 / 0.1 = 2.9999999999999996 must not give 4 segments


def test_forward_per_segment_lengths_are_the_chain_of_that_routing(tmp_path):
    # issue 46: a built routing of unequal segments written down; the same shape as the Routing of those lengths
    from vine_nlp.model.shape import forward_shape

    pf = forward(tmp_path, "segment_length = [20.0, 25.0, 15.0]\ntheta_deg = [10.0, -20.0, 5.0]\nlambda = [0.8, 1.0, 0.6]\n")
    r = pf.problem.routing
    np.testing.assert_array_equal(r.length, [20.0, 25.0, 15.0])
    np.testing.assert_array_equal(r.theta, np.radians([10.0, -20.0, 5.0]))
    built = Routing(theta=np.radians([10.0, -20.0, 5.0]), lam=np.array([0.8, 1.0, 0.6]), length=np.array([20.0, 25.0, 15.0]))
    np.testing.assert_array_equal(forward_shape(r, 2.0).center, forward_shape(built, 2.0).center)
    # length, if given, is their sum; expressions are taken at the segment starts 0, 20, 45
    r = forward(tmp_path, "length = 60.0\nsegment_length = [20.0, 25.0, 15.0]\ntheta = '0.001 * s'\nlambda = 1\n").problem.routing
    np.testing.assert_allclose(r.theta, [0.0, 0.02, 0.045], rtol=0, atol=1e-15)


def test_one_routing_check_names_the_readers_key():
    # problem files, the API and archives check a routing with io.validate.validate_routing; each names its own keys
    from vine_nlp.io.h5read import ArchiveError
    from vine_nlp.io.validate import SourceFile, validate_routing

    keys = {k: f"/runs/nlp/design/{k}" for k in ("theta", "lam", "length", "initial_pose")}
    with pytest.raises(ArchiveError) as e:
        validate_routing(SourceFile("a.h5", ArchiveError), np.zeros(3), np.array([1.0, 0.0, 1.0]), np.ones(3), np.eye(4), keys)
    assert str(e.value) == "a.h5: /runs/nlp/design/lam: must be in (0, 1] (segment 2: 0)"
    with pytest.raises(InputError, match=r"^p.toml: theta: needs 3 values \(one per segment\), got 2$"):
        validate_routing(SourceFile("p.toml"), np.zeros(2), 1.0, np.ones(3))
    r = validate_routing(SourceFile("p.toml"), 0.1, np.array([0.5, 1.0]), 2.0)  # numbers repeat over the segments
    np.testing.assert_array_equal(r.theta, [0.1, 0.1]) and np.testing.assert_array_equal(r.length, [2.0, 2.0])


def test_forward_initial_pose(tmp_path):
    pose = [[0, -1, 0, 1.5], [1, 0, 0, 0], [0, 0, 1, -2], [0, 0, 0, 1]]
    r = forward(tmp_path, f"length = 2\nsegment_length = 1\ntheta = 0\nlambda = 1\ninitial_pose = {pose}\n").problem.routing
    np.testing.assert_array_equal(r.initial_pose, pose)


# ------------------------------------------------------------------ design problems


def design(tmp_path, target, rest=""):
    return load_problem(write(tmp_path, "design.toml", TUBE + "[target]\n" + textwrap.dedent(target) + textwrap.dedent(rest)))


def test_design_trefoil_defaults(tmp_path):
    pf = design(tmp_path, 'curve = "trefoil"\n')
    p = pf.problem
    assert pf.kind == "design" and isinstance(p, DesignProblem)
    np.testing.assert_allclose(p.target, targets.trefoil())
    assert p.actuator == Actuator() and p.options == DesignOptions()


def test_design_trefoil_keys(tmp_path):
    p = design(tmp_path, 'curve = "trefoil"\nscale = [2, 3, 4]\nt_range = [0.0, 3.0]\nsamples = 50\n').problem
    np.testing.assert_allclose(p.target, targets.trefoil((2, 3, 4), (0.0, 3.0), 50))


@pytest.mark.parametrize(
    "control", [[[0, 0, 0], [76, 0, 0], [-4, 19, 42], [34, -52, 13], [16, 19, 48]], [[0, 0], [50, 0], [24, -24], [0, -50], [50, -50]]]
)
def test_design_bezier(tmp_path, control):
    p = design(tmp_path, f'curve = "bezier"\ncontrol_points = {control}\n').problem
    np.testing.assert_allclose(p.target, targets.bezier(control, 400))


def test_design_polyline(tmp_path):
    control = [[0, 0, 0], [54, 0, 0], [61, -50, 18], [8, -60, 18], [33, 0, 30], [13, -10, 6]]
    p = design(tmp_path, f'curve = "polyline"\ncontrol_points = {control}\nsamples = 200\n').problem
    np.testing.assert_allclose(p.target, targets.polyline(control, 200))


def test_design_helix(tmp_path):
    p = design(tmp_path, 'curve = "helix"\nradius = 3.0\npitch = 1.2\nlength = 60.0\nsamples = 100\n').problem
    np.testing.assert_allclose(p.target, targets.helix(3.0, 1.2, 60.0, 100))


FOUR_POINTS = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [2, 1, 0.5]]


@pytest.mark.parametrize(
    "name, content, expected",
    [
        ("pts.csv", "x,y,z\n0,0,0\n1, 0, 0\n1,1,0\n\n# comment\n2,1,0.5\n", FOUR_POINTS),
        ("pts.csv", "0 0 0\n1\t0 0\n1 1 0\n2 1 0.5\n", FOUR_POINTS),
        ("pts.csv", "x y\n0 0\n1 0\n1 1\n2 1\n", [[0, 0, 0], [1, 0, 0], [1, 1, 0], [2, 1, 0]]),
        ("pts.npy", np.array(FOUR_POINTS), FOUR_POINTS),
    ],
)
def test_design_points_file(tmp_path, name, content, expected):
    (tmp_path / "data").mkdir()
    if isinstance(content, str):
        (tmp_path / "data" / name).write_text(content)
    else:
        np.save(tmp_path / "data" / name, content)
    p = design(tmp_path, f'curve = "points"\nfile = "data/{name}"\n', "[design]\npoints_per_segment = 3\n").problem
    np.testing.assert_allclose(p.target, expected)


def test_design_actuator_and_options(tmp_path):
    text = 'name = "trefoil-m4"\nunits = "mm"\n' + TUBE + """
    [target]
    curve = "trefoil"
    [actuator]
    kind = "spam"
    theta_max_deg = 45
    [design]
    method = "greedy"
    points_per_segment = 8
    lookahead = 3
    starts = 4
    hops = 5
    greedy_starts = 2
    seed = 7
    max_iter = 100
    tol = 1e-6
    [design.smoothness]
    theta = 0.5
    lambda = 0
    """
    pf = load_problem(write(tmp_path, "d.toml", text))
    p = pf.problem
    assert pf.name == p.name == "trefoil-m4" and pf.units == p.units == "mm"
    assert p.actuator == Actuator(kind="spam", lambda_min=0.5, theta_max=math.radians(45))  # sPAM default lambda_min
    assert p.options == DesignOptions(
        method="greedy", points_per_segment=8, lookahead=3, starts=4, hops=5, greedy_starts=2, seed=7,
        max_iter=100, tol=1e-6, smooth_theta=0.5, smooth_lambda=0.0,
    )


def test_fit_problem(tmp_path):
    (tmp_path / "frame12.csv").write_text("3 1 2\n0 0 0\n3 1 2\n5 5 5\n")  # any order, repeats allowed
    text = TUBE + """
    [measured]
    file = "frame12.csv"
    line = "outer"
    [routing]
    length = 60.0
    segment_length = 1.0
    theta_deg = 4.0
    lambda = 0.9
    [fit]
    free = ["lambda"]
    """
    pf = load_problem(write(tmp_path, "fit.toml", text))
    p = pf.problem
    assert pf.kind == "fit" and isinstance(p, FitProblem)
    assert p.line == "outer" and p.free == ("lambda",) and p.measured.shape == (4, 3)
    assert p.routing.segments == 60 and np.allclose(p.routing.theta, np.radians(4))


# ------------------------------------------------------------------ bad files

FWD = TUBE + "[routing]\nlength = 5\nsegment_length = 1\n"
FWD_LENGTHS = TUBE + "[routing]\nsegment_length = {}\n"
SEG = FWD_LENGTHS.format("[20.0, 25.0, 15.0]")
TREFOIL = TUBE + '[target]\ncurve = "trefoil"\n'
POINTS = TUBE + '[target]\ncurve = "points"\nfile = "t.csv"\n'
GOOD_CSV = "0 0 0\n1 0 0\n2 1 0\n3 1 1\n"

# (id, problem text, data files, file named in the error ("" = the problem file), "key: reason")
BAD = [
    ("syntax", TUBE.replace("2.0", ""), {}, "", "line 2: invalid TOML: Invalid value"),
    ("syntax-table", "name = 'a'\n[tube\n", {}, "", "line 2: invalid TOML: Expected ']' at the end of a table declaration"),
    ("unclosed-array", TUBE.replace("2.0", "[2.0") + "\n\n", {}, "", "line 2: invalid TOML: Unclosed array"),
    ("unknown-key", "[tube]\ndiamter = 2.0\n[routing]\n", {}, "", "tube.diamter: unknown key; did you mean 'diameter'?"),
    ("unknown-top", TREFOIL + "[actuatr]\nkind = 'tendon'\n", {}, "", "actuatr: unknown key; did you mean 'actuator'?"),
    ("unknown-no-match", TREFOIL + "[design]\nzzz = 1\n", {}, "", "design.zzz: unknown key"),
    ("wrong-kind-table", FWD + "theta = 0\nlambda = 1\n[actuator]\nkind = 'tendon'\n", {}, "", "actuator: not used in a forward problem"),
    ("no-kind", TUBE, {}, "", "target: missing: a problem needs [target] (design), [routing] (forward) or [measured] (fit)"),
    ("no-tube", '[target]\ncurve = "trefoil"\n', {}, "", "tube: missing table"),
    ("negative-diameter", TREFOIL.replace("2.0", "-1.0"), {}, "", "tube.diameter: must be > 0"),
    ("nan-diameter", TREFOIL.replace("2.0", "nan"), {}, "", "tube.diameter: must be finite"),
    ("string-diameter", TREFOIL.replace("2.0", "'2'"), {}, "", "tube.diameter: must be a number"),
    ("lambda-min", TREFOIL + "[actuator]\nlambda_min = 1.5\n", {}, "", "actuator.lambda_min: must be in (0, 1]"),
    ("theta-max", TREFOIL + "[actuator]\ntheta_max_deg = 95\n", {}, "", "actuator.theta_max_deg: must be in (0, 90)"),
    ("kind", TREFOIL + "[actuator]\nkind = 'tendom'\n", {}, "", "actuator.kind: must be one of 'tendon', 'programmed', 'spam'; did you mean 'tendon'?"),
    ("curve", TUBE + "[target]\ncurve = 'trefol'\n", {}, "", "target.curve: must be one of 'trefoil', 'bezier', 'polyline', 'helix', 'points'; did you mean 'trefoil'?"),
    ("curve-key", TREFOIL + "control_points = [[0, 0], [1, 1]]\n", {}, "", "target.control_points: not used by curve 'trefoil'"),
    ("scale-length", TREFOIL + "scale = [1, 2]\n", {}, "", "target.scale: must be a list of 3 numbers"),
    ("scale-inf", TREFOIL + "scale = [1, 2, inf]\n", {}, "", "target.scale: must be finite (entry 3)"),
    ("scale-zero", TREFOIL + "scale = [0, 0, 0]\n", {}, "", "target.scale: points 1 and 2 are identical"),
    ("t-range", TREFOIL + "t_range = [1, 0]\n", {}, "", "target.t_range: must be [start, end] with start < end"),
    ("samples", TREFOIL + "samples = 2\n", {}, "", "target.samples: must be an integer >= 3"),
    ("samples-float", TREFOIL + "samples = 10.5\n", {}, "", "target.samples: must be an integer >= 3"),
    ("too-few-points", TREFOIL + "samples = 5\n", {}, "", "target.samples: needs at least points_per_segment + 1 = 11 points, got 5"),
    ("too-few-file-points", POINTS, {"t.csv": GOOD_CSV}, "", "target.file: needs at least points_per_segment + 1 = 11 points, got 4"),
    ("bezier-missing", TUBE + "[target]\ncurve = 'bezier'\n", {}, "", "target.control_points: missing (required)"),
    ("bezier-mixed", TUBE + "[target]\ncurve = 'bezier'\ncontrol_points = [[0, 0], [1, 1, 1]]\n", {}, "", "target.control_points: points must all have 3 coordinates (or all 2)"),
    ("helix-flat", TUBE + "[target]\ncurve = 'helix'\nradius = 0\npitch = 0\nlength = 3\n", {}, "", "target.radius: radius and pitch cannot both be 0"),
    ("points-per-segment", TREFOIL + "[design]\npoints_per_segment = 0\n", {}, "", "design.points_per_segment: must be an integer >= 1"),
    ("lookahead-bool", TREFOIL + "[design]\nlookahead = true\n", {}, "", "design.lookahead: must be an integer >= 1"),
    ("hops", TREFOIL + "[design]\nhops = -1\n", {}, "", "design.hops: must be an integer >= 0"),
    ("smoothness", TREFOIL + "[design.smoothness]\ntheta = -1e-3\n", {}, "", "design.smoothness.theta: must be >= 0"),
    ("smoothness-key", TREFOIL + "[design.smoothness]\nlamda = 1e-3\n", {}, "", "design.smoothness.lamda: unknown key; did you mean 'lambda'?"),
    ("method", TREFOIL + "[design]\nmethod = 'ipopt'\n", {}, "", "design.method: must be one of 'nlp', 'greedy'"),
    ("theta-and-phi", FWD + "theta = 0.1\nphi = 's'\nlambda = 1\n", {}, "", "routing.phi: conflicts with routing.theta (give only one of theta, theta_deg, phi)"),
    ("no-theta", FWD + "lambda = 1\n", {}, "", "routing.theta: missing (give one of theta, theta_deg, phi)"),
    ("no-lambda", FWD + "theta = 0\n", {}, "", "routing.lambda: missing (required)"),
    ("wrong-length", FWD + "theta = [0.1, 0.2, 0.3]\nlambda = 1\n", {}, "", "routing.theta: needs 5 values (one per segment), got 3"),
    ("phi-length", FWD + "phi = [0, 1, 2, 3, 4]\nlambda = 1\n", {}, "", "routing.phi: needs 6 values (one per segment end), got 5"),
    ("lambda-above-1", FWD + "theta = 0\nlambda = 1.2\n", {}, "", "routing.lambda: must be in (0, 1]"),
    ("lambda-array", FWD + "theta = 0\nlambda = [1, 1, 0.5, 0, 1]\n", {}, "", "routing.lambda: must be in (0, 1] (segment 4: 0)"),
    ("theta-90", FWD + "theta_deg = 90\nlambda = 1\n", {}, "", "routing.theta_deg: |theta| must be < 90 deg"),
    ("theta-expression-big", FWD + "theta = 's'\nlambda = 1\n", {}, "", "routing.theta: |theta| must be < 90 deg (segment 3: 114.592 deg)"),
    ("bad-expression", FWD + "theta = 'x * s'\nlambda = 1\n", {}, "", "routing.theta: name 'x' is not allowed (use s, pi, e, sin, cos, tan, exp, log, sqrt, abs)"),
    ("unsafe-expression", FWD + "theta = '__import__(\"os\")'\nlambda = 1\n", {}, "", "routing.theta: function '__import__' is not allowed (use sin, cos, tan, exp, log, sqrt, abs)"),
    ("expression-not-finite", FWD + "theta = 'log(s)'\nlambda = 1\n", {}, "", "routing.theta: expression is not finite at s = 0"),
    ("theta-type", FWD + "theta = true\nlambda = 1\n", {}, "", "routing.theta: must be a number, an array or an expression of s"),
    ("segment-length", TUBE + "[routing]\nlength = 5\nsegment_length = 6\ntheta = 0\nlambda = 1\n", {}, "", "routing.segment_length: must be <= routing.length"),
    ("too-many-segments", TUBE + "[routing]\nlength = 1e9\nsegment_length = 1\ntheta = 0\nlambda = 1\n", {}, "", "routing.segment_length: gives more than 100000 segments"),
    ("pose-mirror", FWD + "theta = 0\nlambda = 1\ninitial_pose = [[1,0,0,0],[0,1,0,0],[0,0,-1,0],[0,0,0,1]]\n", {}, "", "routing.initial_pose: rotation part has det -1 (a mirror, not a rotation)"),
    ("pose-scaled", FWD + "theta = 0\nlambda = 1\ninitial_pose = [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]\n", {}, "", "routing.initial_pose: rotation part (first 3 rows and columns) is not orthonormal"),
    ("pose-last-row", FWD + "theta = 0\nlambda = 1\ninitial_pose = [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,1,1]]\n", {}, "", "routing.initial_pose: last row must be [0, 0, 0, 1]"),
    ("pose-shape", FWD + "theta = 0\nlambda = 1\ninitial_pose = [[1,0,0],[0,1,0],[0,0,1]]\n", {}, "", "routing.initial_pose: must be a 4 x 4 array (4 rows of 4 numbers)"),
    ("missing-data-file", POINTS, {}, "", "target.file: no such file: {dir}/t.csv"),
    ("data-file-type", POINTS.replace("t.csv", "t.txt"), {"t.txt": GOOD_CSV}, "", "target.file: unsupported file type '.txt' (use .csv or .npy)"),
    ("nan-in-csv", POINTS, {"t.csv": "x,y,z\n0,0,0\nnan,1,0\n"}, "t.csv", "line 3: 'nan' is not finite"),
    ("word-in-csv", POINTS, {"t.csv": "0,0,0\n1,a,0\n"}, "t.csv", "line 2: 'a' is not a number"),
    ("second-header", POINTS, {"t.csv": "x,y,z\nu,v,w\n"}, "t.csv", "line 2: 'u' is not a number"),
    ("columns-in-csv", POINTS, {"t.csv": "0,0,0\n1,0\n"}, "t.csv", "line 2: expected 3 values like the first row, got 2"),
    ("four-columns", POINTS, {"t.csv": "0 0 0 0\n"}, "t.csv", "line 1: expected 3 values (x y z) or 2 (x y), got 4"),
    ("empty-csv", POINTS, {"t.csv": "x,y,z\n\n"}, "t.csv", "values: no data rows"),
    ("repeated-points", POINTS, {"t.csv": "0,0,0\n1,0,0\n1,0,0\n2,0,0\n"}, "t.csv", "values: points 2 and 3 are identical"),
    ("two-points", POINTS, {"t.csv": "0,0,0\n1,0,0\n"}, "t.csv", "values: needs at least 3 points, got 2"),
    ("npy-shape", POINTS.replace("t.csv", "t.npy"), {"t.npy": np.zeros((4, 5))}, "t.npy", "values: must be an N x 3 (or N x 2) array, N <= 100000 (vine_nlp.io.limits.MAX_TARGET_POINTS), got shape (4, 5)"),
    ("npy-garbage", POINTS.replace("t.csv", "t.npy"), {"t.npy": "not an npy file"}, "t.npy", "values: not a readable .npy array file"),
    ("npy-objects", POINTS.replace("t.csv", "t.npy"), {"t.npy": np.array([[1, "a", None]] * 3, dtype=object)}, "t.npy", "values: must hold an array of real numbers"),
    ("fit-free", TUBE + "[measured]\nfile = 'm.csv'\nline = 'outer'\n" + FWD.replace(TUBE, "") + "theta = 0\nlambda = 1\n[fit]\nfree = ['mu']\n", {"m.csv": GOOD_CSV}, "", "fit.free: must be one of 'lambda'"),
    ("fit-line", TUBE + "[measured]\nfile = 'm.csv'\nline = 'middle'\n", {"m.csv": GOOD_CSV}, "", "measured.line: must be one of 'center', 'inner', 'outer'"),
    ("target-and-measured", TREFOIL + "[measured]\nfile = 'm.csv'\n", {}, "", "target: a problem has [target] (design) or [measured] (fit), not both"),
    ("units", 'units = ""\n' + TREFOIL, {}, "", "units: must be a non-empty string"),
    # per-segment lengths (issue 46): one line naming the key
    ("lengths-count", SEG + "theta = [0.1, 0.2]\nlambda = 1\n", {}, "", "routing.theta: needs 3 values (one per segment), got 2"),
    ("lengths-lambda-count", SEG + "theta = 0\nlambda = [1, 1, 1, 1]\n", {}, "", "routing.lambda: needs 3 values (one per segment), got 4"),
    ("lengths-phi-count", SEG + "phi = [0, 1, 2]\nlambda = 1\n", {}, "", "routing.phi: needs 4 values (one per segment end), got 3"),
    ("lengths-sum", SEG + "length = 50\ntheta = 0\nlambda = 1\n", {}, "", "routing.length: must be the sum of routing.segment_length (60), got 50"),
    ("lengths-negative", FWD_LENGTHS.format("[20.0, -1.0, 15.0]") + "theta = 0\nlambda = 1\n", {}, "", "routing.segment_length: must be > 0 (segment 2: -1)"),
    ("lengths-empty", FWD_LENGTHS.format("[]") + "theta = 0\nlambda = 1\n", {}, "", "routing.segment_length: needs 1 to 100000 values (one per segment)"),
    ("lengths-text", FWD_LENGTHS.format("[1.0, 'a']") + "theta = 0\nlambda = 1\n", {}, "", "routing.segment_length: must be a list of numbers"),
]


@pytest.mark.parametrize("text, files, error_file, expected", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_files_give_one_exact_line(tmp_path, text, files, error_file, expected):
    for name, content in files.items():
        if isinstance(content, str):
            (tmp_path / name).write_text(content)
        else:
            np.save(tmp_path / name, content)
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        load_problem(path)
    shown = tmp_path / error_file if error_file else path
    assert str(info.value) == f"{shown}: {expected.format(dir=tmp_path)}"


def test_bad_file_ids_are_distinct():
    assert len({b[0] for b in BAD}) == len(BAD) >= 15


def test_missing_problem_file(tmp_path):
    with pytest.raises(InputError) as info:
        load_problem(tmp_path / "nope.toml")
    assert str(info.value) == f"{tmp_path / 'nope.toml'}: file: no such file"


def test_parse_problem_accepts_a_parsed_dict(tmp_path):
    data = {"tube": {"diameter": 2.43}, "target": {"curve": "helix", "radius": 3, "pitch": 1, "length": 30}}
    pf = parse_problem(data, str(tmp_path / "x.toml"), "")
    assert pf.kind == "design" and pf.name == "x" and pf.problem.target.shape == (400, 3)


# ------------------------------------------------------------------ sweeps

BASE = TUBE + '[target]\ncurve = "trefoil"\nscale = [4.0, 4.0, 4.0]\nsamples = 40\n'


def test_sweep_items_are_the_cartesian_product(tmp_path):
    write(tmp_path, "trefoil.toml", BASE)
    sweep_text = """
    name = "tre"
    base = "trefoil.toml"
    methods = ["nlp", "greedy"]
    [grid]
    "target.scale.0" = [2, 3]
    target.scale.1 = [5, 6, 7]
    "design.lookahead" = [2]
    """
    sweep = load_sweep(write(tmp_path, "sweep.toml", sweep_text))
    assert sweep.name == "tre" and sweep.methods == ["nlp", "greedy"]
    assert list(sweep.grid) == ["target.scale.0", "target.scale.1", "design.lookahead"]
    items = sweep.items()
    assert [i[0] for i in items] == [f"tre-{k:04d}" for k in range(6)]
    name, overrides, pf = items[4]
    assert overrides == {"target.scale.0": 3, "target.scale.1": 6, "design.lookahead": 2}
    assert pf.name == pf.problem.name == name and pf.kind == "design"
    assert pf.problem.options.lookahead == 2
    np.testing.assert_allclose(pf.problem.target, targets.trefoil((3, 6, 4), samples=40))
    assert sweep.base_data["target"]["scale"] == [4.0, 4.0, 4.0]  # items do not leak into the base


def test_sweep_without_grid_is_one_item_named_after_the_file(tmp_path):
    write(tmp_path, "trefoil.toml", BASE)
    sweep = load_sweep(write(tmp_path, "my sweep.toml", 'base = "trefoil.toml"\n'))
    assert sweep.name == "my_sweep" and sweep.methods == ["nlp"] and sweep.grid == {}
    [(name, overrides, pf)] = sweep.items()
    assert name == "my_sweep-0000" and overrides == {} and pf.problem.target.shape == (40, 3)
    assert pf.source.startswith(BASE) and "the base problem" in pf.source


def test_apply_override_deep_copies_and_indexes_arrays():
    data = {"target": {"scale": [4, 4, 4]}}
    out = apply_override(data, "target.scale.2", 9)
    assert out == {"target": {"scale": [4, 4, 9]}} and data == {"target": {"scale": [4, 4, 4]}}
    assert apply_override(data, "design.smoothness.theta", 0.1)["design"] == {"smoothness": {"theta": 0.1}}


@pytest.mark.parametrize(
    "key, reason",
    [
        ("target.scale.3", "index 3 is out of range ('target.scale' has 3 elements)"),
        ("target.scale.x", "'target.scale' is an array; 'x' is not an index"),
        ("target.t_range.0", "'target.t_range' is not in the base problem; an index needs an existing array"),
        ("target.scale.0.1", "'target.scale.0' is a value, not a table or array"),
        ("target..scale", "not a dotted key like target.scale.0"),
    ],
)
def test_apply_override_bad_paths(key, reason):
    with pytest.raises(InputError) as info:
        apply_override({"target": {"scale": [4, 4, 4]}}, key, 1, file="s.toml")
    assert str(info.value) == f"s.toml: {key}: {reason}"


@pytest.mark.parametrize(
    "sweep_text, expected",
    [
        ('base = "missing.toml"\n', "base: no such file: {dir}/missing.toml"),
        ('base = "trefoil.toml"\nmethods = ["nlp", "ipopt"]\n', "methods: must be one of 'nlp', 'greedy'"),
        ('base = "trefoil.toml"\nname = "../x"\n', "name: must be a plain file name (letters, digits, . _ + -)"),
        ('base = "trefoil.toml"\n[grid]\n"tube.diameter" = 2\n', "grid.tube.diameter: must be a non-empty list of values"),
        ('base = "trefoil.toml"\n[grid]\n"target.scale.5" = [1]\n', "target.scale.5: index 5 is out of range ('target.scale' has 3 elements)"),
        ('name = "s"\nbase = "trefoil.toml"\n[grid]\n"tube.diameter" = [1, -1]\n', "tube.diameter: must be > 0 (item s-0001: tube.diameter = -1)"),
        ('base = "trefoil.toml"\n[grid]\n"design.lookahed" = [1]\n', "design.lookahed: unknown key; did you mean 'lookahead'? (item sweep-0000: design.lookahed = 1)"),
        ('base = "trefoil.toml"\nmetods = ["nlp"]\n', "metods: unknown key; did you mean 'methods'?"),
    ],
)
def test_bad_sweeps_name_the_sweep_file(tmp_path, sweep_text, expected):
    write(tmp_path, "trefoil.toml", BASE)
    path = write(tmp_path, "sweep.toml", sweep_text)
    with pytest.raises(InputError) as info:
        load_sweep(path)
    assert str(info.value) == f"{path}: {expected.format(dir=tmp_path)}"


def test_sweep_base_must_be_a_design_problem(tmp_path):
    write(tmp_path, "fwd.toml", FWD + "theta = 0\nlambda = 1\n")
    path = write(tmp_path, "sweep.toml", 'base = "fwd.toml"\n')
    with pytest.raises(InputError) as info:
        load_sweep(path)
    assert str(info.value) == f"{path}: base: must be a design problem file (one with [target], or [[actuators]] and [[states]])"


# ------------------------------------------------------------------ fuzz
# Mostly well-formed problems of every kind, then up to two random mutations
# (replace any value by junk, delete a key, add a stray key), so that the fuzz
# reaches the deep checks and not only the first missing table.

_junk = st.recursive(
    st.one_of(
        st.booleans(),
        st.integers(),
        st.floats(),
        st.text(max_size=12),
        st.sampled_from([-1, 0, 0.5, 1.5, 95, 10**6, 1e308, "s", "pi/12*sin(0.1*s)", "x", "log(s)", "1e308*s", "good.csv"]),
    ),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=3),
    max_leaves=8,
)
_num = st.floats(-5, 5) | st.integers(-3, 50)
_positive = st.floats(0.1, 5)
_samples = st.integers(3, 300)
_word = st.text("abc-_ ", min_size=1, max_size=6).filter(str.strip)
_top = {"name": _word, "units": _word}

_target = st.one_of(
    st.fixed_dictionaries(
        {"curve": st.just("trefoil")},
        optional={"scale": st.lists(_num, min_size=3, max_size=3), "t_range": st.just([0.0, 4.0]), "samples": _samples},
    ),
    st.fixed_dictionaries(
        {
            "curve": st.sampled_from(["bezier", "polyline"]),
            "control_points": st.lists(st.lists(_num, min_size=3, max_size=3), min_size=2, max_size=5),
        },
        optional={"samples": _samples},
    ),
    st.fixed_dictionaries(
        {"curve": st.just("helix"), "radius": _positive, "pitch": _num, "length": _positive}, optional={"samples": _samples}
    ),
    st.fixed_dictionaries({"curve": st.just("points"), "file": st.sampled_from(["good.csv", "good.npy", "bad.csv"])}),
)
_design = st.fixed_dictionaries(
    {"tube": st.fixed_dictionaries({"diameter": _positive}), "target": _target},
    optional={
        **_top,
        "actuator": st.fixed_dictionaries(
            {},
            optional={
                "kind": st.sampled_from(["tendon", "programmed", "spam"]),
                "lambda_min": st.floats(0.1, 1),
                "theta_max_deg": st.floats(1, 89),
            },
        ),
        "design": st.fixed_dictionaries(
            {},
            optional={
                "method": st.sampled_from(["nlp", "greedy"]),
                "points_per_segment": st.integers(1, 5),
                "lookahead": st.integers(1, 5),
                "seed": st.integers(0, 5),
                "tol": st.floats(1e-9, 1),
                "smoothness": st.fixed_dictionaries({}, optional={"theta": _positive, "lambda": _positive}),
            },
        ),
    },
)
_angle = st.one_of(
    st.floats(-1, 1),
    st.lists(st.floats(-1, 1), min_size=1, max_size=12),
    st.sampled_from(["0.1*s", "sin(s)", "pi/3", "s**s", "1/s", "0.01 * s**2"]),
)


@st.composite
def _routing(draw):
    routing = {"length": draw(st.floats(0.5, 12)), "segment_length": draw(st.floats(0.2, 3)), "lambda": draw(st.floats(0.1, 1) | st.sampled_from(["0.9", "1 - s/100"]))}
    routing[draw(st.sampled_from(["theta", "theta_deg", "phi"]))] = draw(_angle)
    if draw(st.booleans()):
        routing["initial_pose"] = draw(st.just(np.eye(4).tolist()) | st.lists(st.lists(_num, min_size=4, max_size=4), min_size=4, max_size=4))
    return routing


_tube = st.fixed_dictionaries({"diameter": _positive})
_forward = st.fixed_dictionaries({"tube": _tube, "routing": _routing()}, optional=_top)
_fit = st.fixed_dictionaries(
    {
        "tube": _tube,
        "measured": st.fixed_dictionaries(
            {"file": st.sampled_from(["good.csv", "good.npy", "bad.csv"]), "line": st.sampled_from(["center", "inner", "outer"])}
        ),
        "routing": _routing(),
    },
    optional={**_top, "fit": st.fixed_dictionaries({"free": st.sampled_from([[], ["lambda"], ["lambda", "lambda"]])})},
)
_mutation = st.tuples(st.integers(0, 10**6), st.sampled_from(["replace", "delete", "extra"]), _junk)


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    directory = tmp_path_factory.mktemp("fuzz")
    (directory / "good.csv").write_text("x y z\n0 0 0\n1 0 0\n1 1 0\n1 1 1\n2 1 1\n")
    (directory / "bad.csv").write_text("0 0 0\n0 0 0\n")
    np.save(directory / "good.npy", targets.trefoil(samples=30))
    return directory


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.one_of(_design, _forward, _fit), mutations=st.lists(_mutation, max_size=2))
def test_parse_problem_fuzz_gives_a_problem_or_input_error(fuzz_dir, data, mutations):
    for mutation in mutations:
        mutate(data, *mutation)
    try:
        pf = parse_problem(data, str(fuzz_dir / "p.toml"), "")
    except InputError as err:
        assert err.file and err.key and err.reason
        return
    assert pf.kind in ("design", "forward", "fit")
    p = pf.problem
    assert p.diameter > 0 and pf.name and pf.units
    if pf.kind == "design":
        assert np.all(np.isfinite(p.target)) and p.target.shape[0] >= p.options.points_per_segment + 1
    else:
        r = p.routing
        assert np.all(np.abs(r.theta) < np.pi / 2) and np.all((r.lam > 0) & (r.lam <= 1)) and np.all(r.length > 0)
        assert r.length.sum() == pytest.approx(data["routing"]["length"])
