"""Arithmetic that does not depend on the x86-64 CPU it runs on.

Torch picks its vectorised kernels (ATen: DEFAULT, AVX2 or AVX512) and MKL its BLAS code path by the instruction set
of the host, and each choice rounds differently: the same demos trained with the ATen DEFAULT and the AVX2 kernels
(or MKL's default and its COMPATIBLE path) give weights that differ by up to 1e-4, and so other episode records.
numpy's exp, log, sin, ... have AVX-512 versions of their own. `pin_cpu_dispatch` fixes these choices to code paths
that every x86-64 CPU runs the same way, before torch is loaded (numpy: before it is imported, as `pih` does):

    ATEN_CPU_CAPABILITY=default                           (ATen's scalar/SSE kernels)
    MKL_CBWR=COMPATIBLE                                   (MKL's conditional numerical reproducibility, SSE2)
    NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR" (numpy's AVX-512 loops; its AVX2 loops round as its
                                                           baseline: records equal with X86_V3 disabled too)

Set by the user, a variable is left as it is. The compiled kernels need no pin: numba code is built without
fast-math (no fused multiply-add, no reassociation), so it rounds the same on every x86-64 CPU. OpenBLAS (numpy,
scipy) is not pinned: ``OPENBLAS_CORETYPE`` is the host's own setting, so what feeds an episode record avoids BLAS
(`numerics.small_linalg`).
"""

from __future__ import annotations

import os
import sys
import warnings
from typing import Mapping, MutableMapping

PINNED_ENVIRONMENT: dict[str, str] = {"ATEN_CPU_CAPABILITY": "default", "MKL_CBWR": "COMPATIBLE",
                                      "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"}
"""The dispatch settings every process of this project runs with (module docstring)."""
GENERIC_CPU_ENVIRONMENT: dict[str, str] = {"NUMBA_CPU_NAME": "generic", "NPY_DISABLE_CPU_FEATURES": "X86_V3",
                                           "MKL_ENABLE_INSTRUCTIONS": "SSE4_2", "ONEDNN_MAX_CPU_ISA": "SSE41"}
"""A process that runs the code of a generic x86-64 on this one: numba compiled for a generic x86-64, numpy's AVX2
loops off, MKL and oneDNN held to SSE4. Its records equal those of a process with the host's features
(tests/end_to_end/test_cpu_independence.py); `pih warmup --generic-too` compiles its kernels."""
DISPATCH_VARIABLES: tuple[str, ...] = (*PINNED_ENVIRONMENT, "NPY_ENABLE_CPU_FEATURES")
"""Every variable that chooses these code paths, the user's own choice of numpy's loops included: what a batch sends
to the workers of a cluster, whose nodes do not share this process's environment (`batch.BatchConfig`)."""


def pin_cpu_dispatch(environ: MutableMapping[str, str] = os.environ) -> None:
    """Set ``PINNED_ENVIRONMENT`` in ``environ`` where the user has not set the variable (spawned workers inherit it).

    Must run before torch runs its first kernel and before numpy is imported; the `numerics`, `rflow`, `envs` and
    `controllers` packages call it first thing on import, and so does `pih`. A user's ``NPY_ENABLE_CPU_FEATURES``
    is the user's choice of numpy's loops too (numpy refuses to load with both variables set), so the numpy pin is
    then left out.
    """
    for key, value in PINNED_ENVIRONMENT.items():
        if key == "NPY_DISABLE_CPU_FEATURES" and "NPY_ENABLE_CPU_FEATURES" in environ:
            continue
        environ.setdefault(key, value)


def generic_cpu_environment(environ: Mapping[str, str] = os.environ) -> dict[str, str]:
    """``environ`` for a process that runs as on a generic x86-64 (`GENERIC_CPU_ENVIRONMENT`); the pinned settings
    are left for that process to set (`pin_cpu_dispatch`, which keeps the generic numpy setting: it is set)."""
    keep = {k: v for k, v in environ.items() if k not in GENERIC_CPU_ENVIRONMENT and k not in PINNED_ENVIRONMENT}
    return {**keep, **GENERIC_CPU_ENVIRONMENT}


def check_numpy_dispatch(features: Mapping[str, bool] | None = None,
                         environ: Mapping[str, str] = os.environ) -> None:
    """Warn (RuntimeWarning) when numpy runs loops that ``NPY_DISABLE_CPU_FEATURES`` turns off: numpy reads the
    variable once, when it is imported, so a program that imported numpy before `numerics` (or `envs`,
    `controllers`, `rflow`, which pin first) keeps the host's AVX-512 loops, whose exp, arctan2, ... round
    otherwise, and its episode records differ from `pih`'s on this CPU and from other CPUs'.

    Args:
        features: numpy's runtime CPU features (default: its own ``__cpu_features__``, when numpy is loaded).
        environ: where the wanted setting is read.
    """
    if features is None:
        if "numpy" not in sys.modules:
            return
        try:
            from numpy._core._multiarray_umath import __cpu_features__ as features
        except ImportError:  # another numpy layout: nothing to check against
            return
    running = [group for group in environ.get("NPY_DISABLE_CPU_FEATURES", "").split() if features.get(group)]
    if running:
        warnings.warn(f"numpy was imported before numerics and runs its {' '.join(running)} loops: episode records "
                      f"will differ from pih's and from other CPUs'; import numerics (or envs) before numpy, or start "
                      f"Python with NPY_DISABLE_CPU_FEATURES={PINNED_ENVIRONMENT['NPY_DISABLE_CPU_FEATURES']!r}",
                      RuntimeWarning, stacklevel=3)


def check_torch_dispatch(capability: str) -> None:
    """Warn (RuntimeWarning) when torch was started with another kernel choice than the pinned one, e.g. because
    torch ran before `numerics` (or `rflow`) was imported: the weights then depend on this CPU.

    Args:
        capability: the kernels torch runs, ``torch.backends.cpu.get_cpu_capability()`` (this package never imports
            torch).
    """
    wanted = os.environ.get("ATEN_CPU_CAPABILITY", PINNED_ENVIRONMENT["ATEN_CPU_CAPABILITY"])
    if capability.lower() != wanted.lower():
        warnings.warn(f"torch runs its {capability} kernels, not {wanted!r}: import numerics (or rflow) before torch "
                      f"runs, or trained weights will depend on this CPU", RuntimeWarning, stacklevel=2)
