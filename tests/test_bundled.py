"""Every bundled problem runs end to end and its figure renders without warnings (do-mpc style)."""

import warnings
from pathlib import Path

import pytest

from vine_nlp.front.cli import main
from vine_nlp.io.problem_file import load_problem

PROBLEMS = sorted((Path(__file__).resolve().parents[1] / "problems").glob("*.toml"))
COMMAND = {"forward": "forward", "design": "design", "multishape": "design", "tip": "design", "fit": "fit"}


@pytest.mark.slow
@pytest.mark.parametrize("path", PROBLEMS, ids=lambda p: p.stem)
def test_bundled_problem_runs_and_plots_without_warnings(path, tmp_path, capsys):
    kind = load_problem(path).kind
    out, fig = tmp_path / "out.h5", tmp_path / "fig.png"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main([COMMAND[kind], str(path), "-o", str(out)]) == 0
        assert main(["plot", str(out), "-o", str(fig)]) == 0
    assert fig.stat().st_size > 10_000
