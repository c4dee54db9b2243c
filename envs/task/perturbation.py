"""Per-episode task perturbations: a hole-pose error (a perception error) and a grasp offset.

Hole-pose error. The real hole frame H' is the nominal hole frame H moved in its own frame,
    T_H' = T_H T_err,   T_err = (t = [dx, dy, 0], R_err = R_axis(a_t, tilt) Rz(yaw)),
with (dx, dy) uniform in the disk of radius R (r = R sqrt(u), polar angle uniform), yaw uniform in [-A, A]
about the hole axis, and tilt uniform in [0, A] about a horizontal axis a_t = (cos phi, sin phi, 0) of H with
phi uniform. The whole sorter moves rigidly with the target hole (T_S' = T_H T_err T_H^-1 T_S) while the skill
keeps the demonstrated goal, so the peg meets the hole off by up to R and A.

Grasp offset. The peg sits in the fingers shifted along its own axis by g uniform in [-G, G] (positive: the
peg_tip sticks out farther from the hand); the skill still commands the nominal grasp.

The cell's imperfections, each off at 0:

- friction (envs.sim.friction): the sliding friction of the peg against the sorter, mu_hole, and against the finger
  pads, mu_pad, each uniform in its [min, max] (0: the scene's, 0.5 and 1.0);
- in-hand pose: the peg sits in the fingers shifted by l uniform in [-L, L] along the hand's x axis (in the pads'
  plane), tilted by t uniform in [-T, T] about the fingers' closing axis (the hand's y; about the peg's top) and
  turned by y uniform in [-Y, Y] about its own axis;
- payload: the simulated peg's mass is m (1 + e), e uniform in [-E, E], while the controller's tool load and the
  wrist sensor's zeroing keep the nominal m (a payload the cell's model gets wrong);
- payload centre of mass: the simulated peg's centre of mass is moved across its axis by (cx, cy) uniform in the
  disk of radius C (in the peg's frame), while the controller and the sensor's zeroing keep it on the axis;
- joint friction: each arm joint's transmission friction, the Panda's identified friction (envs.sim.joint_friction:
  Gaz et al., RA-L 2019) scaled by s uniform in [min, max] per episode, as stick-slip (MuJoCo's frictionloss, the
  identified Coulomb friction, plus the identified viscous friction on top of the model's joint damping) or as the
  identified smooth law (no stiction); which of the two is ``joint_friction_model``; the controller knows neither
  the law nor s;
- torque noise: each arm joint delivers its commanded torque plus white noise of sigma N m per physics step
  (drawn per control period from the episode's own generator, envs.sim.model_error.ActuatorNoise), which the
  controller does not know;
- hole observation: where the cell believes the hole is (the policy's ``nominal_hole`` and ``nominal_goal``) is a
  hole moved by its own error, (dx, dy) uniform in the disk of radius R_o, a yaw uniform in [-A_o, A_o] about its
  axis and a tilt uniform in [0, T_o] about a horizontal axis of uniform direction (as the hole-pose error above).
  The hole so moved is the nominal one (``hole_observation = "nominal"``: the cell does not see the part, and
  the error is that of its calibration, independent of the true hole-pose error) or the true, perturbed one
  (``"measured"``: a sensor, e.g. a camera, measures the part's hole, and the error is the sensor's).

Their draws come from a generator seeded by the episode's six draws above, so a task with imperfections keeps the
hole errors, grasp offsets and starts of the same task without them, episode for episode (paired comparisons of one
imperfection).
"""

from __future__ import annotations

from dataclasses import asdict, astuple, dataclass, fields
from typing import Any

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError

FloatArray = npt.NDArray[np.float64]

MAX_HOLE_ERROR_M: float = 0.01
MAX_HOLE_ERROR_DEG: float = 10.0
MAX_GRASP_OFFSET_M: float = 0.01
MAX_FRICTION: float = 2.0
MAX_GRASP_LATERAL_M: float = 0.005
MAX_GRASP_ANGLE_DEG: float = 5.0
MAX_PAYLOAD_ERROR: float = 0.5
MAX_JOINT_FRICTION_SCALE: float = 5.0
MAX_COM_ERROR_M: float = 0.01
MAX_ACTUATOR_NOISE_NM: float = 5.0
MAX_OBSERVATION_ERROR_M: float = 0.01
MAX_OBSERVATION_ERROR_DEG: float = 10.0
IMPERFECTION_DRAWS: int = 15
"""Uniform draws of the imperfections' generator per episode (their order: mu_hole, mu_pad, l, t, y, e, f, then the
observation's radius, polar angle and yaw, then the centre of mass's radius and polar angle and one unused draw, then
the observation's tilt and its direction; a new imperfection takes draws after these, so the ones before keep theirs
and episodes pair across task versions; f is the joint friction's scale s)."""
JOINT_FRICTION_MODELS: tuple[str, ...] = ("stick_slip", "smooth")
"""How the joints' friction depends on their speed (envs.sim.joint_friction): stick-slip (Coulomb with stiction plus
viscous) or the identified smooth law."""
HOLE_OBSERVATIONS: tuple[str, ...] = ("nominal", "measured")
"""What the observed hole is the error of (module docstring): the nominal hole, or the true one measured."""


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
        grasp_lateral_m: bound L of the peg's shift in the pads' plane, in [0, 5 mm].
        grasp_tilt_deg, grasp_yaw_deg: bounds T, Y of its tilt about the closing axis and turn about its own axis,
            in [0, 5 deg].
        payload_mass_error: bound E of the simulated peg's relative mass error, in [0, 0.5].
        joint_friction_scale_min, joint_friction_scale_max: range of the scale s of the arm joints' identified
            friction per episode (both 0: none; 1: the Panda's as identified); 0 < min <= max <= 5.
        joint_friction_model: "stick_slip" or "smooth" (`JOINT_FRICTION_MODELS`, envs.sim.joint_friction).
        hole_observation_error_m, hole_observation_error_deg: R_o and A_o of the observed hole's error, in
            [0, 10 mm] and [0, 10 deg].
        hole_observation: "nominal" (the observed hole is the nominal one with that error) or "measured" (the true,
            perturbed hole with that error: a sensor that sees the part).
        hole_observation_tilt_deg: T_o, the bound of the observed hole's tilt error, in [0, 10 deg].
        payload_com_error_m: bound C of the simulated peg's centre-of-mass shift across its axis, in [0, 10 mm].
        actuator_noise_nm: sigma of the white noise on each arm joint's delivered torque per physics step, in
            [0, 5] N m (not drawn: every episode has it).

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
    grasp_lateral_m: float = 0.0
    grasp_tilt_deg: float = 0.0
    grasp_yaw_deg: float = 0.0
    payload_mass_error: float = 0.0
    joint_friction_scale_min: float = 0.0
    joint_friction_scale_max: float = 0.0
    hole_observation_error_m: float = 0.0
    hole_observation_error_deg: float = 0.0
    payload_com_error_m: float = 0.0
    actuator_noise_nm: float = 0.0
    hole_observation: str = "nominal"
    hole_observation_tilt_deg: float = 0.0
    joint_friction_model: str = "stick_slip"

    def __post_init__(self) -> None:
        if self.hole_observation not in HOLE_OBSERVATIONS:
            raise EnvError(f"hole_observation={self.hole_observation!r} must be one of {', '.join(HOLE_OBSERVATIONS)}")
        if self.joint_friction_model not in JOINT_FRICTION_MODELS:
            raise EnvError(f"joint_friction_model={self.joint_friction_model!r} must be one of "
                           f"{', '.join(JOINT_FRICTION_MODELS)}")
        _check_range("hole_error_m", self.hole_error_m, MAX_HOLE_ERROR_M)
        _check_range("hole_error_deg", self.hole_error_deg, MAX_HOLE_ERROR_DEG)
        _check_range("grasp_offset_m", self.grasp_offset_m, MAX_GRASP_OFFSET_M)
        _check_range("grasp_lateral_m", self.grasp_lateral_m, MAX_GRASP_LATERAL_M)
        _check_range("grasp_tilt_deg", self.grasp_tilt_deg, MAX_GRASP_ANGLE_DEG)
        _check_range("grasp_yaw_deg", self.grasp_yaw_deg, MAX_GRASP_ANGLE_DEG)
        _check_range("payload_mass_error", self.payload_mass_error, MAX_PAYLOAD_ERROR)
        _check_range("payload_com_error_m", self.payload_com_error_m, MAX_COM_ERROR_M)
        _check_range("actuator_noise_nm", self.actuator_noise_nm, MAX_ACTUATOR_NOISE_NM)
        _check_range("hole_observation_error_m", self.hole_observation_error_m, MAX_OBSERVATION_ERROR_M)
        _check_range("hole_observation_error_deg", self.hole_observation_error_deg, MAX_OBSERVATION_ERROR_DEG)
        _check_range("hole_observation_tilt_deg", self.hole_observation_tilt_deg, MAX_OBSERVATION_ERROR_DEG)
        for low_name, high_name, top in (("hole_friction_min", "hole_friction_max", MAX_FRICTION),
                                         ("pad_friction_min", "pad_friction_max", MAX_FRICTION),
                                         ("joint_friction_scale_min", "joint_friction_scale_max",
                                          MAX_JOINT_FRICTION_SCALE)):
            low = _check_range(low_name, getattr(self, low_name), top)
            high = _check_range(high_name, getattr(self, high_name), top)
            if (low, high) != (0.0, 0.0) and not 0.0 < low <= high:
                raise EnvError(f"{low_name}={low:g}, {high_name}={high:g}: a friction range needs 0 < min <= max "
                               f"(both 0: off)")

    @property
    def imperfect(self) -> bool:
        """Some imperfection of the cell is set (its draws are made)."""
        return any(getattr(self, name) > 0.0 for name in (
            "hole_friction_max", "pad_friction_max", "grasp_lateral_m", "grasp_tilt_deg", "grasp_yaw_deg",
            "payload_mass_error", "joint_friction_scale_max", "hole_observation_error_m", "hole_observation_error_deg",
            "payload_com_error_m", "actuator_noise_nm", "hole_observation_tilt_deg"))


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
        grasp_lateral_m, grasp_tilt_deg, grasp_yaw_deg: the peg's in-hand pose error (module docstring).
        payload_mass_error: relative error e of the simulated peg's mass.
        joint_friction_scale: the scale s of the arm joints' identified friction (0: none).
        observed_hole_dx_m, observed_hole_dy_m, observed_hole_yaw_deg, observed_hole_tilt_deg,
            observed_hole_tilt_dir_deg: the observed hole's error in the frame of the hole it is the error of
            (`PerturbationRanges.hole_observation`), as the hole-pose error's fields.
        payload_com_x_m, payload_com_y_m: the simulated peg's centre-of-mass shift in its own frame (m).
        actuator_noise_nm: sigma of the noise on each arm joint's delivered torque (N m).
    """

    hole_dx_m: float = 0.0
    hole_dy_m: float = 0.0
    hole_yaw_deg: float = 0.0
    hole_tilt_deg: float = 0.0
    hole_tilt_dir_deg: float = 0.0
    grasp_offset_m: float = 0.0
    hole_friction: float = 0.0
    pad_friction: float = 0.0
    grasp_lateral_m: float = 0.0
    grasp_tilt_deg: float = 0.0
    grasp_yaw_deg: float = 0.0
    payload_mass_error: float = 0.0
    joint_friction_scale: float = 0.0
    observed_hole_dx_m: float = 0.0
    observed_hole_dy_m: float = 0.0
    observed_hole_yaw_deg: float = 0.0
    payload_com_x_m: float = 0.0
    payload_com_y_m: float = 0.0
    actuator_noise_nm: float = 0.0
    observed_hole_tilt_deg: float = 0.0
    observed_hole_tilt_dir_deg: float = 0.0

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not np.isfinite(value):
                raise EnvError(f"Perturbation.{name}={value!r} must be finite")
        if min(self.hole_friction, self.pad_friction, self.joint_friction_scale, self.actuator_noise_nm) < 0.0:
            raise EnvError(f"Perturbation frictions ({self.hole_friction}, {self.pad_friction}, joint scale "
                           f"{self.joint_friction_scale}) and torque noise {self.actuator_noise_nm} N m must be >= 0")
        if self.payload_mass_error <= -1.0:
            raise EnvError(f"Perturbation.payload_mass_error={self.payload_mass_error} must be > -1 (a mass > 0)")

    def seed_values(self) -> tuple[float, ...]:
        """The values that seed the episode's own generators (envs.sim.sensor_reading.episode_generator): the fields up
        to ``actuator_noise_nm``, in order. They are drawn from the episode's draws and tell episodes apart; the fields
        added after them (the observation's tilt) are left out, so the sensors of an episode read the noise they
        read before those fields existed."""
        values = astuple(self)
        return values[:_SEED_FIELDS]

    def observation_error(self) -> Perturbation:
        """The observed hole's error as a hole-pose error (for `perturbed_frame` of the hole it is the error of)."""
        return Perturbation(hole_dx_m=self.observed_hole_dx_m, hole_dy_m=self.observed_hole_dy_m,
                            hole_yaw_deg=self.observed_hole_yaw_deg, hole_tilt_deg=self.observed_hole_tilt_deg,
                            hole_tilt_dir_deg=self.observed_hole_tilt_dir_deg)

    @property
    def hole_offset_m(self) -> float:
        """|(dx, dy)|."""
        return float(np.hypot(self.hole_dx_m, self.hole_dy_m))

    def hole_transform(self) -> tuple[FloatArray, FloatArray]:
        """(t (3,), R_err (3, 3)) of T_err in the hole frame."""
        # here: the task configs import this module, --help must not load numba
        from numerics.small_linalg import matmul
        phi, tilt, yaw = np.deg2rad([self.hole_tilt_dir_deg, self.hole_tilt_deg, self.hole_yaw_deg])
        axis = np.array([np.cos(phi), np.sin(phi), 0.0])
        k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
        r_tilt = np.eye(3) + np.sin(tilt) * k + (1.0 - np.cos(tilt)) * matmul(k, k)  # Rodrigues
        r_yaw = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
        return np.array([self.hole_dx_m, self.hole_dy_m, 0.0]), matmul(r_tilt, r_yaw)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields plus the horizontal offset magnitude, in mm and deg; the imperfections only where set."""
        imperfections = {k: v for k, v in (
            ("hole_friction", self.hole_friction), ("pad_friction", self.pad_friction),
            ("grasp_lateral_mm", self.grasp_lateral_m * 1e3), ("grasp_tilt_deg", self.grasp_tilt_deg),
            ("grasp_yaw_deg", self.grasp_yaw_deg), ("payload_mass_error", self.payload_mass_error),
            ("joint_friction_scale", self.joint_friction_scale), ("observed_hole_dx_mm", self.observed_hole_dx_m * 1e3),
            ("observed_hole_dy_mm", self.observed_hole_dy_m * 1e3),
            ("observed_hole_yaw_deg", self.observed_hole_yaw_deg),
            ("observed_hole_tilt_deg", self.observed_hole_tilt_deg),
            ("observed_hole_tilt_dir_deg", self.observed_hole_tilt_dir_deg),
            ("payload_com_x_mm", self.payload_com_x_m * 1e3), ("payload_com_y_mm", self.payload_com_y_m * 1e3),
            ("actuator_noise_nm", self.actuator_noise_nm))
            if v != 0.0}
        return {
            "hole_dx_mm": self.hole_dx_m * 1e3,
            "hole_dy_mm": self.hole_dy_m * 1e3,
            "hole_offset_mm": self.hole_offset_m * 1e3,
            "hole_yaw_deg": self.hole_yaw_deg,
            "hole_tilt_deg": self.hole_tilt_deg,
            "hole_tilt_dir_deg": self.hole_tilt_dir_deg,
            "grasp_offset_mm": self.grasp_offset_m * 1e3,
            **imperfections,
        }


_SEED_FIELDS: int = [f.name for f in fields(Perturbation)].index("actuator_noise_nm") + 1
"""How many of Perturbation's fields, from the first, seed an episode's generators (`Perturbation.seed_values`)."""


def sample_perturbation(ranges: PerturbationRanges, rng: np.random.Generator) -> Perturbation:
    """One seeded draw within ``ranges`` (distributions in the module docstring).

    Always consumes the same number of draws from ``rng`` (6), whatever the ranges; the imperfections come from a
    generator seeded by those six (IMPERFECTION_DRAWS of them, whichever are set).
    """
    u = rng.random(6)
    v = np.full(IMPERFECTION_DRAWS, 0.5)  # 0.5: the middle of a symmetric range, 0
    if ranges.imperfect:
        v = np.random.default_rng(np.frombuffer(u.tobytes(), dtype=np.uint64)).random(IMPERFECTION_DRAWS)

    observed_radius = ranges.hole_observation_error_m * np.sqrt(v[7])
    com_radius = ranges.payload_com_error_m * np.sqrt(v[10])

    def within(low: float, high: float, draw: float) -> float:
        return float(low + (high - low) * draw) if high > 0.0 else 0.0
    radius = ranges.hole_error_m * np.sqrt(u[0])
    angle = 2.0 * np.pi * u[1]
    return Perturbation(
        hole_dx_m=float(radius * np.cos(angle)),
        hole_dy_m=float(radius * np.sin(angle)),
        hole_yaw_deg=float(ranges.hole_error_deg * (2.0 * u[2] - 1.0)),
        hole_tilt_deg=float(ranges.hole_error_deg * u[3]),
        hole_tilt_dir_deg=float(360.0 * u[4]),
        grasp_offset_m=float(ranges.grasp_offset_m * (2.0 * u[5] - 1.0)),
        hole_friction=within(ranges.hole_friction_min, ranges.hole_friction_max, v[0]),
        pad_friction=within(ranges.pad_friction_min, ranges.pad_friction_max, v[1]),
        grasp_lateral_m=float(ranges.grasp_lateral_m * (2.0 * v[2] - 1.0)),
        grasp_tilt_deg=float(ranges.grasp_tilt_deg * (2.0 * v[3] - 1.0)),
        grasp_yaw_deg=float(ranges.grasp_yaw_deg * (2.0 * v[4] - 1.0)),
        payload_mass_error=float(ranges.payload_mass_error * (2.0 * v[5] - 1.0)),
        joint_friction_scale=within(ranges.joint_friction_scale_min, ranges.joint_friction_scale_max, v[6]),
        observed_hole_dx_m=float(observed_radius * np.cos(2.0 * np.pi * v[8])),
        observed_hole_dy_m=float(observed_radius * np.sin(2.0 * np.pi * v[8])),
        observed_hole_yaw_deg=float(ranges.hole_observation_error_deg * (2.0 * v[9] - 1.0)),
        payload_com_x_m=float(com_radius * np.cos(2.0 * np.pi * v[11])),
        payload_com_y_m=float(com_radius * np.sin(2.0 * np.pi * v[11])),
        actuator_noise_nm=float(ranges.actuator_noise_nm),
        observed_hole_tilt_deg=float(ranges.hole_observation_tilt_deg * v[13]),
        observed_hole_tilt_dir_deg=float(360.0 * v[14]) if ranges.hole_observation_tilt_deg > 0.0 else 0.0,
    )


def perturbed_frame(frame_pos: npt.ArrayLike, frame_quat: npt.ArrayLike, hole_pos: npt.ArrayLike,
                    hole_quat: npt.ArrayLike, perturbation: Perturbation) -> tuple[FloatArray, FloatArray]:
    """Pose of a frame F rigidly attached to the hole after the hole error: T_F' = T_H T_err T_H^-1 T_F.

    Returns:
        (position (3,), quaternion w, x, y, z (4,)).
    """
    from numerics.quaternion import mat_to_quat, quat_to_mat
    from numerics.small_linalg import matmul, matvec

    r_h = quat_to_mat(hole_quat)
    p_h = np.asarray(hole_pos, dtype=np.float64)
    t_err, r_err = perturbation.hole_transform()
    r_f = quat_to_mat(frame_quat)
    p_f = np.asarray(frame_pos, dtype=np.float64)
    rot = matmul(matmul(r_h, r_err), r_h.T)
    pos = p_h + matvec(r_h, t_err) + matvec(rot, p_f - p_h)
    return pos, mat_to_quat(matmul(rot, r_f))
