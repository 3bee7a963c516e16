"""Line count of a package: all lines (``wc -l``) and code lines without docstrings, comments and blanks.

Usage: ``python3 benchmarks/line_count.py [DIR] [--per-file N]`` (DIR defaults to src/vine_nlp). A code line is a
physical line that holds at least one token other than a comment, a newline or a docstring (the string expression
that opens a module, class or function).
"""

import argparse
import ast
import io
import sys
import tokenize
from pathlib import Path


def docstring_lines(tree):
    """The line numbers of every module, class and function docstring in a parsed module."""
    lines = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                lines.update(range(first.lineno, first.end_lineno + 1))
    return lines


def count(path):
    """(all lines, code lines) of one Python file."""
    text = Path(path).read_text()
    skip = docstring_lines(ast.parse(text))
    ignored = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT, tokenize.ENDMARKER}
    code = set()
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type in ignored:
            continue
        for line in range(tok.start[0], tok.end[0] + 1):
            if line not in skip:
                code.add(line)
    return len(text.splitlines()), len(code)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dir", nargs="?", default="src/vine_nlp")
    parser.add_argument("--per-file", type=int, default=0, metavar="N", help="also list the N largest files by code lines")
    args = parser.parse_args(argv)
    rows = [(str(p), *count(p)) for p in sorted(Path(args.dir).rglob("*.py"))]
    if args.per_file:
        for name, total, code in sorted(rows, key=lambda r: -r[2])[: args.per_file]:
            print(f"{total:6d} {code:6d}  {name}")
    print(f"{len(rows)} files: {sum(r[1] for r in rows)} lines (wc -l), {sum(r[2] for r in rows)} code lines")


if __name__ == "__main__":
    sys.exit(main())
