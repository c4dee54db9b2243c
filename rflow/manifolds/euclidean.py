"""Euclidean space R^n: Log_g(x) = x - g, Exp_g(v) = g + v (positions, and the naive baselines)."""

from __future__ import annotations

from rflow.errors import RFlowError
from rflow.manifolds._backend import Array, as_array, norm


def check_points(x: Array, name: str = "point") -> Array:
    """Validate points (..., n) with n >= 1.

    Raises:
        RFlowError: scalar input or NaN/inf.
    """
    x = as_array(x, name)
    if x.ndim < 1 or x.shape[-1] < 1:
        raise RFlowError(f"{name} has shape {tuple(x.shape)}, expected (..., n) with n >= 1")
    return x


def _same_dim(a: Array, b: Array, name_a: str, name_b: str) -> None:
    if a.shape[-1] != b.shape[-1]:
        raise RFlowError(f"{name_a} has dimension {a.shape[-1]} but {name_b} has {b.shape[-1]}")


def log_map(x: Array, base: Array) -> Array:
    """Log_g(x) = x - g.

    Raises:
        RFlowError: NaN or mismatched dimensions.
    """
    x, base = check_points(x, "point"), check_points(base, "base point")
    _same_dim(x, base, "point", "base point")
    return x - base


def exp_map(v: Array, base: Array) -> Array:
    """Exp_g(v) = g + v.

    Raises:
        RFlowError: NaN or mismatched dimensions.
    """
    v, base = check_points(v, "tangent"), check_points(base, "base point")
    _same_dim(v, base, "tangent", "base point")
    return base + v


def distance(a: Array, b: Array) -> Array:
    """Euclidean distance ||a - b||, batched -> (...).

    Raises:
        RFlowError: NaN or mismatched dimensions.
    """
    a, b = check_points(a, "a"), check_points(b, "b")
    _same_dim(a, b, "a", "b")
    return norm(a - b, keepdims=False)
