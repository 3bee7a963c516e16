"""``python -m vine_nlp`` (and the ``vine-nlp`` script): Ctrl-C and SIGTERM are handled from the first line,
before the command line's heavy imports, to the exit: one line and exit 130 whenever one arrives."""

import sys

from vine_nlp import interrupt


def run() -> int:
    interrupt.install()
    code = None
    try:
        interrupt.hold("start")  # tests: a signal before the command line is even imported
        from vine_nlp.front.cli import main

        code = main()
        interrupt.quiet()
    except KeyboardInterrupt:
        interrupt.quiet()
    if code is None or (code != 130 and interrupt.requested()):
        print("interrupted: nothing partial was written", file=sys.stderr)
        code = 130
    return code


if __name__ == "__main__":
    raise SystemExit(run())
