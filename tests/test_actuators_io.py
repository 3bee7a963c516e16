"""Problem files and archives of several actuators on one tube (io.actuators): forward shapes, the archive's
layout read back, and every bad input as one error line, exit 2, nothing written."""

import subprocess
import sys

import h5py
import numpy as np
import pytest

from vine_nlp.io.actuators import read_actuators_archive
from vine_nlp.io.problems import load_problem
from vine_nlp.model import forward_shape

LAM_A = "[" + ", ".join(["0.6"] * 10 + ["1.0"] * 10) + "]"
LAM_B = "[" + ", ".join(["1.0"] * 10 + ["0.7"] * 10) + "]"
FORWARD = f"""name = "two"
[tube]
diameter = 2.4
[routing]
length = 20.0
segment_length = 1.0
[[actuators]]
name = "A"
theta_deg = 5.0
lambda = {LAM_A}
[[actuators]]
name = "B"
theta_deg = -3.0
lambda = {LAM_B}
phi0_deg = 180
[[states]]
name = "a"
active = ["A"]
[[states]]
name = "ab"
active = ["A", "B"]
"""
DESIGN = """name = "d"
[tube]
diameter = 2.4
[[actuators]]
name = "A"
[[actuators]]
name = "B"
[[states]]
name = "a"
active = ["A"]
[states.target]
curve = "bezier"
control_points = [[0, 0, 0], [20, 0, 0], [30, 10, 0]]
samples = 41
[[states]]
name = "b"
active = ["B"]
[states.target]
curve = "bezier"
control_points = [[0, 0, 0], [20, 0, 0], [30, -10, 0]]
samples = 41
"""


def _run(tmp_path, text, command="forward"):
    p = tmp_path / "p.toml"
    p.write_text(text)
    out = tmp_path / "o.h5"
    r = subprocess.run([sys.executable, "-m", "vine_nlp", command, str(p), "-o", str(out)], capture_output=True, text=True)
    return r, out, p


def test_forward_archive_round_trip(tmp_path):
    r, out, p = _run(tmp_path, FORWARD)
    assert r.returncode == 0, r.stderr
    assert "state ab (A, B): tip at" in r.stdout
    a, res, targets = read_actuators_archive(out)
    assert a.kind == "actuators-forward" and targets == {}
    pf = load_problem(p).problem
    assert res.lines.names == ("A", "B") and np.allclose(res.lines.theta, pf.lines.theta) and np.allclose(res.lines.phi0, [0, np.pi])
    with h5py.File(out) as h5:
        g = h5["runs/forward"]
        assert g["actuators/B/design/phi"].shape == (21,) and g["design/length"].shape == (20,)
        assert np.allclose(g["states/a/shape/center"][()], forward_shape(pf.lines.routing(0), 2.4).center)
    # state ab: A shapes the first half as in state a (2 pieces per segment: rows 0..20), B the second
    assert np.allclose(res.shapes["ab"].center[:21], res.shapes["a"].center[:21], atol=1e-12)
    assert np.linalg.norm(res.shapes["ab"].center[-1] - res.shapes["a"].center[-1]) > 1.0
    assert res.stats["states"] == {"a": ["A"], "ab": ["A", "B"]}
    shown = subprocess.run([sys.executable, "-m", "vine_nlp", "show", str(out)], capture_output=True, text=True).stdout
    assert "  actuator B: starts at phi = 180 deg around the tube" in shown and "  state ab (A, B)" in shown
    assert "  actuated    1 piece(s) (segments 10-19)" in shown  # B's line alone: its one piece


BAD = [
    (FORWARD.replace('active = ["A", "B"]', 'active = ["A", "C"]'), "states.1.active: unknown actuator 'C' (actuators: A, B)"),
    (FORWARD.replace('name = "B"', 'name = "A"'), "actuators.1.name: 'A' is used twice"),
    (FORWARD.replace('name = "ab"', 'name = "a"'), "states.1.name: 'a' is used twice"),
    (FORWARD.replace('phi0_deg = 180', 'width = 7.6'), "actuators.1.width: 7.6 is wider than the tube's circumference pi D = 7.53982"),
    (FORWARD.replace(LAM_B, "0.8"), "states.1.active: state 'ab': segment 1 has 2 active lines (A, B); the model allows one per segment"),
    (DESIGN.replace('name = "b"\n', 'name = "b"\nunits = "mm"\n'), "states.1.units: 'mm' differs from the problem's units 'cm' (one tube, one unit)"),
    (DESIGN.replace('[states.target]\ncurve = "bezier"\ncontrol_points = [[0, 0, 0], [20, 0, 0], [30, -10, 0]]\nsamples = 41\n', ""),
     "states.1.target: missing: every state of a design problem needs a target"),
    (DESIGN.replace("samples = 41\n[[states]]", "samples = 51\n[[states]]"), "states.1.target: has 41 points; every state needs as many as states.0 (51)"),
    (DESIGN.replace('curve = "bezier"', 'curve = "spiral"', 1), "states.0.target.curve: must be one of"),
    (FORWARD.replace("lambda = " + LAM_A, "lambda = 1.5"), "actuators.0.lambda: must be in (0, 1]"),
]


@pytest.mark.parametrize("text,message", BAD, ids=range(len(BAD)))
def test_bad_input(tmp_path, text, message):
    command = "forward" if "[routing]" in text else "design"
    r, out, p = _run(tmp_path, text, command)
    assert r.returncode == 2 and not out.exists()
    assert r.stderr.startswith(f"error: {p}: {message}") and r.stderr.count("\n") == 1, r.stderr


def test_a_design_short_of_its_tolerance_is_written_with_its_status_and_rerun_forward(tmp_path):
    lam_a = "[" + ", ".join(["0.7"] * 5 + ["1.0"] * 5) + "]"
    src = (FORWARD.replace("length = 20.0", "length = 10.0").replace(LAM_A, lam_a)
           .replace(LAM_B, "[" + ", ".join(["1.0"] * 5 + ["0.8"] * 5) + "]"))
    r, out, _ = _run(tmp_path, src)
    assert r.returncode == 0
    out = out.rename(tmp_path / "fwd.h5")
    # the forward shapes as targets of a design capped at 2 iterations: written, status max_iter, exit 1
    a, fwd, _ = read_actuators_archive(out)
    for s, shape in fwd.shapes.items():
        np.savetxt(tmp_path / f"{s}.csv", shape.center[:: max(1, (len(shape.center) - 1) // 20)][:21], delimiter=",")
    design = DESIGN.replace('name = "b"', 'name = "ab"').replace('active = ["B"]', 'active = ["A", "B"]')
    for s in ("a", "ab"):
        design = design.replace('curve = "bezier"', f'curve = "points"\nfile = "{s}.csv"', 1)
    design = design.replace("control_points = [[0, 0, 0], [20, 0, 0], [30, 10, 0]]\nsamples = 41\n", "")
    design = design.replace("control_points = [[0, 0, 0], [20, 0, 0], [30, -10, 0]]\nsamples = 41\n", "")
    r, out2, _ = _run(tmp_path, design + "[design]\npoints_per_segment = 2\nmax_iter = 2\n", "design")
    assert r.returncode == 1 and out2.exists(), r.stderr
    assert read_actuators_archive(out2)[1].status == "max_iter" and "nlp: max_iter" in r.stderr
    # forward ARCHIVE --run: every state's shape of the stored lines
    again = tmp_path / "again.h5"
    assert subprocess.run([sys.executable, "-m", "vine_nlp", "forward", str(out), "--run", "forward", "-o", str(again)]).returncode == 0
    _, back, _ = read_actuators_archive(again)
    for s in fwd.shapes:
        assert np.allclose(back.shapes[s].center, fwd.shapes[s].center, atol=1e-12)


@pytest.mark.parametrize("command, message", [
    (["correct", "m.csv", "-o", "c.h5"], "/problem@kind: correct needs a design archive with a target (this is 'actuators-forward')"),
    (["calibrate", "-o", "c.toml"], "/correction: not a correction archive (made by vine-nlp correct)"),
], ids=["correct", "calibrate"])
def test_correct_and_calibrate_of_a_forward_archive_of_several_are_one_line(tmp_path, command, message, capsys):
    """correct and calibrate read archives of several actuators (tests/test_correct_actuators.py); a forward one is
    no design and no correction: one line, exit 2, nothing written."""
    from vine_nlp.front.cli import main

    r, out, _ = _run(tmp_path, FORWARD)
    assert r.returncode == 0
    argv = [command[0], str(out), *[str(tmp_path / a) if "." in a else a for a in command[1:]]]
    assert main(argv) == 2
    assert capsys.readouterr().err == f"error: {out}: {message}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.h5", "p.toml"]
