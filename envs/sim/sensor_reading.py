"""The wrench a real cell senses: a wrist force/torque sensor (noise, a bias per episode, a low-pass filter) or, as on
a stock Panda, which has no wrist sensor, an estimate from its joint torque sensors.

The simulator gives the exact wrench the environment exerts on the tool, zeroed for the tool load (envs.sim.sensing).
A real sensor adds, per reading (1 kHz, every physics step k) and per axis j,

    m_k = w_k + b + n_k,      n_k ~ N(0, sigma_j^2),   b ~ N(0, beta_j^2) drawn once per episode,
    y_k = y_{k-1} + alpha (m_k - y_{k-1}),   alpha = 1 - exp(-2 pi f_c h)      (first-order low-pass, cutoff f_c),

with y_0 = 0 (the episode starts from a sensor zeroed at rest). With ``sensor_mode = "wrist"`` the policy's observation
and the force limit use y; every figure of the record (peaks, medians, the trace) keeps the true w. ``sensor_mode =
"ideal"`` (the default) is the exact wrench. The noise comes from a generator seeded by the episode's
perturbation (`episode_generator`), so an episode's readings are the same wherever it runs and paired runs share them.

``sensor_mode = "joint_torque"``: the external wrench estimated from the arm's link-side joint torque sensors through
the Jacobian (envs.sim.sensing_kernel.joint_torque_reading), as the Panda does. Per reading and joint i the sensors add
noise and a bias per episode to the torque the contacts exert on the joint, tau_c,

    tau_m = tau_c + b_tau + n_k,   n_k ~ N(0, sigma_tau^2 I),   b_tau ~ N(0, beta_tau^2 I) once per episode,
    W_hat = (J J^T)^-1 J tau_m                                  (J: the F/T site's 6 x n arm Jacobian),

then zeroed for the nominal peg's weight and low-passed like the wrist sensor's y. The joints' own friction is on
the motor side of the sensors and does not show (the Panda's sensors sit after the gears); the payload error does,
as on a real arm whose load is set wrong. The wrench error is posture-dependent, (J J^T)^-1 J maps the joint error.

The settings are the task's (envs.task.sensor_config.WristSensorConfig; the realistic preset's magnitudes are in
envs.evaluation.sensitivity), not a calibration of one device: no datasheet or paper was checked for them. The
reading itself is compiled per physics step in envs.sim.sensing_kernel.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def episode_generator(perturbation: Any, salt: int | None = None) -> np.random.Generator:
    """The sensor's generator of an episode: seeded by the bits of its perturbation's seed values
    (`envs.task.perturbation.Perturbation.seed_values`), so the same episode reads the same noise in any process; with
    ``salt`` appended to the seed words, another stream of the same episode (envs.sim.model_error.ActuatorNoise)."""
    values = np.array(perturbation.seed_values(), dtype=np.float64)
    words = np.frombuffer(values.tobytes(), dtype=np.uint64)
    return np.random.default_rng(words if salt is None else [*words.tolist(), salt])
