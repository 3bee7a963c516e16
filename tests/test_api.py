"""The public Python API (vine_nlp.api, README "Python API"): known answers, archives every command reads,
figures, templates, argument errors naming the argument, and a cheap ``import vine_nlp``."""

import math
import os
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import numpy as np
import pytest
from conftest import model_target
from matplotlib.figure import Figure

import vine_nlp as vn
from vine_nlp.errors import InputError
from vine_nlp.front.cli import main
from vine_nlp.io.archive import load_archive
from vine_nlp.io.problems import parse_problem

D = 2.0
M, N_PER = 6, 5


@pytest.fixture(scope="module")
def target():
    """A target made by the forward model (6 segments of 2, random pose) and its true routing."""
    return model_target(M=M, n=N_PER, D=D, seed=1)


@pytest.fixture(scope="module")
def designed(target):
    points, _ = target
    return vn.design(points, diameter=D, points_per_segment=N_PER)


def _run(code: str, env=None) -> str:
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=240, env=env)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip()


# ---------------------------------------------------------------- import


def test_import_loads_no_heavy_package():
    out = _run("""
        import sys
        import vine_nlp
        print(sorted(m for m in ("casadi", "matplotlib", "h5py", "scipy", "vine_nlp.api", "vine_nlp.methods") if m in sys.modules))
    """)
    # importing the package loads nothing heavy: the API's names load on first use
    assert out.splitlines() == ["[]"]


def test_backend_unchanged_by_the_api(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"} | {"MPLBACKEND": "svg", "MPLCONFIGDIR": str(tmp_path)}
    out = _run("""
        import matplotlib
        import vine_nlp as vn
        vn.design
        vn.load
        before = matplotlib.get_backend()
        f = vn.forward(0.1, 0.8, 1.0, 2.0, segments=5)
        f.plot()
        print(before, matplotlib.get_backend())
    """, env=env)
    assert out == "svg svg"


def test_help_shows_the_api_functions(designed):
    import inspect

    import vine_nlp.api

    # plain functions: help(vn.design) is the function's own documentation and signature
    for name in ("design", "forward", "fit", "load", "solve", "correct"):
        assert getattr(vn, name) is getattr(vine_nlp.api, name)
        assert inspect.isfunction(getattr(vn, name))
    assert "points" in str(inspect.signature(vn.design))
    assert vn.design.__doc__.startswith("Inverse design")
    assert isinstance(designed, vn.Design)


def test_callable_whatever_was_imported_first():
    # the subpackage imported (by the io layer) before the package's API names are touched
    out = _run("""
        import vine_nlp.io.archive
        import vine_nlp as vn
        r = vn.forward(0.0, 1.0, 2.0, 2.0, segments=3)
        print(r.kind, r.segments, round(float(r.shape.center[-1][0]), 9))
    """)
    assert out == "forward 3 6.0"


def test_top_level_names():
    for name in vn.__all__:
        assert getattr(vn, name) is not None
    assert {"design", "forward", "fit", "load", "DesignProblem", "TipProblem", "Routing", "Sigmas"} <= set(dir(vn))
    with pytest.raises(AttributeError, match="has no attribute 'no_such_name'"):
        vn.no_such_name  # noqa: B018


# ---------------------------------------------------------------- design: known answer and archive


def test_design_recovers_a_model_made_target(designed, target):
    _, truth = target
    r = designed
    assert r.status == "optimal" and r.converged
    assert r.segments == M and r.kind == "design" and r.run == "nlp" and r.method == "nlp"
    assert r.rmse < 1e-3 * D and r.max_error < 5e-3 * D
    assert r.rmse == r.metrics["rmse"] and r.max_error == r.metrics["max_error"]
    assert float(r.length.sum()) == pytest.approx(float(truth.length.sum()), rel=1e-3)
    assert r.theta is r.routing.theta and r.lam is r.routing.lam and r.length is r.routing.length
    assert r.phi.shape == (M + 1,) and r.phi[0] == 0.0
    assert r.shape.center.shape == r.target.shape
    assert np.all(np.abs(r.theta) <= math.radians(60) + 1e-12) and np.all((r.lam >= 0.4 - 1e-12) & (r.lam <= 1 + 1e-12))


def test_save_load_round_trip(designed, tmp_path):
    path = designed.save(tmp_path / "out.h5")
    a = vn.load(path)
    assert isinstance(a, vn.Project) and list(a.runs) == ["nlp"] and a.kind == "design"
    r = a.run()
    assert r.run == "nlp"
    for key in ("theta", "lam", "length", "initial_pose"):
        np.testing.assert_array_equal(getattr(r.routing, key), getattr(designed.routing, key))
    assert r.metrics == designed.metrics
    assert r.status == designed.status and r.iterations == designed.iterations
    np.testing.assert_array_equal(a.target, designed.target)
    np.testing.assert_array_equal(r.shape.center, designed.shape.center)
    assert a.diameter == D and a.units == "cm" and a.name == "design"
    # the source is a problem file's text: its tables are what the commands read (bounds, spam)
    src = tomllib.loads(r.source)
    assert src["actuator"] == {"kind": "tendon", "lambda_min": 0.4, "theta_max_deg": 60.0}
    assert src["tube"]["diameter"] == D and src["design"]["points_per_segment"] == N_PER
    # a loaded design saves the file as it was
    copy = r.save(tmp_path / "copy.h5")
    assert copy.read_bytes() == path.read_bytes()


def test_saved_archive_read_by_the_commands(designed, tmp_path, capsys):
    path = designed.save(tmp_path / "out.h5")
    assert main(["show", str(path)]) == 0
    assert "run nlp" in capsys.readouterr().out
    assert main(["plot", str(path), "-o", str(tmp_path / "fig.png")]) == 0
    assert (tmp_path / "fig.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["template", str(path), "-o", str(tmp_path / "t.pdf")]) == 0
    assert (tmp_path / "t.pdf").read_bytes()[:5] == b"%PDF-"


def test_save_does_not_overwrite(designed, tmp_path):
    path = tmp_path / "out.h5"
    path.write_text("keep")
    with pytest.raises(FileExistsError, match="overwrite=True"):
        designed.save(path)
    assert path.read_text() == "keep"
    designed.save(path, overwrite=True)
    assert load_archive(path).runs["nlp"].status == designed.status
    with pytest.raises(vn.ArgumentError, match=r"^path: directory .* does not exist"):
        designed.save(tmp_path / "no" / "out.h5")


def test_plot_returns_a_figure_outside_pyplot(designed, tmp_path):
    import matplotlib.pyplot as plt

    before = plt.get_fignums()
    fig = designed.plot()
    assert isinstance(fig, Figure) and len(fig.axes) >= 4
    assert plt.get_fignums() == before  # not registered: a notebook shows it once
    out = tmp_path / "fig.pdf"
    assert isinstance(designed.plot(out), Figure)
    assert out.read_bytes()[:5] == b"%PDF-"
    with pytest.raises(vn.ArgumentError, match=r"^path: .*figure format"):
        designed.plot(tmp_path / "fig.jpg")


def test_template_writes_a_pdf_and_cut_list(designed, tmp_path):
    info = designed.template(tmp_path / "t.pdf", paper="Letter", csv=tmp_path / "cuts.csv")
    assert info["run"] == "nlp" and info["segments"] == M and info["paper"] == "Letter"
    assert (tmp_path / "t.pdf").read_bytes()[:5] == b"%PDF-"
    assert len((tmp_path / "cuts.csv").read_text().strip().splitlines()) == M + 1  # header + one row per segment
    with pytest.raises(vn.ArgumentError, match="^paper: must be one of A4, Letter"):
        designed.template(tmp_path / "t2.pdf", paper="A3")


def test_repr_and_html(designed):
    assert repr(designed).startswith("<Design 'design' run 'nlp': optimal, 6 segments, rmse ")
    vn.Design.html_plotlyjs = None
    try:
        table = designed._repr_html_()
    finally:
        vn.Design.html_plotlyjs = True
    assert table.startswith("<table>") and "rmse" in table and "optimal" in table and "plotly" not in table
    pytest.importorskip("plotly")
    full = designed._repr_html_()
    assert full.startswith(table) and "plotly" in full


# ---------------------------------------------------------------- argument errors


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(diameter=-1), "diameter: must be > 0, got -1"),
        (dict(diameter=float("nan")), "diameter: must be finite"),
        (dict(diameter="2"), "diameter: must be a number"),
        (dict(theta_max_deg=90), "theta_max_deg: must be in (0, 90)"),
        (dict(lambda_min=0), "lambda_min: must be in (0, 1]"),
        (dict(actuator="pam"), "actuator: must be one of 'tendon', 'programmed', 'spam'; did you mean 'spam'?"),
        (dict(method="ipopt"), "method: must be one of 'nlp', 'greedy'"),
        (dict(points_per_segment=0), "points_per_segment: must be an integer >= 1"),
        (dict(starts=1.5), "starts: must be an integer >= 1"),
        (dict(hops=-1), "hops: must be an integer >= 0"),
        (dict(solver="fatrop"), "solver: must be one of 'auto', 'ipopt'; did you mean 'auto'?"),
        (dict(smoothing=-1e-3), "smoothing: must be >= 0"),
        (dict(clearance=-0.1), "clearance: must be >= 0, got -0.1"),
        (dict(robust={"theta": 1.0}), "robust: unknown key 'theta'; the keys are theta_deg, lambda, length, length_abs"),
        (dict(robust={"theta_deg": 0.0}), "robust: every sigma is 0: there is no construction error to be robust against"),
        (dict(units=""), "units: must be a non-empty string"),
        (dict(points_per_segment=50), "points: needs at least points_per_segment + 1 = 51 points, got 31"),
    ],
)
def test_bad_arguments_name_the_argument(target, change, message):
    points, _ = target
    kw = dict(diameter=D, points_per_segment=N_PER) | change
    with pytest.raises(ValueError) as e:
        vn.design(points, **kw)
    assert isinstance(e.value, vn.ArgumentError) and str(e.value) == message


@pytest.mark.parametrize(
    "points, message",
    [
        ("nan", "points: point 4 is not finite"),
        ("wide", "points: points must be an N x 3 (or N x 2) array, got shape (31, 4)"),
        ("repeat", "points: points 2 and 3 are identical"),
        ("text", "points: points must be an N x 3 (or N x 2) array of numbers"),
    ],
)
def test_bad_points(target, points, message):
    p = np.array(target[0])
    bad = {
        "nan": lambda: np.where(np.arange(len(p))[:, None] == 3, np.nan, p),
        "wide": lambda: np.hstack([p, p[:, :1]]),
        "repeat": lambda: np.vstack([p[:2], p[1:]]),
        "text": lambda: [["a", "b", "c"]] * 12,
    }[points]()
    with pytest.raises(vn.ArgumentError) as e:
        vn.design(bad, D)
    assert str(e.value) == message and e.value.argument == "points"


def test_same_reasons_as_problem_files(tmp_path, capsys, target):
    # one rule, two front doors: the reason after the key is the problem file's
    (tmp_path / "p.toml").write_text(
        '[tube]\ndiameter = 2.0\n[target]\ncurve = "helix"\nradius = 3.0\npitch = 1.0\nlength = 20.0\n'
        "[actuator]\ntheta_max_deg = 90\n"
    )
    assert main(["design", str(tmp_path / "p.toml"), "-o", str(tmp_path / "o.h5")]) == 2
    cli_reason = capsys.readouterr().err.strip().split("actuator.theta_max_deg: ")[1]
    with pytest.raises(vn.ArgumentError) as e:
        vn.design(target[0], D, theta_max_deg=90)
    assert e.value.reason == cli_reason
    assert not (tmp_path / "o.h5").exists()


# ---------------------------------------------------------------- forward, fit, load, solve


def test_forward_closed_form_arc():
    # theta = 0: the actuator runs along one side; that side shortens to lam, the other keeps its
    # length, so the center line is a circle of radius R = (D/2)(1 + lam)/(1 - lam), of arc (1 + lam)/2 L
    lam, L = 0.8, 6.0
    f = vn.forward(0.0, lam, L / 4, D, segments=4)
    R = 0.5 * D * (1 + lam) / (1 - lam)
    arc = 0.5 * (1 + lam) * L
    assert f.kind == "forward" and f.run == "forward" and f.segments == 4
    assert np.linalg.norm(f.shape.center[-1] - f.shape.center[0]) == pytest.approx(2 * R * math.sin(arc / (2 * R)), rel=1e-12)
    assert math.isnan(f.rmse) and math.isnan(f.max_error)
    # numbers repeat over the segments: the same as arrays
    g = vn.forward([0.0] * 4, lam, [L / 4] * 4, D)
    np.testing.assert_array_equal(f.shape.center, g.shape.center)


def test_forward_errors():
    with pytest.raises(vn.ArgumentError, match=r"^lam: needs 4 values \(one per segment\), got 3$"):
        vn.forward([0.1] * 4, [0.8] * 3, 1.0, D)
    with pytest.raises(vn.ArgumentError, match=r"^theta: \|theta\| must be < 90 deg \(segment 2: 91 deg\)$"):
        vn.forward(np.radians([0.0, 91.0]), 0.8, 1.0, D)
    with pytest.raises(vn.ArgumentError, match=r"^length: must be > 0$"):  # a number: the problem files' reason
        vn.forward(0.1, 0.8, 0.0, D)
    with pytest.raises(vn.ArgumentError, match=r"^length: must be > 0 \(segment 2: -1\)$"):
        vn.forward(0.1, 0.8, [1.0, -1.0], D)
    with pytest.raises(vn.ArgumentError, match=r"^initial_pose: rotation part has det -1"):
        vn.forward(0.1, 0.8, 1.0, D, initial_pose=np.diag([1.0, 1.0, -1.0, 1.0]))


def test_forward_archive_round_trip(tmp_path, capsys):
    name = 'arc "1" \\ \u00e9\U0001f600'  # quotes, backslash, non-ASCII, astral: the source stays TOML (control characters are refused)
    f = vn.forward(np.linspace(-0.3, 0.3, 8), 0.7, 1.5, D, name=name)
    path = f.save(tmp_path / "f.h5")
    a = vn.load(path)
    assert a.kind == "forward" and list(a.runs) == ["forward"]
    np.testing.assert_array_equal(a.run().shape.center, f.shape.center)
    assert a.name == name and tomllib.loads(a.source)["name"] == name
    routing = tomllib.loads(a.source)["routing"]
    assert routing["length"] == pytest.approx(12.0) and routing["segment_length"] == 1.5 and routing["lambda"] == 0.7
    assert main(["show", str(path)]) == 0 and "run forward" in capsys.readouterr().out


def test_design_routing_as_a_forward_problem_reproduces_the_shape(designed, tmp_path):
    # issue 46: the routing of a design archive, written down as a forward problem (per-segment segment_length)
    r = vn.load(designed.save(tmp_path / "d.h5")).run().routing
    assert np.ptp(r.length) > 0  # unequal segments: what a single segment_length cannot say
    rows = ", ".join("[" + ", ".join(map(repr, row)) + "]" for row in r.initial_pose.tolist())
    (tmp_path / "built.toml").write_text(
        f"[tube]\ndiameter = {D!r}\n[routing]\nsegment_length = {list(map(float, r.length))}\ntheta = {list(map(float, r.theta))}\n"
        f"lambda = {list(map(float, r.lam))}\ninitial_pose = [{rows}]\n")
    f = vn.solve(tmp_path / "built.toml")
    assert f.kind == "forward" and f.segments == M
    g = vn.forward(r.theta, r.lam, r.length, D, initial_pose=r.initial_pose)
    np.testing.assert_allclose(f.shape.center, g.shape.center, rtol=0, atol=1e-12)
    np.testing.assert_allclose(f.shape.center[[0, -1]], designed.shape.center[[0, -1]], rtol=0, atol=1e-12)  # base and tip
    # the text archived with an API routing is such a problem: read back, the same routing
    back = parse_problem(tomllib.loads(g.source), "g.toml", g.source)
    for k in ("theta", "lam", "length", "initial_pose"):
        np.testing.assert_array_equal(getattr(back.problem.routing, k), getattr(r, k))


def test_fit_recovers_lambda(tmp_path):
    theta, lam = np.full(10, 0.3), 0.75
    built = vn.forward(theta, lam, 2.0, D)
    measured = built.shape.outer[::2]
    r = vn.fit(measured, {"theta": theta, "lam": 0.9, "length": 2.0}, D, line="outer", starts=6)
    assert r.kind == "fit" and r.status == "optimal"
    assert r.metrics["lambda"] == pytest.approx(lam, abs=1e-4) and r.rmse < 1e-3
    path = r.save(tmp_path / "fit.h5")
    a = vn.load(path)
    np.testing.assert_array_equal(a.extra["measured/points"], measured)
    assert main(["plot", str(path), "-o", str(tmp_path / "fit.png")]) == 0
    assert r.plot().get_suptitle() == "fit: model fit" == a.run().plot().get_suptitle()  # the command's figure of a fit
    with pytest.raises(vn.ArgumentError, match="^free: must be one of 'lambda'"):
        vn.fit(measured, built, D, free=("theta",))
    with pytest.raises(vn.ArgumentError, match="^line: must be one of 'center', 'inner', 'outer'"):
        vn.fit(measured, built, D, line="middle")


def test_load_errors(tmp_path, designed):
    with pytest.raises(FileNotFoundError):
        vn.load(tmp_path / "missing.h5")
    (tmp_path / "junk.h5").write_bytes(b"not hdf5")
    with pytest.raises(vn.ArgumentError, match="^path: cannot read the archive"):
        vn.load(tmp_path / "junk.h5")
    a = vn.load(designed.save(tmp_path / "a.h5"))
    with pytest.raises(vn.ArgumentError, match=r"^name: no run 'greedy' in the archive \(runs: nlp\)$"):
        a.run("greedy")


def test_solve_takes_problem_objects(target):
    points, _ = target
    pb = vn.DesignProblem("p", D, points, options=vn.DesignOptions(points_per_segment=N_PER))
    r = vn.solve(pb)
    assert r.run == "nlp" and r.rmse < 1e-3 * D
    with pytest.raises(vn.ArgumentError, match=r"^method: unknown design method 'tip'; one of nlp, greedy, greedy_filtered, nlp_free, greedy_buildable$"):
        vn.solve(pb, method="tip")
    with pytest.raises(TypeError, match="colour"):
        vn.solve(pb, colour=1)
    bad = vn.DesignProblem("p", D, points, actuator=vn.Actuator(theta_max=math.radians(95)))
    with pytest.raises(vn.ArgumentError, match=r"^theta_max_deg: must be in \(0, 90\)$"):
        vn.solve(bad)


def test_clearance_run_beside_nlp(target, tmp_path):
    points, _ = target
    r = vn.design(points, D, points_per_segment=N_PER, clearance=0.1)
    assert r.run == "nlp_clearance" and list(r.runs) == ["nlp", "nlp_clearance"]
    assert r.stats["clearance_met"] and r.stats["min_gap"] == 0.1
    a = vn.load(r.save(tmp_path / "c.h5"))
    assert list(a.runs) == ["nlp", "nlp_clearance"] and a.run().run == "nlp"


def test_solve_multishape_keeps_its_levels(tmp_path, capsys):
    # targets made by the forward model: one routing at three contraction levels, one base pose
    theta = 0.5 * np.sin(np.linspace(0, 3, 5))
    truth = (0.93, 0.72, 0.85)  # inside the sPAM's buildable band [2/pi + margin, 1 - margin]
    targets = [vn.forward(theta, lam, 2.0, D).shape.center for lam in truth]  # pieces of D/4: 4 points per segment
    pb = vn.MultiShapeProblem("ms", D, targets, actuator=vn.Actuator("spam", 0.5),
                              options=vn.DesignOptions(points_per_segment=4, starts=1, smooth_theta=0.0, smooth_lambda=0.0))
    r = vn.solve(pb)
    assert r.run == "multishape" and r.kind == "multishape" and r.status == "optimal"
    np.testing.assert_allclose(r.result.levels, truth, atol=1e-6)
    assert isinstance(r.plot(), Figure)  # its figure reads the archive file: drawn from a temporary one
    path = r.save(tmp_path / "ms.h5")
    back = vn.load(path).run()
    np.testing.assert_array_equal(back.result.levels, r.result.levels)
    assert isinstance(back.plot(), Figure)
    assert main(["show", str(path)]) == 0 and "run multishape" in capsys.readouterr().out


def test_solve_tip_problem(tmp_path, capsys):
    built = vn.forward(0.3 * np.sin(np.linspace(0, 4, 8)), 0.7, 3.0, D)
    pb = vn.TipProblem("tip", D, built.shape.center[-1], 24.0, 8, options=vn.DesignOptions(starts=2))
    r = vn.solve(pb)
    assert r.run == "tip" and r.converged and r.metrics["tip_error"] < 1e-6
    assert float(r.length.sum()) == pytest.approx(24.0)
    path = r.save(tmp_path / "tip.h5")
    assert vn.load(path).kind == "tip"
    assert main(["show", str(path)]) == 0 and "run tip" in capsys.readouterr().out
    with pytest.raises(vn.ArgumentError, match=r"^starts: not available for forward problems$"):
        vn.solve(vn.ForwardProblem("f", D, built.routing), starts=2)


@pytest.mark.slow
def test_notebook_shows_the_figure_once(tmp_path):
    # with and without pyplot imported (the inline backend's formatter registers with pyplot):
    # the cell's value is one PNG, and no figure is left to the backend to show again
    nbclient = pytest.importorskip("nbclient")
    nbformat = pytest.importorskip("nbformat")
    nb = nbformat.v4.new_notebook()
    nb.cells = [
        nbformat.v4.new_code_cell("import vine_nlp as vn\nf = vn.forward(0.1, 0.8, 1.0, 2.0, segments=5)\nf.plot()"),
        nbformat.v4.new_code_cell("import matplotlib.pyplot as plt\nf.plot()"),
        nbformat.v4.new_code_cell("vn.Design.html_plotlyjs = None\nf"),
    ]
    nbclient.NotebookClient(nb, timeout=120, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    kinds = [[(o["output_type"], sorted(o.get("data", {}))) for o in cell.outputs] for cell in nb.cells]
    assert kinds[0] == kinds[1] == [("execute_result", ["image/png", "text/plain"])]
    assert kinds[2] == [("execute_result", ["text/html", "text/plain"])]


@pytest.mark.slow
def test_correct_through_the_api_lowers_the_built_error(tmp_path):
    # the bundled simulated build of the trefoil (problems/data/make_built.py: known construction errors)
    root = Path(__file__).resolve().parents[1]
    arch = tmp_path / "t.h5"
    assert main(["design", str(root / "problems/trefoil-m4.toml"), "-o", str(arch)]) == 0
    out = tmp_path / "c.h5"
    r = vn.correct(arch, [root / "problems/data/trefoil-built.csv"], output=out)
    assert r.corrected.metrics["rmse"] < 0.5 * r.as_built.metrics["target_rmse"]
    assert sorted(vn.load(out).runs) >= ["as_built", "corrected"]
    with pytest.raises(InputError):
        vn.correct(arch, [tmp_path / "missing.csv"])


def test_solver_choice_reaches_the_problem_and_its_source(target, tmp_path):
    points, _ = target
    d = vn.design(points, D, points_per_segment=N_PER, solver="ipopt")
    assert d.result.stats["solver"] == "ipopt"
    d.save(tmp_path / "d.h5")
    assert 'solver = "ipopt"' in vn.load(tmp_path / "d.h5").source
