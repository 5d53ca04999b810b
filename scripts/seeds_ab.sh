#!/usr/bin/env bash
# Learning of the defaults with and without one environment setting: `train.py` (defaults, no
# built-in evaluation) for each seed, once with NAME=VALUE and once without; then each run's final
# state (checkpoint.pt, not best.pt) evaluated on the default test bank (40 held-out procedural
# textures, `python -m aectorch.evaluate`, into final.json); then both sets side by side
# (python -m aectorch.report table --eval final.json: each set's rows, mean and standard deviation).
#
#   bash scripts/seeds_ab.sh AECTORCH_ONEDNN=0 [extra train.py overrides...]
#
# OUT (default /tmp/seeds_ab) and SEEDS (default "0 1 2") come from the environment; the runs go
# to $OUT/with_s<seed> and $OUT/without_s<seed>. The setting applies to training and evaluation.
set -euo pipefail
cd "$(dirname "$0")/.."
setting=${1:?usage: scripts/seeds_ab.sh NAME=VALUE [train.py overrides...]}
shift
[[ $setting == *=* ]] || { echo "scripts/seeds_ab.sh: the first argument must be NAME=VALUE, got '$setting'" >&2; exit 2; }
out=${OUT:-/tmp/seeds_ab}
seeds=${SEEDS:-0 1 2}
mkdir -p "$out"
export PYOPENGL_PLATFORM=osmesa OMP_WAIT_POLICY=PASSIVE
quiet=(train.progress=false train.tensorboard=false train.figures=false eval.enabled=false)
for seed in $seeds; do
  for side in with without; do
    dir="$out/${side}_s$seed"
    rm -rf "$dir"
    echo "seed $seed, $side $setting -> $dir" >&2
    prefix=()
    [[ $side == with ]] && prefix=(env "$setting")
    "${prefix[@]}" .venv/bin/python train.py seed="$seed" hydra.run.dir="$dir" "${quiet[@]}" "$@" > "$dir.log" 2>&1
    "${prefix[@]}" .venv/bin/python -m aectorch.evaluate checkpoint="$dir/checkpoint.pt" progress=false \
        out="$dir/final.json" >> "$dir.log" 2>&1
  done
done
for side in with without; do
  echo "## $side $setting (final states)"
  .venv/bin/python -m aectorch.report table --eval final.json $(for seed in $seeds; do echo "$out/${side}_s$seed"; done)
done
