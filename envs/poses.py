"""Poses of the peg tip: the Pose type (`numerics.pose`, re-exported here), pose validation, start-pose sampling and
trajectory resampling.

All quaternions are unit quaternions in (w, x, y, z) order, the MuJoCo convention. A pose is a
position in metres and a quaternion mapping the body frame to the world frame. The quaternion algebra is
`numerics.quaternion`'s (one definition for every layer); its functions are re-exported here for the
modules of `envs` that import them with the poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.geometry import all_finite
from numerics.pose import Pose
from numerics.quaternion import (quat_angle_rad, quat_conj, quat_from_rotvec, quat_from_rotvec_one, quat_mul,
                                 quat_mul_one, quat_to_rotvec, quat_to_rotvec_one, rotate, slerp)
from numerics.small_linalg import matvec, norm

FloatArray = npt.NDArray[np.float64]

#: Largest |norm - 1| accepted for a quaternion given by a user before it is normalised.
QUAT_NORM_TOL: float = 1e-3


def make_continuous(quat: npt.ArrayLike, reference: npt.ArrayLike | None = None) -> FloatArray:
    """Flip signs so consecutive quaternions of a sequence (..., M, 4) have q_m . q_{m+1} >= 0.

    With ``reference`` (4,), the LAST sample is first put on the reference's hemisphere, so a
    trajectory ending at the goal ends at +goal, not -goal.
    """
    q = np.array(quat, dtype=float)
    if q.ndim < 2 or q.shape[-2] == 0:
        return q
    if reference is not None:
        flip = np.sum(q[..., -1, :] * np.asarray(reference, dtype=float), axis=-1) < 0.0
        q[..., -1, :] = np.where(flip[..., None], -q[..., -1, :], q[..., -1, :])
    for m in range(q.shape[-2] - 2, -1, -1):
        flip = np.sum(q[..., m, :] * q[..., m + 1, :], axis=-1) < 0.0
        q[..., m, :] = np.where(flip[..., None], -q[..., m, :], q[..., m, :])
    return q


def mean_quat(quat: npt.ArrayLike) -> FloatArray:
    """Mean orientation of nearby quaternions (M, 4): normalised sum after sign alignment to the first."""
    q = np.asarray(quat, dtype=float)
    signs = np.where(matvec(q, q[0]) < 0.0, -1.0, 1.0)
    total = np.sum(signs[:, None] * q, axis=0)
    return total / norm(total)


def validate_pose(pos: npt.ArrayLike, quat: npt.ArrayLike, what: str = "pose") -> Pose:
    """Check a user-given pose and return it with a normalised quaternion.

    Raises:
        EnvError: wrong shape, NaN/inf, or a quaternion whose norm differs from 1 by more than
            QUAT_NORM_TOL.
    """
    try:
        p = np.asarray(pos, dtype=float)
        q = np.asarray(quat, dtype=float)
    except (TypeError, ValueError) as err:
        raise EnvError(f"{what}: position/quaternion are not numeric arrays ({err})") from None
    if p.shape != (3,):
        raise EnvError(f"{what}: position must have shape (3,), got {p.shape}")
    if q.shape != (4,):
        raise EnvError(f"{what}: quaternion must have shape (4,) (w, x, y, z), got {q.shape}")
    if not (all_finite(p) and all_finite(q)):
        raise EnvError(f"{what}: position {p.tolist()} / quaternion {q.tolist()} contain NaN or inf")
    length = norm(q)
    if abs(length - 1.0) > QUAT_NORM_TOL:
        raise EnvError(f"{what}: quaternion {q.tolist()} is not unit (norm {length:.6g})")
    return Pose(pos=p.copy(), quat=q / length)


def format_pose(pose: Pose) -> str:
    """Short human-readable pose: 'pos [x, y, z] m, quat [w, x, y, z]'."""
    pos = ", ".join(f"{v:.4f}" for v in pose.pos)
    quat = ", ".join(f"{v:.4f}" for v in pose.quat)
    return f"pos [{pos}] m, quat [{quat}]"


@dataclass(frozen=True)
class StartRegion:
    """Where scripted demonstrations and evaluation episodes start (peg_tip pose).

    The nominal start is the hole opening raised by ``height_above_opening_m`` along the hole axis and
    moved ``toward_base_m`` horizontally toward the robot base (the world origin), with the goal
    orientation. A start pose is sampled as:
      - position: nominal + d, d uniform in the box [-h, h] (h = ``pos_half_width_m`` per world axis);
      - orientation: exp(r) * goal_quat, r a rotation vector (world frame) drawn uniformly from the
        ball of radius ``max_angle_deg``: direction uniform on the sphere, angle = max * u^(1/3).

    Defaults: +-10 cm (horizontal), +-2.5 cm (vertical) and +-20 deg around a nominal start 17.5 cm
    above the opening and 15 cm toward the base: every start lies 15 to 20 cm above the opening, 5 to
    25 cm from the hole axis toward the base and up to 10 cm across. The shift toward the base keeps
    the starts inside the Panda's reach: the paper's goal (0.675 m out, 0.203 m up) is near the edge
    of the workspace; starts above the hole itself, 15-20 cm up and tilted by up to 20 deg, are out of
    reach for about a quarter of the draws, while with the shift ~0.7 % are (corner of the box with the
    peg tilted toward the base). Unreachable draws are rejected by ``PegInHoleEnv.reset``.
    """

    height_above_opening_m: float = 0.175
    toward_base_m: float = 0.15
    pos_half_width_m: tuple[float, float, float] = (0.10, 0.10, 0.025)
    max_angle_deg: float = 20.0

    def __post_init__(self) -> None:
        if not np.isfinite(self.height_above_opening_m) or self.height_above_opening_m <= 0.0:
            raise EnvError(f"StartRegion: height_above_opening_m must be > 0, got {self.height_above_opening_m}")
        if not np.isfinite(self.toward_base_m):
            raise EnvError(f"StartRegion: toward_base_m must be finite, got {self.toward_base_m}")
        widths = np.asarray(self.pos_half_width_m, dtype=float)
        if widths.shape != (3,) or not np.all(np.isfinite(widths)) or np.any(widths < 0.0):
            raise EnvError(f"StartRegion: pos_half_width_m must be 3 values >= 0, got {self.pos_half_width_m}")
        if not 0.0 <= self.max_angle_deg < 180.0:
            raise EnvError(f"StartRegion: max_angle_deg must be in [0, 180), got {self.max_angle_deg}")


def nominal_start(opening_pos: npt.ArrayLike, hole_axis: npt.ArrayLike, goal_quat: npt.ArrayLike,
                  region: StartRegion) -> Pose:
    """Nominal start pose: opening + height * axis + toward_base * u, goal orientation.

    axis points out of the hole; u is the unit vector from the opening toward the world origin (the
    robot base), in the horizontal plane.
    """
    axis = np.asarray(hole_axis, dtype=float)
    axis = axis / norm(axis)
    opening = np.asarray(opening_pos, dtype=float)
    toward = np.array([-opening[0], -opening[1], 0.0])
    length = norm(toward)
    toward = toward / length if length > 1e-9 else np.zeros(3)
    pos = opening + region.height_above_opening_m * axis + region.toward_base_m * toward
    return Pose(pos=pos, quat=np.asarray(goal_quat, dtype=float).copy())


def sample_start_poses(nominal: Pose, region: StartRegion, rng: np.random.Generator,
                       num: int) -> list[Pose]:
    """Draw ``num`` start poses around ``nominal`` as documented in :class:`StartRegion`.

    Args:
        nominal: nominal start pose (its quaternion is the centre of the orientation ball).
        region: sampling region.
        rng: random generator (the only source of randomness).
        num: number of poses.

    Returns:
        list of Pose.
    """
    widths = np.asarray(region.pos_half_width_m, dtype=float)
    poses = []
    for _ in range(num):
        offset = rng.uniform(-1.0, 1.0, size=3) * widths
        direction = rng.normal(size=3)
        direction /= norm(direction)
        angle = np.deg2rad(region.max_angle_deg) * rng.uniform() ** (1.0 / 3.0)
        quat = quat_mul(quat_from_rotvec(angle * direction), nominal.quat)
        poses.append(Pose(pos=nominal.pos + offset, quat=quat / norm(quat)))
    return poses


def resample_trajectory(times: npt.ArrayLike, pos: npt.ArrayLike, quat: npt.ArrayLike,
                        new_times: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Resample a pose trajectory: positions linearly, orientations by slerp between neighbours.

    Args:
        times: (K,) strictly increasing sample times, seconds.
        pos: (K, 3) positions.
        quat: (K, 4) unit quaternions, norms within QUAT_NORM_TOL of 1 (made continuous first).
        new_times: (L,) query times within [times[0], times[-1]] (clipped to it).

    Returns:
        (pos (L, 3), quat (L, 4)).

    Raises:
        EnvError: inputs that are not numbers, mismatched shapes, NaN/inf, non-increasing times, or a quaternion
            whose norm is off 1 by more than QUAT_NORM_TOL (a zero one).
    """
    arrays = []
    for name, value in (("times", times), ("pos", pos), ("quat", quat), ("new_times", new_times)):
        try:
            arrays.append(np.asarray(value, dtype=float))
        except (TypeError, ValueError) as err:
            raise EnvError(f"resample_trajectory: {name} must be an array of numbers ({err})") from None
    t, p, q, tn = arrays
    if t.ndim != 1 or t.size < 2 or p.shape != (t.size, 3) or q.shape != (t.size, 4):
        raise EnvError(f"resample_trajectory: need times (K>=2,), pos (K, 3), quat (K, 4); got "
                       f"{t.shape}, {p.shape}, {q.shape}")
    for name, arr in (("times", t), ("pos", p), ("quat", q), ("new_times", tn)):
        if not np.isfinite(arr).all():
            raise EnvError(f"resample_trajectory: {name} contains NaN or inf (first at "
                           f"{np.argwhere(~np.isfinite(arr))[0].tolist()})")
    if np.any(np.diff(t) <= 0.0):
        raise EnvError("resample_trajectory: times must be strictly increasing")
    off = np.abs(np.linalg.norm(q, axis=-1) - 1.0)
    if off.max() > QUAT_NORM_TOL:
        worst = int(np.argmax(off))
        raise EnvError(f"resample_trajectory: quat {q[worst].tolist()} at sample {worst} is not a unit quaternion "
                       f"(norm {np.sqrt(np.sum(q[worst] ** 2)):.6g}, tolerance {QUAT_NORM_TOL:g})")
    q = make_continuous(q)
    tn = np.clip(tn, t[0], t[-1])
    new_pos = np.stack([np.interp(tn, t, p[:, i]) for i in range(3)], axis=-1)
    seg = np.clip(np.searchsorted(t, tn, side="right") - 1, 0, t.size - 2)
    s = (tn - t[seg]) / (t[seg + 1] - t[seg])
    new_quat = slerp(q[seg], q[seg + 1], s)
    new_quat /= np.linalg.norm(new_quat, axis=-1, keepdims=True)
    return new_pos, new_quat


def minimum_jerk(s: npt.ArrayLike) -> FloatArray:
    """Minimum-jerk time scaling 10 s^3 - 15 s^4 + 6 s^5 of s clipped to [0, 1] (zero vel./acc. at ends)."""
    s = np.clip(np.asarray(s, dtype=float), 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


def quintic_hermite(s: npt.ArrayLike, p0: float, v0: float, p1: float, v1: float) -> FloatArray:
    """Quintic on s in [0, 1] (clipped) with p(0) = p0, p'(0) = v0, p(1) = p1, p'(1) = v1, p''(0) = p''(1) = 0.

    Velocities are per unit of s (multiply a physical velocity by the segment duration). With v0 = v1 = 0
    this is the minimum-jerk profile p0 + (p1 - p0)(10 s^3 - 15 s^4 + 6 s^5).
    """
    s = np.clip(np.asarray(s, dtype=float), 0.0, 1.0)
    s2, s3 = s * s, s * s * s
    h0 = 1.0 - 10.0 * s3 + 15.0 * s3 * s - 6.0 * s3 * s2
    h1 = s - 6.0 * s3 + 8.0 * s3 * s - 3.0 * s3 * s2
    h4 = -4.0 * s3 + 7.0 * s3 * s - 3.0 * s3 * s2
    h5 = 10.0 * s3 - 15.0 * s3 * s + 6.0 * s3 * s2
    return h0 * p0 + h1 * v0 + h4 * v1 + h5 * p1


__all__ = [
    "Pose", "QUAT_NORM_TOL", "StartRegion", "format_pose", "make_continuous", "mean_quat", "minimum_jerk",
    "nominal_start", "quintic_hermite", "resample_trajectory", "sample_start_poses", "validate_pose",
    # numerics.quaternion's, re-exported for the envs modules that import them with the poses
    "quat_angle_rad", "quat_conj", "quat_from_rotvec", "quat_from_rotvec_one", "quat_mul", "quat_mul_one",
    "quat_to_rotvec", "quat_to_rotvec_one", "rotate", "slerp",
]
