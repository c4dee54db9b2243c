"""Commanding a pose trajectory to an episode (envs.sim.env.PegInHoleEnv), one pose per control period: a trajectory
sampled at the control period (`track_trajectory`) or at any rate (`replay_trajectory`: a demo or a generated skill,
resampled)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.poses import resample_trajectory
from envs.sim.observation import StepResult

if TYPE_CHECKING:
    from envs.sim.env import PegInHoleEnv


def track_trajectory(env: PegInHoleEnv, pos: npt.ArrayLike, quat: npt.ArrayLike,
                     on_step: Callable[[StepResult], None] | None = None,
                     stiffness: npt.ArrayLike | None = None) -> StepResult | None:
    """Command a tcp pose trajectory sampled at the control period, one pose per step, until it ends or the
    episode ends (a reset episode is required).

    Args:
        env: an environment after ``reset``.
        pos: (K, 3) commanded peg_tip positions, one per control step.
        quat: (K, 4) commanded orientations (w, x, y, z).
        on_step: called with every StepResult (e.g. to record or render).
        stiffness: optional 6x6 stiffness for every step.

    Returns:
        the last StepResult (None for an empty trajectory).

    Raises:
        EnvError: mismatched shapes or a malformed pose.
    """
    p = np.asarray(pos, dtype=float)
    q = np.asarray(quat, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or q.shape != (p.shape[0], 4):
        raise EnvError(f"trajectory must be pos (K, 3) and quat (K, 4), got {p.shape} and {q.shape}")
    result = None
    for k in range(p.shape[0]):
        result = env.step((p[k], q[k]), stiffness)
        if on_step is not None:
            on_step(result)
        if result.done:
            break
    return result


def replay_trajectory(env: PegInHoleEnv, pos: npt.ArrayLike, quat: npt.ArrayLike, dt: float,
                      on_step: Callable[[StepResult], None] | None = None, hold_s: float = 0.0,
                      stiffness: npt.ArrayLike | None = None) -> StepResult | None:
    """Execute a pose trajectory sampled every ``dt`` seconds (e.g. a demo or a generated skill).

    The trajectory is resampled to the control period (positions linearly, quaternions by slerp; the
    command at step k is the pose at time k * control_period) and commanded from the current state,
    then its last pose is held for ``hold_s``. Call ``env.reset`` first (e.g. at the first pose).

    Returns:
        the last StepResult (None when no step was taken).

    Raises:
        EnvError: malformed trajectory or dt.
    """
    p = np.asarray(pos, dtype=float)
    q = np.asarray(quat, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or q.shape != (p.shape[0], 4) or p.shape[0] < 2:
        raise EnvError(f"trajectory must be pos (K>=2, 3) and quat (K, 4), got {p.shape} and {q.shape}")
    if not (np.isfinite(dt) and dt > 0.0):
        raise EnvError(f"trajectory dt={dt!r} must be a positive number of seconds")
    duration = dt * (p.shape[0] - 1)
    period = env.control_period_s
    steps = int(np.ceil(duration / period - 1e-9)) + int(round(max(hold_s, 0.0) / period))
    times = np.minimum(period * np.arange(1, steps + 1), duration)
    cmd_pos, cmd_quat = resample_trajectory(dt * np.arange(p.shape[0]), p, q, times)
    return track_trajectory(env, cmd_pos, cmd_quat, on_step=on_step, stiffness=stiffness)
