"""Compiled NLP functions: CasADi's C code generation, compiled once per structure and cached on disk.

IPOPT calls five functions of the NLP per iteration; interpreted, they run CasADi's MX virtual machine over the mapped
per-stage SX blocks, compiled the same expressions run as C (the answers agree to rounding). A structure built from an
active set (clearance pairs, obstacle rows) seldom recurs: it runs interpreted with each block type compiled on its own
(``block_functions``, up to BLOCK_BUDGET instructions; a map of samples runs on its one-sample block).

A library is keyed by everything that decides the generated code: the Spec without the solver's settings, the CasADi
version, the compiler and its flags, and the source of model/ and methods/ (a changed formula never loads a stale
library); a run never waits for the compiler: where the library is missing it solves on the interpreted functions and
leaves the C code to a detached, niced compiler process (one per library on the machine: ``<library>.lock``; one at a
time per cache: ``.compiler.lock``) that writes the library atomically; later builds, in this process too
(``Upgrading``), load it. A failed compile leaves ``<library>.failed`` (delete it to try again). Environment:
``VINE_NLP_CODEGEN`` ``auto`` (default: compile in the background where a C compiler is found, else interpreted, said
once), ``on`` (compile before the solve; a missing or failing compiler is an error), ``off``; ``VINE_NLP_CACHE_DIR``
(default ``$XDG_CACHE_HOME/vine_nlp`` or ``~/.cache/vine_nlp``); ``CC``, ``VINE_NLP_CFLAGS`` (default gcc, then cc;
``-O1``). Notes go to the ``vine_nlp`` logger: compiling (INFO) and falling back to interpreted functions (WARNING, once
per process). ``wait(timeout)`` waits for this process's background compilers (tests, benchmarks)."""

from __future__ import annotations

import fcntl
import hashlib
import logging
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from functools import lru_cache
from pathlib import Path

from vine_nlp.errors import InputError
from vine_nlp.methods import blas
from vine_nlp.methods.settings import BLOCK_BUDGET

__all__ = ["mode", "cache_dir", "compiler", "wait", "nlpsol", "block_functions", "stored", "CompileError", "stats"]

_log = logging.getLogger("vine_nlp.methods.compiled")

# the functions IPOPT's interface asks an imported NLP for, by the names CasADi expects
_NAMES = ("nlp_f", "nlp_g", "nlp_grad_f", "nlp_grad", "nlp_jac_g")
MODES = ("auto", "on", "off")
DEFAULT_MODE = "auto"

# what happened in this process: loads from the cache, compilations, interpreted builds
stats = {"loaded": 0, "compiled": 0, "background": 0, "interpreted": 0, "compile_time_s": 0.0}
_warned: set[str] = set()
_running: list = []  # this process's background compilers (subprocess.Popen)

# the detached compiler (niced): one at a time per cache (.compiler.lock), the library's own lock inherited (its fd),
# the library renamed into place whole, or a .failed note with the compiler's first line; the build dir removed
_BACKGROUND = """import fcntl, os, shutil, subprocess, sys
work, target, queue, *cc = sys.argv[1:]
os.nice(10)  # the runs that need the CPU now come first (its own session: Linux weighs sessions by their autogroup's nice)
try:
    with open("/proc/self/autogroup", "w") as f:
        f.write("10")
except OSError:
    pass
try:
    with open(queue, "a") as q:
        fcntl.flock(q, fcntl.LOCK_EX)
        tmp = os.path.join(work, "lib.so")
        run = subprocess.run(cc + ["-shared", "-fPIC", os.path.join(work, "nlp.c"), "-o", tmp, "-lm"], capture_output=True, text=True)
        if run.returncode == 0:
            os.replace(tmp, target)
        elif run.returncode > 0:  # the compiler refused the code (a killed one leaves no note: tried again later)
            with open(os.path.join(work, "failed"), "w") as f:
                f.write((run.stderr.strip().splitlines() or ["no message"])[0])
            os.replace(os.path.join(work, "failed"), os.path.splitext(target)[0] + ".failed")
finally:
    shutil.rmtree(work, ignore_errors=True)
"""


class CompileError(RuntimeError):
    """VINE_NLP_CODEGEN=on and the NLP functions could not be compiled or loaded."""


class Upgrading:
    """An interpreted IPOPT solver that loads the compiled one once its background compile has written it
    (every call asks; the rest is the current solver's)."""

    def __init__(self, solver, path: Path, name: str, opts: dict):
        self._solver, self._path, self._name, self._opts = solver, path, name, opts

    def __call__(self, **kwargs):
        if self._path is not None and self._path.is_file():
            import casadi as ca
            try:
                self._solver = ca.nlpsol(self._name, "ipopt", str(self._path), self._opts)
                stats["loaded"] += 1
            except RuntimeError:
                _warn_once(f"cannot load {self._path}: the NLP functions run interpreted (slower)")
            self._path = None
        return self._solver(**kwargs)

    def __getattr__(self, name):
        return getattr(self._solver, name)


def mode() -> str:
    """The codegen setting: ``auto``, ``on`` or ``off`` (raises InputError on anything else)."""
    m = os.environ.get("VINE_NLP_CODEGEN", DEFAULT_MODE).strip().lower() or DEFAULT_MODE
    if m not in MODES:
        raise InputError("environment", "VINE_NLP_CODEGEN", f"expected one of {', '.join(MODES)}, got {m!r}")
    return m


def cache_dir() -> Path:
    d = os.environ.get("VINE_NLP_CACHE_DIR")
    return Path(d) if d else Path(os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")) / "vine_nlp"


def compiler() -> list[str] | None:
    """The C compiler command with its flags, or None where none is found."""
    cc = os.environ.get("CC")
    exe = shutil.which(cc) if cc else (shutil.which("gcc") or shutil.which("cc"))
    return [exe, *shlex.split(os.environ.get("VINE_NLP_CFLAGS", "-O1"))] if exe else None


@lru_cache(maxsize=1)
def _code_fingerprint() -> str:
    """The source of the layers whose formulas end up in the generated code."""
    h = hashlib.sha256()
    root = Path(__file__).resolve().parents[1]
    for sub in ("model", "methods"):
        for f in sorted((root / sub).rglob("*.py")):
            h.update(str(f.relative_to(root)).encode())
            h.update(f.read_bytes())
    return h.hexdigest()


def _key(spec_text: str, cc: list[str]) -> str | None:
    import casadi as ca  # CasADi loads where code is built: the command line checks settings without it
    # a repr that shows an address or numpy's elision does not describe the code: no disk cache
    if " at 0x" in spec_text or "..." in spec_text:
        return None
    h = hashlib.sha256()
    for part in (ca.__version__, _code_fingerprint(), " ".join(cc[1:]), os.path.basename(cc[0]), spec_text):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()[:40]


def _warn_once(text: str) -> None:
    if text not in _warned:
        _warned.add(text)
        _log.warning(text)


def _fallback(text: str, strict: bool):
    if strict:
        raise CompileError(text)
    _warn_once(text + ": the NLP functions run interpreted (slower)")
    stats["interpreted"] += 1
    return None


def library(spec_text: str, build_functions, prefix: str = "nlp", what: str = "the NLP functions for this structure",
            later: list | None = None) -> str | None:
    """Path of the compiled library for a solver (or one block type: ``prefix``, ``what``) where it is in the cache;
    else None (run interpreted) after starting its compile in the background (codegen ``auto``; ``on``: compiled first,
    its path returned). ``later`` gets the library's path where it is being compiled (here or by another process).

    ``build_functions()`` returns the CasADi functions to compile (called only on a cache miss)."""
    import casadi as ca
    _running[:] = [proc for proc in _running if proc.poll() is None]  # reap the compilers that ended
    m = mode()
    if m == "off":
        stats["interpreted"] += 1
        return None
    strict = m == "on"
    cc = compiler()
    if cc is None:
        return _fallback("no C compiler found (gcc or cc; set CC)", strict)
    key = _key(spec_text, cc)
    if key is None:
        stats["interpreted"] += 1
        return None
    target = cache_dir() / f"casadi-{ca.__version__}" / f"{prefix}-{key}.so"
    if target.is_file():
        stats["loaded"] += 1
        return str(target)
    failed = target.with_suffix(".failed")
    if not strict and failed.is_file():
        return _fallback(f"the C compiler failed ({failed.read_text(errors='replace').strip()}; delete {failed} to try again)", strict)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        lock = open(target.with_suffix(".lock"), "a")
    except OSError as e:
        return _fallback(f"cannot write the code cache {target.parent} ({e.strerror or e})", strict)
    with lock:
        try:  # one compile per library: "on" waits for another process's, "auto" runs interpreted meanwhile
            fcntl.flock(lock, fcntl.LOCK_EX if strict else fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            stats["interpreted"] += 1
            later is not None and later.append(target)
            return None
        if target.is_file():
            stats["loaded"] += 1
            return str(target)
        started = len(_running)
        path = _compile(target, build_functions, cc, strict, what, lock)
        if len(_running) > started and later is not None:
            later.append(target)
        return path


def _compile(target: Path, build_functions, cc: list[str], strict: bool, what: str, lock) -> str | None:
    """Generate the C code (milliseconds), then compile it: now (``strict``) or in a detached process
    that inherits the held ``lock``."""
    import casadi as ca
    try:
        work = tempfile.mkdtemp(prefix=".build-", dir=target.parent)
    except OSError as e:
        return _fallback(f"cannot write the code cache {target.parent} ({e.strerror or e})", strict)
    background = False
    try:
        t0 = time.perf_counter()
        _log.info("compiling %s %s (%s; cached in %s)", what, "now" if strict else "in the background", target.stem, target.parent)
        cg = ca.CodeGenerator("nlp.c", {"with_header": False})
        for f in build_functions():
            cg.add(f)
        cg.generate(work + os.sep)
        if not strict:
            queue = str(target.parent / ".compiler.lock")
            _running.append(subprocess.Popen([sys.executable, "-c", _BACKGROUND, work, str(target), queue, *cc], pass_fds=(lock.fileno(),),
                                             start_new_session=True, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            background = True
            stats["background"] += 1
            stats["interpreted"] += 1
            return None
        tmp = os.path.join(work, target.name)
        run = subprocess.run([*cc, "-shared", "-fPIC", os.path.join(work, "nlp.c"), "-o", tmp, "-lm"], capture_output=True, text=True)
        if run.returncode != 0:
            first = (run.stderr.strip().splitlines() or ["no message"])[0]
            return _fallback(f"the C compiler failed ({first})", strict)
        os.replace(tmp, target)
        stats["compiled"] += 1
        stats["compile_time_s"] += time.perf_counter() - t0
        return str(target)
    except OSError as e:
        return _fallback(f"cannot compile into {target.parent} ({e.strerror or e})", strict)
    finally:
        if not background:
            shutil.rmtree(work, ignore_errors=True)


def wait(timeout: float | None = None) -> bool:
    """Wait for this process's background compilers (at most ``timeout`` seconds in all); True when all ended."""
    end = None if timeout is None else time.monotonic() + timeout
    for proc in list(_running):
        try:
            proc.wait(None if end is None else max(0.0, end - time.monotonic()))
        except subprocess.TimeoutExpired:
            return False
        _running.remove(proc)
    return True


def block_functions(name: str, functions: list, budget: int | None = None) -> list | None:
    """Compiled copies of one block type's SX ``functions`` (value, derivatives), for a solver whose
    structure seldom recurs (an active set): the structure stays interpreted, its blocks run as C.

    Cached on disk per the functions' serialized form, so every structure built of the same block
    types (each new active set of pairs) loads them. None where they stay interpreted: codegen off, no
    compiler, a failed compile, or more than ``budget`` instructions (None: BLOCK_BUDGET)."""
    import casadi as ca
    if mode() == "off" or sum(f.n_instructions() for f in functions) > (BLOCK_BUDGET if budget is None else budget):
        return None
    digest = hashlib.sha256("\0".join(f.serialize() for f in functions).encode()).hexdigest()
    path = library(f"block {digest}", lambda: functions, prefix="blk", what=f"the block {name}")
    if path is None:
        return None
    try:
        return [ca.external(f.name(), path) for f in functions]
    except RuntimeError as e:
        if mode() == "on":
            raise CompileError(f"cannot load {path}: {str(e).splitlines()[0]}") from e
        _warn_once(f"cannot load {path}: the block {name} runs interpreted (slower)")
        return None


def stored(name: str, build) -> list:
    """CasADi functions kept serialized in the cache directory: reading them back takes
    milliseconds where building the segment's SX expressions takes tens (a command's start-up).

    ``build()`` returns the functions; it runs where codegen is off, on a miss, or when the
    stored copy does not match its checksum (then it is written again)."""
    import casadi as ca
    if mode() == "off":
        return build()
    path = cache_dir() / f"casadi-{ca.__version__}" / f"{name}-{_code_fingerprint()[:24]}.casadi"
    try:
        blob = path.read_bytes()
        digest, body = blob[:64], blob[64:]
        if hashlib.sha256(body).hexdigest().encode() == digest:
            return [ca.Function.deserialize(part.decode()) for part in body.split(b"\0")]
    except (OSError, RuntimeError, UnicodeDecodeError):
        pass
    functions = build()
    body = b"\0".join(f.serialize().encode() for f in functions)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}")
        tmp.write_bytes(hashlib.sha256(body).hexdigest().encode() + body)
        os.replace(tmp, path)
    except OSError:
        pass  # no cache: built again next time
    return functions


def oracle_functions(nlp: dict, interpreted):
    """The functions an imported NLP needs, named as CasADi's IPOPT interface asks for them:
    the oracle itself and the interpreted solver's derivative functions."""
    import casadi as ca
    out = [ca.Function("nlp", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]], ["x", "p"], ["f", "g"])]
    out += [interpreted.get_function(n) for n in _NAMES]
    h = interpreted.get_function("nlp_hess_l")
    args = [ca.MX.sym(h.name_in(i), h.sparsity_in(i)) for i in range(h.n_in())]
    # the importer checks output names: the triangle is named as CasADi's own Hessian factory names it
    out.append(ca.Function("nlp_hess_l", args, [h(*args)], ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"]))
    return out


def nlpsol(name: str, spec_text: str, nlp, opts: dict, enabled: bool = True):
    """An IPOPT solver on the compiled functions (``nlp``: a callable building the symbolic
    problem and the derivative options only when they are needed), or interpreted.
    ``enabled=False``: a structure that seldom recurs (an active set), not worth a compile."""
    import casadi as ca
    blas.one_thread()
    derived = {}

    def interpreted():
        if "solver" not in derived:
            problem, derivative_opts = nlp()
            derived["problem"] = problem
            derived["solver"] = ca.nlpsol(name, "ipopt", problem, dict(opts) | derivative_opts)
        return derived["solver"]

    def functions():
        solver = interpreted()
        return oracle_functions(derived["problem"], solver)

    if not enabled:
        stats["interpreted"] += 1
        return interpreted()
    later = []
    path = library(spec_text, functions, later=later)
    if path is None:
        return Upgrading(interpreted(), later[0], name, dict(opts)) if later else interpreted()
    try:
        return ca.nlpsol(name, "ipopt", path, dict(opts))
    except RuntimeError as e:
        if mode() == "on":
            raise CompileError(f"cannot load {path}: {str(e).splitlines()[0]}") from e
        _warn_once(f"cannot load {path}: the NLP functions run interpreted (slower)")
        return interpreted()
