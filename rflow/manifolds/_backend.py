"""Tiny numpy/torch dispatch used by the manifold maps: the same equation runs on either array type (the light
part, `is_torch`, `xp`, `concat`, `stack`, lives in `numerics.arrays`; here the checks and the linear algebra)."""

from __future__ import annotations

from typing import Any

import numpy as np

from numerics.arrays import Array, _torch, concat, is_torch, stack, xp
from numerics.small_linalg import eigh_sym
from numerics.small_linalg import matmul as small_matmul
from rflow.errors import RFlowError


def as_array(x: Any, name: str) -> Array:
    """Return ``x`` as a floating numpy array (or the float tensor itself); reject NaN/inf.

    Raises:
        RFlowError: ``x`` is not numeric or holds NaN/inf.
    """
    if is_torch(x):
        torch = _torch()
        if not torch.is_floating_point(x):
            x = x.to(torch.get_default_dtype())
        if not bool(torch.isfinite(x).all()):
            raise RFlowError(f"{name} contains NaN or inf")
        return x
    try:
        arr = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise RFlowError(f"{name} is not a numeric array: {err}") from None
    if not np.all(np.isfinite(arr)):
        raise RFlowError(f"{name} contains NaN or inf")
    return arr


def check_last_dims(x: Array, dims: tuple[int, ...], name: str) -> None:
    """Raise RFlowError unless the trailing dimensions of ``x`` equal ``dims``."""
    shape = tuple(x.shape)
    if len(shape) < len(dims) or shape[len(shape) - len(dims):] != dims:
        want = "(..., " + ", ".join(str(d) for d in dims) + ")"
        raise RFlowError(f"{name} has shape {shape}, expected {want}")


def norm(x: Array, keepdims: bool = True) -> Array:
    """Euclidean norm over the last axis."""
    if is_torch(x):
        return _torch().linalg.vector_norm(x, dim=-1, keepdim=keepdims)
    return np.linalg.norm(x, axis=-1, keepdims=keepdims)


def swap_last(x: Array) -> Array:
    """Transpose the last two axes."""
    return x.transpose(-1, -2) if is_torch(x) else np.swapaxes(x, -1, -2)


def eigh(x: Array) -> tuple[Array, Array]:
    """Symmetric eigendecomposition, batched over leading axes (numpy: `numerics.small_linalg.eigh_sym`, no LAPACK)."""
    return _torch().linalg.eigh(x) if is_torch(x) else eigh_sym(x)


def matmul(a: Array, b: Array) -> Array:
    """a @ b, batched over leading axes (numpy: `numerics.small_linalg.matmul`, no BLAS)."""
    return a @ b if is_torch(a) or is_torch(b) else small_matmul(a, b)  # blas-ok: torch (pinned), numpy in small_linalg


def max_abs(x: Array) -> float:
    """Largest absolute entry as a Python float (0 for an empty array)."""
    if is_torch(x):
        return float(x.abs().max()) if x.numel() else 0.0
    return float(np.abs(x).max()) if x.size else 0.0


__all__ = ["Array", "as_array", "check_last_dims", "concat", "eigh", "is_torch", "matmul", "max_abs", "norm", "stack",
           "swap_last", "xp"]
