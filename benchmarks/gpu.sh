#!/usr/bin/env bash
# One prepared GPU run (issues 21 and 33): env-iterations/s of the training loop on CUDA, today's
# defaults, in stages that each write their own JSON into ${OUT:-benchmarks/results} (a stage cut
# short by its time limit loses only itself):
#   1. the device, and the torch renderer's first frames on CUDA (a smoke test, seconds);
#   2. eager at B = 256 ... 16,384 (train_step_cuda_eager.json, a plot beside it);
#   3. compiled, then with CUDA graphs, at B = 4,096 (train_step_cuda_compile.json, _cudagraphs.json);
#   4. pyrender on EGL.
# Run on a machine with an NVIDIA GPU from the repository root:
#     bash benchmarks/gpu.sh            (at most 6 min 20 s: each stage has a time limit)
# PY names the Python (default: .venv/bin/python, else python, installing the package on a bare
# machine). The CUDA path is the pure-torch code (the fused CPU kernels do not run there);
# tests/test_sim.py and tests/test_pursuit.py keep it equal to them on CPU.
set -uo pipefail
OUT=${OUT:-benchmarks/results}
mkdir -p "$OUT"
PY=${PY:-python}
if [ ! -x .venv/bin/python ] && [ "$PY" = python ]; then
    # a bare machine: the CUDA build of torch and the package
    $PY -m pip install -q -e . >/dev/null
fi
[ -x .venv/bin/python ] && [ "$PY" = python ] && PY=.venv/bin/python
status=0
echo "== 1. the device"
timeout 60 $PY - <<'PYEOF' || { echo "the CUDA smoke test failed"; exit 1; }
import time, torch
from aectorch.sim import ActiveDepthEnv
print("torch", torch.__version__, "cuda", torch.version.cuda, "device", torch.cuda.get_device_name(0))
env = ActiveDepthEnv(256, renderer="torch", device="cuda")
for _ in range(2):
    torch.cuda.synchronize(); t = time.perf_counter(); obs = env.stereo_observation(); torch.cuda.synchronize()
    print("torch renderer on CUDA, B = 256, one stereo frame:", round(time.perf_counter() - t, 4), "s",
          {k: tuple(v.shape) for k, v in obs.items()})
PYEOF
echo "== 2. eager, B = 256 ... 16,384"
timeout 150 $PY benchmarks/train_step.py --device cuda --renderers torch --learner default \
    --batches 256 1024 4096 16384 --modes eager --threads 1 --iterations 20 --warmup 5 \
    --json "$OUT/train_step_cuda_eager.json" --plot "$OUT/train_step_cuda_eager.png" 2>&1 | tail -20 || status=1
for mode in compile cudagraphs; do
    echo "== 3. $mode, B = 4,096"
    timeout 130 $PY benchmarks/train_step.py --device cuda --renderers torch --learner default \
        --batches 4096 --modes $mode --threads 1 --iterations 20 --warmup 5 \
        --json "$OUT/train_step_cuda_$mode.json" 2>&1 | tail -12 || status=1
done
echo "== 4. pyrender on EGL"
PYOPENGL_PLATFORM=egl timeout 40 $PY - <<'PYEOF' || { echo "EGL check failed"; status=1; }
import time, torch
from aectorch.sim import ActiveDepthEnv
env = ActiveDepthEnv(4, renderer="pyrender", renderer_options={"platform": "egl"})
t = time.perf_counter(); env.stereo_observation(); print("pyrender on EGL:", round(time.perf_counter() - t, 3), "s")
PYEOF
exit $status
