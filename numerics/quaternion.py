"""Unit quaternions (w, x, y, z): the project's one definition of their algebra.

Convention: MuJoCo's order (w, x, y, z); a unit quaternion q maps a body frame to the world frame, and its
rotation matrix R(q) acts on column vectors. The product is Hamilton's,

    (w1 + u1)(w2 + u2) = w1 w2 - u1.u2 + w1 u2 + w2 u1 + u1 x u2,

the conjugate w - u is the inverse of a unit quaternion, and a rotation vector r = angle * axis gives
q = (cos(|r|/2), sin(|r|/2) r/|r|). (The RiemannianFlow maps of S^3, without the factor 2, are
`rflow.manifolds.sphere`'s, built on this product.)

Each formula is written once, over scalar components, in `hamilton`, `matrix_to_quat_components`,
`rotvec_components` and `quat_of_rotvec_components`; the same Python function serves numpy arrays and torch tensors
(`quat_mul`), one quaternion in Python floats (`quat_mul_one`) and, compiled with ``numba.njit``, the kernels
(`controllers.impedance_kernel` at 1 kHz, `envs.policies.closed_loop_kernel` once per control period). One source
means one rounding: a kernel's quaternion equals the array version's to the bit (tests/test_numba_twins.py). scipy's `Rotation` is the reference these are tested
against (tests/numerics/test_quaternion.py); it is not used here because it rounds differently, and what feeds an
episode record must not change with a library's internals.

This module imports numpy only (no numba, no torch), so the task configs may use it while `pih evaluate
--help` stays fast.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from numerics.arrays import Array, as_float, concat, is_torch, stack
from numerics.errors import NumericsError

FloatArray = npt.NDArray[np.float64]

#: Largest | ||q|| - 1 | of a quaternion `slerp` takes. Its result has the norm of q0, so a quaternion normalised in
#: float32 or read from a file passes; a zero or unnormalised one is a mistake.
SLERP_UNIT_TOL: float = 1e-3
_SLERP_NORM2_RANGE = ((1.0 - SLERP_UNIT_TOL) ** 2, (1.0 + SLERP_UNIT_TOL) ** 2)
#: Largest Frobenius norm of R^T R - I of a matrix `mat_to_quat` takes as a rotation (float32 rounding is ~1e-7).
ROTATION_TOL: float = 1e-5


# ------------------------------------------------------------------------------------- the scalar formulas


def hamilton(w1: Any, x1: Any, y1: Any, z1: Any, w2: Any, x2: Any, y2: Any, z2: Any) -> tuple[Any, Any, Any, Any]:
    """Components (w, x, y, z) of the Hamilton product (w1, x1, y1, z1) * (w2, x2, y2, z2).

    w = w1 w2 - u1.u2 and u = w1 u2 + w2 u1 + u1 x u2, each sum evaluated left to right as written. The
    components may be Python floats, numpy arrays or torch tensors (broadcast), or numba scalars.
    """
    return (w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2)


def matrix_to_quat_components(m00: float, m01: float, m02: float, m10: float, m11: float, m12: float,
                              m20: float, m21: float, m22: float) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z), w >= 0, of the rotation matrix [[m00, m01, m02], [m10, ...], ...].

    Shepperd's method: of 4 w^2 = 1 + tr R and 4 x^2 = 1 + R00 - R11 - R22 (and alike for y, z), the largest
    is taken from the diagonal, so the square root is of a number >= 1 and the division by it is well
    conditioned; the other components come from the off-diagonal sums and differences, e.g. for w:
    s = 2 sqrt(1 + tr R) = 4 w, x = (R21 - R12)/s, y = (R02 - R20)/s, z = (R10 - R01)/s. The result is
    normalised (q / |q|, |q| summed w, x, y, z in that order) and put on the w >= 0 hemisphere.
    """
    trace = m00 + m11 + m22
    if trace > max(m00, m11, m22):
        s = 2.0 * math.sqrt(1.0 + trace)
        w, x, y, z = 0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s
    elif m00 >= m11 and m00 >= m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        w, x, y, z = (m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s
    elif m11 >= m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        w, x, y, z = (m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        w, x, y, z = (m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s
    length = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        length = -length
    return w / length, x / length, y / length, z / length


# ------------------------------------------------------------------------------------- arrays and tensors


def quat_mul(a: Array, b: Array) -> Array:
    """Hamilton product a * b of quaternions (..., 4), broadcasting over leading axes (`hamilton`).

    numpy input (or anything array-like) gives a float64 numpy array; torch tensors give a tensor (and keep
    their autograd graph).
    """
    if type(a) is np.ndarray and type(b) is np.ndarray and a.shape == b.shape == (4,) \
            and a.dtype == b.dtype == np.float64:  # one pair (the control loop's): Python floats, the same rounding
        return np.array(hamilton(*a.tolist(), *b.tolist()))
    a, b = as_float(a), as_float(b)
    return stack(list(hamilton(a[..., 0], a[..., 1], a[..., 2], a[..., 3],
                               b[..., 0], b[..., 1], b[..., 2], b[..., 3])), a)


def quat_conj(q: Array) -> Array:
    """Conjugate w - u of quaternions (..., 4): the inverse of a unit quaternion."""
    if type(q) is np.ndarray and q.shape == (4,) and q.dtype == np.float64:  # one quaternion: no concatenate
        w, x, y, z = q.tolist()
        return np.array([w, -x, -y, -z])
    q = as_float(q)
    return concat([q[..., :1], -q[..., 1:]], q)


def quat_to_mat(quat: npt.ArrayLike) -> FloatArray:
    """Rotation matrix (3, 3) of the quaternion q = (w, x, y, z), normalised first:

        R = [[1 - 2(y^2 + z^2), 2(xy - wz), 2(xz + wy)],
             [2(xy + wz), 1 - 2(x^2 + z^2), 2(yz - wx)],
             [2(xz - wy), 2(yz + wx), 1 - 2(x^2 + y^2)]].

    Raises:
        NumericsError: not 4 finite numbers, or a norm below 1e-9 (no rotation).
    """
    q = np.asarray(quat, dtype=np.float64).reshape(-1)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise NumericsError(f"quaternion {quat!r} must be 4 finite numbers (w, x, y, z)")
    w, x, y, z = q.tolist()  # Python floats: the same arithmetic, without numpy scalars
    if math.sqrt(w * w + x * x + y * y + z * z) < 1e-9:
        raise NumericsError(f"quaternion {quat!r} has zero norm and is no rotation")
    return np.array(matrix_components(w, x, y, z)).reshape(3, 3)


def matrix_components(w: float, x: float, y: float, z: float) -> tuple[float, float, float, float, float, float,
                                                                        float, float, float]:
    """`quat_to_mat` of one quaternion of non-zero norm over its components, the matrix row by row (Python floats, or
    numba scalars compiled: envs.sim.observation_kernel)."""
    length = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / length, x / length, y / length, z / length
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


def mat_to_quat(rot: npt.ArrayLike) -> FloatArray:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (3, 3) (`matrix_to_quat_components`).

    The matrix must be a rotation: ||R^T R - I||_F <= ROTATION_TOL and det R > 0 (checked in Python floats, ~1 us; a
    scaled, sheared, reflecting or zero matrix has no quaternion, and Shepperd's method would return one anyway).

    Raises:
        NumericsError: not numbers, not 3x3, NaN/inf, or not a rotation.
    """
    try:
        m = np.asarray(rot, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise NumericsError(f"rotation matrix must be 3x3 numbers: {err}") from None
    if m.shape != (3, 3):
        raise NumericsError(f"rotation matrix must be 3x3 and finite, got shape {m.shape}")
    values = m.reshape(9).tolist()
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = values
    a = m00 * m00 + m10 * m10 + m20 * m20 - 1.0  # R^T R - I: the columns' norms and dot products
    b = m01 * m01 + m11 * m11 + m21 * m21 - 1.0
    c = m02 * m02 + m12 * m12 + m22 * m22 - 1.0
    d = m00 * m01 + m10 * m11 + m20 * m21
    e = m00 * m02 + m10 * m12 + m20 * m22
    f = m01 * m02 + m11 * m12 + m21 * m22
    off = a * a + b * b + c * c + 2.0 * (d * d + e * e + f * f)
    det = m00 * (m11 * m22 - m12 * m21) - m01 * (m10 * m22 - m12 * m20) + m02 * (m10 * m21 - m11 * m20)
    if not (off <= ROTATION_TOL * ROTATION_TOL and det > 0.0):  # NaN and inf fail both comparisons
        if not all(map(math.isfinite, values)):
            raise NumericsError("rotation matrix must be 3x3 and finite, got NaN or inf")
        raise NumericsError(f"rotation matrix {values} is no rotation: ||R^T R - I|| = {math.sqrt(off):.3g} (tolerance "
                         f"{ROTATION_TOL:g}), det R = {det:.6g}")
    return np.array(matrix_to_quat_components(*values))


def quat_from_rotvec(rotvec: npt.ArrayLike) -> FloatArray:
    """Unit quaternion of a rotation vector r = angle * axis: q = (cos(|r|/2), sin(|r|/2) r/|r|)."""
    r = np.asarray(rotvec, dtype=float)
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(|r|/2)/|r| -> 1/2 as |r| -> 0
    scale = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5)
    return np.concatenate([np.cos(half), scale * r], axis=-1)


def quat_to_rotvec(q: npt.ArrayLike) -> FloatArray:
    """Rotation vector (angle * axis, angle in [0, pi]) of a unit quaternion; q and -q give the same.

    angle = 2 atan2(|u|, |w|), axis = sign(w) u / |u|.
    """
    q = np.asarray(q, dtype=float)
    w = q[..., :1]
    u = q[..., 1:] * np.where(w < 0.0, -1.0, 1.0)
    norm_u = np.linalg.norm(u, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(norm_u, np.abs(w))
    scale = np.where(norm_u > 1e-12, angle / np.where(norm_u > 1e-12, norm_u, 1.0), 2.0)
    return scale * u


def quat_angle_rad(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """Rotation angle between two orientations, in [0, pi]: |rotvec(a * conj(b))|."""
    return np.linalg.norm(quat_to_rotvec(quat_mul(a, quat_conj(b))), axis=-1)


def _check_slerp_input(q0: Any, q1: Any, s: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
    """q0, q1 and s of `slerp` as float64 arrays, checked: unit quaternions (..., 4) within SLERP_UNIT_TOL, finite s.

    One quaternion (the control loop's case) is checked in Python floats (~0.3 us), a batch with one einsum.

    Raises:
        NumericsError: naming the input: not numbers, not (..., 4), NaN/inf, a norm off 1 (a zero quaternion).
    """
    lo, hi = _SLERP_NORM2_RANGE
    out = []
    for name, value in (("q0", q0), ("q1", q1)):
        try:
            q = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as err:
            raise NumericsError(f"slerp: {name} is not an array of numbers: {err}") from None
        if q.shape == (4,):
            w, x, y, z = q.tolist()
            n2 = w * w + x * x + y * y + z * z
            ok = lo <= n2 <= hi  # NaN fails, and so does inf
        elif q.shape[-1:] != (4,):
            raise NumericsError(f"slerp: {name} has shape {q.shape}, expected quaternions (..., 4) (w, x, y, z)")
        else:
            n2 = np.einsum("...i,...i->...", q, q)
            ok = q.size == 0 or bool(n2.min() >= lo and n2.max() <= hi)  # NaN fails
        if not ok:
            n2 = np.asarray(n2)
            bad = np.unravel_index(int(np.argmax(~((n2 >= lo) & (n2 <= hi)))), n2.shape) if n2.ndim else ()
            where = f" at {list(map(int, bad))}" if bad else ""
            if not np.all(np.isfinite(q)):
                raise NumericsError(f"slerp: {name}{where} contains NaN or inf")
            raise NumericsError(f"slerp: {name}{where} is not a unit quaternion: norm {math.sqrt(float(n2[bad])):.6g} "
                             f"(tolerance {SLERP_UNIT_TOL:g})")
        out.append(q)
    try:
        t = np.asarray(s, dtype=float)
    except (TypeError, ValueError) as err:
        raise NumericsError(f"slerp: s is not an array of numbers: {err}") from None
    if not (math.isfinite(t.item()) if t.ndim == 0 else bool(np.isfinite(t).all())):
        raise NumericsError(f"slerp: s contains NaN or inf: "
                            f"{t.tolist() if t.size <= 8 else 'of shape ' + str(t.shape)}")
    return out[0], out[1], t


def slerp(q0: npt.ArrayLike, q1: npt.ArrayLike, s: npt.ArrayLike) -> FloatArray:
    """Spherical linear interpolation along the shorter arc, broadcasting q0, q1 (..., 4) and s (...).

    slerp(q0, q1, s) = q0 * exp(s log(conj(q0) * q1)), with q1 sign-flipped onto q0's hemisphere. s in [0, 1] goes
    from q0 to q1; s outside it extrapolates along the same arc (still a rotation). The result has the norm of q0.

    Raises:
        NumericsError: q0 or q1 not quaternions (..., 4) of norm 1 within SLERP_UNIT_TOL (NaN, inf, zero), s not
            finite, or shapes that do not broadcast.
    """
    q0, q1, t = _check_slerp_input(q0, q1, s)
    if not (q0.shape == q1.shape == (4,) and t.ndim == 0):  # one rotation (the control loop's case) broadcasts
        try:
            np.broadcast_shapes(q0.shape[:-1], q1.shape[:-1], t.shape)
        except ValueError:
            raise NumericsError(f"slerp: q0 {q0.shape}, q1 {q1.shape} and s {t.shape} do not broadcast") from None
    rel = quat_mul(quat_conj(q0), q1)
    rel = np.where(rel[..., :1] < 0.0, -rel, rel)
    return quat_mul(q0, quat_from_rotvec(t[..., None] * quat_to_rotvec(rel)))


def rotate(quat: npt.ArrayLike, vec: npt.ArrayLike) -> FloatArray:
    """Rotate vector(s) by unit quaternion(s): q * (0, v) * conj(q)."""
    v = np.asarray(vec, dtype=float)
    q = quat if is_torch(quat) else np.asarray(quat, dtype=float)
    if v.shape == (3,) and q.shape == (4,) and not is_torch(q):  # one vector, one quaternion: products in Python floats
        w, x, y, z = q.tolist()
        return np.array(hamilton(*hamilton(w, x, y, z, 0.0, *v.tolist()), w, -x, -y, -z)[1:])
    qv = np.concatenate([np.zeros(v.shape[:-1] + (1,)), v], axis=-1)
    return quat_mul(quat_mul(quat, qv), quat_conj(quat))[..., 1:]


# ------------------------------------------------------------------------------ one quaternion, Python floats

# The closed loop's hot path: tiny arrays cost more in numpy call overhead than in arithmetic. The product is
# `hamilton` itself; the rotation-vector maps repeat quat_to_rotvec and quat_from_rotvec operation for
# operation (np.linalg.norm over the last axis is a left-to-right sum of squares), so the results are the same
# to the bit (tests/envs/policies/test_policy_single_pose.py); the transcendental functions are numpy's own ufuncs,
# which are what the array versions call.


def quat_mul_one(a: list[float], b: list[float]) -> list[float]:
    """Hamilton product a * b of two quaternions (w, x, y, z) in Python floats (`hamilton`)."""
    return list(hamilton(*a, *b))


def rotvec_components(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """`quat_to_rotvec` of one quaternion over its components (Python floats, or numba scalars compiled)."""
    sign = -1.0 if w < 0.0 else 1.0
    ux, uy, uz = x * sign, y * sign, z * sign
    norm_u = math.sqrt(ux * ux + uy * uy + uz * uz)
    angle = 2.0 * float(np.arctan2(norm_u, abs(w)))
    scale = angle / norm_u if norm_u > 1e-12 else 2.0
    return scale * ux, scale * uy, scale * uz


def quat_of_rotvec_components(x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """`quat_from_rotvec` of one rotation vector over its components (Python floats, or numba scalars compiled)."""
    angle = math.sqrt(x * x + y * y + z * z)
    half = 0.5 * angle
    scale = float(np.sin(half)) / angle if angle > 1e-12 else 0.5
    return float(np.cos(half)), scale * x, scale * y, scale * z


def quat_to_rotvec_one(q: list[float]) -> list[float]:
    """`quat_to_rotvec` of one quaternion (`rotvec_components`)."""
    return list(rotvec_components(*q))


def quat_from_rotvec_one(r: list[float]) -> list[float]:
    """`quat_from_rotvec` of one rotation vector (`quat_of_rotvec_components`)."""
    return list(quat_of_rotvec_components(*r))
