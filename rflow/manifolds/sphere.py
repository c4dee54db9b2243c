"""Unit quaternions S^3 (w, x, y, z): the log and exp maps at a goal, as in the RiemannianFlow paper.

Convention (no factor 2): for q = w + u,
    Log(q) = arccos(w) u / ||u||   (0 when u = 0),
    Exp(v) = cos||v|| + sin||v|| v / ||v||   (1 when v = 0),
    Log_g(p) = Log(p * conj(g)),   Exp_g(v) = Exp(v) * g.
Every function takes numpy arrays or torch tensors (batched over leading axes) and returns the same type.
The product and conjugate are `numerics.quaternion`'s.
"""

from __future__ import annotations

import numpy as np

from numerics.quaternion import quat_conj, quat_mul
from rflow.errors import RFlowError
from rflow.manifolds._backend import Array, as_array, check_last_dims, concat, is_torch, max_abs, norm, xp

UNIT_TOLERANCE = 1e-6  # | ||q|| - 1 | allowed for an input quaternion
_SMALL_ANGLE = 1e-4  # below this rotation angle the sinc / angle-over-sine series are used


def check_quaternions(q: Array, name: str = "quaternion") -> Array:
    """Validate unit quaternions (..., 4) in w-x-y-z order.

    Raises:
        RFlowError: wrong shape, NaN/inf, or a norm off 1 by more than UNIT_TOLERANCE.
    """
    q = as_array(q, name)
    check_last_dims(q, (4,), name)
    err = abs(norm(q, keepdims=False) - 1.0)
    worst = max_abs(err)
    if worst > UNIT_TOLERANCE:
        raise RFlowError(f"{name} is not a unit quaternion: | ||q|| - 1 | = {worst:.3g} > {UNIT_TOLERANCE:g}")
    return q


def check_tangent(v: Array, name: str = "tangent") -> Array:
    """Validate tangent vectors (..., 3) of T S^3.

    Raises:
        RFlowError: wrong shape or NaN/inf.
    """
    v = as_array(v, name)
    check_last_dims(v, (3,), name)
    return v


def quat_log(q: Array) -> Array:
    """Log(w + u) = arccos(w) u / ||u|| of unit quaternions (..., 4) -> (..., 3), with ||Log|| <= pi.

    The angle is computed as atan2(||u||, w) (equal to arccos(w) on S^3, accurate near w = +-1); the
    factor angle/||u|| uses its series 1 + ||u||^2/6 near the identity. At the antipode itself (u = 0,
    w = -1) the direction is undefined and the x axis is returned (||Log|| = pi).
    """
    m = xp(q)
    w = q[..., :1]
    u = q[..., 1:]
    s = norm(u)
    angle = m.arctan2(s, w)
    s_safe = m.where(s > 0, s, m.ones_like(s))
    # near the identity angle/s = 1 + s^2/6 (w > 0); near the antipode angle/s is large but finite
    near_identity = (s < _SMALL_ANGLE) & (w > 0)
    factor = m.where(near_identity, 1.0 + s * s / 6.0, angle / s_safe)
    v = factor * u
    antipode = (s == 0) & (w < 0)
    if bool(antipode.any()):
        axis = m.zeros_like(v)
        axis[..., 0] = np.pi
        v = m.where(antipode, axis, v)
    return v


def quat_exp(v: Array) -> Array:
    """Exp(v) = cos||v|| + sin||v|| v/||v|| of tangent vectors (..., 3) -> unit quaternions (..., 4)."""
    m = xp(v)
    t = norm(v)
    small = t < _SMALL_ANGLE
    t_safe = m.where(small, m.ones_like(t), t)
    sinc = m.where(small, 1.0 - t * t / 6.0, m.sin(t_safe) / t_safe)
    return concat([m.cos(t), sinc * v], v)


def log_map(q: Array, base: Array) -> Array:
    """Log_g(q) = Log(q * conj(g)) of unit quaternions (..., 4) at base g (..., 4) -> T_g S^3 (..., 3).

    Raises:
        RFlowError: non-unit, NaN or wrongly shaped input.
    """
    q = check_quaternions(q, "quaternion")
    base = check_quaternions(base, "base quaternion")
    return quat_log(quat_mul(q, quat_conj(base)))


def exp_map(v: Array, base: Array) -> Array:
    """Exp_g(v) = Exp(v) * g of tangent vectors (..., 3) at base g (..., 4) -> unit quaternions (..., 4).

    Raises:
        RFlowError: NaN or wrongly shaped input, non-unit base.
    """
    v = check_tangent(v, "tangent")
    base = check_quaternions(base, "base quaternion")
    return quat_mul(quat_exp(v), base)


def distance(q1: Array, q2: Array) -> Array:
    """The paper's orientation error ||2 Log(q1 * conj(q2))|| (rad), batched -> (...).

    No sign folding: q and -q are at distance 2 pi, as in the paper's formula.

    Raises:
        RFlowError: non-unit, NaN or wrongly shaped input.
    """
    q1 = check_quaternions(q1, "q1")
    q2 = check_quaternions(q2, "q2")
    return 2.0 * norm(quat_log(quat_mul(q1, quat_conj(q2))), keepdims=False)


def make_continuous(q: Array) -> Array:
    """Hemisphere continuity along a trajectory: if q_m . q_{m+1} < 0, replace q_{m+1} by -q_{m+1}.

    Args:
        q: unit quaternions (..., M, 4), the trajectory along axis -2.

    Returns:
        The trajectory with signs flipped so consecutive quaternions have a non-negative dot product.

    Raises:
        RFlowError: non-unit, NaN or wrongly shaped input.
    """
    q = check_quaternions(q, "quaternion trajectory")
    if q.ndim < 2:
        raise RFlowError(f"quaternion trajectory has shape {tuple(q.shape)}, expected (..., M, 4)")
    m = xp(q)
    dots = (q[..., 1:, :] * q[..., :-1, :]).sum(-1)
    step_sign = m.where(dots < 0, -m.ones_like(dots), m.ones_like(dots))
    first = m.ones_like(dots[..., :1])
    if is_torch(q):
        signs = m.cumprod(m.cat([first, step_sign], -1), -1)
    else:
        signs = np.cumprod(np.concatenate([first, step_sign], -1), -1)
    return q * signs[..., None]
