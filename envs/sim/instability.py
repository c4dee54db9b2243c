"""Physics failures of an episode, checked after every control period: a MuJoCo bad-state or bad-control warning
(MuJoCo has then reset the state or zeroed the controls), a non-finite state, or an arm joint faster than the
episode allows. The episode records what was found as its end reason ("instability: ..."), it does not raise. The check is one compiled call on views of the
MjData (`state_problem`, ~1 us instead of ~15 us of numpy calls per period); Python only words what it found."""

from __future__ import annotations

import math

import mujoco
import numba
import numpy as np
import numpy.typing as npt

BAD_STATE_WARNINGS: tuple[mujoco.mjtWarning, ...] = (
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADCTRL,
)
"""MuJoCo's warnings of a bad state (it then resets the state) or a bad control (it then zeroes the controls: the
arm falls limp)."""
_BAD_STATE_INDICES = np.array([int(w) for w in BAD_STATE_WARNINGS])


STATE_OK, STATE_WARNING, STATE_NOT_FINITE, STATE_TOO_FAST = range(4)
"""What `state_problem` found (in the order it looks)."""


@numba.njit(cache=True, nogil=True)
def state_problem(numbers: npt.NDArray[np.int32], indices: npt.NDArray[np.int64], counts: npt.NDArray[np.int64],
                  fresh: npt.NDArray[np.int64], qpos: npt.NDArray[np.float64], qvel: npt.NDArray[np.float64],
                  qacc: npt.NDArray[np.float64], dof_start: int, dof_stop: int, max_speed: float) -> tuple[int, float]:
    """One control period's check of an MjData, compiled: a bad-state warning counted since ``counts`` (the
    counts now, ``numbers[indices]``, go to ``fresh``), a non-finite entry of qpos, qvel or qacc, or
    max_i |qvel_i| over the arm's dofs [dof_start, dof_stop) above ``max_speed`` -- checked in this order.

    Returns:
        (STATE_* code, the fastest arm joint's speed in rad/s; NaN unless the state is finite).
    """
    fired = False
    for k in range(indices.shape[0]):
        fresh[k] = numbers[indices[k]]
        if fresh[k] > counts[k]:
            fired = True
    if fired:
        return STATE_WARNING, math.nan
    for values in (qpos, qvel, qacc):
        for v in values:
            if not math.isfinite(v):
                return STATE_NOT_FINITE, math.nan
    speed = 0.0
    for i in range(dof_start, dof_stop):
        speed = max(speed, abs(qvel[i]))
    return (STATE_TOO_FAST if speed > max_speed else STATE_OK), speed


class InstabilityCheck:
    """The checks of one MjData: `reset` at the start of an episode, `check` after each control period."""

    def __init__(self, data: mujoco.MjData, arm_dof: slice, max_joint_speed_rad_s: float) -> None:
        """Args:
            data: the episode's MjData (its arrays are read through views kept here: the same MjData throughout).
            arm_dof: the arm's joints in ``data.qvel`` (a slice with step 1).
            max_joint_speed_rad_s: a joint faster than this is an instability.
        """
        self.data = data
        self.arm_dof = arm_dof
        self.max_joint_speed_rad_s = max_joint_speed_rad_s
        self._counts = np.zeros(len(BAD_STATE_WARNINGS), dtype=np.int64)  # at the last check
        self._fresh = np.zeros(len(BAD_STATE_WARNINGS), dtype=np.int64)  # now
        self._numbers = data.warning.number  # live views of the MjData's memory
        self._state = (data.qpos, data.qvel, data.qacc)
        start, stop, step = arm_dof.indices(data.qvel.shape[0])
        if step != 1:
            raise ValueError(f"arm dofs {arm_dof} must be a slice with step 1")
        self._dofs = (start, stop)

    def reset(self) -> None:
        """Count only the warnings from now on."""
        self._counts[:] = self._numbers[_BAD_STATE_INDICES]

    def check(self, time_s: float) -> str | None:
        """What went wrong since the last check, at episode time ``time_s`` (for the message), or None."""
        code, speed = state_problem(self._numbers, _BAD_STATE_INDICES, self._counts, self._fresh, *self._state,
                                    *self._dofs, self.max_joint_speed_rad_s)
        before, self._counts, self._fresh = self._counts, self._fresh, self._counts  # count from now on
        if code == STATE_OK:
            return None
        now = f"t={time_s:.3f} s"
        if code == STATE_WARNING:
            fired = [w.name for w, new, old in zip(BAD_STATE_WARNINGS, self._counts, before) if new > old]
            what = "zeroed the controls" if fired == ["mjWARN_BADCTRL"] else "reset the state"
            return f"MuJoCo warning {', '.join(fired)} at {now} (MuJoCo {what})"
        if code == STATE_NOT_FINITE:
            return f"non-finite state at {now}"
        return f"joint speed {speed:.1f} rad/s exceeds {self.max_joint_speed_rad_s} rad/s at {now}"
