#!/usr/bin/env bash
# Create/refresh .venv-lerobot: aectorch with its `lerobot` and `test` extras, for the LeRobot
# bridge (aectorch.integrations.lerobot) and its tests.
#
# LeRobot 0.4.4 (the newest for Python 3.11) pins torch < 2.11 and torchvision, which cannot share
# the main .venv's torch, so it gets its own environment. The first install downloads about 8 GB
# (torch with its CUDA libraries, as PyPI ships it) and takes a few minutes; a stamp file
# (.venv-lerobot/.aectorch-setup, a hash of pyproject.toml and this script) makes reruns instant.
#
# Environment:
#   PYTHON   interpreter used to create .venv-lerobot (default: python3, >= 3.10)
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
PYTHON="${PYTHON:-python3}"
VENV="$ROOT/.venv-lerobot"
VPY="$VENV/bin/python"
STAMP="$VENV/.aectorch-setup"
PIP_FLAGS=(-q --disable-pip-version-check --no-input)
say() { printf '[setup-lerobot] %s\n' "$*"; }

bash "$ROOT/scripts/setup.sh" >/dev/null  # system packages (OSMesa, g++) and the main .venv
HASH="$(cat pyproject.toml scripts/setup_lerobot.sh | sha256sum | cut -d' ' -f1)"
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$HASH" ]; then
    say "packages: up to date (stamp matches), skipping pip"
    exit 0
fi
rm -f "$STAMP"
[ -x "$VPY" ] || { say "venv: creating .venv-lerobot"; "$PYTHON" -m venv "$VENV"; }
say "aectorch: pip install -e .[lerobot,test,rl] (LeRobot and its own torch; the first time ~8 GB, a few minutes)"
"$VPY" -m pip install "${PIP_FLAGS[@]}" --upgrade-strategy only-if-needed -e ".[lerobot,test,rl]"
TV="$("$VPY" -c 'import importlib.metadata as m; print(m.version("torch"))')"
printf 'torch==%s\n' "${TV%%+*}" > "$VENV/.aectorch-torch-constraint.txt"
say "PyOpenGL: upgrading to >=3.1.7 for OSMesa (pip's warning about pyrender's pin is expected)"
"$VPY" -m pip install "${PIP_FLAGS[@]}" --upgrade-strategy only-if-needed \
    -c "$VENV/.aectorch-torch-constraint.txt" "PyOpenGL>=3.1.7"
say "kernel: building the fused CPU kernels for torch $TV (cached per machine)"
"$VPY" -W error::RuntimeWarning -c 'from aectorch.ops import native; native.load()' \
    || say "kernel: could not be built; the pursuits use the pure-torch code here"
printf '%s\n' "$HASH" > "$STAMP"
say "done: .venv-lerobot ready (torch $TV, lerobot $("$VPY" -c 'import importlib.metadata as m; print(m.version("lerobot"))'))"
