#!/usr/bin/env bash
# The whole suite N times in a row on a clean clone of the current commit (issue 48: "20 runs of the whole
# suite in a row on a clean clone without a failure").
#
#   benchmarks/suite_repeat.sh [N]      (default 20)
#
# Clones HEAD (committed work only) into a temporary folder, makes a virtual environment there that sees this
# machine's packages (python3 -m venv --system-site-packages: the README's `pip install -e` goes into it, not
# into the machine's Python), then runs the README's test command N times in a row, exactly:
#     python3 -m pip install -e '.[test]' && python3 -m pytest -q
# One line per run: its number, wall seconds, pass or FAIL (with the log's last lines). Stops at the first
# failure (exit 1; the clone and every run's log are kept and named), else removes the clone (exit 0).
# It takes N times the suite's time (about 6 minutes on 2 idle cores): run it on a machine nobody shares.
set -uo pipefail
n="${1:-20}"
if ! [[ "$n" =~ ^[1-9][0-9]{0,3}$ ]]; then
  echo "error: command line: N: must be a whole number from 1 to 9999, got '$n'" >&2
  exit 2
fi
root="$(cd "$(dirname "$0")/.." && pwd)"
commit="$(git -C "$root" rev-parse HEAD)" || { echo "error: $root: not a git checkout" >&2; exit 2; }
work="$(mktemp -d "${TMPDIR:-/tmp}/vine-nlp-suite.XXXXXX")"
repo="$work/vine_nlp"
echo "suite_repeat: $n run(s) of commit ${commit:0:10} in $work"
git clone --quiet --no-hardlinks "$root" "$repo" && git -C "$repo" checkout --quiet --detach "$commit" || { echo "error: cannot clone $root into $repo" >&2; exit 1; }
python3 -m venv --system-site-packages "$work/venv" || { echo "error: cannot make a virtual environment in $work/venv" >&2; exit 1; }
export PATH="$work/venv/bin:$PATH" VIRTUAL_ENV="$work/venv"
export PYTHONPATH="$repo/src"  # the clone's package, whatever else the machine has installed
unset VINE_NLP_CACHE_DIR
cd "$repo" || exit 1
total=0
for ((k = 1; k <= n; k++)); do
  log="$work/run-$k.log"
  t0=$(date +%s.%N)
  { python3 -m pip install -e '.[test]' && python3 -m pytest -q; } >"$log" 2>&1
  rc=$?
  dt=$(python3 -c "print(f'{$(date +%s.%N) - $t0:.0f}')")
  total=$((total + dt))
  if [ "$rc" -ne 0 ]; then
    echo "run $k/$n: ${dt} s, FAIL (exit $rc); log $log, clone $repo kept:"
    tail -n 25 "$log"
    exit 1
  fi
  echo "run $k/$n: ${dt} s, pass ($(tail -n 1 "$log" | tr -d '='))"
done
echo "suite_repeat: $n of $n runs passed, ${total} s in all"
rm -rf "$work"
