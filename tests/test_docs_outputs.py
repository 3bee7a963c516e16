"""The documentation prints what the code prints (issue 35): every block marked
``<!-- printed by: vine-nlp ... -->`` in the README and docs/ is checked against a run of its
commands (tests/printed.py says how: text and counts exactly, timings not: benchmarks/bench_docs_timings.py
checks those); the tutorials' blocks are checked by tests/test_examples.py
against their examples' runs. And the README's and getting-started's commands write into
results/ (or a temporary folder), never into the repository's root."""

from __future__ import annotations

import re
import shlex

import printed
import pytest

from vine_nlp.front.cli import main

ROOT = printed.ROOT
BLOCKS = printed.blocks()
COMMAND_BLOCKS = [b for b in BLOCKS if b.command.startswith("vine-nlp ")]
OUTPUT_OPTIONS = ("-o", "--output", "--plot", "--csv", "--tolerance-figure", "--clearance-figure", "--frames-plot")


@pytest.mark.parametrize("block", COMMAND_BLOCKS, ids=lambda b: f"{b.file.name}:{b.line}")
def test_a_documented_output_is_what_the_commands_print(block, tmp_path, monkeypatch, capsys):
    for name in ("problems", "examples"):
        (tmp_path / name).symlink_to(ROOT / name)
    (tmp_path / "results").mkdir()
    monkeypatch.chdir(tmp_path)  # the documented paths, relative to a copy of the repository's root
    stdout = stderr = ""
    for command in block.command.split(" && "):
        main(shlex.split(command)[1:])
        out = capsys.readouterr()
        stdout, stderr = stdout + out.out, stderr + out.err
    problems = printed.check(block, stdout, stderr)
    problems += [f"printed on stderr, not shown: {line!r}" for line in printed.unshown(stderr, [block])]
    assert not problems, "\n".join(problems)


def test_every_marked_block_names_something_that_runs():
    for b in BLOCKS:
        if b.command.startswith("vine-nlp "):
            continue
        script = b.command.removeprefix("python3 ")
        assert re.fullmatch(r"examples/\d\d_\w+\.(py|ipynb)", script) and (ROOT / script).is_file(), f"{b.file}:{b.line}: {b.command}"
    # every tutorial shows at least one output of its example, so that test_examples checks it
    for page in sorted((ROOT / "docs" / "tutorials").glob("[0-9][0-9]-*.md")):
        assert any(b.file == page for b in BLOCKS), f"{page.name}: no <!-- printed by: ... --> block"


def _written(path) -> list[str]:
    """The files that the commands and the Python lines of a page's code blocks write."""
    out = []
    for lang, code in re.findall(r"```(bash|python)\n(.*?)```", path.read_text(), re.S):
        for line in code.splitlines():
            if lang == "bash" and line.lstrip().startswith("vine-nlp "):
                words = shlex.split(line, comments=True)
                out += [words[i + 1] for i, w in enumerate(words[:-1]) if w in OUTPUT_OPTIONS]
            elif lang == "python":
                out += re.findall(r"\.(?:save|template|plot)\(\"([^\"]+)\"", line)
    return out


@pytest.mark.parametrize("page", ["README.md", "docs/getting-started.md"])
def test_the_first_pages_write_into_results_not_the_repository_root(page):
    written = _written(ROOT / page)
    assert written  # the page has commands that write
    assert [w for w in written if not w.startswith(("results/", "/tmp/"))] == []


def test_the_commands_pages_write_are_ignored_by_git():
    """What a newcomer's documented commands leave behind (results/..., the site of `mkdocs build`) is not
    untracked clutter: git ignores it (tracked reports in results/ stay tracked)."""
    import shutil
    import subprocess

    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    pages = ["README.md", "docs/getting-started.md", "docs/index.md", *(f"docs/tutorials/{p.name}" for p in (ROOT / "docs" / "tutorials").glob("*.md"))]
    written = sorted({w for page in pages for w in _written(ROOT / page) if not w.startswith("/tmp/")})
    assert "results/trefoil-m4-cuts.csv" in written  # docs/index.md's template command
    paths = [*written, "site/index.html", "results/08_model_explained.ipynb"]
    ignored = subprocess.run(["git", "check-ignore", "--no-index", *paths], cwd=ROOT, capture_output=True, text=True).stdout.split()
    assert sorted(ignored) == sorted(paths)
    assert subprocess.run(["git", "check-ignore", "-q", "--no-index", "results/BENCHMARKS.md"], cwd=ROOT).returncode == 1


def test_vine_nlp_alone_lists_the_commands(capsys):
    assert main([]) == 2
    out = capsys.readouterr().out
    assert out.startswith("usage: vine-nlp COMMAND") and "--help" in out.splitlines()[0]
    for command in ("forward", "design", "analyze", "plot", "template", "view", "animate", "show"):
        assert f"\n  {command} " in out


def test_ci_says_each_long_step_before_it_starts():
    """No minutes of silence in .ci/run: a `step` line (printed with the time) before every install, the lint,
    the tests and the docs build; and it runs the README's test command as written there."""
    lines = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]
    long = [i for i, line in enumerate(lines)
            if not line.startswith("step ") and re.search(r"pip install|apt-get update|lint-imports \|\||pytest -q|mkdocs build", line)]
    assert len(long) >= 6
    for i in long:
        before = [line for line in lines[:i] if line and not line.startswith("#")]
        assert before and before[-1].startswith("step "), lines[i]
    readme = (ROOT / "README.md").read_text()
    test_command = "python3 -m pip install -e '.[test]' && python3 -m pytest -q"
    assert test_command in readme and test_command in lines


def test_a_timing_is_not_compared_by_the_tests_but_counts_and_other_numbers_are():
    """A test that depends on the clock is a defect: ``about N s`` is checked by benchmarks/bench_docs_timings.py."""
    block = printed.Block(ROOT / "README.md", 1, "vine-nlp x", 0.02, ["nlp: RMSE about 0.002 cm, solve time about 0.3 s, 27 iterations"])
    assert printed.check(block, "nlp: RMSE 0.0021 cm, solve time 30 s, 27 iterations") == []
    assert printed.check(block, "nlp: RMSE 0.0021 cm, solve time 30 s, 27 iterations", timings=True) == [
        "README.md:1: 'nlp: RMSE about 0.002 cm, solve time about 0.3 s, 27 iterations': 0.3 shown, 30 printed (not within 2x)"]
    assert printed.check(block, "nlp: RMSE 0.0021 cm, solve time 0.3 s, 28 iterations") == [
        "README.md:1: 'nlp: RMSE about 0.002 cm, solve time about 0.3 s, 27 iterations': 27 shown, 28 printed (a count must be exact)"]
    assert "not within 2x" in printed.check(block, "nlp: RMSE 0.02 cm, solve time 0.3 s, 27 iterations")[0]  # not a timing: 2x
