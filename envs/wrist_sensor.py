"""The wrench a real cell senses: a wrist force/torque sensor (noise, a bias per episode, a low-pass filter) or, as on
a stock Panda, which has no wrist sensor, an estimate from its joint torque sensors.

The simulator gives the exact wrench the environment exerts on the tool, zeroed for the tool load (envs.sensing).
A real sensor adds, per reading (1 kHz, every physics step k) and per axis j,

    m_k = w_k + b + n_k,      n_k ~ N(0, sigma_j^2),   b ~ N(0, beta_j^2) drawn once per episode,
    y_k = y_{k-1} + alpha (m_k - y_{k-1}),   alpha = 1 - exp(-2 pi f_c h)      (first-order low-pass, cutoff f_c),

with y_0 = 0 (the episode starts from a sensor zeroed at rest). With ``sensor_mode = "wrist"`` the policy's observation and
the force limit use y; every figure of the record (peaks, medians, the trace) keeps the true w. ``sensor_mode = "ideal"``
(the default) is the exact wrench, as before. The noise comes from a generator seeded by the episode's perturbation
(`episode_generator`), so an episode's readings are the same wherever it runs and paired runs share them.

``sensor_mode = "joint_torque"``: the external wrench estimated from the arm's link-side joint torque sensors through
the Jacobian (envs.sensing_kernel.joint_torque_reading), as the Panda does. Per reading and joint i the sensors add
noise and a bias per episode to the torque the contacts exert on the joint, tau_c,

    tau_m = tau_c + b_tau + n_k,   n_k ~ N(0, sigma_tau^2 I),   b_tau ~ N(0, beta_tau^2 I) once per episode,
    W_hat = (J J^T)^-1 J tau_m                                  (J: the F/T site's 6 x n arm Jacobian),

then zeroed for the nominal peg's weight and low-passed like the wrist sensor's y. The joints' own friction is on
the motor side of the sensors and does not show (the Panda's sensors sit after the gears); the payload error does,
as on a real arm whose load is set wrong. The wrench error is posture-dependent, (J J^T)^-1 J maps the joint error.

Magnitudes are settings of the task (the realistic preset's are in envs.execution.sensitivity), not a calibration of
one device: no datasheet or paper was checked for them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError

FloatArray = npt.NDArray[np.float64]

SENSOR_MODES: tuple[str, ...] = ("ideal", "wrist", "joint_torque")

SENSOR_ON, SENSOR_ALPHA, SENSOR_BIAS, SENSOR_JOINT_BIAS = 0, 1, 2, 8
"""Slots of the kernel's sensor array: the mode (0 ideal, SENSOR_WRIST, SENSOR_JOINT_TORQUE), alpha, the wrist
sensor's bias b (6), then the joint torque sensors' bias b_tau (MAX_ARM_JOINTS)."""
SENSOR_WRIST, SENSOR_JOINT_TORQUE = 1.0, 2.0
MAX_ARM_JOINTS = 7
SENSOR_SIZE = SENSOR_JOINT_BIAS + MAX_ARM_JOINTS


@dataclass(frozen=True)
class WristSensorConfig:
    """The wrist sensor's model (module docstring).

    Attributes:
        sensor_mode: "ideal" (the exact wrench), "wrist" (noise, bias, low-pass) or "joint_torque" (estimated
            from the joint torques, module docstring).
        force_noise_n, torque_noise_nm: sigma of the wrist sensor's white noise per reading and axis.
        force_bias_n, torque_bias_nm: beta, the standard deviation of the wrist sensor's per-episode bias per axis.
        sensor_cutoff_hz: the low-pass filter's cutoff f_c (0: no filter), either mode.
        joint_torque_noise_nm: sigma_tau of each joint torque sensor's white noise per reading (N m).
        joint_torque_bias_nm: beta_tau, the standard deviation of each joint torque sensor's per-episode bias (N m).

    Raises:
        EnvError: an unknown mode, a negative, infinite or NaN magnitude or cutoff, a magnitude set for the other
            sensor mode (one line naming it).
    """

    sensor_mode: str = "ideal"
    force_noise_n: float = 0.0
    torque_noise_nm: float = 0.0
    force_bias_n: float = 0.0
    torque_bias_nm: float = 0.0
    sensor_cutoff_hz: float = 0.0
    joint_torque_noise_nm: float = 0.0
    joint_torque_bias_nm: float = 0.0

    def __post_init__(self) -> None:
        if self.sensor_mode not in SENSOR_MODES:
            raise EnvError(f"sensor_mode={self.sensor_mode!r} must be one of {', '.join(SENSOR_MODES)}")
        for name in ("force_noise_n", "torque_noise_nm", "force_bias_n", "torque_bias_nm", "sensor_cutoff_hz",
                     "joint_torque_noise_nm", "joint_torque_bias_nm"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0.0):
                raise EnvError(f"sensing {name}={value!r} must be a finite number >= 0")
        for mode, names in (("wrist", ("force_noise_n", "torque_noise_nm", "force_bias_n", "torque_bias_nm")),
                            ("joint_torque", ("joint_torque_noise_nm", "joint_torque_bias_nm"))):
            for name in names:
                if getattr(self, name) > 0.0 and self.sensor_mode != mode:
                    raise EnvError(f"sensing {name}={getattr(self, name)!r} is a magnitude of sensor_mode "
                                   f"{mode!r}, not of {self.sensor_mode!r}")

    def alpha(self, timestep_s: float) -> float:
        """The filter's gain per reading, 1 - exp(-2 pi f_c h) (1: no filter)."""
        cutoff = self.sensor_cutoff_hz
        return 1.0 if cutoff == 0.0 else 1.0 - math.exp(-2.0 * math.pi * cutoff * timestep_s)

    @property
    def noise_sigma(self) -> FloatArray:
        """(6,) sigma per axis [force x3, torque x3]."""
        return np.array([self.force_noise_n] * 3 + [self.torque_noise_nm] * 3)

    @property
    def bias_sigma(self) -> FloatArray:
        """(6,) beta per axis."""
        return np.array([self.force_bias_n] * 3 + [self.torque_bias_nm] * 3)

    @property
    def mode_code(self) -> float:
        """The kernel's SENSOR_ON slot: 0 ideal, SENSOR_WRIST or SENSOR_JOINT_TORQUE."""
        return {"ideal": 0.0, "wrist": SENSOR_WRIST, "joint_torque": SENSOR_JOINT_TORQUE}[self.sensor_mode]


def episode_generator(perturbation: Any, salt: int | None = None) -> np.random.Generator:
    """The sensor's generator of an episode: seeded by the bits of its perturbation's seed values
    (`envs.perturbation.Perturbation.seed_values`), so the same episode reads the same noise in any process; with
    ``salt`` appended to the seed words, another stream of the same episode (envs.model_error.ActuatorNoise)."""
    values = np.array(perturbation.seed_values(), dtype=np.float64)
    words = np.frombuffer(values.tobytes(), dtype=np.uint64)
    return np.random.default_rng(words if salt is None else [*words.tolist(), salt])
