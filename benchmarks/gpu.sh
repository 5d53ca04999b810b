#!/usr/bin/env bash
# One prepared GPU run (issue 21): env-iterations/s of the training loop on CUDA at B = 256 ... 16,384,
# eager, compiled and with CUDA graphs, today's defaults; plus an EGL check of pyrender. Writes JSON
# into ${OUT:-benchmarks/results}. Run on a machine with an NVIDIA GPU from the repository root:
#     bash benchmarks/gpu.sh            (about 8 minutes on an H100-class GPU)
# The CUDA path is the pure-torch code (the fused CPU kernels do not run there); tests/test_sim.py
# and tests/test_pursuit.py keep it equal to them on CPU.
set -euo pipefail
OUT=${OUT:-benchmarks/results}
mkdir -p "$OUT"
PY=${PY:-python}
if [ ! -x .venv/bin/python ] && [ "$PY" = python ]; then
    # a bare machine: the CUDA build of torch and the package
    $PY -m pip install -q -e . >/dev/null
fi
[ -x .venv/bin/python ] && [ "$PY" = python ] && PY=.venv/bin/python
$PY - <<'PYEOF'
import torch
print("torch", torch.__version__, "cuda", torch.version.cuda, "device", torch.cuda.get_device_name(0))
PYEOF
timeout 420 $PY benchmarks/train_step.py --device cuda --renderers torch --learner default \
    --batches 256 1024 4096 16384 --modes eager compile cudagraphs --threads 1 \
    --iterations 20 --warmup 5 --json "$OUT/train_step_cuda.json" --plot "$OUT/train_step_cuda.png" \
    2>&1 | tail -30
PYOPENGL_PLATFORM=egl timeout 60 $PY - <<'PYEOF' || echo "EGL check failed"
import time, torch
from aectorch.sim import ActiveDepthEnv
env = ActiveDepthEnv(4, renderer="pyrender", renderer_options={"platform": "egl"})
t = time.perf_counter(); env.stereo_observation(); print("pyrender on EGL:", round(time.perf_counter() - t, 3), "s")
PYEOF
