"""Compiled NLP functions (methods.compiled): the same iterates as the interpreted ones, cached on disk,
compiled in the background where a run would wait (once per machine: the lock), and a clear fallback where
no compiler works."""

import logging
import os
import time
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from vine_nlp.errors import InputError
from vine_nlp.methods import compiled
from vine_nlp.methods.common import geometric_guess, pair_points
from vine_nlp.methods.nlp import design_bounds, nlp_parameters, nlp_spec, start_x
from vine_nlp.methods.transcription import Solver, clear_caches
from vine_nlp.problem import DesignOptions, DesignProblem

# small structures compile in about a second without optimization
SPEC = nlp_spec(6, 3, False, hessian="gauss-newton")


@pytest.fixture
def codegen(monkeypatch, tmp_path):
    monkeypatch.setenv("VINE_NLP_CODEGEN", "on")
    monkeypatch.setenv("VINE_NLP_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("VINE_NLP_CFLAGS", "-O0")
    monkeypatch.delenv("CC", raising=False)
    compiled._warned.clear()
    # the command line's note handler (installed by any test that ran main()) stops propagation: caplog listens at the root
    monkeypatch.setattr(logging.getLogger("vine_nlp"), "propagate", True)
    if compiled.compiler() is None:
        pytest.skip("no C compiler on this machine")
    return tmp_path / "cache"


def _libraries(cache: Path) -> list[Path]:
    return sorted(cache.rglob("*.so"))


def _solve(solver, make_target):
    target, _ = make_target(M=6, n=3, seed=3)
    problem = DesignProblem("compiled", 2.0, target, options=DesignOptions(points_per_segment=3))
    pairing = pair_points(problem.target, 3)
    guess = geometric_guess(problem, pairing)
    p = solver.pack_params(nlp_parameters(problem, pairing, guess.initial_pose[:3, :3]))
    lbx, ubx = solver.bounds(**design_bounds(problem, pairing))
    return solver.solve(start_x(solver, guess, problem.diameter), p, lbx, ubx)


def test_compiled_solver_takes_the_interpreted_ones_steps(codegen, monkeypatch, make_target):
    before = dict(compiled.stats)
    fast = Solver(SPEC)
    assert compiled.stats["compiled"] == before["compiled"] + 1
    assert len(_libraries(codegen)) == 1
    monkeypatch.setenv("VINE_NLP_CODEGEN", "off")
    slow = Solver(SPEC)
    x_fast, status_fast, st_fast = _solve(fast, make_target)
    x_slow, status_slow, st_slow = _solve(slow, make_target)
    assert status_fast == status_slow == "optimal"
    assert st_fast["iterations"] == st_slow["iterations"]
    np.testing.assert_allclose(x_fast, x_slow, rtol=0, atol=1e-9)
    assert st_fast["objective"] == pytest.approx(st_slow["objective"], rel=1e-9, abs=1e-15)
    # the derivative functions themselves, at a point away from the answer
    rng = np.random.default_rng(0)
    x = x_slow + rng.normal(scale=0.1, size=x_slow.size)
    p = rng.uniform(0.1, 1.0, slow.nlpsol.size_in("p")[0])
    lam = rng.normal(size=slow.nlpsol.size_out("g")[0])
    for name, args in [("nlp_jac_g", (x, p)), ("nlp_hess_l", (x, p, 0.7, lam)), ("nlp_grad_f", (x, p))]:
        a = fast.nlpsol.get_function(name)(*args)
        b = slow.nlpsol.get_function(name)(*args)
        a, b = (a, b) if isinstance(a, (list, tuple)) else ([a], [b])
        for u, v in zip(a, b):
            np.testing.assert_allclose(np.array(u), np.array(v), rtol=1e-12, atol=1e-12)


def test_a_second_build_loads_the_library_from_disk(codegen):
    Solver(SPEC)
    (lib,) = _libraries(codegen)
    stamp = lib.stat().st_mtime_ns
    before = dict(compiled.stats)
    Solver(SPEC)
    assert compiled.stats["loaded"] == before["loaded"] + 1
    assert compiled.stats["compiled"] == before["compiled"]
    assert _libraries(codegen) == [lib] and lib.stat().st_mtime_ns == stamp
    # no temporary build directory is left beside it
    assert not [p for p in lib.parent.iterdir() if p.name.startswith(".build-")]


def test_two_processes_compile_one_structure_once(codegen):
    import subprocess
    import sys

    code = ("from vine_nlp.methods import compiled; from vine_nlp.methods.transcription import Solver; "
            "from vine_nlp.methods.nlp import nlp_spec; Solver(nlp_spec(5, 2, False, hessian='gauss-newton')); "
            "print(compiled.stats['compiled'], compiled.stats['loaded'])")
    procs = [subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True) for _ in range(2)]
    counts = [tuple(map(int, p.communicate()[0].split())) for p in procs]
    assert all(p.returncode == 0 for p in procs)
    assert sorted(counts) == [(0, 1), (1, 0)]  # one compiled, the other waited and loaded
    assert len(_libraries(codegen)) == 1


def test_the_key_follows_the_spec_the_compiler_and_the_code(monkeypatch):
    cc = ["/usr/bin/gcc", "-O1"]
    text = repr(SPEC)
    key = compiled._key(text, cc)
    assert key == compiled._key(text, cc)
    assert key != compiled._key(repr(nlp_spec(7, 3, False, hessian="gauss-newton")), cc)
    assert key != compiled._key(repr(nlp_spec(6, 3, False, hessian="exact")), cc)
    assert key != compiled._key(text, ["/usr/bin/gcc", "-O0"])
    monkeypatch.setattr(compiled, "_code_fingerprint", lambda: "another version of the model")
    assert key != compiled._key(text, cc)
    # a description that does not pin the code down is never cached
    assert compiled._key("Term(<object at 0x7f00>)", cc) is None
    assert compiled._key("Term(array([1., 2., ..., 9.]))", cc) is None


@pytest.mark.parametrize("cc, reason", [("/nonexistent/cc", "no C compiler found"), ("false", "the C compiler failed")])
def test_without_a_working_compiler_it_runs_interpreted_and_says_so_once(codegen, monkeypatch, caplog, make_target, cc, reason):
    monkeypatch.setenv("CC", cc)
    monkeypatch.setenv("VINE_NLP_CODEGEN", "auto")
    with caplog.at_level(logging.WARNING, logger="vine_nlp"):
        solver = Solver(SPEC)
        assert compiled.wait(60)  # a compiler that fails in the background leaves its complaint for the next build
        Solver(SPEC)
        Solver(SPEC)
    notes = [r.getMessage() for r in caplog.records]
    assert len(notes) == 1 and notes[0].startswith(reason) and notes[0].endswith("the NLP functions run interpreted (slower)")
    assert _solve(solver, make_target)[1] == "optimal"
    assert _libraries(codegen) == []
    monkeypatch.setenv("VINE_NLP_CODEGEN", "on")
    with pytest.raises(compiled.CompileError, match=reason):
        Solver(SPEC)


def _wait_for(path: Path, deadline_s: float = 120.0) -> bool:
    """True once ``path`` exists (the background compiler renames the library into place), False at the deadline."""
    end = time.monotonic() + deadline_s
    while not path.exists():
        if time.monotonic() > end:
            return False
        time.sleep(0.02)
    return True


def test_a_first_build_solves_at_once_and_a_later_solve_runs_compiled(codegen, monkeypatch, make_target):
    monkeypatch.setenv("VINE_NLP_CODEGEN", "auto")
    before = dict(compiled.stats)
    solver = Solver(SPEC)  # nothing compiled yet: interpreted now, the library compiled in the background
    assert compiled.stats["background"] == before["background"] + 1 and compiled.stats["compiled"] == before["compiled"]
    assert isinstance(solver.nlpsol, compiled.Upgrading)
    first = _solve(solver, make_target)
    assert compiled.wait(120)
    (lib,) = _libraries(codegen)
    loaded = compiled.stats["loaded"]
    again = _solve(solver, make_target)  # the same solver object now runs on the library
    assert compiled.stats["loaded"] == loaded + 1
    assert first[1] == again[1] == "optimal" and first[2]["iterations"] == again[2]["iterations"]
    np.testing.assert_allclose(first[0], again[0], rtol=0, atol=1e-9)
    Solver(SPEC)  # a new build loads it and starts no compiler
    assert compiled.stats["loaded"] == loaded + 2 and compiled.stats["background"] == before["background"] + 1
    assert not [p for p in lib.parent.iterdir() if p.name.startswith(".build-")]


def test_two_processes_start_one_background_compile_that_outlives_them(codegen):
    import subprocess
    import sys

    # each process builds the structure and exits at once, printing how many compilers it started
    code = ("from vine_nlp.methods import compiled; from vine_nlp.methods.transcription import Solver; "
            "from vine_nlp.methods.nlp import nlp_spec; Solver(nlp_spec(5, 2, False, hessian='gauss-newton')); "
            "print(compiled.stats['background'], compiled.stats['loaded'])")
    env = os.environ | {"VINE_NLP_CODEGEN": "auto"}
    procs = [subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env) for _ in range(2)]
    counts = [tuple(map(int, p.communicate()[0].split())) for p in procs]
    assert all(p.returncode == 0 for p in procs)
    # one started the compiler; the other found its lock held (interpreted) or, later, the library (loaded)
    assert sorted(counts) in ([(0, 0), (1, 0)], [(0, 1), (1, 0)])
    lock = next(codegen.rglob("nlp-*.lock"))
    assert _wait_for(lock.with_suffix(".so"))
    assert _libraries(codegen) == [lock.with_suffix(".so")]


def test_a_held_lock_means_another_process_compiles(codegen, monkeypatch):
    import fcntl

    monkeypatch.setenv("VINE_NLP_CODEGEN", "auto")
    Solver(SPEC)
    lock = next(codegen.rglob("nlp-*.lock"))
    assert compiled.wait(120) and lock.with_suffix(".so").is_file()
    lock.with_suffix(".so").unlink()
    with open(lock, "a") as held:  # as a compiler in another process holds it
        fcntl.flock(held, fcntl.LOCK_EX)
        before = dict(compiled.stats)
        solver = Solver(SPEC)
        assert compiled.stats["background"] == before["background"] and compiled.stats["interpreted"] == before["interpreted"] + 1
        assert isinstance(solver.nlpsol, compiled.Upgrading)  # it loads the other's library once it is there
    assert _libraries(codegen) == []


def test_an_unwritable_cache_falls_back(codegen, monkeypatch, caplog, tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    monkeypatch.setenv("VINE_NLP_CACHE_DIR", str(blocker))
    monkeypatch.setenv("VINE_NLP_CODEGEN", "auto")
    with caplog.at_level(logging.WARNING, logger="vine_nlp"):
        Solver(SPEC)
    (note,) = [r.getMessage() for r in caplog.records]
    assert note.startswith(f"cannot write the code cache {blocker}")


def test_a_bad_setting_is_one_clear_error(monkeypatch):
    monkeypatch.setenv("VINE_NLP_CODEGEN", "fast")
    with pytest.raises(InputError, match="VINE_NLP_CODEGEN: expected one of auto, on, off, got 'fast'"):
        compiled.mode()


def test_the_command_line_notes_the_compile_once(codegen, tmp_path, capsys, monkeypatch):
    from vine_nlp.front.cli import main
    from vine_nlp.methods.transcription import clear_caches

    clear_caches()  # solvers built by earlier tests in this process would hide the compile
    monkeypatch.setenv("VINE_NLP_CODEGEN", "auto")
    problem = Path(__file__).resolve().parents[1] / "problems" / "trefoil-m4.toml"
    assert main(["design", str(problem), "-o", str(tmp_path / "a.h5")]) == 0
    first = capsys.readouterr().err
    assert main(["design", str(problem), "-o", str(tmp_path / "b.h5")]) == 0
    second = capsys.readouterr().err
    assert first.count("note: compiling the NLP functions") >= 1
    assert "note:" not in second
    assert compiled.wait(300)  # no compiler left running after the test
    monkeypatch.setenv("VINE_NLP_CODEGEN", "fast")
    assert main(["design", str(problem), "-o", str(tmp_path / "c.h5")]) == 2
    assert capsys.readouterr().err == "error: environment: VINE_NLP_CODEGEN: expected one of auto, on, off, got 'fast'\n"
    assert not (tmp_path / "c.h5").exists()


def test_stored_functions_round_trip_and_a_damaged_copy_is_rebuilt(codegen):
    import casadi as ca

    calls = []

    def build():
        calls.append(1)
        x = ca.SX.sym("x", 2)
        return [ca.Function("f", [x], [ca.sin(x[0]) * x[1]]), ca.Function("g", [x], [x * x])]

    first = compiled.stored("probe", build)
    again = compiled.stored("probe", build)
    assert len(calls) == 1
    for a, b in zip(first, again):
        np.testing.assert_array_equal(np.array(a([0.3, 2.0])), np.array(b([0.3, 2.0])))
    (path,) = codegen.rglob("probe-*.casadi")
    blob = bytearray(path.read_bytes())
    blob[-10] ^= 0xFF  # one flipped byte: the checksum no longer matches
    path.write_bytes(bytes(blob))
    rebuilt = compiled.stored("probe", build)
    assert len(calls) == 2
    assert float(rebuilt[0]([0.3, 2.0])) == pytest.approx(np.sin(0.3) * 2.0)
    assert compiled.stored("probe", build) and len(calls) == 2  # written again, whole


def _pair_solver(pairs):
    from vine_nlp.methods.clearance import ClearancePairs

    return Solver(nlp_spec(6, 2, False, terms=(ClearancePairs(pairs),)))


def _blocks(cache: Path) -> list[Path]:
    return sorted(cache.rglob("blk-*.so"))


def test_an_active_set_of_pairs_compiles_its_block_types_once(codegen):
    # the structure (which segments the pairs join) changes every solve: never compiled as a whole
    before = dict(compiled.stats)
    _pair_solver(((0, 4), (1, 5)))
    assert compiled.stats["interpreted"] == before["interpreted"] + 1
    assert not sorted(codegen.rglob("nlp-*.so"))
    # its block types are: the pose, the segment of 2 points, a pair of rows
    first = _blocks(codegen)
    assert len(first) == 3 and compiled.stats["compiled"] == before["compiled"] + 3
    # another active set of one row per segment pair reuses all three
    _pair_solver(((0, 3), (2, 5), (1, 4)))
    assert _blocks(codegen) == first and compiled.stats["compiled"] == before["compiled"] + 3
    # two rows between the same two segments are a new block type: one more library
    _pair_solver(((0, 4), (0, 4)))
    assert len(_blocks(codegen)) == 4


def test_compiled_blocks_give_the_interpreted_functions(codegen, monkeypatch):
    pairs = ((0, 4), (1, 5), (1, 5))
    fast = _pair_solver(pairs)
    assert _blocks(codegen)
    monkeypatch.setenv("VINE_NLP_CODEGEN", "off")
    _same_functions(fast, _pair_solver(pairs), seed=1, tol=1e-12)


def _same_functions(fast, slow, seed, tol):
    """The NLP functions of two solvers of one spec agree at a random point (x, p and multipliers)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=slow.nlpsol.size_in("x0")[0])
    p = rng.uniform(0.1, 1.0, slow.nlpsol.size_in("p")[0])
    lam = rng.normal(size=slow.nlpsol.size_out("g")[0])
    for name, args in [("nlp_f", (x, p)), ("nlp_g", (x, p)), ("nlp_grad_f", (x, p)), ("nlp_jac_g", (x, p)),
                       ("nlp_hess_l", (x, p, 0.7, lam))]:
        a, b = fast.nlpsol.get_function(name)(*args), slow.nlpsol.get_function(name)(*args)
        a, b = (a, b) if isinstance(a, (list, tuple)) else ([a], [b])
        for u, v in zip(a, b):
            np.testing.assert_allclose(np.array(ca.densify(u)), np.array(ca.densify(v)), rtol=tol, atol=tol, err_msg=name)


def test_a_clearance_design_takes_the_same_steps_on_compiled_blocks(codegen, monkeypatch, make_target):
    from vine_nlp.methods.clearance import design_with_clearance
    from vine_nlp.methods.nlp import design_nlp
    from vine_nlp.problem import Actuator
    from vine_nlp.targets import helix

    # a helix whose turns are closer than D: the tube must open it up (rows between neighbouring turns)
    coil = DesignProblem("coil", 2.0, helix(radius=3.0, pitch=0.25, length=30.0, samples=61), actuator=Actuator("tendon", 0.4),
                         options=DesignOptions(points_per_segment=3, hessian="exact", starts=1, hops=0))
    monkeypatch.setenv("VINE_NLP_CODEGEN", "off")
    start = design_nlp(coil)
    slow = design_with_clearance(coil, start=start)
    monkeypatch.setenv("VINE_NLP_CODEGEN", "on")
    clear_caches()  # the built solvers are kept per structure, whatever the setting they were built under
    fast = design_with_clearance(coil, start=start)
    assert _blocks(codegen)
    assert slow.stats["clearance_met"] and fast.stats["clearance_met"]
    assert fast.stats["ipopt_iterations"] == slow.stats["ipopt_iterations"]
    assert fast.stats["clearance_pairs"] == slow.stats["clearance_pairs"]
    np.testing.assert_allclose(fast.routing.theta, slow.routing.theta, rtol=0, atol=1e-8)
    np.testing.assert_allclose(fast.routing.length, slow.routing.length, rtol=0, atol=1e-8)


def test_a_block_over_the_budget_stays_interpreted(codegen, monkeypatch):
    monkeypatch.setattr(compiled, "BLOCK_BUDGET", 10)
    before = dict(compiled.stats)
    _pair_solver(((0, 4),))
    assert _blocks(codegen) == [] and compiled.stats["compiled"] == before["compiled"]


def test_obstacle_rows_run_on_one_samples_compiled_block(codegen, monkeypatch, caplog):
    # 12 samples a segment against 1 or 2 primitives, or 2 mesh triangles each: each block is over the budget,
    # so the block of one sample is compiled and mapped over the 12 (the same for every sample count)
    from vine_nlp.methods.obstacles.rows import ObstacleRows

    spec = nlp_spec(6, 2, False, terms=(ObstacleRows(slots=(0, 2, 0, 1, 1, 0), meshes=((2, 3, 4),), S=12, k=2),))
    with caplog.at_level(logging.INFO, logger="vine_nlp"):
        fast = Solver(spec)
    built = sorted(r.getMessage().split()[3] for r in caplog.records if r.getMessage().startswith("compiling the block"))
    assert built == ["obstacle_mesh1x2", "obstacle_prims1x1", "obstacle_prims1x2", "pose", "segment2"]
    assert len(_blocks(codegen)) == 5
    monkeypatch.setenv("VINE_NLP_CODEGEN", "off")
    _same_functions(fast, Solver(spec), seed=2, tol=1e-11)
