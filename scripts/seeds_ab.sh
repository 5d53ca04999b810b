#!/usr/bin/env bash
# Learning of the defaults with and without one environment setting: `train.py` (defaults) for
# each seed, once with NAME=VALUE and once without, then both sets' final states side by side
# (scripts/results_table.py: each set's rows, mean and standard deviation).
#
#   bash scripts/seeds_ab.sh AECTORCH_ONEDNN=0 [OUT=/tmp/seeds_ab] [SEEDS="0 1 2"] [extra train.py overrides...]
#
# The runs go to $OUT/with_s<seed> and $OUT/without_s<seed>; OUT and SEEDS come from the environment.
set -euo pipefail
cd "$(dirname "$0")/.."
setting=${1:?usage: scripts/seeds_ab.sh NAME=VALUE [train.py overrides...]}
shift
[[ $setting == *=* ]] || { echo "scripts/seeds_ab.sh: the first argument must be NAME=VALUE, got '$setting'" >&2; exit 2; }
out=${OUT:-/tmp/seeds_ab}
seeds=${SEEDS:-0 1 2}
mkdir -p "$out"
export PYOPENGL_PLATFORM=osmesa OMP_WAIT_POLICY=PASSIVE
quiet=(train.progress=false train.tensorboard=false train.figures=false)
for seed in $seeds; do
  for side in with without; do
    dir="$out/${side}_s$seed"
    rm -rf "$dir"
    echo "seed $seed, $side $setting -> $dir" >&2
    if [[ $side == with ]]; then
      env "$setting" .venv/bin/python train.py seed="$seed" hydra.run.dir="$dir" "${quiet[@]}" "$@" > "$dir.log" 2>&1
    else
      .venv/bin/python train.py seed="$seed" hydra.run.dir="$dir" "${quiet[@]}" "$@" > "$dir.log" 2>&1
    fi
  done
done
for side in with without; do
  echo "## $side $setting"
  .venv/bin/python scripts/results_table.py $(for seed in $seeds; do echo "$out/${side}_s$seed"; done)
done
