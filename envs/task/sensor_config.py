"""The wrench sensing a task sets: `WristSensorConfig` (a wrist force/torque sensor's noise, bias and low-pass, or the
stock Panda's estimate from its joint torque sensors), checked, and the slots of the sensing kernel's sensor array it
fills. The reading model these settings parameterise, and the per-episode generator that draws its noise, are the
simulator's: envs.sim.sensor_reading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from pihutil.bounds import JOINT_TORQUE_NM, SENSOR_CUTOFF_HZ, SENSOR_FORCE_N, SENSOR_TORQUE_NM

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
    """The wrist sensor's model (its equations: envs.sim.sensor_reading).

    Attributes:
        sensor_mode: "ideal" (the exact wrench), "wrist" (noise, bias, low-pass) or "joint_torque" (estimated
            from the joint torques, envs.sim.sensor_reading).
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
        for name, bound in (("force_noise_n", SENSOR_FORCE_N), ("torque_noise_nm", SENSOR_TORQUE_NM),
                            ("force_bias_n", SENSOR_FORCE_N), ("torque_bias_nm", SENSOR_TORQUE_NM),
                            ("sensor_cutoff_hz", SENSOR_CUTOFF_HZ), ("joint_torque_noise_nm", JOINT_TORQUE_NM),
                            ("joint_torque_bias_nm", JOINT_TORQUE_NM)):
            value = getattr(self, name)
            if not bound.contains(value):
                raise EnvError(f"sensing {name}={value!r} must be a number {bound.text()}")
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
