#!/usr/bin/env bash
# Set up pih-rflow on a fresh Debian machine: system packages for headless rendering (Mesa EGL/OSMesa) and the
# PostgreSQL server of the shared-study test, a virtual environment in .venv with the CPU build of torch, and
# the project with its test (pytest, stable-baselines3), cluster (Ray), search (Optuna), datasets (pyarrow,
# h5py) and docs (MkDocs, whose --strict build is a test) extras. stable-baselines3 needs torch, which the pinned
# CPU build installed first already satisfies.
set -euo pipefail
cd "$(dirname "$0")"

if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    need=()
    for pkg in libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libosmesa6 libglu1-mesa postgresql; do
        dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
    done
    if [ "${#need[@]}" -gt 0 ]; then
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq
        apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
    fi
fi

PYTHON="${PYTHON:-python3}"
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
# torch first, pinned, so no resolver pulls another build: the CPU file this project's machines hold; elsewhere set
# TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu (PyPI's torch for Linux is the CUDA build).
.venv/bin/python -m pip install -q ${TORCH_INDEX_URL:+--index-url "$TORCH_INDEX_URL"} "torch==2.13.0"
# The rest with uv (into the venv, from PyPI): the same resolution as pip, with downloads and bytecode compilation in
# parallel (a third of pip's time here). uv reads its own settings, not pip's (UV_INDEX_URL, not PIP_INDEX_URL); the
# torch installed above satisfies the pin, so uv keeps it.
.venv/bin/python -m pip install -q uv
.venv/bin/uv pip install -q --python .venv/bin/python --compile-bytecode -e ".[test,cluster,search,datasets,docs]"
# Compile the numba kernels once (cached beside their modules), so the first `pih run` does not wait ~25 s; and at
# the same time, on the second core, for a generic x86-64 (the test that records do not depend on the CPU runs those).
MUJOCO_GL="${MUJOCO_GL:-egl}" .venv/bin/pih warmup --generic-too
echo "setup.sh: ready -- activate with: source .venv/bin/activate"
