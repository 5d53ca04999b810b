#!/usr/bin/env bash
# Two commits on the benchmark suite, one command: each commit's suite runs in a git worktree of its
# own (pytest-benchmark saving its timings), then pytest-benchmark's comparison table.
#     bash benchmarks/compare.sh A B [pytest arguments, default: benchmarks]     (make bench-compare A=.. B=..)
# The two runs follow each other: on a shared machine their drift differs, so for a ratio that
# counts prefer a side-by-side variant (AECTORCH_BENCH_BASELINE=<commit> for train.py's rate).
set -euo pipefail
A=$1 B=$2
shift 2
ROOT=$(git rev-parse --show-toplevel)
PY=${PY:-$ROOT/.venv/bin/python}
OUT=$(mktemp -d)
for commit in "$A" "$B"; do
    dir="${TMPDIR:-/tmp}/aectorch-$commit"
    [ -e "$dir/train.py" ] || git -C "$ROOT" worktree add --detach "$dir" "$commit" >/dev/null
    (cd "$dir" && PYOPENGL_PLATFORM=osmesa AECTORCH_BENCH=${AECTORCH_BENCH:-full} "$PY" -m pytest -q -p no:xdist \
        --benchmark-only --benchmark-json="$OUT/$commit.json" "${@:-benchmarks}")
done
"$(dirname "$PY")/pytest-benchmark" compare "$OUT/$A.json" "$OUT/$B.json" --columns=min,median,iqr,rounds
