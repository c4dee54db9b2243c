"""Physics failures of an episode, checked after every control period: a MuJoCo bad-state warning (MuJoCo has then
reset the state), a non-finite state, or an arm joint faster than the episode allows. The episode records what was
found as its end reason ("instability: ..."), it does not raise."""

from __future__ import annotations

import mujoco
import numpy as np
import numpy.typing as npt

from envs.geometry import all_finite

BAD_STATE_WARNINGS: tuple[mujoco.mjtWarning, ...] = (
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQACC,
)
_BAD_STATE_INDICES = np.array([int(w) for w in BAD_STATE_WARNINGS])


class InstabilityCheck:
    """The checks of one MjData: `reset` at the start of an episode, `check` after each control period."""

    def __init__(self, data: mujoco.MjData, arm_dof: slice, max_joint_speed_rad_s: float) -> None:
        """Args:
            data: the episode's MjData.
            arm_dof: the arm's joints in ``data.qvel``.
            max_joint_speed_rad_s: a joint faster than this is an instability.
        """
        self.data = data
        self.arm_dof = arm_dof
        self.max_joint_speed_rad_s = max_joint_speed_rad_s
        self._counts = np.zeros(len(BAD_STATE_WARNINGS), dtype=int)

    def _warning_counts(self) -> npt.NDArray[np.int_]:
        return self.data.warning.number[_BAD_STATE_INDICES]

    def reset(self) -> None:
        """Count only the warnings from now on."""
        self._counts = self._warning_counts()

    def check(self, time_s: float) -> str | None:
        """What went wrong since the last check, at episode time ``time_s`` (for the message), or None."""
        counts, before = self._warning_counts(), self._counts
        self._counts = counts
        now = f"t={time_s:.3f} s"
        if (counts > before).any():
            fired = [w.name for w, new, old in zip(BAD_STATE_WARNINGS, counts, before) if new > old]
            return f"MuJoCo warning {', '.join(fired)} at {now} (MuJoCo reset the state)"
        data = self.data
        if not (all_finite(data.qpos) and all_finite(data.qvel) and all_finite(data.qacc)):
            return f"non-finite state at {now}"
        speed = float(np.max(np.abs(data.qvel[self.arm_dof])))
        if speed > self.max_joint_speed_rad_s:
            return f"joint speed {speed:.1f} rad/s exceeds {self.max_joint_speed_rad_s} rad/s at {now}"
        return None
