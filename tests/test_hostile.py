"""Hostile files (issues 34, 48): every case an attacker tried, and a fuzzer per reader.

Each case is one ``error: <file>: <key>: <reason>`` line, exit 2, nothing written. Cases that
could exhaust memory or hang run the command in a subprocess held to 1 GB of address space
(RLIMIT_AS) and a timeout of TIME_LIMIT seconds (a broken reader fails the test instead of
hanging it); no test waits a guessed time. NumPy's RuntimeWarnings are errors here (``pytestmark``, ``limited``).
"""

from __future__ import annotations

import os
import re
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from holdpoint import finish, hold_env, release, spawn, wait_for_marker
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from texts import TINY_TREFOIL

from vine_nlp.errors import InputError, printable
from vine_nlp.front.cli import main
from vine_nlp.io import limits, outputs
from vine_nlp.io.archive import ArchiveError, load_archive, write_atomic
from vine_nlp.io.problem_file import load_problem, load_sweep
from vine_nlp.problem import Result

# every case here, in this process and in the commands it starts (limited), with NumPy's RuntimeWarnings (overflow,
# invalid value, divide by zero) as errors: hostile input is refused or handled, never a warning on stderr (issue 48)
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")
ROOT = Path(__file__).resolve().parents[1]
MEMORY = 1 << 30
TIME_LIMIT = 10
FUZZ = settings(max_examples=int(os.environ.get("VINE_NLP_FUZZ_EXAMPLES", "40")), deadline=None, derandomize=not os.environ.get("VINE_NLP_FUZZ_RANDOM"), database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
FORWARD = """name = "f"
units = "cm"
[tube]
diameter = 2.0
[routing]
length = 12.0
segment_length = 1.0
theta_deg = 5
lambda = 0.8
"""


def limited(*args, timeout=TIME_LIMIT, python=False):
    """``python -m vine_nlp ARGS`` (or ``python -c ARGS[0]``) within 1 GB of address space and ``timeout`` s."""
    def preexec():
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (MEMORY, MEMORY))

    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", PYTHONWARNINGS="error::RuntimeWarning")
    cmd = [sys.executable, "-c", *args] if python else [sys.executable, "-m", "vine_nlp", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, preexec_fn=preexec, env=env)


def one_line(stderr: str, file, key: str) -> str:
    lines = stderr.splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith(f"error: {file}: {key}: "), stderr
    return lines[0]


def refused(capsys, args, file, key) -> str:
    """``main(args)`` exits 2 with one error line naming ``file`` and ``key``; returns the line."""
    assert main([str(a) for a in args]) == 2
    return one_line(capsys.readouterr().err, file, key)


@pytest.fixture(scope="module")
def forward_archive(tmp_path_factory):
    d = tmp_path_factory.mktemp("hostile")
    (d / "f.toml").write_text(FORWARD)
    assert main(["forward", str(d / "f.toml"), "-o", str(d / "f.h5")]) == 0
    return d / "f.h5"


@pytest.fixture(scope="module")
def design_archive(tmp_path_factory):
    d = tmp_path_factory.mktemp("hostile-design")
    (d / "p.toml").write_text(TINY_TREFOIL)
    assert main(["design", str(d / "p.toml"), "-o", str(d / "d.h5")]) == 0
    return d / "d.h5"


def hostile(src: Path, tmp_path: Path, edit, name="h.h5") -> Path:
    path = tmp_path / name
    path.write_bytes(src.read_bytes())
    with h5py.File(path, "a") as h5:
        edit(h5)
    return path


# ---------------------------------------------------------------- archives: links, virtual and external data, bombs

def _external(h5, where):
    other = Path(h5.filename).with_name("other.h5")
    with h5py.File(other, "a") as o:
        o.require_dataset("x", shape=(10, 3), dtype="f8")
    h5[where] = h5py.ExternalLink(str(other), "/x")


def _fifo_link(h5, where):
    fifo = Path(h5.filename).with_name("pipe.h5")
    if not fifo.exists():
        os.mkfifo(fifo)
    h5[where] = h5py.ExternalLink(str(fifo), "/x")


def _virtual(h5, where):
    layout = h5py.VirtualLayout(shape=(10, 3), dtype="f8")
    layout[:] = h5py.VirtualSource("missing.h5", "data", shape=(10, 3))
    h5.create_virtual_dataset(where, layout, fillvalue=0.0)


def _bomb(h5, where):
    # 80 kB on disk, 4.8 GB when read: refused by its declared size before a byte of it is read
    h5.create_dataset(where, shape=(2 * 10**8, 3), dtype="f8", chunks=(10**5, 3), compression="gzip", fillvalue=1.0)


# name -> (edit(h5, dataset path), the key of the error, part of its reason)
HOSTILE_ARCHIVES = {
    "external-link": (_external, "/measured/points", "ExternalLink"),
    "external-link-to-a-fifo": (_fifo_link, "/measured/points", "ExternalLink"),
    "soft-link": (lambda h5, w: h5.__setitem__(w, h5py.SoftLink("/runs/forward/shape/center")), "/measured/points", "SoftLink"),
    "virtual-dataset": (_virtual, "/measured/points", "virtual dataset"),
    "external-storage": (lambda h5, w: h5.create_dataset(w, shape=(10, 3), dtype="f8", external=[("raw.bin", 0, 240)]),
                         "/measured/points", "external files"),
    "compressed-bomb": (_bomb, "/obstacles/0/vertices", "600000000 values, more than the limit"),
    "ansi-in-a-name": (lambda h5, w: h5.create_dataset(f"{w}\x1b[31mred", data=np.zeros(3)), "/measured/points\x1b[31mred", "printable"),
    "ansi-in-a-text": (lambda h5, w: h5["problem"].attrs.__setitem__("name", "\x1b]0;owned\x07"), "/problem@name", "printable"),
    "text-dataset": (lambda h5, w: h5.create_dataset(w, data=np.array([b"a", b"b"])), "/measured/points", "real numbers"),
    "chunks": (lambda h5, w: h5.create_dataset(w, shape=(10**6,), dtype="f8", chunks=(1,)), "/measured/points", "chunks"),
    "declared-size": (lambda h5, w: h5.create_dataset(w, shape=(4 * 10**6, 3), dtype="f4", chunks=(10**4, 3), fillvalue=1.0),
                      "/measured/points", "12000000 values"),
}


@pytest.mark.parametrize("case", list(HOSTILE_ARCHIVES))
def test_hostile_archive_is_one_line_within_limits(forward_archive, tmp_path, case):
    edit, key, reason = HOSTILE_ARCHIVES[case]
    path = hostile(forward_archive, tmp_path, lambda h5: edit(h5, key.strip("/").split("\x1b")[0]))
    r = limited("show", path)
    assert r.returncode == 2
    line = one_line(r.stderr, path, printable(key))
    assert reason in line and "\x1b" not in line


def test_correct_copies_nothing_through_a_link(design_archive, tmp_path, capsys):
    def edit(h5):
        other = tmp_path / "secret.h5"
        with h5py.File(other, "w") as o:
            o["x"] = np.full((50, 3), 7.0)
        h5["measured/points"] = h5py.ExternalLink(str(other), "/x")

    path = hostile(design_archive, tmp_path, edit)
    pts = load_archive(design_archive).runs["nlp"].shape.outer
    np.savetxt(tmp_path / "m.csv", pts, delimiter=",")
    refused(capsys, ["correct", path, tmp_path / "m.csv", "-o", tmp_path / "c.h5"], path, "/measured/points")
    assert not (tmp_path / "c.h5").exists()


def test_an_archived_source_is_read_with_the_problem_checks(design_archive, tmp_path, capsys):
    source = load_archive(design_archive).source.replace("samples = 41", "samples = " + "9" * 5000)
    path = hostile(design_archive, tmp_path, lambda h5: h5["problem"].attrs.__setitem__("source", source))
    np.savetxt(tmp_path / "m.csv", load_archive(design_archive).runs["nlp"].shape.outer, delimiter=",")
    # the source cannot be read: the archive's own data stands in (its target, the run's own pairing)
    assert main(["correct", str(path), str(tmp_path / "m.csv"), "-o", str(tmp_path / "c.h5")]) == 0
    assert load_archive(tmp_path / "c.h5").runs["as_built"].routing.segments == load_archive(path).runs["nlp"].routing.segments


def test_calibrate_refuses_a_compressed_bomb(forward_archive, tmp_path):
    def edit(h5):
        h5.create_dataset("runs/forward/uncertainty/theta", shape=(10**9,), dtype="f8", chunks=(10**5,), compression="gzip", fillvalue=0.5)
        h5.create_group("correction").attrs["format"] = "vine_nlp/correction"

    path = hostile(forward_archive, tmp_path, edit)
    r = limited("calibrate", path, "-o", tmp_path / "cal.toml")
    assert r.returncode == 2
    assert "1000000000 values" in one_line(r.stderr, path, "/runs/forward/uncertainty/theta")
    assert not (tmp_path / "cal.toml").exists()


# ---------------------------------------------------------------- text files: pipes, devices, sizes

def test_problem_file_that_is_no_regular_file(tmp_path):
    fifo = tmp_path / "p.toml"
    os.mkfifo(fifo)
    for path in (fifo, Path("/dev/zero"), tmp_path):
        r = limited("design", path, "-o", tmp_path / "o.h5")
        assert r.returncode == 2
        assert re.search("not a regular file|is a directory", one_line(r.stderr, path, "file"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.toml"]


def test_a_4_gb_calibration_file_is_refused_by_its_size(tmp_path):
    with open(tmp_path / "cal.toml", "wb") as fh:
        fh.truncate(4 << 30)  # sparse: no disk used
    (tmp_path / "p.toml").write_text(TINY_TREFOIL.replace('units = "cm"', 'units = "cm"\ncalibration = "cal.toml"'))
    r = limited("design", tmp_path / "p.toml", "-o", tmp_path / "o.h5")
    assert r.returncode == 2
    assert "MAX_TOML_BYTES" in one_line(r.stderr, tmp_path / "p.toml", "calibration")
    assert not (tmp_path / "o.h5").exists()


def test_problem_files_up_to_the_limit_make_archives_that_load(tmp_path, capsys):
    text = FORWARD + "# padding\n" * ((limits.MAX_TOML_BYTES - len(FORWARD)) // 10)
    assert len(text) <= limits.MAX_TOML_BYTES
    (tmp_path / "big.toml").write_text(text)
    assert main(["forward", str(tmp_path / "big.toml"), "-o", str(tmp_path / "big.h5")]) == 0
    assert load_archive(tmp_path / "big.h5").source == text
    (tmp_path / "huge.toml").write_text(text + "#" * (11 << 20))  # the 11 MB file of the issue
    refused(capsys, ["forward", tmp_path / "huge.toml", "-o", tmp_path / "huge.h5"], tmp_path / "huge.toml", "file")
    assert not (tmp_path / "huge.h5").exists()


def test_a_csv_of_1e7_rows_stops_at_the_point_limit(tmp_path):
    (tmp_path / "big.csv").write_bytes(b"x,y,z\n" + b"1,2,3\n" * 10**7)
    (tmp_path / "p.toml").write_text('[tube]\ndiameter = 2\n[target]\ncurve = "points"\nfile = "big.csv"\n')
    r = limited("design", tmp_path / "p.toml", "-o", tmp_path / "o.h5")
    assert r.returncode == 2
    assert "MAX_TARGET_POINTS" in one_line(r.stderr, tmp_path / "big.csv", "values")
    assert not (tmp_path / "o.h5").exists()


@pytest.mark.parametrize("row, reason", [("1_0, 2, 3", "'1_0' is not a number"), ("1, 2, " + "3" * 20000, "longer than 10000 characters"),
                                         ("0x10, 2, 3", "'0x10' is not a number")], ids=["underscore", "long-line", "hex"])
def test_csv_numbers_are_plain_decimal(tmp_path, capsys, row, reason):
    (tmp_path / "t.csv").write_text(f"0,0,0\n{row}\n2,0,0\n")
    (tmp_path / "p.toml").write_text('[tube]\ndiameter = 2\n[target]\ncurve = "points"\nfile = "t.csv"\n')
    line = refused(capsys, ["design", tmp_path / "p.toml", "-o", tmp_path / "o.h5"], tmp_path / "t.csv", "line 2")
    assert reason in line


BOX_OBJ = """v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1
f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8
"""
MESH_PROBLEM = TINY_TREFOIL + '[[obstacles]]\nshape = "mesh"\nfile = "{file}"\n'
READ = "import sys; from vine_nlp.io.problem_file import load_problem; print(len(load_problem(sys.argv[1]).problem.obstacles[0].faces))"


def test_obj_mtllib_is_never_opened(tmp_path):
    pytest.importorskip("trimesh")
    with open(tmp_path / "huge.mtl", "wb") as fh:
        fh.truncate(3 << 30)
    os.mkfifo(tmp_path / "pipe.mtl")
    (tmp_path / "box.obj").write_text("mtllib pipe.mtl\nmtllib huge.mtl\nusemtl stone\n" + BOX_OBJ)
    (tmp_path / "p.toml").write_text(MESH_PROBLEM.format(file="box.obj"))
    r = limited(READ, str(tmp_path / "p.toml"), python=True)
    assert r.returncode == 0 and r.stdout.strip() == "12", r.stderr


def test_mesh_paths_outside_the_problem_folder_are_allowed(tmp_path):
    pytest.importorskip("trimesh")
    (tmp_path / "box.obj").write_text(BOX_OBJ)
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub/p.toml").write_text(MESH_PROBLEM.format(file="../box.obj"))
    assert len(load_problem(tmp_path / "sub/p.toml").problem.obstacles[0].faces) == 12  # documented: like a script's


# ---------------------------------------------------------------- numbers where they enter

def _trefoil(**changes) -> str:
    text = TINY_TREFOIL
    for old, new in changes.items():
        text = text.replace(old, new)
    return text


NUMBERS = {
    "diameter-1e-15": (_trefoil(**{"diameter = 2.43": "diameter = 1e-15"}), "tube.diameter", "too thin"),
    "diameter-1e300": (_trefoil(**{"diameter = 2.43": "diameter = 1e300"}), "tube.diameter", "must be <= 1e+09"),
    "scale-1e300": (_trefoil(**{"[4.0, 4.0, 4.0]": "[1e300, 1e300, 1e300]"}), "target.scale", "coordinates up to"),
    "scale-1e-300": (_trefoil(**{"[4.0, 4.0, 4.0]": "[1e-300, 1e-300, 1e-300]"}), "target.scale", "less than 1e-06 tube diameters"),
    "5000-digit-integer": (_trefoil(**{"samples = 41": "samples = " + "9" * 5000}), "line 8", "64-bit"),
    "400-digit-calibration": (TINY_TREFOIL + "[calibration]\nlambda_offset = " + "9" * 400 + "\n", "calibration.lambda_offset", "64-bit"),
    "nul-in-name": (_trefoil(**{'name = "tiny-trefoil"': 'name = "a\\u0000b"'}), "name", "printable"),
    "nul-in-units": (_trefoil(**{'units = "cm"': 'units = "c\\u0000m"'}), "units", "printable"),
    "units-of-100-characters": (_trefoil(**{'units = "cm"': f'units = "{"u" * 100}"'}), "units", "longer than 32"),
    "nul-in-obstacle-name": (TINY_TREFOIL + '[[obstacles]]\nshape = "sphere"\nname = "o\\u0000"\ncenter = [0, 0, 50]\nradius = 1\n',
                             "obstacles.0.name", "printable"),
    "huge-obstacle": (TINY_TREFOIL + '[[obstacles]]\nshape = "sphere"\ncenter = [1e300, 0, 0]\nradius = 1\n',
                      "obstacles[0].center", "magnitude"),
}


@pytest.mark.parametrize("case", list(NUMBERS))
def test_bad_values_are_one_line_where_they_enter(tmp_path, case):
    text, key, reason = NUMBERS[case]
    (tmp_path / "p.toml").write_text(text)
    r = limited("design", tmp_path / "p.toml", "-o", tmp_path / "o.h5")
    assert r.returncode == 2 and reason in one_line(r.stderr, tmp_path / "p.toml", key)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.toml"]


def test_400_digit_integer_in_a_calibration_file(tmp_path, capsys):
    (tmp_path / "cal.toml").write_text("[calibration]\nlength_scale = " + "1" * 400 + "\n")
    (tmp_path / "p.toml").write_text(_trefoil(**{'units = "cm"': 'units = "cm"\ncalibration = "cal.toml"'}))
    refused(capsys, ["design", tmp_path / "p.toml", "-o", tmp_path / "o.h5"], tmp_path / "cal.toml", "calibration.length_scale")


def test_32_character_units_make_an_archive_that_loads(tmp_path):
    (tmp_path / "f.toml").write_text(FORWARD.replace('units = "cm"', f'units = "{"u" * limits.MAX_UNITS_CHARS}"'))
    assert main(["forward", str(tmp_path / "f.toml"), "-o", str(tmp_path / "f.h5")]) == 0
    assert load_archive(tmp_path / "f.h5").units == "u" * limits.MAX_UNITS_CHARS


def test_a_30000_level_dotted_key_in_a_sweep_grid(tmp_path):
    (tmp_path / "base.toml").write_text(TINY_TREFOIL)
    (tmp_path / "s.toml").write_text('base = "base.toml"\n[grid]\n' + ".".join(["a"] * 30000) + " = [1]\n")
    r = limited("sweep", tmp_path / "s.toml", "-o", tmp_path / "out")
    assert r.returncode == 2
    assert "more than 32 dotted parts" in one_line(r.stderr, tmp_path / "s.toml", "line 3")
    assert not (tmp_path / "out").exists()


def test_a_nul_through_a_sweep_grid_is_refused_before_any_work(tmp_path, capsys):
    (tmp_path / "base.toml").write_text(TINY_TREFOIL)
    (tmp_path / "s.toml").write_text('base = "base.toml"\n[grid]\nunits = ["cm", "c\\u0000m"]\n')
    refused(capsys, ["sweep", tmp_path / "s.toml", "-o", tmp_path / "out"], tmp_path / "s.toml", "grid.units.1")
    assert not (tmp_path / "out").exists()  # no summary.csv, no lock


# ---------------------------------------------------------------- strings: the error line cannot be forged

@pytest.mark.parametrize("key", ["tube\nerror: forged", "\x1b[2J\x1b[31mred", "nul\x00key", "\u202eevil"])
def test_keys_never_forge_or_colour_the_error_line(tmp_path, capsys, key):
    toml_key = key.encode("unicode_escape").decode().replace("\\x", "\\u00")
    (tmp_path / "p.toml").write_text(f'"{toml_key}" = 1\n' + TINY_TREFOIL)
    assert main(["design", str(tmp_path / "p.toml"), "-o", str(tmp_path / "o.h5")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: {tmp_path / 'p.toml'}: ")
    assert err.strip().isprintable() and printable(key) in err


def test_input_error_escapes_what_it_shows():
    e = InputError("a\nb.toml", "k\x1b[0m", "bad\x00")
    assert str(e) == "a\\nb.toml: k\\x1b[0m: bad\\x00" and e.key == "k\x1b[0m"


# ---------------------------------------------------------------- a degenerate measurement

def test_400_copies_of_one_point_are_no_measurement(design_archive, tmp_path, capsys):
    np.savetxt(tmp_path / "one.csv", np.tile([[1.0, 2.0, 3.0]], (400, 1)), delimiter=",")
    line = refused(capsys, ["correct", design_archive, tmp_path / "one.csv", "-o", tmp_path / "c.h5"], tmp_path / "one.csv", "values")
    assert "1 distinct points" in line and not (tmp_path / "c.h5").exists()
    (tmp_path / "fit.toml").write_text(FORWARD.replace("[routing]", '[measured]\nfile = "one.csv"\nline = "outer"\n[routing]'))
    refused(capsys, ["fit", tmp_path / "fit.toml", "-o", tmp_path / "f.h5"], tmp_path / "one.csv", "values")
    # collinear but spread along the robot: a straight tube is a measurement
    t = np.linspace(0.0, 12.0, 50)[:, None]
    np.savetxt(tmp_path / "line.csv", np.hstack([t, 0 * t, 0 * t]), delimiter=",")
    assert load_problem(_fit_file(tmp_path, "line.csv")).problem.measured.shape == (50, 3)


def _fit_file(tmp_path, data):
    (tmp_path / "fit2.toml").write_text(FORWARD.replace("[routing]", f'[measured]\nfile = "{data}"\nline = "outer"\n[routing]'))
    return tmp_path / "fit2.toml"


# ---------------------------------------------------------------- outputs: all or none, created exclusively

def test_design_with_a_figure_in_a_read_only_directory_writes_nothing(tmp_path, capsys):
    if os.geteuid() != 0:
        pytest.skip("a read-only directory needs a read-only mount (root) here")
    ro = tmp_path / "ro"
    ro.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)], capture_output=True).returncode:
        pytest.skip("mount -t tmpfs not allowed here")
    try:
        out = tmp_path / "a.h5"
        line = refused(capsys, ["design", ROOT / "problems/bezier-c.toml", "-o", out, "--plot", ro / "fig.png"], ro / "fig.png", "write")
        assert "Read-only file system" in line and not out.exists()
    finally:
        subprocess.run(["umount", "-l", str(ro)], capture_output=True)


def test_export_writes_both_files_or_none(forward_archive, tmp_path, capsys, monkeypatch):
    pytest.importorskip("trimesh")
    written = []
    real = Path.write_bytes

    def second_fails(self, data):
        written.append(self)
        if len(written) == 2:
            raise OSError(28, "No space left on device")
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", second_fails)
    refused(capsys, ["export", forward_archive, "-o", tmp_path / "tube.stl"], tmp_path / "tube.actuator.stl", "write")
    assert list(tmp_path.iterdir()) == []  # no tube.stl, no temporary file


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_force_never_replaces_what_is_not_a_regular_file(tmp_path, capsys, kind):
    target = tmp_path / "null"
    if kind == "fifo":
        os.mkfifo(target)
    elif os.geteuid() == 0:
        os.mknod(target, stat.S_IFCHR | 0o666, os.makedev(1, 3))  # a /dev/null of our own
    else:
        pytest.skip("making a device node needs root")
    line = refused(capsys, ["forward", ROOT / "problems/three-section-helix.toml", "-o", target, "--force"], target, "write")
    assert "never replaced" in line
    mode = os.lstat(target).st_mode
    assert (stat.S_ISFIFO if kind == "fifo" else stat.S_ISCHR)(mode) and sorted(p.name for p in tmp_path.iterdir()) == ["null"]


def test_two_runs_to_one_new_file_one_of_them_exits_2(tmp_path):
    out = tmp_path / "d.h5"
    env, fifo = hold_env(tmp_path / "hold", "solve")
    first = spawn(["design", ROOT / "problems/bezier-c.toml", "-o", out], env)  # reserved d.h5, held in its solve
    _, marker = wait_for_marker(first, "solve")
    second = subprocess.run([sys.executable, "-m", "vine_nlp", "design", str(ROOT / "problems/bezier-c.toml"), "-o", str(out)],
                            capture_output=True, text=True, env=env, timeout=120)
    assert second.returncode == 0, second.stderr
    written = out.read_bytes()
    release(fifo)
    rc, err = finish(first, marker)
    err = "\n".join(line for line in err.splitlines() if not line.startswith("vine-nlp: test hold"))
    assert rc == 2 and "exists (written meanwhile by another process)" in one_line(err, out, "-o")
    assert out.read_bytes() == written and sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_temporary_files_of_a_killed_run_are_swept(tmp_path):
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    env, fifo = hold_env(tmp_path / "hold", "solve")
    proc = spawn(["design", ROOT / "problems/bezier-c.toml", "-o", out_dir / "d.h5"], env)
    pid, _ = wait_for_marker(proc, "solve")
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)
    left = [p.name for p in out_dir.iterdir()]
    assert len(left) == 1 and f".vine-nlp-{pid}-" in left[0]  # what SIGKILL leaves
    outputs._swept.discard(os.path.abspath(out_dir))
    write_atomic(out_dir / "other.txt", lambda t: Path(t).write_text("x"))
    assert [p.name for p in out_dir.iterdir()] == ["other.txt"]


def test_a_failed_commit_puts_back_the_files_it_replaced(tmp_path):
    a = tmp_path / "a.txt"
    a.write_text("old a")
    with pytest.raises(InputError), outputs.run():
        outputs.reserve(a, True)
        outputs.reserve(tmp_path / "c.txt", False)
        write_atomic(a, lambda t: Path(t).write_text("new a"))
        write_atomic(tmp_path / "c.txt", lambda t: Path(t).write_text("c"))
        (tmp_path / "c.txt").mkdir()  # after the check: the second output cannot be committed
    assert a.read_text() == "old a" and sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "c.txt"]
    assert (tmp_path / "c.txt").is_dir()


# ---------------------------------------------------------------- the solver honours Ctrl-C and SIGTERM

SOLVE_1E15 = """
import dataclasses, sys
from vine_nlp import interrupt
from vine_nlp.io.problem_file import load_problem
from vine_nlp.methods.nlp import design_nlp
interrupt.install()
pf = load_problem(sys.argv[1])
design_nlp(pf.problem)  # builds (and compiles) the solvers of this structure
print("solving", flush=True)
try:
    # a solve that runs until stopped: IPOPT (C++) and the compiled functions (C) asked for a tolerance no iterate meets
    slow = dataclasses.replace(pf.problem.options, tol=1e-300, max_iter=10**9, starts=1, hops=0)
    while True:
        design_nlp(dataclasses.replace(pf.problem, options=slow))
except KeyboardInterrupt:
    print("interrupted", flush=True)
    sys.exit(130)
"""


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="CPU time read from /proc")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_solve_in_c_code_honours_signals(tmp_path, sig):
    from vine_nlp.methods import compiled

    if compiled.compiler() is None:
        pytest.skip("no C compiler: the solve is to run in compiled functions")
    env = dict(os.environ, VINE_NLP_CODEGEN="on", VINE_NLP_CFLAGS="-O0", VINE_NLP_CACHE_DIR=str(tmp_path / "cache"))
    proc = subprocess.Popen([sys.executable, "-c", SOLVE_1E15, str(ROOT / "problems/trefoil-m4.toml")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout.readline().strip() == "solving"
        start, give_up = _cpu_seconds(proc.pid), time.monotonic() + 300
        while _cpu_seconds(proc.pid) < start + 2.0:  # two seconds of CPU in the solve (an event, not a guess)
            if proc.poll() is not None or time.monotonic() > give_up:
                proc.kill()
                pytest.fail(f"no solve to interrupt: {proc.communicate()[1]}")
            time.sleep(0.05)  # polling for the event, not assuming it
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=TIME_LIMIT)
    finally:
        proc.kill()
    assert proc.returncode == 130 and out.strip() == "interrupted", err


# ---------------------------------------------------------------- fuzzing each reader

_text = st.text(st.characters(blacklist_categories=("Cs",)), max_size=12)
_value = st.one_of(st.integers(-(10**30), 10**30), st.floats(allow_nan=True), _text,
                   st.sampled_from(["1e-300", "1e300", "1e-15", '"\\u0000"', '"\\u001b[31m"', "nan", "-inf", "9" * 500, "1_0"]))
_keys = st.sampled_from(["name", "units", "tube.diameter", "target.scale", "target.samples", "target.curve", "target.file",
                         "design.points_per_segment", "calibration", "actuator.lambda_min", "obstacles"])


def _toml(v) -> str:
    """A TOML value: strings quoted with every non-ASCII or control character escaped; the sampled literals as they are."""
    if isinstance(v, str) and not v.startswith(('"', "1", "9", "n", "-")):
        return '"' + "".join(c if " " <= c < "\x7f" and c not in '"\\' else f"\\U{ord(c):08x}" for c in v) + '"'
    return repr(v) if isinstance(v, float) else str(v)


PROBLEM_TEMPLATE = """name = {name}
units = {units}
calibration = {calibration}
[tube]
diameter = {diameter}
[target]
curve = "trefoil"
scale = [{scale}, 4.0, 4.0]
samples = {samples}
[design]
points_per_segment = {n}
[[obstacles]]
shape = "sphere"
name = {obstacle}
center = [{center}, 0.0, 40.0]
radius = 1.0
"""
_FIELDS = {"name": '"p"', "units": '"cm"', "calibration": "{lambda_offset = 0.0}", "diameter": "2.43", "scale": "4.0", "samples": "41",
           "n": "5", "obstacle": '"o"', "center": "0.0"}


@FUZZ
@given(changes=st.dictionaries(st.sampled_from(sorted(_FIELDS)), _value, max_size=3))
def test_fuzz_problem_files(tmp_path, changes):
    text = PROBLEM_TEMPLATE.format(**{**_FIELDS, **{k: _toml(v) for k, v in changes.items()}})
    (tmp_path / "p.toml").write_text(text)
    try:
        pf = load_problem(tmp_path / "p.toml")
    except InputError as e:
        assert str(e).isprintable() and e.file == str(tmp_path / "p.toml")
        return
    p = pf.problem
    assert pf.name.isprintable() and pf.units.isprintable() and len(pf.units) <= limits.MAX_UNITS_CHARS
    assert all(o.name.isprintable() for o in p.obstacles) and np.abs(p.obstacles[0].center).max() <= limits.MAX_COORDINATE
    span = np.linalg.norm(np.ptp(p.target, axis=0)) / p.diameter
    assert np.abs(p.target).max() <= limits.MAX_COORDINATE and limits.MIN_DIAMETERS <= span <= limits.MAX_DIAMETERS


@FUZZ
@given(key=st.one_of(_keys, _text, st.just(".".join(["a"] * 40))), values=st.lists(_value, min_size=1, max_size=3))
def test_fuzz_sweep_files(tmp_path, key, values):
    (tmp_path / "base.toml").write_text(TINY_TREFOIL)
    grid = ", ".join(_toml(v) for v in values)
    (tmp_path / "s.toml").write_text(f'base = "base.toml"\n[grid]\n"{_toml(key).strip(chr(34))}" = [{grid}]\n')
    try:
        sweep = load_sweep(tmp_path / "s.toml")
    except InputError as e:
        assert all(c.isprintable() for c in str(e))
        return
    for _, _, pf in sweep.items():
        assert len(pf.source) <= limits.MAX_TEXT_CHARS


_DECIMAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")
_cell = st.one_of(st.floats(allow_nan=False, allow_infinity=False).map(repr),
                  st.sampled_from(["1_0", "0x1", "1e999", "nan", "١", "１", "\x00", "1,", "#", "x"]))


@FUZZ
@given(rows=st.lists(st.lists(_cell, min_size=3, max_size=3), min_size=1, max_size=12), sep=st.sampled_from([",", " ", "\t", ", "]))
def test_fuzz_csv_points(tmp_path, rows, sep):
    from vine_nlp.io.data_files import data_points
    from vine_nlp.io.validate import SourceFile

    (tmp_path / "m.csv").write_text("\n".join(sep.join(r) for r in rows), encoding="utf-8")
    try:
        pts = data_points(SourceFile(str(tmp_path / "p.toml")), "measured.file", "m.csv", ordered=False)
    except InputError as e:
        assert str(e).isprintable()
        return
    # accepted: every row a plain decimal row (a first row of words is a header), read as Python reads decimals
    cells = [r for r in rows if "#" not in "".join(r)]
    data = cells[1:] if not all(_DECIMAL.fullmatch(c) for c in cells[0]) else cells
    assert all(_DECIMAL.fullmatch(c) for r in data for c in r)
    np.testing.assert_array_equal(pts, np.array([[float(c) for c in r] for r in data]))


def _mesh_bytes(kind: str) -> bytes:
    import trimesh

    data = trimesh.creation.box().export(file_type=kind)
    return data.encode() if isinstance(data, str) else data


@FUZZ
@given(kind=st.sampled_from(["stl", "obj", "ply"]), cuts=st.lists(st.tuples(st.integers(0, 2000), st.binary(max_size=12)), max_size=4),
       head=st.sampled_from([b"", b"mtllib /dev/zero\n", b"element vertex 99999999999\n", b"solid x\n"]))
def test_fuzz_meshes(tmp_path, kind, cuts, head):
    pytest.importorskip("trimesh")
    from vine_nlp.io.obstacles import load_mesh_file

    data = bytearray(_mesh_bytes(kind))
    for at, junk in cuts:
        data[at % len(data):at % len(data) + len(junk)] = junk
    path = tmp_path / f"m.{kind}"
    path.write_bytes(bytes(head) + bytes(data))
    try:
        v, f = load_mesh_file(path)
    except InputError as e:
        assert e.file == str(path)
        return
    assert np.all(np.isfinite(v)) and len(f) <= 20_000 and f.max() < len(v)


@FUZZ
@given(edits=st.lists(st.tuples(st.sampled_from(sorted(HOSTILE_ARCHIVES)), st.sampled_from(["measured", "runs/forward", "x/y"])),
                     min_size=1, max_size=3))
def test_fuzz_archives(forward_archive, tmp_path, edits):
    (tmp_path / "h.h5").unlink(missing_ok=True)

    def edit(h5):
        for k, (case, group) in enumerate(edits):
            HOSTILE_ARCHIVES[case][0](h5, f"{group}/fuzz{k}")

    path = hostile(forward_archive, tmp_path, edit)
    with pytest.raises(ArchiveError):  # every edit is one the reader refuses, reading none of the data
        load_archive(path)


# ---------------------------------------------------------------- round 2 (issue 48): commands that add to an archive keep the rest

def _contents(path) -> dict:
    """Every attribute and dataset of an archive: path -> bytes or repr."""
    out = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            out[name] = obj[()].tobytes()
        out.update({f"{name}@{k}": repr(v) for k, v in obj.attrs.items()})

    with h5py.File(path, "r") as h5:
        visit("", h5)
        h5.visititems(visit)
    return out


@pytest.fixture(scope="module")
def archive_kinds(tmp_path_factory, design_archive):
    """One archive of each kind a command makes: kind -> path."""
    d = tmp_path_factory.mktemp("kinds")
    (d / "f.toml").write_text(FORWARD)
    (d / "cal.toml").write_text(TINY_TREFOIL + "[calibration]\nlambda_offset = 0.01\ntheta_offset_deg = 0.2\n")
    np.savetxt(d / "m.csv", load_archive(design_archive).runs["nlp"].shape.outer + 0.05, delimiter=",")
    commands = {"forward": ["forward", d / "f.toml"], "calibrated": ["design", d / "cal.toml"],
                "correction": ["correct", design_archive, d / "m.csv"], "multishape": ["design", ROOT / "problems/multishape-spam.toml"],
                "tip": ["design", ROOT / "problems/tip-target.toml"], "obstacle": ["design", ROOT / "problems/obstacle-gap.toml"],
                "fit": ["fit", ROOT / "problems/fit-sinusoidal.toml"]}
    kinds = {"design": design_archive}
    for kind, args in commands.items():
        assert main([*map(str, args), "-o", str(d / f"{kind}.h5")]) == 0
        kinds[kind] = d / f"{kind}.h5"
    return kinds


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["design", "forward", "calibrated", "correction", "multishape", "tip", "obstacle", "fit"])
def test_write_metrics_keeps_everything_it_does_not_own(archive_kinds, tmp_path, capsys, kind):
    path = tmp_path / "a.h5"
    path.write_bytes(archive_kinds[kind].read_bytes())
    before = _contents(path)
    run = load_archive(path).default_run()
    assert main(["analyze", str(path), "--write-metrics", "--samples", "20"]) == 0
    after = _contents(path)
    assert {k: v for k, v in after.items() if k in before} == before  # nothing lost, nothing changed
    added = set(after) - set(before)
    assert added and all(k.startswith(f"runs/{run}/metrics@") for k in added)
    load_archive(path)
    if kind == "correction":  # what the issue found broken afterwards: the next correction and calibrate
        out = capsys.readouterr().out
        assert main(["calibrate", str(path), "-o", str(tmp_path / "cal.toml")]) == 0, out


# ---------------------------------------------------------------- round 2: every number of an archive checked by the problem files' rules

def _fill(path, value):
    def edit(h5):
        h5[path][...] = np.full(h5[path].shape, value)
    return edit


def _zero_segments(h5):
    for name in ("theta", "lambda", "length", "phi"):
        del h5[f"runs/nlp/design/{name}"]
        h5[f"runs/nlp/design/{name}"] = np.zeros(1 if name == "phi" else 0)


RANGES = {
    "theta-90-deg": (_fill("runs/nlp/design/theta", np.pi / 2), "/runs/nlp/design/theta", "|theta| must be < 90 deg (segment 1: 90 deg)"),
    "theta-1e6-deg": (_fill("runs/nlp/design/theta", -np.radians(1e6)), "/runs/nlp/design/theta", "|theta| must be < 90 deg"),
    "theta-just-under-90-deg": (_fill("runs/nlp/design/theta", np.radians(89.9999999)), "/runs/nlp/design/theta", "MAX_WINDING"),
    "lambda-1.5": (_fill("runs/nlp/design/lambda", 1.5), "/runs/nlp/design/lambda", "must be in (0, 1] (segment 1: 1.5)"),
    "lambda-1e300": (_fill("runs/nlp/design/lambda", 1e300), "/runs/nlp/design/lambda", "must be in (0, 1]"),
    "length-1e300": (_fill("runs/nlp/design/length", 1e300), "/runs/nlp/design/length", "MAX_COORDINATE"),
    "length-1e-300": (_fill("runs/nlp/design/length", 1e-300), "/runs/nlp/design/length", "MIN_DIAMETERS"),
    "diameter-1e300": (lambda h5: h5["tube"].attrs.__setitem__("diameter", 1e300), "/tube@diameter", "MAX_COORDINATE"),
    "diameter-1e-300": (lambda h5: h5["tube"].attrs.__setitem__("diameter", 1e-300), "/runs/nlp/design/length", "MAX_DIAMETERS"),
    "zero-segments": (_zero_segments, "/runs/nlp/design/theta", "at least one segment"),
    "shape-1e300": (_fill("runs/nlp/shape/center", 1e300), "/runs/nlp/shape/center", "MAX_COORDINATE"),
    "pose-far-away": (lambda h5: h5["runs/nlp/design/initial_pose"].__setitem__((0, 3), 1e300), "/runs/nlp/design/initial_pose", "MAX_COORDINATE"),
    "target-1e300": (_fill("target/points", 1e300), "/target/points", "MAX_COORDINATE"),
}
ARCHIVE_COMMANDS = {
    "show": [], "plot": ["-o", "{out}/o.png"], "template": ["-o", "{out}/o.pdf"], "view": ["-o", "{out}/o.html"],
    "animate": ["-o", "{out}/o.gif"], "export": ["-o", "{out}/o.stl"], "analyze": [], "correct": ["{out}/m.csv", "-o", "{out}/c.h5"],
    "forward": ["-o", "{out}/f.h5"], "calibrate": ["-o", "{out}/cal.toml"],
}


@pytest.mark.parametrize("case", list(RANGES))
def test_archive_values_out_of_range_are_one_line_in_every_command(design_archive, tmp_path, capsys, case):
    edit, key, reason = RANGES[case]
    path = hostile(design_archive, tmp_path, edit)
    out = tmp_path / "out"
    out.mkdir()
    np.savetxt(out / "m.csv", load_archive(design_archive).runs["nlp"].shape.outer, delimiter=",")
    for command, rest in ARCHIVE_COMMANDS.items():
        assert reason in refused(capsys, [command, path, *(a.format(out=out) for a in rest)], path, key), command
    assert sorted(p.name for p in out.iterdir()) == ["m.csv"]
    (tmp_path / "p.toml").write_text(TINY_TREFOIL)
    assert reason in refused(capsys, ["design", tmp_path / "p.toml", "--warm", path, "-o", out / "d.h5"], path, key)


# ---------------------------------------------------------------- round 2: an archive is self-contained

POINTS_PROBLEM = 'name = "pts"\nunits = "cm"\ncalibration = "cal.toml"\n[tube]\ndiameter = 2.0\n[target]\ncurve = "points"\nfile = "t.csv"\n' \
                 '[design]\npoints_per_segment = 4\n'


def test_analyze_and_correct_open_no_file_an_archive_names(tmp_path, capsys):
    made, moved = tmp_path / "made", tmp_path / "moved"
    made.mkdir(), moved.mkdir()
    (made / "p.toml").write_text(POINTS_PROBLEM)
    (made / "cal.toml").write_text("[calibration]\nlambda_offset = 0.01\n")
    t = np.linspace(0.0, 1.0, 33)[:, None]
    np.savetxt(made / "t.csv", np.hstack([30 * t, 5 * np.sin(3 * t), 3 * t * t]), delimiter=",")
    assert main(["design", str(made / "p.toml"), "-o", str(moved / "d.h5")]) == 0
    for name in ("p.toml", "cal.toml", "t.csv"):  # what the archive names, beside it and where it was made: unreadable
        (made / name).unlink()
        os.mkfifo(moved / name)
    os.mkfifo(made / "t.csv")
    np.savetxt(tmp_path / "m.csv", load_archive(moved / "d.h5").runs["nlp"].shape.outer + 0.02, delimiter=",")
    capsys.readouterr()
    assert main(["analyze", str(moved / "d.h5"), "--samples", "20"]) == 0
    assert "Monte Carlo" in capsys.readouterr().out
    assert main(["correct", str(moved / "d.h5"), str(tmp_path / "m.csv"), "-o", str(tmp_path / "c.h5")]) == 0


def test_a_run_that_cannot_pair_with_the_archived_target_is_one_line(design_archive, tmp_path, capsys):
    def two_points(h5):
        del h5["target/points"]
        h5["target/points"] = np.array([[0.0, 0, 0], [1.0, 0, 0]])
        for line in ("center", "inner", "outer"):
            del h5[f"runs/nlp/shape/{line}"]
            h5[f"runs/nlp/shape/{line}"] = np.array([[0.0, 0, 0], [1.0, 0, 0]])

    path = hostile(design_archive, tmp_path, two_points)
    np.savetxt(tmp_path / "m.csv", load_archive(design_archive).runs["nlp"].shape.outer, delimiter=",")
    reason = "8 segments cannot pair with the 2 points of /target/points"
    assert reason in refused(capsys, ["analyze", path], path, "/runs/nlp/design/theta")
    assert reason in refused(capsys, ["correct", path, tmp_path / "m.csv", "-o", tmp_path / "c.h5"], path, "/runs/nlp/design/theta")
    assert not (tmp_path / "c.h5").exists()


@pytest.mark.slow
def test_one_segment_designs_a_uniform_helix(tmp_path, capsys):
    # a helix of 6 samples, 5 per segment: one segment (CasADi's "matrices are not iterable" before)
    (tmp_path / "p.toml").write_text('[tube]\ndiameter = 2.0\n[target]\ncurve = "helix"\nradius = 3.0\npitch = 1.2\nlength = 10.0\n'
                                     'samples = 6\n[design]\npoints_per_segment = 5\n')
    assert main(["design", str(tmp_path / "p.toml"), "-o", str(tmp_path / "d.h5")]) == 0
    r = load_archive(tmp_path / "d.h5").runs["nlp"]
    assert r.routing.segments == 1 and r.metrics["rmse"] < 1e-3  # a helix is what one segment makes


# ---------------------------------------------------------------- round 2: what the tool writes, it reads

def test_a_shortfall_of_several_lines_reads_back(forward_archive, tmp_path):
    from vine_nlp.io.archive import write_archive

    a = load_archive(forward_archive)
    r = a.runs["forward"]
    r.shortfall = ("obstacle margin: 0.1 short", "clearance:\nmin gap 0.2 short")
    write_archive(tmp_path / "s.h5", a)
    assert load_archive(tmp_path / "s.h5").runs["forward"].shortfall == ("obstacle margin: 0.1 short", "clearance:; min gap 0.2 short")


@pytest.mark.parametrize("value, key, reason", [(1e300, "/correction/systematic", "lambda_offset must be a finite number of magnitude <= 1e+06"),
                                                (0.7, "/correction/systematic", "lambda_offset must be within +-0.5, got 0.7")])
def test_calibrate_writes_only_what_a_design_reads(archive_kinds, tmp_path, capsys, value, key, reason):
    path = hostile(archive_kinds["correction"], tmp_path, lambda h5: h5["correction/systematic"].__setitem__(1, value))
    for args in (["calibrate", path, "-o", tmp_path / "cal.toml"], ["correct", path, tmp_path / "m.csv", "-o", tmp_path / "c.h5"]):
        assert reason in refused(capsys, args, path, key)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h.h5"]


def test_write_calibration_refuses_what_the_reader_refuses(tmp_path):
    from vine_nlp.io.calibration import write_calibration
    from vine_nlp.model.calibration import Calibration

    with pytest.raises(InputError, match="calibration.length_scale: must be > 0 and <= 10, got 20.0"):
        write_calibration(tmp_path / "cal.toml", Calibration(length_scale=20.0))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_each_written_file_feeds_the_next_command(archive_kinds, tmp_path, capsys):
    # correct -> correct (a second round) -> calibrate -> a design naming the calibration -> analyze, forward
    c = archive_kinds["correction"]
    np.savetxt(tmp_path / "m2.csv", load_archive(c).runs["corrected"].shape.outer + 0.03, delimiter=",")
    assert main(["correct", str(c), str(tmp_path / "m2.csv"), "-o", str(tmp_path / "c2.h5")]) == 0
    assert main(["calibrate", str(tmp_path / "c2.h5"), "-o", str(tmp_path / "cal.toml")]) == 0
    (tmp_path / "p.toml").write_text(TINY_TREFOIL.replace('units = "cm"', 'units = "cm"\ncalibration = "cal.toml"'))
    assert load_problem(tmp_path / "p.toml").problem.calibration.prototypes == 1
    assert main(["design", str(tmp_path / "p.toml"), "-o", str(tmp_path / "d.h5")]) == 0
    assert main(["analyze", str(tmp_path / "d.h5"), "--samples", "20", "--write-metrics"]) == 0
    assert main(["forward", str(tmp_path / "d.h5"), "-o", str(tmp_path / "f.h5")]) == 0
    assert main(["show", str(tmp_path / "f.h5")]) == 0


# ---------------------------------------------------------------- round 2: signals end in one line and exit 130

def _interrupting(monkeypatch, raiser):
    import vine_nlp.front.cli as cli

    monkeypatch.setattr(cli, "cmd_show", lambda args: raiser())


def test_a_signal_that_h5py_turns_into_a_system_error_is_the_interrupt(forward_archive, monkeypatch, capsys):
    from vine_nlp import interrupt

    def fast_rlock():
        interrupt._requested.set()  # what the signal's handler did before h5py's lock swallowed its KeyboardInterrupt
        raise SystemError("<cyfunction FastRLock.__exit__> returned a result with an exception set")

    _interrupting(monkeypatch, fast_rlock)
    assert main(["show", str(forward_archive)]) == 130
    assert capsys.readouterr().err == "interrupted: nothing partial was written\n"


def test_a_keyboard_interrupt_in_a_weakref_callback_ends_the_command(forward_archive, monkeypatch, capsys):
    import weakref

    def callback_raises():
        def stop(_):
            raise KeyboardInterrupt

        class Thing:
            pass

        thing = Thing()
        ref = weakref.ref(thing, stop)
        del thing  # the callback's KeyboardInterrupt cannot propagate: Python reports it as unraisable
        for _ in range(10**6):  # the command goes on: the interrupt comes back to it in the main thread
            pass
        return ref

    _interrupting(monkeypatch, callback_raises)
    assert main(["show", str(forward_archive)]) == 130
    assert capsys.readouterr().err == "interrupted: nothing partial was written\n"  # no "Exception ignored in" traceback


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("command", ["show", "plot", "view", "template", "export", "analyze", "correct"])
def test_a_signal_while_an_archive_is_open_is_one_line(design_archive, tmp_path, command, sig):
    out = tmp_path / "out"
    out.mkdir()
    np.savetxt(tmp_path / "m.csv", load_archive(design_archive).runs["nlp"].shape.outer, delimiter=",")
    rest = {"plot": ["-o", out / "o.png"], "view": ["-o", out / "o.html"], "template": ["-o", out / "o.pdf"], "export": ["-o", out / "o.stl"],
            "analyze": ["--write-metrics"], "correct": [tmp_path / "m.csv", "-o", out / "c.h5"]}.get(command, [])
    archive = tmp_path / "d.h5"
    archive.write_bytes(design_archive.read_bytes())
    env, fifo = hold_env(tmp_path / "hold", "archive")
    proc = spawn([command, archive, *rest], env)
    _, marker = wait_for_marker(proc, "archive")
    proc.send_signal(sig)
    rc, err = finish(proc, marker)
    err = [line for line in err.splitlines() if not line.startswith("vine-nlp: test hold")]
    assert rc == 130 and err == ["interrupted: nothing partial was written"], (err, marker)
    assert list(out.iterdir()) == [] and archive.read_bytes() == design_archive.read_bytes()


# ---------------------------------------------------------------- round 2: a full disk is one line, whatever the output

def _full_disk(*args, size=200):
    """``python -m vine_nlp ARGS`` able to write at most ``size`` bytes to any file (RLIMIT_FSIZE; SIGXFSZ ignored: EFBIG)."""
    def preexec():
        import resource

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))

    return subprocess.run([sys.executable, "-m", "vine_nlp", *map(str, args)], capture_output=True, text=True, timeout=120, preexec_fn=preexec)


FULL_DISK = {"pdf": ("template", "o.pdf"), "svg": ("template", "o.svg"), "dxf": ("template", "o.dxf"), "png": ("plot", "o.png"),
             "plot-pdf": ("plot", "o.pdf"), "gif": ("animate", "o.gif"), "mp4": ("animate", "o.mp4"), "stl": ("export", "o.stl"),
             "glb": ("export", "o.glb"), "html": ("view", "o.html"), "hdf5": ("forward", "o.h5"), "toml": ("calibrate", "cal.toml"),
             "tolerance-pdf": ("analyze", "t.pdf")}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(FULL_DISK))
def test_a_full_disk_is_one_line_and_nothing_written(archive_kinds, tmp_path, case):
    command, name = FULL_DISK[case]
    if case == "mp4":
        from vine_nlp.front.animate import ffmpeg_available

        if not ffmpeg_available():
            pytest.skip("no ffmpeg")
    out = tmp_path / "out"
    out.mkdir()
    archive = archive_kinds["correction" if command == "calibrate" else "design"]
    args = [command, archive, "--samples", "10", "--tolerance-figure", out / name] if command == "analyze" else [command, archive, "-o", out / name]
    r = _full_disk(*args, *(["--frames", "3"] if command == "animate" else []))
    assert r.returncode == 2 and "nothing was written" in one_line(r.stderr, out / name, "write")
    assert list(out.iterdir()) == []


# ---------------------------------------------------------------- round 2: command-line numbers are checked like a file's

COMMAND_LINE = [
    (["analyze", "{a}", "--samples", "-5"], "--samples: must be an integer >= 1 and <= 100000, got -5"),
    (["analyze", "{a}", "--samples", "1000000000"], "--samples: must be an integer >= 1 and <= 100000"),
    (["analyze", "{a}", "--seed", "-1"], "--seed: must be an integer >= 0 and <= 4294967295, got -1"),
    (["analyze", "{a}", "--margin", "nan"], "--margin: must be a finite number >= 0 and <= 1e+09, got nan"),
    (["analyze", "{a}", "--margin", "1000"], "--margin: 1000 is more than the tube's length"),
    (["analyze", "{a}", "--sigma-lambda", "nan"], "--sigma-lambda: must be a finite number >= 0 and <= 1, got nan"),
    (["design", "{p}", "-o", "{o}", "--clearance", "--min-gap", "nan"], "--min-gap: must be a finite number >= 0"),
    (["design", "{p}", "-o", "{o}", "--clearance", "--min-gap", "1e308"], "--min-gap: must be a finite number >= 0 and <= 1e+09, got 1e308"),
    (["design", "{p}", "-o", "{o}", "--clearance", "--min-gap", "1e6"], "--min-gap: 1e+06 is wider than the target"),
    (["design", "{p}", "-o", "{o}", "--starts", "1000000", "--budget", "0"], "--starts: must be an integer >= 1 and <= 1000"),
    (["design", "{p}", "-o", "{o}", "--hops", "1000000"], "--hops: must be an integer >= 0 and <= 1000"),
    (["design", "{p}", "-o", "{o}", "--budget", "inf"], "--budget: must be a finite number >= 0"),
    (["animate", "{a}", "-o", "{o}.gif", "--frames", "100000"], "--frames: must be an integer >= 2 and <= 150, got 100000"),
    (["template", "{a}", "-o", "{o}.pdf", "--run", ""], "--run: must be the name of a run"),
    (["export", "{a}", "-o", "{o}.stl", "--run", "\x1b[31m"], "--run: must be the name of a run"),
    (["correct", "{a}", "{a}", "-o", "{o}", "--sigma-measurement", "inf"], "--sigma-measurement: must be a finite number > 0"),
]


@pytest.mark.parametrize("args, reason", COMMAND_LINE, ids=[" ".join(a[:1] + a[3:]) for a, _ in COMMAND_LINE])
def test_command_line_numbers_are_one_line(design_archive, tmp_path, capsys, args, reason):
    (tmp_path / "p.toml").write_text(TINY_TREFOIL)
    fill = dict(a=design_archive, p=tmp_path / "p.toml", o=tmp_path / "o")
    args = [a.format(**fill) for a in args]
    err = capsys.readouterr() and main(args)
    line = capsys.readouterr().err.strip()
    assert err == 2 and reason in line and line.count("\n") == 0 and line.startswith("error: command line: "), line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.toml"]


def test_a_warm_start_that_cannot_be_read_names_the_archive(design_archive, tmp_path, capsys):
    (tmp_path / "p.toml").write_text(TINY_TREFOIL)
    (tmp_path / "EMPTY.h5").write_bytes(b"")
    line = refused(capsys, ["design", tmp_path / "p.toml", "--warm", tmp_path / "EMPTY.h5", "-o", tmp_path / "o.h5"], tmp_path / "EMPTY.h5", "file")
    assert "not an HDF5 file" in line
    empty = hostile(design_archive, tmp_path, _zero_segments, "no-segments.h5")
    line = refused(capsys, ["design", tmp_path / "p.toml", "--warm", empty, "-o", tmp_path / "o.h5"], empty, "/runs/nlp/design/theta")
    assert "at least one segment" in line and not (tmp_path / "o.h5").exists()


# ---------------------------------------------------------------- round 2: every limit costs at most its time and memory

def _long_tube(tmp_path, length, step, name="long", D=2.0):
    (tmp_path / f"{name}.toml").write_text(FORWARD.replace("length = 12.0", f"length = {length}").replace("segment_length = 1.0", f"segment_length = {step}")
                                           .replace("diameter = 2.0", f"diameter = {D}")
                                           .replace("theta_deg = 5", 'theta_deg = "10 * sin(0.01 * s)"'))
    assert main(["forward", str(tmp_path / f"{name}.toml"), "-o", str(tmp_path / f"{name}.h5")]) == 0
    return tmp_path / f"{name}.h5"


DRAWING = {"plot": ["-o", "o.png"], "view": ["-o", "o.html"], "animate": ["-o", "o.gif", "--frames", "3"], "export": ["-o", "o.stl"],
           "template": ["-o", "o.svg"], "analyze": ["--samples", "20"]}


def test_commands_say_what_they_cannot_afford(tmp_path, capsys):
    path = _long_tube(tmp_path, 600.0, 0.1)  # 6000 segments, 300 tube diameters
    out = tmp_path / "out"
    out.mkdir()
    for command, rest in DRAWING.items():
        most = limits.COMMAND_LIMITS[command][0]
        line = refused(capsys, [command, path, *(str(out / a) if a.startswith("o.") else a for a in rest)], path, "runs")
        assert f"run forward: 6000 segments; {command} handles at most {most}" in line
    short = _long_tube(tmp_path, 580.0, 1.0, "short")  # 580 segments, 290 diameters: 5.8 m of tube
    line = refused(capsys, ["template", short, "-o", out / "o.pdf"], short, "runs")
    assert "5.8 m of tube; a 1:1 template takes at most 5 m" in line
    assert list(out.iterdir()) == []


@pytest.mark.slow
@pytest.mark.parametrize("command", list(DRAWING))
def test_each_command_at_its_limits_within_time_and_memory(tmp_path_factory, tmp_path, command):
    most_segments, most_diameters = limits.COMMAND_LIMITS[command]
    d = tmp_path_factory.mktemp("corner")
    D = 1.6 if command == "template" else 2.0  # a template's 300 diameters within its 5 m (limits.MAX_TEMPLATE_MM)
    path = _long_tube(d, D * most_diameters, D * most_diameters / most_segments, D=D)  # both limits at once
    r = limited(command, path, *(str(tmp_path / a) if a.startswith("o.") else a for a in DRAWING[command]), timeout=3 * TIME_LIMIT)
    assert r.returncode == 0, r.stderr  # 3 x 10 s: the machine these were measured on was shared (idle: 3 to 6 s)


@pytest.mark.slow
@pytest.mark.parametrize("command", list(DRAWING))
def test_a_tube_the_size_of_a_planet_through_every_drawing_command(tmp_path_factory, tmp_path, command):
    # 10 segments of a tube 5e8 cm wide and 1e9 cm long: every size and count within the limits, so nothing is
    # refused for its segments or diameters; each command draws it in its time and memory, the template alone says
    # its 1:1 print cannot take 1e7 m of tube (one line), with the machine's usual numbers nowhere near overflow
    path = _long_tube(tmp_path_factory.mktemp("huge"), 1e9, 1e8, name="huge", D=5e8)
    r = limited(command, path, *(str(tmp_path / a) if a.startswith("o.") else a for a in DRAWING[command]), timeout=3 * TIME_LIMIT)
    if command == "template":
        assert r.returncode == 2, r.stderr
        assert "run forward: 1e+07 m of tube; a 1:1 template takes at most 5 m" in one_line(r.stderr, path, "runs")
        assert list(tmp_path.iterdir()) == []
    else:
        assert r.returncode == 0 and r.stderr == "", r.stderr
        written = {p.suffix for p in tmp_path.iterdir()}  # export: the tube's mesh and its actuator's
        assert written == (set() if command == "analyze" else {Path(DRAWING[command][1]).suffix}), written


def _many_runs(h5):
    for k in range(limits.MAX_RUNS):
        h5.copy(h5["runs/forward"], f"runs/r{k}")


ARCHIVE_SIZES = {
    "101-runs": (_many_runs, "/runs", "101 runs, more than the limit of 100"),
    "2000-nested-groups": (lambda h5: h5.create_group("deep/" + "/".join(["a"] * 2000)), "/deep/" + "/".join(["a"] * 16), "nested more than 16"),
    "20000-groups": (lambda h5: [h5.create_group(f"junk/{k}") for k in range(20000)], None, "more than 5000 objects"),
    "a-mesh-of-40000-faces": (lambda h5: (h5.create_group("obstacles/0").attrs.__setitem__("shape", "mesh"),
                                          h5.create_dataset("obstacles/0/vertices", data=np.zeros((4, 3))),
                                          h5.create_dataset("obstacles/0/faces", data=np.zeros((40000, 3), int))),
                              "/obstacles/0/faces", "has 40000 rows; at most 20000"),
}


@pytest.mark.parametrize("case", list(ARCHIVE_SIZES))
def test_archive_sizes_are_refused_within_time(forward_archive, tmp_path, case):
    edit, key, reason = ARCHIVE_SIZES[case]
    path = hostile(forward_archive, tmp_path, edit)
    r = limited("view", path, "-o", tmp_path / "v.html")
    assert r.returncode == 2 and reason in r.stderr and r.stderr.count("\n") == 1, r.stderr
    if key:
        one_line(r.stderr, path, key)
    assert not (tmp_path / "v.html").exists()


@pytest.mark.slow
def test_analyze_of_a_mesh_at_the_face_limit_within_time_and_memory(design_archive, tmp_path):
    trimesh = pytest.importorskip("trimesh")
    mesh = trimesh.creation.uv_sphere(radius=3.0, count=[70, 72])  # 19 584 faces, closed
    assert len(mesh.faces) <= 20_000 and mesh.is_watertight

    def edit(h5):
        g = h5.create_group("obstacles/0")
        g.attrs["shape"] = "mesh"
        g["vertices"], g["faces"] = np.asarray(mesh.vertices) + [0.0, 0.0, 30.0], np.asarray(mesh.faces)

    r = limited("analyze", hostile(design_archive, tmp_path, edit), "--samples", "20", timeout=3 * TIME_LIMIT)
    assert r.returncode == 0 and "obstacles   1" in r.stdout, r.stderr


@pytest.mark.parametrize("obstacle, design, key, reason", [
    ('shape = "sphere"\ncenter = [0.0, 0.0, 0.0]\nradius = 100.0', "", "obstacles[0]", "the whole target lies inside the obstacles"),
    ('shape = "sphere"\ncenter = [0.0, 0.0, 100.0]\nradius = 3.0', "obstacle_margin = 1e9\n", "design.obstacle_margin",
     "1e+09 is wider than the room around the target"),
], ids=["target-inside", "margin-1e9"])
def test_a_design_that_cannot_start_is_one_line_before_it_solves(tmp_path, obstacle, design, key, reason):
    (tmp_path / "p.toml").write_text(TINY_TREFOIL + design + f"[[obstacles]]\n{obstacle}\n")
    r = limited("design", tmp_path / "p.toml", "-o", tmp_path / "o.h5")
    assert r.returncode == 2 and reason in one_line(r.stderr, tmp_path / "p.toml", key)
    assert not (tmp_path / "o.h5").exists()


def test_an_archived_measurement_of_1e5_copies_of_one_point(archive_kinds, tmp_path, capsys):
    def edit(h5):
        del h5["measured/0/points"]
        h5["measured/0/points"] = np.tile([[1.0, 2.0, 3.0]], (10**5, 1))

    path = hostile(archive_kinds["correction"], tmp_path, edit)
    np.savetxt(tmp_path / "m.csv", load_archive(archive_kinds["correction"]).runs["corrected"].shape.outer, delimiter=",")
    line = refused(capsys, ["correct", path, tmp_path / "m.csv", "-o", tmp_path / "c.h5"], path, "/measured/0/points")
    assert "1 distinct points" in line and not (tmp_path / "c.h5").exists()


@pytest.mark.parametrize("rows, reason, key", [(10**6, "more than 200 items", "rows"), (1, "longer than 10000 characters", "line 2")],
                         ids=["1e6-rows", "a-field-of-200000-characters"])
def test_a_sweep_view_of_a_summary_beyond_its_limits(forward_archive, tmp_path, rows, reason, key):
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    (sweep / "i-0001.h5").write_bytes(forward_archive.read_bytes())
    row = "i-0001,nlp,optimal,0.1,0.2,1.0,10," + ("x" * 200_000 if rows == 1 else "") + "\n"
    (sweep / "summary.csv").write_text("item,method,status,rmse,max_error,solve_time_s,iterations,error\n" + row * rows)
    r = limited("view", sweep, "-o", tmp_path / "v.html")
    assert r.returncode == 2 and reason in one_line(r.stderr, sweep / "summary.csv", key)
    assert not (tmp_path / "v.html").exists()


# ---------------------------------------------------------------- round 2: a fuzzer over archive values

EDGE_VALUES = [0.0, -1.0, 1e-300, -1e-300, 1e300, -1e300, float("nan"), float("inf"), float("-inf"), np.pi / 2, 90.0, 2**63]
FUZZ_COMMANDS = {"show": [], "plot": ["-o", "o.png"], "template": ["-o", "o.svg"], "view": ["-o", "o.html"], "export": ["-o", "o.stl"],
                 "animate": ["-o", "o.gif", "--frames", "2"], "analyze": ["--samples", "10", "--write-metrics"], "forward": ["-o", "o.h5"],
                 "correct": ["m.csv", "-o", "o.h5"], "calibrate": ["-o", "o.toml"]}


def _places(path) -> list:
    """Every dataset and attribute of an archive: ("ds", path) or ("attr", node path, name)."""
    out = []

    def visit(name, obj):
        out.extend(("attr", name, k) for k in obj.attrs)
        if isinstance(obj, h5py.Dataset):
            out.append(("ds", name, None))

    with h5py.File(path, "r") as h5:
        visit("/", h5)
        h5.visititems(visit)
    return sorted(out)


def _put(h5, place, value, whole):
    kind, name, attr = place
    if kind == "attr":
        h5[name].attrs[attr] = value
        return
    data = np.array(h5[name][()], dtype=float)
    if whole or data.ndim == 0:
        data[...] = value
    else:
        data.flat[len(data.flat) // 2] = value
    del h5[name]
    h5[name] = data


@pytest.mark.slow
@settings(max_examples=int(os.environ.get("VINE_NLP_FUZZ_EXAMPLES", "40")), deadline=None, derandomize=not os.environ.get("VINE_NLP_FUZZ_RANDOM"),
          database=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_fuzz_archive_values_through_every_command(archive_kinds, tmp_path, capsys, data):
    source = data.draw(st.sampled_from(["design", "correction", "obstacle", "multishape"]))
    place = data.draw(st.sampled_from(_places(archive_kinds[source])))
    value = data.draw(st.sampled_from(EDGE_VALUES))
    command = data.draw(st.sampled_from(sorted(FUZZ_COMMANDS)))
    work = tmp_path / f"x{len(list(tmp_path.iterdir()))}"
    work.mkdir()
    path = work / "a.h5"
    path.write_bytes(archive_kinds[source].read_bytes())
    with h5py.File(path, "a") as h5:
        _put(h5, place, value, data.draw(st.booleans()))
    np.savetxt(work / "m.csv", load_archive(archive_kinds["design"]).runs["nlp"].shape.outer + 0.02, delimiter=",")
    capsys.readouterr()
    code = main([command, str(path), *(str(work / a) if a[:2] in ("o.", "m.") else a for a in FUZZ_COMMANDS[command])])
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if not x.startswith("note: ")]
    assert code in (0, 1, 2), (place, value, command, err)
    if code == 2:
        assert len(lines) == 1 and lines[0].startswith("error: ") and lines[0].isprintable(), (place, value, command, err)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_before_the_command_line_is_imported(design_archive, tmp_path, sig):
    env, fifo = hold_env(tmp_path / "hold", "start")
    proc = spawn(["template", design_archive, "-o", tmp_path / "t.pdf"], env)
    _, marker = wait_for_marker(proc, "start")
    proc.send_signal(sig)
    rc, err = finish(proc, marker)
    assert rc == 130 and [x for x in err.splitlines() if not x.startswith("vine-nlp: test hold")] == ["interrupted: nothing partial was written"]
    assert not (tmp_path / "t.pdf").exists()


# ---------------------------------------------------------------- round 2: --budget bounds the whole design (starts, hops, rounds)

def test_a_spent_budget_runs_the_first_step_of_each_loop_only():
    from vine_nlp.methods import drive

    ran = []
    with drive.budget(0) as cut:
        found = drive.multistart(lambda s: ran.append(s) or Result("x", None, None, "optimal", objective=float(s)), [3, 1, 2])
        rounds = drive.refine(_Counting(), 5)
    assert ran == [3] and found.best.objective == 3.0 and rounds.rounds == 1
    assert cut == ["1 of 3 starts", "1 of 5 rounds"]
    with drive.budget(None) as cut:  # no budget: every start, every round
        assert len(drive.multistart(lambda s: Result("x", None, None, "optimal", objective=float(s)), [3, 1, 2]).results) == 3
        assert drive.refine(_Counting(), 5).rounds == 5 and cut == []


def test_a_budget_spent_during_a_start_stops_before_the_next():
    from vine_nlp.methods import drive

    ran = []

    def solve(s):  # the second start lasts until the budget is spent (the event itself, no guessed time)
        ran.append(s)
        while s == 2 and drive.remaining() > 0:
            time.sleep(drive.remaining())
        return Result("x", None, None, "optimal", objective=float(s))

    with drive.budget(0.05) as cut:
        found = drive.multistart(solve, [1, 2, 3, 4])
    assert ran == [1, 2] and found.best.objective == 1.0 and cut == ["2 of 4 starts"]


class _Counting:
    def solve(self, x, round, last):
        return x, Result("x", None, None, "optimal", objective=1.0)

    def judge(self, result):
        from vine_nlp.methods.drive import Verdict

        return Verdict(False, (False, 1.0))

    def refresh(self, result, verdict, x):
        return x


@pytest.mark.parametrize("more, cut", [(["--starts", "3"], "1 of 3 starts"), (["--hops", "2"], "0 of 2 hops")])
def test_design_within_a_budget_of_0_is_the_first_start_not_optimal(tmp_path, capsys, more, cut):
    (tmp_path / "p.toml").write_text(TINY_TREFOIL)
    assert main(["design", str(tmp_path / "p.toml"), "-o", str(tmp_path / "d.h5"), "--budget", "0", *more]) == 1
    assert capsys.readouterr().err.splitlines()[-1] == f"tiny-trefoil: nlp: max_time, the budget cut {cut}"
    run = load_archive(tmp_path / "d.h5").runs["nlp"]
    assert run.status == "max_time" and run.stats.get("starts", 1) == 1 and run.stats.get("hop_objectives", "[]") == "[]"


def test_a_budget_that_cuts_nothing_leaves_the_design_as_it_was(tmp_path):
    import vine_nlp as vn

    (tmp_path / "p.toml").write_text(TINY_TREFOIL)
    whole = vn.solve(tmp_path / "p.toml", starts=2, budget=3600).result
    assert whole.status == "optimal" and whole.stats["starts"] == 2 and "budget_cut" not in whole.stats
    cut = vn.solve(tmp_path / "p.toml", starts=2, budget=0).result
    assert cut.status == "max_time" and cut.stats["budget_cut"] == "1 of 2 starts" and not cut.ok
    points = load_problem(tmp_path / "p.toml").problem.target  # vn.design: the same bound
    assert vn.design(points, 2.43, starts=2, budget=0).status == "max_time" and vn.design(points, 2.43, starts=2).status == "optimal"


# ---------------------------------------------------------------- round 2: archives of several actuators, every number checked

@pytest.fixture(scope="module")
def actuators_archive(tmp_path_factory):
    """problems/actuators-reach.toml (three actuators, three states) on 41 samples a state: 4 segments."""
    d = tmp_path_factory.mktemp("actuators")
    (d / "p.toml").write_text((ROOT / "problems" / "actuators-reach.toml").read_text().replace("samples = 201", "samples = 41"))
    assert main(["design", str(d / "p.toml"), "-o", str(d / "a.h5")]) == 0
    return d / "a.h5"


def _all_lines(h5, names=("theta", "lambda", "phi")):
    for name in names:
        for where in ["runs/nlp/design", *(f"runs/nlp/actuators/{a}/design" for a in ("left", "right", "up"))]:
            del h5[f"{where}/{name}"]
            h5[f"{where}/{name}"] = np.zeros(1 if name == "phi" else 0)
    del h5["runs/nlp/design/length"]
    h5["runs/nlp/design/length"] = np.zeros(0)


def _phi0(value):
    def edit(h5):
        phi = h5["runs/nlp/actuators/right/design/phi"]
        phi[0] = value
    return edit


ACTUATOR_RANGES = {  # the second line's values (the first line's are the run's design/, checked as every archive's)
    "theta-90-deg": (_fill("runs/nlp/actuators/right/design/theta", np.pi / 2), "/runs/nlp/actuators/right/design/theta",
                     "|theta| must be < 90 deg (segment 1: 90 deg)"),
    "lambda-1.5": (_fill("runs/nlp/actuators/right/design/lambda", 1.5), "/runs/nlp/actuators/right/design/lambda", "must be in (0, 1] (segment 1: 1.5)"),
    "length-1e300": (_fill("runs/nlp/design/length", 1e300), "/runs/nlp/design/length", "MAX_COORDINATE"),
    "zero-segments": (_all_lines, "/runs/nlp/design/theta", "a routing needs at least one segment"),
    "phi0-nan": (_phi0(np.nan), "/runs/nlp/actuators/right/design/phi", "non-finite value nan at [0]"),
    "phi0-inf": (_phi0(-np.inf), "/runs/nlp/actuators/right/design/phi", "non-finite value -inf at [0]"),
}
ACTUATOR_COMMANDS = {"show": [], "plot": ["-o", "{out}/o.png"], "forward": ["--run", "nlp", "-o", "{out}/f.h5"]}


@pytest.mark.parametrize("case", list(ACTUATOR_RANGES))
def test_archives_of_several_actuators_out_of_range_are_one_line_in_every_command(actuators_archive, tmp_path, capsys, case):
    edit, key, reason = ACTUATOR_RANGES[case]
    path = hostile(actuators_archive, tmp_path, edit)
    out = tmp_path / "out"
    out.mkdir()
    np.savetxt(out / "m.csv", np.c_[np.arange(12.0), np.zeros(12), np.zeros(12)], delimiter=",")  # a measurement correct reads
    for command, rest in ACTUATOR_COMMANDS.items():  # the commands that read them
        assert reason in refused(capsys, [command, path, *(a.format(out=out) for a in rest)], path, key), command
    for command, rest in ARCHIVE_COMMANDS.items():  # and every other: one line (most refuse the kind today)
        if command not in ACTUATOR_COMMANDS:
            assert main([command, str(path), *(a.format(out=out) for a in rest)]) == 2, command
            lines = capsys.readouterr().err.splitlines()
            # calibrate reads correction archives only: a readable design archive is refused for that
            also = (f"error: {path}: /correction: ",) if command == "calibrate" else ()
            assert len(lines) == 1 and lines[0].startswith((f"error: {path}: {key}: ", f"error: {path}: kind: ", *also)), (command, lines)
    assert sorted(p.name for p in out.iterdir()) == ["m.csv"]


def test_a_width_wider_than_the_tube_in_an_archived_source_is_read_by_no_command(actuators_archive, tmp_path, capsys):
    """The archive stores no width (only the source text names one, and no command reads it back): a hostile one changes nothing."""
    def wide(h5):
        h5["problem"].attrs["source"] = h5["problem"].attrs["source"].replace("width = 0.4", "width = 100", 1)

    path = hostile(actuators_archive, tmp_path, wide)
    assert main(["show", str(actuators_archive)]) == 0
    plain = capsys.readouterr().out
    assert main(["show", str(path)]) == 0 and capsys.readouterr().out == plain.replace(str(actuators_archive), str(path))
    assert main(["forward", str(path), "--run", "nlp", "-o", str(tmp_path / "f.h5")]) == 0
    assert "width" not in load_archive(tmp_path / "f.h5").source
    (tmp_path / "p.toml").write_text(load_archive(path).source)  # designed again from it: the problem reader refuses it
    refused(capsys, ["design", tmp_path / "p.toml", "-o", tmp_path / "d.h5"], tmp_path / "p.toml", "actuators.0.width")


def test_runtime_warnings_are_errors_in_every_case_and_command_here():
    """The guard itself (module ``pytestmark`` and ``limited``): an overflow fails a case instead of passing beside a warning."""
    with pytest.raises(RuntimeWarning, match="overflow"):
        np.float64(1e308) * 10
    r = limited("import numpy; numpy.float64(1e308) * 10", python=True)
    assert r.returncode == 1 and r.stderr.strip().endswith("RuntimeWarning: overflow encountered in scalar multiply"), r.stderr


def test_a_line_wound_almost_at_90_deg_is_one_line_in_a_problem_file(tmp_path, capsys):
    """At 89.9999999 deg every command would sample a line 5.7e8 times the tube's length (terabytes): the routing rule
    MAX_WINDING refuses it; at 89 deg (57x) the tube is run."""
    path = tmp_path / "w.toml"
    text = 'name = "w"\nunits = "cm"\n[tube]\ndiameter = 2\n[routing]\nlength = 12\nsegment_length = 1\ntheta_deg = {}\nlambda = 0.8\n'
    path.write_text(text.format(89.9999999))
    assert main(["forward", str(path), "-o", str(tmp_path / "f.h5")]) == 2
    assert capsys.readouterr().err.strip() == (f"error: {path}: routing.theta_deg: the actuator line is 5.73e+08 times as long as the "
                                               "tube (theta near 90 deg): at most 100 (vine_nlp.io.limits.MAX_WINDING)")
    assert not (tmp_path / "f.h5").exists()
    path.write_text(text.format(89.0))
    assert main(["forward", str(path), "-o", str(tmp_path / "f.h5")]) == 0


@pytest.mark.parametrize("fmt", ["pdf", "svg", "dxf"])
def test_a_template_longer_than_five_metres_is_one_line(tmp_path, capsys, fmt):
    """A 1:1 template of 5.1 m of tube: one line for every format (a 50 m SVG or DXF took a minute and 5 GB)."""
    problem = tmp_path / "long.toml"
    problem.write_text('name = "long"\nunits = "cm"\n[tube]\ndiameter = 30\n[routing]\nlength = 510\nsegment_length = 51\n'
                       'theta_deg = 10\nlambda = 0.8\n')
    assert main(["forward", str(problem), "-o", str(tmp_path / "f.h5")]) == 0
    capsys.readouterr()
    assert main(["template", str(tmp_path / "f.h5"), "-o", str(tmp_path / f"t.{fmt}")]) == 2
    assert capsys.readouterr().err.strip() == (f"error: {tmp_path / 'f.h5'}: runs: run forward: 5.1 m of tube; a 1:1 template takes "
                                               "at most 5 m (vine_nlp.io.limits.MAX_TEMPLATE_MM)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.h5", "long.toml"]
