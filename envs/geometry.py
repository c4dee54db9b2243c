"""Small rigid-body and planar-polygon helpers for building the scene (pure numpy, no MuJoCo).

Conventions: quaternions are unit and ordered (w, x, y, z); rotation matrices act on column vectors,
so the columns of ``R`` are the axes of a frame expressed in its parent frame.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from numerics.quaternion import mat_to_quat, quat_to_mat  # noqa: F401 -- rflow's, re-exported for envs and tests

FloatArray = npt.NDArray[np.float64]

R_FLIP_X: FloatArray = np.diag([1.0, -1.0, -1.0])
"""Rotation by pi about x: maps a hole frame (z up out of the hole) to the goal peg_tip frame (z down)."""


def all_finite(values: FloatArray) -> bool:
    """Every entry is finite: a finite sum proves it in one reduction; a non-finite one (or an overflow) is
    checked entry by entry."""
    return math.isfinite(values.sum()) or bool(np.all(np.isfinite(values)))


def as_vector(value: npt.ArrayLike, size: int, name: str) -> FloatArray:
    """Return ``value`` as a finite float vector of length ``size``.

    Raises:
        EnvError: if the value has another shape or is not finite.
    """
    try:
        vector = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as error:
        raise EnvError(f"{name}={value!r} is not a numeric vector of length {size}") from error
    if vector.shape != (size,) or not all_finite(vector):
        raise EnvError(f"{name}={value!r} must be {size} finite numbers")
    return vector


def normalize_quat(quat: npt.ArrayLike, name: str = "quat") -> FloatArray:
    """Return the unit quaternion (w, x, y, z) of ``quat``.

    Raises:
        EnvError: if ``quat`` is not 4 finite numbers of non-negligible norm.
    """
    from numerics.small_linalg import norm  # here: the task configs import this module, --help must not load numba

    q = as_vector(quat, 4, name)
    length = norm(q)
    if length < 1e-9:
        raise EnvError(f"{name}={quat!r} has zero norm and is no rotation")
    return q / length


def rot_z(angle_rad: float) -> FloatArray:
    """Rotation by ``angle_rad`` about z."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def z_down_rotation(yaw_deg: float) -> FloatArray:
    """R = Rz(yaw) Rx(pi): the frame whose z axis points straight down and whose x axis has heading yaw."""
    from numerics.small_linalg import matmul  # here: the task configs import this module, --help must not load numba

    return matmul(rot_z(np.deg2rad(yaw_deg)), R_FLIP_X)


def z_down_yaw_deg(quat: npt.ArrayLike) -> float:
    """Heading of the z-down orientation nearest to ``quat``.

    Among R(psi) = Rz(psi) Rx(pi) = [[c, s, 0], [s, -c, 0], [0, 0, -1]], the one closest to Q (geodesic
    and Frobenius distance agree on SO(3)) maximises tr(R^T Q) = c (Q00 - Q11) + s (Q01 + Q10) - Q22, so
        psi = atan2(Q01 + Q10, Q00 - Q11).

    Args:
        quat: orientation (w, x, y, z), e.g. the paper's goal g_q = 0.022 + [0.991, -0.125, 0.035].

    Returns:
        psi in degrees, in (-180, 180].

    Raises:
        EnvError: if ``quat`` is not a valid quaternion or its z axis points up (no unique nearest z-down heading).
    """
    q_mat = quat_to_mat(quat)
    a, b = q_mat[0, 0] - q_mat[1, 1], q_mat[0, 1] + q_mat[1, 0]
    if np.hypot(a, b) < 1e-9:
        raise EnvError(f"quat={quat!r} points its z axis up: the nearest z-down heading is not unique")
    return float(np.rad2deg(np.arctan2(b, a)))


def tilt_from_down_deg(rot: npt.ArrayLike) -> float:
    """Angle in degrees between the z axis of ``rot`` and the world's downward direction -e_z."""
    z_axis = np.asarray(rot, dtype=np.float64)[:, 2]
    return float(np.rad2deg(np.arccos(np.clip(-z_axis[2], -1.0, 1.0))))


def twist_angle_deg(rot: npt.ArrayLike) -> float:
    """Rotation about z of the z-rotation nearest to ``rot``: atan2(R10 - R01, R00 + R11), in degrees."""
    m = np.asarray(rot, dtype=np.float64)
    return float(np.rad2deg(np.arctan2(m[1, 0] - m[0, 1], m[0, 0] + m[1, 1])))


def look_at_xyaxes(position: npt.ArrayLike, target: npt.ArrayLike, up: npt.ArrayLike) -> FloatArray:
    """MJCF camera ``xyaxes`` for a camera at ``position`` looking at ``target`` (parent frame).

    A MuJoCo camera looks along its -z axis, x to the image right and y to the image top:
    f = (target - position)/|.|, x = f x up/|.|, y = x x f.

    Raises:
        EnvError: if the camera sits on its target or ``up`` is parallel to the viewing direction.
    """
    from numerics.small_linalg import norm  # here: the task configs import this module, --help must not load numba

    forward = np.asarray(target, dtype=np.float64) - np.asarray(position, dtype=np.float64)
    if norm(forward) < 1e-9:
        raise EnvError(f"camera position {position!r} coincides with its target")
    forward /= norm(forward)
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    if norm(right) < 1e-9:
        raise EnvError(f"camera up {up!r} is parallel to its viewing direction")
    right /= norm(right)
    return np.concatenate([right, np.cross(right, forward)])


# ----------------------------------------------------------------------------------------------- polygons


def regular_polygon(n_sides: int, inradius_m: float, first_vertex_deg: float = 0.0) -> FloatArray:
    """Counter-clockwise vertices (n, 2) of a regular n-gon centred at the origin.

    The circumradius is inradius / cos(pi/n); the first vertex lies at angle ``first_vertex_deg``.
    """
    circumradius = inradius_m / np.cos(np.pi / n_sides)
    angles = np.deg2rad(first_vertex_deg) + 2.0 * np.pi * np.arange(n_sides) / n_sides
    return circumradius * np.stack([np.cos(angles), np.sin(angles)], axis=1)


def polygon_area(vertices: npt.ArrayLike) -> float:
    """Signed area (positive for counter-clockwise) by the shoelace formula."""
    from numerics.small_linalg import dot  # here: the task configs import this module, --help must not load numba

    v = np.asarray(vertices, dtype=np.float64)
    x, y = v[:, 0], v[:, 1]
    return 0.5 * (dot(x, np.roll(y, -1)) - dot(np.roll(x, -1), y))


def edge_lines(vertices: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Outward unit normals n_i (n, 2) and offsets d_i (n,) of a counter-clockwise convex polygon.

    Edge i runs from vertex i to vertex i+1; the polygon is {p : n_i . p <= d_i for all i}.
    """
    v = np.asarray(vertices, dtype=np.float64)
    edges = np.roll(v, -1, axis=0) - v
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return normals, np.einsum("ij,ij->i", normals, v)


def offset_convex_polygon(vertices: npt.ArrayLike, distance_m: float) -> FloatArray:
    """Move every edge of a counter-clockwise convex polygon outwards by ``distance_m``.

    The new vertex i is the intersection of the shifted lines of edges i-1 and i:
    n . p = d + distance for both.
    """
    from numerics.small_linalg import solve  # here: the task configs import this module, --help must not load numba

    normals, offsets = edge_lines(vertices)
    shifted = offsets + distance_m
    out = np.empty((len(normals), 2))
    for i in range(len(normals)):
        a = np.stack([normals[i - 1], normals[i]])
        out[i] = solve(a, np.array([shifted[i - 1], shifted[i]]))
    return out


def mirror_y(vertices: npt.ArrayLike) -> FloatArray:
    """Mirror a polygon across the x axis (y -> -y), keeping counter-clockwise order."""
    v = np.asarray(vertices, dtype=np.float64) * np.array([1.0, -1.0])
    return v[::-1].copy()


def clip_polygon(vertices: npt.ArrayLike, normal: npt.ArrayLike, offset: float) -> FloatArray:
    """Keep the part of a convex polygon with normal . p <= offset (Sutherland-Hodgman, one plane)."""
    from numerics.small_linalg import dot  # here: the task configs import this module, --help must not load numba

    v = np.asarray(vertices, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    out: list[FloatArray] = []
    for i in range(len(v)):
        p, q = v[i], v[(i + 1) % len(v)]
        sp, sq = dot(n, p) - offset, dot(n, q) - offset
        if sp <= 0.0:
            out.append(p)
        if sp * sq < 0.0:
            out.append(p + (q - p) * sp / (sp - sq))
    return np.asarray(out).reshape(-1, 2)


def rectangle(x_min: float, x_max: float, y_min: float, y_max: float) -> FloatArray:
    """Counter-clockwise vertices of an axis-aligned rectangle."""
    return np.array([[x_min, y_min], [x_max, y_min], [x_max, y_max], [x_min, y_max]])
