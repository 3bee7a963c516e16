"""Printed outputs in the documentation, checked against what the code prints (issue 35).

A fenced block that shows what a command prints follows a marker line in the Markdown:

    <!-- printed by: COMMAND -->               numbers within 2 % (or half a unit of the last digit shown)
    <!-- printed by: COMMAND; within 10 % -->  a stated tolerance

COMMAND is ``python3 examples/NN_name.py`` or ``examples/NN_name.ipynb`` (tests/test_examples.py runs
the example and checks its tutorial's blocks against what it printed) or a ``vine-nlp ...`` command line
(tests/test_docs_outputs.py runs it). Every line of the block must be printed, in order (other lines may
come between); its text must be the printed text (paths compared by their last part, URLs not compared)
and every number must agree within the tolerance, except a number written ``about N``: timings and
iteration counts, which depend on the machine and on whether the compiled functions ran.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
MARKER = re.compile(r"<!-- printed by: (?P<command>.+?)(?:; within (?P<tol>[\d.]+) %)? -->[ \t]*\n```[^\n]*\n(?P<body>.*?)\n```", re.S)
NUMBER = re.compile(r"(?<![\w.])(about )?([-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?)(?![\w.])")
DEFAULT_TOL = 0.02


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
        for m in MARKER.finditer(text):
            tol = float(m["tol"]) / 100 if m["tol"] else DEFAULT_TOL
            lines = [line for line in m["body"].splitlines() if line.strip()]
            out.append(Block(f, text.count("\n", 0, m.start()) + 1, m["command"].strip(), tol, lines))
    return out


def _skeleton(line: str):
    """(text with numbers as '#', [(value, about, last digit's unit)]); paths by their last part, URLs as '<url>'."""
    words = []
    for w in line.split():
        if "://" in w:
            w = "<url>" + ("" if w[-1].isalnum() else w[-1])
        elif "/" in w and not w.startswith("<") and len(w) > 1:
            w = w.rstrip("/").rsplit("/", 1)[-1]
        words.append(w)
    line = " ".join(words)
    numbers = []

    def keep(m):
        digits, _, exponent = m[2].lower().partition("e")
        unit = 10.0 ** (int(exponent or 0) - (len(digits.split(".")[1]) if "." in digits else 0))
        numbers.append((float(m[2]), bool(m[1]), unit))
        return "#"

    return NUMBER.sub(keep, line), numbers


def check(block: Block, stdout: str, stderr: str = "") -> list[str]:
    """What in ``block`` disagrees with what the command printed (empty: it shows what the command prints).
    A line the command printed on stderr is looked for there, the others on stdout, each in order."""
    streams = [[_skeleton(line) for line in text.splitlines() if line.strip()] for text in (stdout, stderr)]
    at = [0, 0]
    problems = []
    where = f"{block.file.relative_to(ROOT)}:{block.line}"
    for line in block.lines:
        text, want = _skeleton(line)
        s = 1 if any(t == text for t, _ in streams[1]) else 0
        out = streams[s]
        j = next((k for k in range(at[s], len(out)) if out[k][0] == text), None)
        if j is None:
            problems.append(f"{where}: not printed (in this order) by `{block.command}`: {line!r}")
            continue
        for (w, about, unit), (g, _, _) in zip(want, out[j][1]):
            if not about and abs(w - g) > max(block.tol * abs(g), 0.5 * unit):
                problems.append(f"{where}: {line!r}: {w:g} shown, {g:g} printed (within {100 * block.tol:g} %)")
        at[s] = j + 1
    return problems


def unshown(printed_stderr: str, shown: list[Block]) -> list[str]:
    """Lines a command printed on stderr (warnings, shortfalls; not the compiler's notes) that no block shows."""
    texts = {_skeleton(line)[0] for b in shown for line in b.lines}
    return [line for line in printed_stderr.splitlines()
            if line.strip() and not line.startswith("note:") and _skeleton(line)[0] not in texts]
