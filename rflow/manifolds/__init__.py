"""Manifolds the skills live on, and a small registry by name.

Each manifold gives the same small interface on arrays of points (numpy or torch, batched):
``log`` (points -> tangent vectors at the goal, (..., D)), ``exp`` (tangent vectors -> points),
``distance`` and ``prepare`` (per-trajectory preprocessing, e.g. quaternion hemisphere continuity).
Tangent vectors are flat: R^n itself, T S^3 as 3-vectors, T SPD(d) as Mandel vectors of length d(d+1)/2.

    >>> from rflow.manifolds import get_manifold
    >>> sphere = get_manifold("sphere")
    >>> sphere.log(q, goal).shape   # (..., 3)
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Mapping

from rflow.errors import RFlowError
from rflow.manifolds import euclidean, sphere, spd
from rflow.manifolds._backend import Array


class Manifold:
    """Interface of a manifold: flat tangent coordinates at a goal point."""

    name: str = ""
    point_ndim: int = 1  # trailing axes of one point: 1 for vectors/quaternions, 2 for matrices

    def check_points(self, points: Array, name: str = "points") -> Array:
        """Validate points (..., *point_shape); return them as a float array/tensor. Raises RFlowError."""
        raise NotImplementedError

    def tangent_dim(self, point_shape: tuple[int, ...]) -> int:
        """Length D of the flat tangent vector for points of shape ``point_shape``."""
        raise NotImplementedError

    def log(self, points: Array, goal: Array) -> Array:
        """Tangent vectors (..., D) at ``goal`` of ``points`` (..., *point_shape)."""
        raise NotImplementedError

    def exp(self, tangent: Array, goal: Array) -> Array:
        """Points (..., *point_shape) of tangent vectors (..., D) at ``goal``."""
        raise NotImplementedError

    def distance(self, a: Array, b: Array) -> Array:
        """Distance between points, batched -> (...)."""
        raise NotImplementedError

    def prepare(self, trajectories: Array) -> Array:
        """Per-trajectory preprocessing of (N, M, *point_shape) before learning (identity by default)."""
        return self.check_points(trajectories, "demos")

    def __repr__(self) -> str:
        return f"Manifold({self.name!r})"


class EuclideanSpace(Manifold):
    """R^n: tangent = x - goal."""

    name = "euclidean"
    point_ndim = 1

    def check_points(self, points: Array, name: str = "points") -> Array:
        return euclidean.check_points(points, name)

    def tangent_dim(self, point_shape: tuple[int, ...]) -> int:
        return int(point_shape[-1])

    def log(self, points: Array, goal: Array) -> Array:
        return euclidean.log_map(points, goal)

    def exp(self, tangent: Array, goal: Array) -> Array:
        return euclidean.exp_map(tangent, goal)

    def distance(self, a: Array, b: Array) -> Array:
        return euclidean.distance(a, b)


class UnitQuaternions(Manifold):
    """S^3 in w-x-y-z order: tangent = Log(q * conj(goal)) in R^3."""

    name = "sphere"
    point_ndim = 1

    def check_points(self, points: Array, name: str = "points") -> Array:
        return sphere.check_quaternions(points, name)

    def tangent_dim(self, point_shape: tuple[int, ...]) -> int:
        return 3

    def log(self, points: Array, goal: Array) -> Array:
        return sphere.log_map(points, goal)

    def exp(self, tangent: Array, goal: Array) -> Array:
        return sphere.exp_map(tangent, goal)

    def distance(self, a: Array, b: Array) -> Array:
        return sphere.distance(a, b)

    def prepare(self, trajectories: Array) -> Array:
        """Hemisphere continuity along each trajectory, then flip whole trajectories so all end on the
        hemisphere of the first trajectory's end (q and -q are the same orientation)."""
        q = sphere.make_continuous(trajectories)
        if q.ndim >= 3:
            ends = q[..., -1, :]
            ref = ends.reshape(-1, 4)[0]
            dots = (ends * ref).sum(-1)
            sign = (dots >= 0) * 2.0 - 1.0
            q = q * sign[..., None, None]
        return q


class SPDMatrices(Manifold):
    """SPD(d) with the affine-invariant maps: tangent = mandel(Log_G(P)) in R^{d(d+1)/2}."""

    name = "spd"
    point_ndim = 2

    def check_points(self, points: Array, name: str = "points") -> Array:
        return spd.check_spd(points, name)

    def tangent_dim(self, point_shape: tuple[int, ...]) -> int:
        return spd.mandel_dim(int(point_shape[-1]))

    def log(self, points: Array, goal: Array) -> Array:
        return spd.mandel(spd.log_map(points, goal))

    def exp(self, tangent: Array, goal: Array) -> Array:
        return spd.exp_map(spd.mandel_inverse(tangent), goal)

    def distance(self, a: Array, b: Array) -> Array:
        return spd.log_euclidean_distance(a, b)


MANIFOLDS: Mapping[str, Manifold] = MappingProxyType(
    {m.name: m for m in (EuclideanSpace(), UnitQuaternions(), SPDMatrices())}
)


def get_manifold(name: str | Manifold) -> Manifold:
    """The manifold registered under ``name`` ("euclidean", "sphere", "spd"); a Manifold passes through.

    Raises:
        RFlowError: unknown name.
    """
    if isinstance(name, Manifold):
        return name
    try:
        return MANIFOLDS[name]
    except (KeyError, TypeError):
        raise RFlowError(f"unknown manifold {name!r}; expected one of {sorted(MANIFOLDS)}") from None


__all__ = [
    "Manifold",
    "EuclideanSpace",
    "UnitQuaternions",
    "SPDMatrices",
    "MANIFOLDS",
    "get_manifold",
    "euclidean",
    "sphere",
    "spd",
]
