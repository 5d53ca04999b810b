#!/usr/bin/env bash
# One ablation run: train with the given overrides (one kernel thread, no built-in evaluation),
# then evaluate the final state (checkpoint.pt) on the 40 test textures (5 distances) and on the
# choosing photographs (data/choose-photos, scripts/heldout_photos.py), as docs/results.md reads runs.
#
#   bash scripts/train_eval.sh runs/NAME SEED [key=value ...]
#
# Two of these side by side use the two cores. Writes runs/NAME/final_{textures,choose}.json.
set -euo pipefail
run=$1; seed=$2; shift 2
export PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-osmesa}
py=.venv/bin/python
$py train.py seed="$seed" train.threads=1 eval.enabled=false "$@" hydra.run.dir="$run" > "$run.log" 2>&1
export OMP_NUM_THREADS=1
$py -m aectorch.evaluate checkpoint="$run/checkpoint.pt" "depths=[1.0,1.5,2.0,2.5,3.0]" progress=false \
    out="$run/final_textures.json" >> "$run.log" 2>&1
$py -m aectorch.evaluate checkpoint="$run/checkpoint.pt" textures=data/choose-photos progress=false \
    out="$run/final_choose.json" >> "$run.log" 2>&1
echo "done $run"
