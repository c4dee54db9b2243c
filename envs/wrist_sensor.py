"""The wrist force/torque sensor as a real cell reads it: noise, a bias per episode and a low-pass filter.

The simulator gives the exact wrench the environment exerts on the tool, zeroed for the tool load (envs.sensing).
A real sensor adds, per reading (1 kHz, every physics step k) and per axis j,

    m_k = w_k + b + n_k,      n_k ~ N(0, sigma_j^2),   b ~ N(0, beta_j^2) drawn once per episode,
    y_k = y_{k-1} + alpha (m_k - y_{k-1}),   alpha = 1 - exp(-2 pi f_c h)      (first-order low-pass, cutoff f_c),

with y_0 = 0 (the episode starts from a sensor zeroed at rest). With ``sensor_mode = "wrist"`` the policy's observation and
the force limit use y; every figure of the record (peaks, medians, the trace) keeps the true w. ``sensor_mode = "ideal"``
(the default) is the exact wrench, as before. The noise comes from a generator seeded by the episode's perturbation
(`episode_generator`), so an episode's readings are the same wherever it runs and paired runs share them.

Magnitudes are settings of the task (the realistic preset's are in envs.execution.sensitivity), not a calibration of
one device: no datasheet or paper was checked for them.
"""

from __future__ import annotations

import math
from dataclasses import astuple, dataclass

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError

FloatArray = npt.NDArray[np.float64]

SENSOR_MODES: tuple[str, ...] = ("ideal", "wrist")

SENSOR_ON, SENSOR_ALPHA, SENSOR_BIAS = 0, 1, 2
"""Slots of the kernel's sensor array: 1.0 when the sensor model is on, alpha, then the episode's bias b (6)."""
SENSOR_SIZE = 8


@dataclass(frozen=True)
class WristSensorConfig:
    """The wrist sensor's model (module docstring).

    Attributes:
        sensor_mode: "ideal" (the exact wrench) or "wrist" (noise, bias, low-pass).
        force_noise_n, torque_noise_nm: sigma of the white noise per reading and axis.
        force_bias_n, torque_bias_nm: beta, the standard deviation of the per-episode bias per axis.
        sensor_cutoff_hz: the low-pass filter's cutoff f_c (0: no filter).

    Raises:
        EnvError: an unknown mode, a negative, infinite or NaN magnitude or cutoff (one line naming it).
    """

    sensor_mode: str = "ideal"
    force_noise_n: float = 0.0
    torque_noise_nm: float = 0.0
    force_bias_n: float = 0.0
    torque_bias_nm: float = 0.0
    sensor_cutoff_hz: float = 0.0

    def __post_init__(self) -> None:
        if self.sensor_mode not in SENSOR_MODES:
            raise EnvError(f"sensor_mode={self.sensor_mode!r} must be one of {', '.join(SENSOR_MODES)}")
        for name in ("force_noise_n", "torque_noise_nm", "force_bias_n", "torque_bias_nm", "sensor_cutoff_hz"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0.0):
                raise EnvError(f"sensing {name}={value!r} must be a finite number >= 0")

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


def episode_generator(perturbation: object) -> np.random.Generator:
    """The sensor's generator of an episode: seeded by the bits of its perturbation's values (a dataclass of
    floats), so the same episode reads the same noise in any process."""
    values = np.array(astuple(perturbation), dtype=np.float64)  # type: ignore[arg-type]
    return np.random.default_rng(np.frombuffer(values.tobytes(), dtype=np.uint64))
