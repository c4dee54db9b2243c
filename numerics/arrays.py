"""The numpy/torch dispatch of array maps (the quaternion algebra, rflow's manifolds): one equation runs on either
array type.

Light on purpose: it imports neither torch nor numba, so a numpy-only user (the simulator, the task configs
that `pih evaluate --help` builds) can use the quaternion algebra (`numerics.quaternion`) without their import
time. `rflow.manifolds._backend` adds the checks and the linear algebra the manifold maps need.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

Array = Any  # numpy.ndarray or torch.Tensor


def _torch() -> Any:
    """The torch module if something imported it, else None. A tensor can only exist once torch is imported, so
    numpy-only users of the maps (the simulator, demos, rendering, the CLI's start) never pay its import time."""
    return sys.modules.get("torch")


def is_torch(x: Array) -> bool:
    """True when ``x`` is a torch tensor (the maps then return tensors and stay differentiable)."""
    torch = _torch()
    return torch is not None and isinstance(x, torch.Tensor)


def as_float(x: Any) -> Array:
    """A torch tensor as it is; anything else as a float64 numpy array (no copy when it already is one)."""
    return x if is_torch(x) else np.asarray(x, dtype=np.float64)


def xp(x: Array) -> Any:
    """The array module (numpy or torch) matching ``x`` for functions named alike in both."""
    return _torch() if is_torch(x) else np


def concat(parts: list[Array], like: Array) -> Array:
    """Concatenate along the last axis."""
    return _torch().cat(parts, dim=-1) if is_torch(like) else np.concatenate(parts, axis=-1)


def stack(parts: list[Array], like: Array) -> Array:
    """Stack along a new last axis."""
    return _torch().stack(parts, dim=-1) if is_torch(like) else np.stack(parts, axis=-1)
