"""Manifolds the skills live on, and a small registry by name.

Each manifold gives the same small interface on arrays of points (numpy or torch, batched):
``log`` (points -> tangent vectors at the goal, (..., D)), ``exp`` (tangent vectors -> points),
``distance`` and ``prepare`` (per-trajectory preprocessing, e.g. quaternion hemisphere continuity).
Tangent vectors are flat: R^n itself, T S^3 as 3-vectors, T SPD(d) as Mandel vectors of length d(d+1)/2
("spd": of Log_G(P); "spd_normal": of its normal coordinates logm(G^-1/2 P G^-1/2)). `ProductManifold`
joins them, points and tangent vectors concatenated flat.

    >>> from rflow.manifolds import get_manifold
    >>> sphere = get_manifold("sphere")
    >>> sphere.log(q, goal).shape   # (..., 3)
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from rflow.errors import RFlowError
from rflow.manifolds import euclidean, sphere, spd
from rflow.manifolds._backend import Array, concat


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


def _finite(points: Array, manifold: str) -> Array:
    """``points`` of an exponential map, refused when it overflowed (NumPy only warns and returns NaN or inf for a
    tangent too long for the map's arithmetic, e.g. 1e155 on S^3 or a normal coordinate of 800 on SPD). Torch
    tensors, which training differentiates, pass unchecked."""
    if isinstance(points, np.ndarray) and not np.all(np.isfinite(points)):
        raise RFlowError(f"{manifold}: the exponential map of a tangent overflowed (the tangent is too long)")
    return points


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
        return _finite(sphere.exp_map(tangent, goal), self.name)

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
        return _finite(spd.exp_map(spd.mandel_inverse(tangent), goal), self.name)

    def distance(self, a: Array, b: Array) -> Array:
        return spd.log_euclidean_distance(a, b)


class SPDNormalMatrices(SPDMatrices):
    """SPD(d) with the affine-invariant maps in normal coordinates at G: tangent = mandel(logm(G^-1/2 P G^-1/2)).

    The same geodesics as "spd" (the tangent matrix is G^-1/2 Log_G(P) G^-1/2), but dimensionless, with
    ||tangent|| the Riemannian distance d(G, P): the chart for SPD factors of a product manifold.
    """

    name = "spd_normal"

    def log(self, points: Array, goal: Array) -> Array:
        return spd.mandel(spd.normal_log_map(points, goal))

    def exp(self, tangent: Array, goal: Array) -> Array:
        return _finite(spd.normal_exp_map(spd.mandel_inverse(tangent), goal), self.name)


class ProductManifold(Manifold):
    """A product M_1 x ... x M_k of the manifolds above with flat points and flat tangent vectors.

    A point is the concatenation of the factors' flattened points (e.g. R^3 x S^3 x SPD(3): [p (3), q (4),
    vec(K) (9)] = 16 numbers), a tangent vector the concatenation of the factors' tangent vectors
    (3 + 3 + 6 = 12):
        Log_g(x) = [Log_{g_1}(x_1), ..., Log_{g_k}(x_k)],   Exp_g(v) = [Exp_{g_1}(v_1), ..., Exp_{g_k}(v_k)],
        d(a, b) = sqrt(sum_i d_i(a_i, b_i)^2)  (units mixed: for ordering only).

    Args:
        name: the name checkpoints record (must be unique among the manifolds a loader knows).
        factors: (manifold, point shape) per factor, e.g. ((EuclideanSpace(), (3,)), (SPDNormalMatrices(), (3, 3))).
    """

    point_ndim = 1

    def __init__(self, name: str, factors: tuple[tuple[Manifold, tuple[int, ...]], ...]):
        if not factors:
            raise RFlowError("a product manifold needs at least one factor")
        self.name = name
        self.factors = tuple((get_manifold(m), tuple(int(n) for n in shape)) for m, shape in factors)
        sizes = [int(np.prod(shape)) for _, shape in self.factors]
        dims = [m.tangent_dim(shape) for m, shape in self.factors]
        self._points = np.concatenate([[0], np.cumsum(sizes)])
        self._tangents = np.concatenate([[0], np.cumsum(dims)])

    @property
    def point_size(self) -> int:
        """Numbers in one flat point."""
        return int(self._points[-1])

    def split(self, points: Array) -> list[Array]:
        """The factors' points (..., *shape_i) of flat points (..., point_size)."""
        return [points[..., a:b].reshape(tuple(points.shape[:-1]) + shape)
                for (_, shape), a, b in zip(self.factors, self._points[:-1], self._points[1:])]

    def join(self, parts: list[Array]) -> Array:
        """Flat points (..., point_size) of the factors' points."""
        flat = [x.reshape(tuple(x.shape[: x.ndim - len(shape)]) + (-1,)) for x, (_, shape) in zip(parts, self.factors)]
        return concat(flat, flat[0])

    def _tangent_parts(self, tangent: Array) -> list[Array]:
        return [tangent[..., a:b] for a, b in zip(self._tangents[:-1], self._tangents[1:])]

    def check_points(self, points: Array, name: str = "points") -> Array:
        x = euclidean.check_points(points, name)
        if x.shape[-1] != self.point_size:
            raise RFlowError(f"{name} has shape {tuple(x.shape)}, expected (..., {self.point_size}) {self.name} points")
        for (m, _), part in zip(self.factors, self.split(x)):
            m.check_points(part, f"{name} {m.name} part")
        return x

    def tangent_dim(self, point_shape: tuple[int, ...]) -> int:
        return int(self._tangents[-1])

    def log(self, points: Array, goal: Array) -> Array:
        x, g = self.check_points(points, "point"), self.check_points(goal, "goal")
        return concat([m.log(a, b) for (m, _), a, b in zip(self.factors, self.split(x), self.split(g))], x)

    def exp(self, tangent: Array, goal: Array) -> Array:
        v = euclidean.check_points(tangent, "tangent")
        if v.shape[-1] != self.tangent_dim(()):
            raise RFlowError(f"tangent has shape {tuple(v.shape)}, expected (..., {self.tangent_dim(())})")
        g = self.check_points(goal, "goal")
        parts = [m.exp(t, b) for (m, _), t, b in zip(self.factors, self._tangent_parts(v), self.split(g))]
        return self.join(parts)

    def distance(self, a: Array, b: Array) -> Array:
        a, b = self.check_points(a, "a"), self.check_points(b, "b")
        sq = [m.distance(x, y) ** 2 for (m, _), x, y in zip(self.factors, self.split(a), self.split(b))]
        return sum(sq[1:], sq[0]) ** 0.5

    def prepare(self, trajectories: Array) -> Array:
        """Each factor's own preprocessing (e.g. quaternion hemisphere continuity) on its part."""
        x = np.array(self.check_points(trajectories, "demos"), dtype=np.float64)
        parts = [np.asarray(m.prepare(part)) for (m, _), part in zip(self.factors, self.split(x))]
        return self.join(parts)

    def __repr__(self) -> str:
        return f"ProductManifold({self.name!r}, {[m.name for m, _ in self.factors]})"


MANIFOLDS: Mapping[str, Manifold] = MappingProxyType(
    {m.name: m for m in (EuclideanSpace(), UnitQuaternions(), SPDMatrices(), SPDNormalMatrices())}
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


def prepare_demos(demos: Any, manifold: str | Manifold, dt: float, method: str) -> tuple[Manifold, np.ndarray]:
    """The manifold named ``manifold`` and the demos (N, M, point) prepared on it (`Manifold.prepare`: e.g.
    quaternion hemisphere continuity), checked for a baseline's fit (``method`` names it in the errors).

    Raises:
        RFlowError: dt <= 0 or not finite; demos that are not (N, M, point) with M >= 2.
    """
    man = get_manifold(manifold)
    if not (np.isfinite(dt) and dt > 0):
        raise RFlowError(f"sampling time dt={dt} must be > 0")
    data = np.asarray(man.prepare(np.asarray(demos, dtype=np.float64)))
    if data.ndim != 2 + man.point_ndim or data.shape[1] < 2:
        raise RFlowError(f"{method} demos have shape {data.shape}, expected (N, M, point) with M >= 2")
    return man, data


__all__ = [
    "Manifold",
    "EuclideanSpace",
    "UnitQuaternions",
    "SPDMatrices",
    "SPDNormalMatrices",
    "ProductManifold",
    "MANIFOLDS",
    "get_manifold",
    "prepare_demos",
    "euclidean",
    "sphere",
    "spd",
]
