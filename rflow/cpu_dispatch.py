"""Arithmetic that does not depend on the x86-64 CPU it runs on.

Torch picks its vectorised kernels (ATen: DEFAULT, AVX2 or AVX512) and MKL its BLAS code path by the instruction set
of the host, and each choice rounds differently: the same demos trained on an AVX2 and an AVX-512 machine give other
weights, and so other episode records. `pin_cpu_dispatch` fixes both choices to the code path every x86-64 CPU
runs before torch is loaded:

    ATEN_CPU_CAPABILITY=default   (ATen's scalar/SSE kernels)
    MKL_CBWR=COMPATIBLE           (MKL's conditional numerical reproducibility, the SSE2 branch)

Set by the user, either variable is left as it is. The compiled kernels need no pin: numba code is built without
fast-math (no fused multiply-add, no reassociation), so it rounds the same on every x86-64 CPU. OpenBLAS (numpy,
scipy) is not pinned: ``OPENBLAS_CORETYPE`` is the host's own setting, so what feeds an episode record avoids BLAS
(`rflow.small_linalg`).
"""

from __future__ import annotations

import os
import warnings
from typing import MutableMapping

PINNED_ENVIRONMENT: dict[str, str] = {"ATEN_CPU_CAPABILITY": "default", "MKL_CBWR": "COMPATIBLE"}
"""The dispatch settings every process of this project runs with (module docstring)."""


def pin_cpu_dispatch(environ: MutableMapping[str, str] = os.environ) -> None:
    """Set ``PINNED_ENVIRONMENT`` in ``environ`` where the user has not set the variable (spawned workers inherit it).

    Must run before torch runs its first kernel; `rflow` calls it on import.
    """
    for key, value in PINNED_ENVIRONMENT.items():
        environ.setdefault(key, value)


def check_torch_dispatch() -> None:
    """Warn (RuntimeWarning) when torch was started with another kernel choice than the pinned one, e.g. because
    torch ran before `rflow` was imported: the weights then depend on this CPU."""
    import torch

    capability = torch.backends.cpu.get_cpu_capability()
    wanted = os.environ.get("ATEN_CPU_CAPABILITY", PINNED_ENVIRONMENT["ATEN_CPU_CAPABILITY"])
    if capability.lower() != wanted.lower():
        warnings.warn(f"torch runs its {capability} kernels, not {wanted!r}: import rflow before torch runs, or "
                      f"trained weights will depend on this CPU", RuntimeWarning, stacklevel=2)
