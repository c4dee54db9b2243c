"""Per-episode task perturbations: a hole-pose error (a perception error) and a grasp offset.

Hole-pose error. The real hole frame H' is the nominal hole frame H moved in its own frame,
    T_H' = T_H T_err,   T_err = (t = [dx, dy, 0], R_err = R_axis(a_t, tilt) Rz(yaw)),
with (dx, dy) uniform in the disk of radius R (r = R sqrt(u), polar angle uniform), yaw uniform in [-A, A]
about the hole axis, and tilt uniform in [0, A] about a horizontal axis a_t = (cos phi, sin phi, 0) of H with
phi uniform. The whole sorter moves rigidly with the target hole (T_S' = T_H T_err T_H^-1 T_S) while the skill
keeps the demonstrated goal, so the peg meets the hole off by up to R and A.

Grasp offset. The peg sits in the fingers shifted along its own axis by g uniform in [-G, G] (positive: the
peg_tip sticks out farther from the hand); the skill still commands the nominal grasp.

Friction (envs.friction). The sliding friction coefficient of the peg against the sorter, mu_hole, and against the
finger pads, mu_pad, each uniform in its [min, max] (0: the scene's, 0.5 and 1.0). Their draws come from a generator
seeded by the episode's six draws above, so a task with friction ranges keeps the hole errors, grasp offsets and
starts of the same task without them, episode for episode (paired comparisons of one imperfection).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError

FloatArray = npt.NDArray[np.float64]

MAX_HOLE_ERROR_M: float = 0.01
MAX_HOLE_ERROR_DEG: float = 10.0
MAX_GRASP_OFFSET_M: float = 0.01
MAX_FRICTION: float = 2.0


def _check_range(name: str, value: float, maximum: float) -> float:
    if not (isinstance(value, (int, float)) and np.isfinite(value) and 0.0 <= value <= maximum):
        raise EnvError(f"{name}={value!r} must be a number in [0, {maximum:g}]")
    return float(value)


@dataclass(frozen=True)
class PerturbationRanges:
    """Ranges of the per-episode perturbations (all zero: the nominal task).

    Attributes:
        hole_error_m: radius R of the horizontal hole offset, in [0, 10 mm].
        hole_error_deg: bound A of the yaw about the hole axis and of the tilt, in [0, 10 deg].
        grasp_offset_m: bound G of the peg's shift along its axis in the grasp, in [0, 10 mm].
        hole_friction_min, hole_friction_max: range of the peg-sorter sliding friction per episode (both 0: the
            scene's); 0 < min <= max <= 2.
        pad_friction_min, pad_friction_max: the same for the peg against the finger pads.

    Raises:
        EnvError: a negative, NaN or too large range, or a friction range that is not 0 < min <= max (one line
            naming it).
    """

    hole_error_m: float = 0.0
    hole_error_deg: float = 0.0
    grasp_offset_m: float = 0.0
    hole_friction_min: float = 0.0
    hole_friction_max: float = 0.0
    pad_friction_min: float = 0.0
    pad_friction_max: float = 0.0

    def __post_init__(self) -> None:
        _check_range("hole_error_m", self.hole_error_m, MAX_HOLE_ERROR_M)
        _check_range("hole_error_deg", self.hole_error_deg, MAX_HOLE_ERROR_DEG)
        _check_range("grasp_offset_m", self.grasp_offset_m, MAX_GRASP_OFFSET_M)
        for name in ("hole_friction", "pad_friction"):
            low = _check_range(f"{name}_min", getattr(self, f"{name}_min"), MAX_FRICTION)
            high = _check_range(f"{name}_max", getattr(self, f"{name}_max"), MAX_FRICTION)
            if (low, high) != (0.0, 0.0) and not 0.0 < low <= high:
                raise EnvError(f"{name}_min={low:g}, {name}_max={high:g}: a friction range needs 0 < min <= max "
                               f"(both 0: the scene's friction)")

    @property
    def randomises_friction(self) -> bool:
        """A friction range is set."""
        return self.hole_friction_max > 0.0 or self.pad_friction_max > 0.0


@dataclass(frozen=True)
class Perturbation:
    """One draw of the perturbations (see the module docstring).

    Attributes:
        hole_dx_m, hole_dy_m: horizontal offset of the hole in its own frame.
        hole_yaw_deg: rotation about the hole axis.
        hole_tilt_deg: tilt of the hole axis.
        hole_tilt_dir_deg: direction phi of the tilt axis in the hole's x-y plane.
        grasp_offset_m: shift of the peg along its axis in the grasp.
        hole_friction, pad_friction: sliding friction of the peg against the sorter and the finger pads (0: the
            scene's).
    """

    hole_dx_m: float = 0.0
    hole_dy_m: float = 0.0
    hole_yaw_deg: float = 0.0
    hole_tilt_deg: float = 0.0
    hole_tilt_dir_deg: float = 0.0
    grasp_offset_m: float = 0.0
    hole_friction: float = 0.0
    pad_friction: float = 0.0

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not np.isfinite(value):
                raise EnvError(f"Perturbation.{name}={value!r} must be finite")
        if min(self.hole_friction, self.pad_friction) < 0.0:
            raise EnvError(f"Perturbation frictions ({self.hole_friction}, {self.pad_friction}) must be >= 0")

    @property
    def hole_offset_m(self) -> float:
        """|(dx, dy)|."""
        return float(np.hypot(self.hole_dx_m, self.hole_dy_m))

    def hole_transform(self) -> tuple[FloatArray, FloatArray]:
        """(t (3,), R_err (3, 3)) of T_err in the hole frame."""
        from rflow.small_linalg import matmul  # here: the task configs import this module, --help must not load numba
        phi, tilt, yaw = np.deg2rad([self.hole_tilt_dir_deg, self.hole_tilt_deg, self.hole_yaw_deg])
        axis = np.array([np.cos(phi), np.sin(phi), 0.0])
        k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
        r_tilt = np.eye(3) + np.sin(tilt) * k + (1.0 - np.cos(tilt)) * matmul(k, k)  # Rodrigues
        r_yaw = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
        return np.array([self.hole_dx_m, self.hole_dy_m, 0.0]), matmul(r_tilt, r_yaw)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields plus the horizontal offset magnitude, in mm and deg; the frictions only where set."""
        frictions = {k: v for k, v in (("hole_friction", self.hole_friction), ("pad_friction", self.pad_friction))
                     if v != 0.0}
        return {
            "hole_dx_mm": self.hole_dx_m * 1e3,
            "hole_dy_mm": self.hole_dy_m * 1e3,
            "hole_offset_mm": self.hole_offset_m * 1e3,
            "hole_yaw_deg": self.hole_yaw_deg,
            "hole_tilt_deg": self.hole_tilt_deg,
            "hole_tilt_dir_deg": self.hole_tilt_dir_deg,
            "grasp_offset_mm": self.grasp_offset_m * 1e3,
            **frictions,
        }


def sample_perturbation(ranges: PerturbationRanges, rng: np.random.Generator) -> Perturbation:
    """One seeded draw within ``ranges`` (distributions in the module docstring).

    Always consumes the same number of draws from ``rng`` (6), whatever the ranges; the frictions come from a
    generator seeded by those six.
    """
    u = rng.random(6)
    hole_friction = pad_friction = 0.0
    if ranges.randomises_friction:
        v = np.random.default_rng(np.frombuffer(u.tobytes(), dtype=np.uint64)).random(2)
        hole_friction = ranges.hole_friction_min + (ranges.hole_friction_max - ranges.hole_friction_min) * v[0]
        pad_friction = ranges.pad_friction_min + (ranges.pad_friction_max - ranges.pad_friction_min) * v[1]
    radius = ranges.hole_error_m * np.sqrt(u[0])
    angle = 2.0 * np.pi * u[1]
    return Perturbation(
        hole_dx_m=float(radius * np.cos(angle)),
        hole_dy_m=float(radius * np.sin(angle)),
        hole_yaw_deg=float(ranges.hole_error_deg * (2.0 * u[2] - 1.0)),
        hole_tilt_deg=float(ranges.hole_error_deg * u[3]),
        hole_tilt_dir_deg=float(360.0 * u[4]),
        grasp_offset_m=float(ranges.grasp_offset_m * (2.0 * u[5] - 1.0)),
        hole_friction=float(hole_friction),
        pad_friction=float(pad_friction),
    )


def perturbed_frame(frame_pos: npt.ArrayLike, frame_quat: npt.ArrayLike, hole_pos: npt.ArrayLike,
                    hole_quat: npt.ArrayLike, perturbation: Perturbation) -> tuple[FloatArray, FloatArray]:
    """Pose of a frame F rigidly attached to the hole after the hole error: T_F' = T_H T_err T_H^-1 T_F.

    Returns:
        (position (3,), quaternion w, x, y, z (4,)).
    """
    from rflow.quaternion import mat_to_quat, quat_to_mat
    from rflow.small_linalg import matmul, matvec

    r_h = quat_to_mat(hole_quat)
    p_h = np.asarray(hole_pos, dtype=np.float64)
    t_err, r_err = perturbation.hole_transform()
    r_f = quat_to_mat(frame_quat)
    p_f = np.asarray(frame_pos, dtype=np.float64)
    rot = matmul(matmul(r_h, r_err), r_h.T)
    pos = p_h + matvec(r_h, t_err) + matvec(rot, p_f - p_h)
    return pos, mat_to_quat(matmul(rot, r_f))
