#!/usr/bin/env bash
# Create/refresh the aectorch development environment in ./.venv.
#
# Idempotent: a stamp file (.venv/.aectorch-setup) records a hash of
# pyproject.toml and this script; when it matches, all pip steps are skipped.
#
# Environment:
#   PYTHON   interpreter used to create .venv (default: python3, must be >= 3.10)
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

PYTHON="${PYTHON:-python3}"
VENV="$ROOT/.venv"
VPY="$VENV/bin/python"
STAMP="$VENV/.aectorch-setup"
PIP_FLAGS=(-q --disable-pip-version-check --no-input)

say() { printf '[setup] %s\n' "$*"; }
die() { printf '[setup] ERROR: %s\n' "$*" >&2; exit 1; }

# --- apt helper: root -> apt-get, passwordless sudo -> sudo apt-get, else explain.
apt_install() {
    local what="$1"; shift
    local -a sudo_cmd=()
    if [ "$(id -u)" -ne 0 ]; then
        if command -v sudo >/dev/null 2>&1 && sudo -n true >/dev/null 2>&1; then
            sudo_cmd=(sudo -n)
        else
            die "aectorch needs Debian's $* for $what; apt is not permitted for this user: run \`sudo apt-get install $*\` and re-run"
        fi
    fi
    command -v apt-get >/dev/null 2>&1 \
        || die "aectorch needs $* for $what, and apt-get is not available: install it with your system's package manager and re-run"
    say "installing $* with apt-get (for $what)"
    ${sudo_cmd[@]+"${sudo_cmd[@]}"} env DEBIAN_FRONTEND=noninteractive apt-get update -qq
    ${sudo_cmd[@]+"${sudo_cmd[@]}"} env DEBIAN_FRONTEND=noninteractive \
        apt-get install -y -qq --no-install-recommends "$@" >/dev/null
}

# --- 1. Python >= 3.10
command -v "$PYTHON" >/dev/null 2>&1 \
    || die "Python >= 3.10 is required but '$PYTHON' was not found (set PYTHON=/path/to/python3.X)"
"$PYTHON" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 10) else 1)' \
    || die "Python >= 3.10 is required, but $PYTHON is $("$PYTHON" -V 2>&1) (set PYTHON=/path/to/python3.X)"
say "python: $("$PYTHON" -V 2>&1)"

# --- 2. OSMesa (off-screen OpenGL used by pyrender)
have_osmesa() {
    local ldc
    ldc="$(command -v ldconfig || true)"
    [ -z "$ldc" ] && [ -x /sbin/ldconfig ] && ldc=/sbin/ldconfig
    # No `grep -q`: with pipefail an early-exiting grep can SIGPIPE ldconfig.
    if [ -n "$ldc" ] && "$ldc" -p 2>/dev/null | grep libOSMesa >/dev/null; then
        return 0
    fi
    dpkg-query -W -f='${Status}' libosmesa6 2>/dev/null | grep "install ok installed" >/dev/null
}
if have_osmesa; then
    say "libosmesa6: present"
else
    apt_install "off-screen rendering" libosmesa6
    have_osmesa || die "libosmesa6 was installed but libOSMesa is still not found by ldconfig"
fi

# --- 3. virtual environment
if [ -x "$VPY" ]; then
    "$VPY" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 10) else 1)' 2>/dev/null \
        || die ".venv exists but its Python is broken or older than 3.10: run \`make clean\` and re-run"
    say "venv: .venv exists"
else
    if ! "$PYTHON" -c 'import ensurepip, venv' >/dev/null 2>&1; then
        apt_install "creating virtual environments" python3-venv
    fi
    say "venv: creating .venv"
    "$PYTHON" -m venv "$VENV"
fi

HASH="$(cat pyproject.toml scripts/setup.sh | sha256sum | cut -d' ' -f1)"
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$HASH" ]; then
    say "packages: up to date (stamp matches), skipping pip"
    exit 0
fi
rm -f "$STAMP"

# --- 4. torch, only if missing; never upgraded or reinstalled afterwards
if "$VPY" -c 'import torch' >/dev/null 2>&1; then
    say "torch: $("$VPY" -c 'import torch; print(torch.__version__)') already installed, leaving it alone"
else
    # --no-index still honours pip's configured find-links, so a local wheel wins
    # over a multi-GB download. If the find-links lack torch's own dependencies,
    # install the wheel alone; the next pip step resolves them from the index.
    say "torch: trying a local wheel (pip find-links, --no-index)"
    if "$VPY" -m pip install "${PIP_FLAGS[@]}" --no-index torch 2>/dev/null \
        || "$VPY" -m pip install "${PIP_FLAGS[@]}" --no-index --no-deps torch 2>/dev/null; then
        say "torch: installed local wheel $("$VPY" -c 'import importlib.metadata as m; print(m.version("torch"))')"
    else
        say "torch: no local wheel; installing torch>=2.4 from the package index (large download)"
        "$VPY" -m pip install "${PIP_FLAGS[@]}" "torch>=2.4"
    fi
fi
TV="$("$VPY" -c 'import importlib.metadata as m; print(m.version("torch"))')"

# --- 5. aectorch (editable) + test extras; torch pinned to what is installed
CONSTRAINTS="$VENV/.aectorch-torch-constraint.txt"
printf 'torch==%s\n' "$TV" > "$CONSTRAINTS"
say "aectorch: pip install -e .[test,docs,rl] (keeping torch $TV)"
"$VPY" -m pip install "${PIP_FLAGS[@]}" --upgrade-strategy only-if-needed \
    -c "$CONSTRAINTS" -e ".[test,docs,rl]"

# --- 6. newer PyOpenGL (after pyrender, which pins PyOpenGL==3.1.0)
say "PyOpenGL: upgrading to >=3.1.7 for OSMesa; pip's warning that pyrender requires PyOpenGL==3.1.0 is expected and harmless"
"$VPY" -m pip install "${PIP_FLAGS[@]}" --upgrade-strategy only-if-needed \
    -c "$CONSTRAINTS" "PyOpenGL>=3.1.7"

TV2="$("$VPY" -c 'import importlib.metadata as m; print(m.version("torch"))')"
[ "$TV" = "$TV2" ] || die "torch changed from $TV to $TV2 during setup; this should not happen"

# --- 7. the fused CPU kernels (coder and renderer; aectorch.ops.native), built now rather than on first use
# (torch.compile on CPU needs the same C++ compiler.)
command -v "${CXX:-g++}" >/dev/null 2>&1 || apt_install "compiling CPU kernels (ours and torch.compile's)" g++
say "kernel: building the fused CPU kernels (coder, renderer; cached per machine)"
"$VPY" -W error::RuntimeWarning -c 'from aectorch.ops import native; native.load()' \
    || say "kernel: could not be built; omp/matching_pursuit will use the pure-torch code (see above)"

printf '%s\n' "$HASH" > "$STAMP"
say "done: .venv ready (torch $TV)"
