"""A `Policy` that replays a recorded tcp pose trajectory (a demonstration, or a dataset episode's poses) open loop.

At ``reset`` the recording (times t_i, poses x_i, optional translational stiffness K_i) is resampled to the control
period, one command per period: the command of period k is the recording at time (k + 1) T (positions linearly,
orientations by slerp, stiffness along Log-Euclidean geodesics). After the recording's end it holds its last pose at
rest. `pih render --demos` shows a demo replayed this way (without feed-forward).

A recording starts where it was recorded, not where the episode starts. With ``blend_s`` > 0 the difference at the
start, delta_p = p_start - p_0 and delta_r = rotvec(q_start conj(q_0)) (the MEASURED start), is added to the
recording and faded out with the minimum-jerk weight w(t) = 1 - s(t / blend_s):
    p(t) = p_rec(t) + w(t) delta_p,   q(t) = exp(w(t) delta_r) q_rec(t),
so the replay begins at the measured pose and joins the recorded path after ``blend_s``.

With ``feedforward`` the action carries the replayed path's twist and acceleration (central differences,
envs.policies.expert_plan.plan_twists), which the impedance controller turns into its lead, so the compliant arm
follows the path instead of lagging behind it (the demos are recorded with the same lead).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.policies.expert_plan import plan_twists
from envs.policies.interface import Action, Observation
from envs.poses import (Pose, make_continuous, minimum_jerk, quat_conj, quat_from_rotvec, quat_mul, quat_to_rotvec,
                        resample_trajectory, validate_pose)
from numerics.small_linalg import dot
from rflow.stiffness import log_euclidean_resample

FloatArray = npt.NDArray[np.float64]


class ReplayPolicy:
    """Replay one recorded trajectory (module docstring)."""

    def __init__(self, times_s: npt.ArrayLike, pos: npt.ArrayLike, quat: npt.ArrayLike,
                 stiffness: npt.ArrayLike | None = None, blend_s: float = 0.0, feedforward: bool = True):
        """Args:
            times_s: (K,) strictly increasing sample times, seconds (K >= 2).
            pos: (K, 3) tcp positions, m, world frame.
            quat: (K, 4) tcp orientations (w, x, y, z).
            stiffness: (K, 3, 3) translational stiffness to command with each sample (N/m), or None (the default).
            blend_s: fade the start offset out over this many seconds (0: replay as recorded).
            feedforward: send the path's twist and acceleration with each command.

        Raises:
            EnvError: mismatched shapes, non-increasing times, NaN, or a negative blend time.
        """
        t = np.asarray(times_s, dtype=np.float64)
        p = np.asarray(pos, dtype=np.float64)
        q = np.asarray(quat, dtype=np.float64)
        if t.ndim != 1 or t.size < 2 or p.shape != (t.size, 3) or q.shape != (t.size, 4):
            raise EnvError(f"a replay needs times (K>=2,), pos (K, 3) and quat (K, 4), got {t.shape}, {p.shape}, "
                           f"{q.shape}")
        if not (np.all(np.isfinite(t)) and np.all(np.diff(t) > 0.0)):
            raise EnvError("a replay's times must be finite and strictly increasing")
        for i in (0, t.size - 1):
            validate_pose(p[i], q[i], f"replay pose {i}")
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
            raise EnvError("a replay's poses contain NaN or inf")
        k = None if stiffness is None else np.asarray(stiffness, dtype=np.float64)
        if k is not None and k.shape != (t.size, 3, 3):
            raise EnvError(f"a replay's stiffness must be (K, 3, 3) = {(t.size, 3, 3)}, got {k.shape}")
        if not (np.isfinite(blend_s) and blend_s >= 0.0):
            raise EnvError(f"blend_s={blend_s!r} must be a finite number of seconds >= 0")
        self.times_s, self.pos, self.quat = t - t[0], p, make_continuous(q / np.linalg.norm(q, axis=-1, keepdims=True))
        self.stiffness = k
        self.blend_s = float(blend_s)
        self.feedforward = bool(feedforward)
        self.cmd_pos: FloatArray = np.zeros((0, 3))
        self.cmd_quat: FloatArray = np.zeros((0, 4))
        self.cmd_stiffness: FloatArray | None = None
        self._twist: FloatArray = np.zeros((0, 6))
        self._accel: FloatArray = np.zeros((0, 6))
        self._step = 0

    def reset(self, observation: Observation, period_s: float) -> None:
        """Resample the recording to the control period and blend it from the measured start pose.

        Raises:
            EnvError: a recording shorter than two control periods.
        """
        duration = float(self.times_s[-1])
        grid = period_s * np.arange(1, int(np.ceil(duration / period_s - 1e-9)) + 1)
        if grid.size < 2:
            raise EnvError(f"a replay of {duration} s is shorter than two control periods of {period_s} s")
        pos, quat = resample_trajectory(self.times_s, self.pos, self.quat, grid)
        if self.blend_s > 0.0:
            start = observation.tcp
            weight = 1.0 - minimum_jerk(grid / self.blend_s)
            q0 = self.quat[0] if dot(self.quat[0], start.quat) >= 0.0 else -self.quat[0]
            rot = quat_to_rotvec(quat_mul(start.quat, quat_conj(q0)))
            pos = pos + weight[:, None] * (np.asarray(start.pos) - self.pos[0])
            quat = quat_mul(quat_from_rotvec(weight[:, None] * rot), quat)
            quat /= np.linalg.norm(quat, axis=-1, keepdims=True)
        self.cmd_pos, self.cmd_quat = pos, make_continuous(quat)
        self.cmd_stiffness = None if self.stiffness is None else log_euclidean_resample(self.times_s, self.stiffness, grid)
        self._twist, self._accel = plan_twists(self.cmd_pos, self.cmd_quat, period_s)
        self._step = 0

    def act(self, observation: Observation) -> Action:
        """The next resampled pose (with its twist and acceleration), or the last one at rest after the end."""
        if self.cmd_pos.shape[0] == 0:
            raise EnvError("ReplayPolicy.act before reset")
        last = self.cmd_pos.shape[0] - 1
        k = min(self._step, last)
        self._step += 1
        pose = Pose(pos=self.cmd_pos[k], quat=self.cmd_quat[k])
        stiffness = None if self.cmd_stiffness is None else self.cmd_stiffness[k]
        if not self.feedforward:
            return Action(pose, stiffness)
        if self._step > last + 1:
            return Action(pose, stiffness, twist=np.zeros(6))
        return Action(pose, stiffness, twist=self._twist[k], accel=self._accel[k])
