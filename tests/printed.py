"""Printed outputs in the documentation, checked against what the code prints (issues 35, 47), and regenerated.

A fenced block that shows what a command prints follows a marker line in the Markdown:

    <!-- printed by: COMMAND -->               numbers within 2 % (or half a unit of the last digit shown)
    <!-- printed by: COMMAND; within 10 % -->  a stated tolerance

COMMAND is ``python3 examples/NN_name.py`` or ``examples/NN_name.ipynb`` (tests/test_examples.py runs
the example and checks its tutorial's blocks against what it printed) or a ``vine-nlp ...`` command line,
several joined by `` && `` (tests/test_docs_outputs.py runs it). Every line of the block must be printed, in
order (other lines may come between); its text must be the printed text (paths compared by their last part,
URLs not compared). Numbers:

- a whole number (no decimal point: iterations, segments, rounds, points) is a count: exactly what was printed;
- a number written ``about N`` is within ABOUT_FACTOR (2x) either way of what was printed; ``about`` before a
  count is refused;
- a timing or a rate (``about N s``, ``ms``, ``min``, ``items/s``: it depends on the clock and the machine's load) is not
  compared by the tests (a test that depends on the clock is a defect): ``python3 benchmarks/bench_docs_timings.py``
  runs the blocks that show one and checks them within 2x (``check(..., timings=True)``);
- every other number within the block's tolerance.

The suite runs the NLP functions interpreted (tests/conftest.py: ``VINE_NLP_CODEGEN=off``), as a first run on a
new machine does; so does the regeneration below. Later runs load the compiled functions, whose last digits may
lead IPOPT to a different iteration count.

Regenerate every block from the commands (after a change to what they print, or a merge):

    python3 tests/printed.py --update [PATTERN]   # rewrites the numbers of each block (of files matching PATTERN)

It runs each command as the tests do and writes the printed numbers into the block's lines (keeping ``about``,
to two digits); a line no longer printed is listed for a person to fix. Prose numbers that quote a block are not
touched: the script lists the blocks it changed so their pages can be re-read. An ``about`` figure is what this
machine printed at the time: on a machine whose load varies (the suite itself runs one process per core), set it
between an idle and a busy run, so that the 2x window holds both.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
MARKER = re.compile(r"<!-- printed by: (?P<command>.+?)(?:; within (?P<tol>[\d.]+) %)? -->[ \t]*\n```[^\n]*\n(?P<body>.*?)\n```", re.S)
NUMBER = re.compile(r"(?<![\w.])(about )?([-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?)(?![\w.])(?=( (?:s|ms|min|items/s)\b)?)")
DEFAULT_TOL = 0.02
ABOUT_FACTOR = 2.0


@dataclass
class Block:
    file: Path
    line: int  # of the marker
    command: str
    tol: float
    lines: list


def blocks(files=DOCS) -> list[Block]:
    """Every marked block of the documentation."""
    out = []
    for f in files:
        text = f.read_text()
        out += [blocks_in(f, m) for m in MARKER.finditer(text)]
    return out


def _word(w: str) -> str:
    """A word as compared: a URL as '<url>', a path by its last part."""
    if "://" in w:
        return "<url>" + ("" if w[-1].isalnum() else w[-1])
    if "/" in w and not w.startswith("<") and len(w) > 1:
        return w.rstrip("/").rsplit("/", 1)[-1]
    return w


def _skeleton(line: str):
    """(text with numbers as '#', [(value, about, last digit's unit, text as printed, a timing)])."""
    line = " ".join(_word(w) for w in line.split())
    numbers = []

    def keep(m):
        digits, _, exponent = m[2].lower().partition("e")
        unit = 10.0 ** (int(exponent or 0) - (len(digits.split(".")[1]) if "." in digits else 0))
        numbers.append((float(m[2]), bool(m[1]), unit, m[2], bool(m[3])))
        return "#"

    return NUMBER.sub(keep, line), numbers


def is_count(text: str) -> bool:
    return re.fullmatch(r"[-+]?\d+", text) is not None


def disagree(shown, got, tol: float, timings: bool = False) -> str | None:
    """Why a number shown disagrees with the one printed (None: it agrees). Counts are exact, ``about`` is 2x;
    a timing agrees unless ``timings`` (then 2x)."""
    w, about, unit, text, timing = shown
    g = got[0]
    if about:
        if is_count(text) and is_count(got[3]):
            return "a count is exact: drop 'about'"
        if timing and not timings:
            return None
        return None if (w == g == 0) or (w * g > 0 and 1 / ABOUT_FACTOR <= w / g <= ABOUT_FACTOR) else f"not within {ABOUT_FACTOR:g}x"
    if is_count(text) and is_count(got[3]):
        return None if w == g else "a count must be exact"
    return None if abs(w - g) <= max(tol * abs(g), 0.5 * unit) else f"not within {100 * tol:g} %"


def _match(block: Block, stdout: str, stderr: str):
    """For every line of the block: (its line, the printed line's skeleton numbers or None)."""
    streams = [[_skeleton(line) for line in text.splitlines() if line.strip()] for text in (stdout, stderr)]
    at = [0, 0]
    out = []
    for line in block.lines:
        text, _ = _skeleton(line)
        s = 1 if any(t == text for t, _ in streams[1]) else 0
        j = next((k for k in range(at[s], len(streams[s])) if streams[s][k][0] == text), None)
        out.append((line, None if j is None else streams[s][j][1]))
        if j is not None:
            at[s] = j + 1
    return out


def check(block: Block, stdout: str, stderr: str = "", timings: bool = False) -> list[str]:
    """What in ``block`` disagrees with what the command printed (empty: it shows what the command prints).
    A line the command printed on stderr is looked for there, the others on stdout, each in order; ``timings``:
    its ``about`` timings too (within 2x; the benchmark, not the tests)."""
    problems = []
    where = f"{block.file.relative_to(ROOT)}:{block.line}"
    for line, got in _match(block, stdout, stderr):
        if got is None:
            problems.append(f"{where}: not printed (in this order) by `{block.command}`: {line!r}")
            continue
        for shown, g in zip(_skeleton(line)[1], got):
            why = disagree(shown, g, block.tol, timings)
            if why:
                problems.append(f"{where}: {line!r}: {shown[3]} shown, {g[3]} printed ({why})")
    return problems


def unshown(printed_stderr: str, shown: list[Block]) -> list[str]:
    """Lines a command printed on stderr (warnings, shortfalls; not the compiler's notes) that no block shows."""
    texts = {_skeleton(line)[0] for b in shown for line in b.lines}
    return [line for line in printed_stderr.splitlines()
            if line.strip() and not line.startswith("note:") and _skeleton(line)[0] not in texts]


# ------------------------------------------------------------------ regeneration (--update)


def rewrite(line: str, got) -> str:
    """``line`` with its numbers replaced by the printed ones (``about`` kept but before a count), word by word as
    compared."""
    values = iter(g[3] for g in got)
    about = [a for _, a, _, _, _ in _skeleton(line)[1]]
    k = 0

    def number(m):
        nonlocal k
        v, rough = next(values, m[2]), about[k] if k < len(about) else False
        k += 1
        return f"{float(v):.2g}" if rough and not is_count(v) else v  # 'about': two digits

    parts = re.split(r"(\s+)", line)
    for i, w in enumerate(parts):
        if not w or w.isspace() or "://" in w:
            continue
        head, tail = (w.rstrip("/").rsplit("/", 1)[0] + "/", w[len(w.rstrip("/").rsplit("/", 1)[0]) + 1:]) if _word(w) != w else ("", w)
        parts[i] = head + NUMBER.sub(number, tail)
    return re.sub(r"\babout ([-+]?\d+)(?![\w.])", r"\1", "".join(parts))  # a count is exact: no 'about'



def run(command: str, cwd: Path) -> tuple[str, str]:
    """(stdout, stderr) of a block's command, as the tests run it (interpreted NLP functions, a fresh cache)."""
    env = dict(os.environ, VINE_NLP_CODEGEN="off", VINE_NLP_CACHE_DIR=str(cwd / ".cache"), MPLBACKEND="Agg",
               PYTHONHASHSEED="0", PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
    if command.startswith("vine-nlp "):
        out = err = ""
        for part in command.split(" && "):
            p = subprocess.run([sys.executable, "-m", "vine_nlp", *shlex.split(part)[1:]], cwd=cwd, env=env, capture_output=True, text=True)
            out, err = out + p.stdout, err + p.stderr
        return out, err
    script = ROOT / command.removeprefix("python3 ")
    if script.suffix == ".ipynb":
        import nbclient
        import nbformat

        env_before = dict(os.environ)
        os.environ.update(VINE_NLP_EXAMPLES_OUT=str(cwd), VINE_NLP_CODEGEN="off", MPLBACKEND="Agg")
        try:
            nb = nbformat.read(script, as_version=4)
            nbclient.NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(script.parent)}}).execute()
        finally:
            os.environ.clear()
            os.environ.update(env_before)
        streams = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "stream"]
        return tuple("".join(o.text for o in streams if o.name == name) for name in ("stdout", "stderr"))
    p = subprocess.run([sys.executable, str(script), "--out", str(cwd)], cwd=ROOT, env=env, capture_output=True, text=True)
    return p.stdout, p.stderr


def update(pattern: str = "") -> int:
    """Rewrite every block (of files whose path contains ``pattern``) from its command's output; 1 if a line
    is no longer printed (listed), else 0."""
    missing = 0

    def fresh(f: Path, m) -> str:
        nonlocal missing
        b = blocks_in(f, m)
        with tempfile.TemporaryDirectory() as tmp:
            cwd = Path(tmp)
            for name in ("problems", "examples"):
                (cwd / name).symlink_to(ROOT / name)
            (cwd / "results").mkdir()
            stdout, stderr = run(b.command, cwd)
        body, changed = m["body"], 0
        for line, got in _match(b, stdout, stderr):
            if got is None:
                missing += 1
                print(f"{f.relative_to(ROOT)}:{b.line}: no longer printed: {line!r}", file=sys.stderr)
            elif rewrite(line, got) != line:
                body, changed = body.replace(line, rewrite(line, got), 1), changed + 1
        print(f"{f.relative_to(ROOT)}:{b.line}: " + (f"{changed} line(s) updated; re-read the prose around it" if changed else "as printed"))
        return m[0][: m.start("body") - m.start()] + body + m[0][m.end("body") - m.start():]

    for f in DOCS:
        if pattern in str(f.relative_to(ROOT)):
            text = f.read_text()
            f.write_text(MARKER.sub(lambda m, f=f: fresh(f, m), text))
    return 1 if missing else 0


def blocks_in(f: Path, m) -> Block:
    """The Block of one MARKER match ``m`` in ``f``."""
    text = m.string
    return Block(f, text.count("\n", 0, m.start()) + 1, m["command"].strip(), float(m["tol"]) / 100 if m["tol"] else DEFAULT_TOL,
                 [line for line in m["body"].splitlines() if line.strip()])


if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] != "--update":
        sys.exit("usage: python3 tests/printed.py --update [PATTERN]  (rewrites the documentation's printed blocks)")
    sys.exit(update(sys.argv[2] if len(sys.argv) > 2 else ""))
