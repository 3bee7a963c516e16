"""The layer rules of the developer guide that a test can check.

* Importing a vine_nlp module never changes the matplotlib backend (a module-level
  ``matplotlib.use`` breaks inline figures in Jupyter).
* No import inside a function dodges a layer or a circle. import-linter
  (``lint-imports``, contracts in pyproject.toml) checks the layers for every
  import, inside functions too; here, every import of vine_nlp inside a function
  could stand at the module top: with all of them counted as module-level edges,
  the module graph has no circle. What remains inside functions is lazy loading
  of lower layers (the command line starts in a fraction of a second).
"""

from __future__ import annotations

import ast
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import vine_nlp

SRC = Path(vine_nlp.__file__).resolve().parent


def all_modules() -> list[str]:
    """Every module of the package, found on disk (so a new module is covered without listing it)."""
    names = ["vine_nlp"]
    for info in pkgutil.walk_packages([str(SRC)], prefix="vine_nlp."):
        if info.name != "vine_nlp.__main__":  # runs the command line when imported
            names.append(info.name)
    return sorted(names)


def test_all_modules_found():
    names = all_modules()
    # one module of each layer, so a broken walk cannot pass the tests below vacuously
    for name in ("vine_nlp.model.segment", "vine_nlp.analysis.tolerance", "vine_nlp.problem", "vine_nlp.io.archive",
                 "vine_nlp.front.plot", "vine_nlp.front.cli"):
        assert name in names


IMPORT_ALL = """
import importlib, sys
import matplotlib
# the backend is set explicitly (never the auto sentinel), so reading it resolves nothing
before = matplotlib.rcParams["backend"]
for name in sys.argv[1:]:
    importlib.import_module(name)
print(before, matplotlib.rcParams["backend"], matplotlib.get_backend(), sep="\\n")
"""


def _import_all(env: dict) -> list[str]:
    proc = subprocess.run([sys.executable, "-c", IMPORT_ALL, *all_modules()], env=env, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.split()


def _clean_env(tmp_path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("MPLBACKEND", "MPLCONFIGDIR")}
    env["MPLCONFIGDIR"] = str(tmp_path)  # a fresh matplotlib config: no user matplotlibrc
    return env


def test_importing_keeps_backend_from_environment(tmp_path):
    env = _clean_env(tmp_path)
    env["MPLBACKEND"] = "svg"
    before, after, resolved = _import_all(env)
    assert (before, after, resolved) == ("svg", "svg", "svg")


def test_importing_keeps_backend_from_matplotlibrc(tmp_path):
    # MPLBACKEND unset, a non-Agg default from the user's matplotlibrc (as a Jupyter user might have)
    (tmp_path / "matplotlibrc").write_text("backend: pdf\n")
    before, after, resolved = _import_all(_clean_env(tmp_path))
    assert (before, after, resolved) == ("pdf", "pdf", "pdf")


def _module_of(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = list(rel.parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    """Module -> the vine_nlp modules it imports anywhere in its body (module top and functions alike)."""
    modules = {_module_of(p): p for p in SRC.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        edges = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            edges |= {t for t in targets if t in modules and t != name}
        graph[name] = edges
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_circle_detector():
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert circles({"a": {"b"}, "b": set()}) == []


def test_no_import_inside_a_function_hides_a_circle():
    graph = import_graph()
    assert "vine_nlp.front.plot" in graph["vine_nlp.front.cli"] or any(e.startswith("vine_nlp.front") for e in graph["vine_nlp.front.cli"])
    found = circles(graph)
    assert not found, f"import circles (counting imports inside functions as module-level ones): {found}"


@pytest.mark.parametrize("name", ["vine_nlp.model", "vine_nlp.analysis", "vine_nlp.targets"])
def test_lower_layers_do_not_load_upper_layers(name):
    # the model, analysis and targets layers load nothing of design, io or front
    code = f"import sys, {name}; print(sorted(m for m in sys.modules if m.startswith(('vine_nlp.methods', 'vine_nlp.io', 'vine_nlp.front'))))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


def test_segment_function_is_cached_and_matches_the_numpy_chain():
    import numpy as np

    from vine_nlp.model import segment_function, segment_point, segment_transform

    assert segment_function(3) is segment_function(3)
    theta, lam, dl, u = 0.4, 0.7, 1.3, np.array([0.0, 0.5, 1.0])
    Xn, pts = segment_function(3)(np.r_[np.eye(3).ravel(order="F"), np.zeros(3)], theta, lam, dl, u)
    T = segment_transform(theta, lam, dl, 1.0)
    Xn = np.array(Xn).ravel()
    assert np.allclose(Xn[:9].reshape(3, 3, order="F"), T[:3, :3], atol=1e-13)
    assert np.allclose(Xn[9:], T[:3, 3], atol=1e-13)
    expected = np.array([segment_point(theta, lam, dl, 1.0, ui) for ui in u])
    assert np.allclose(np.array(pts).T, expected, atol=1e-13)
