"""The per-period instability check on a small MjData: each kind of problem, in its order, worded with its time;
a warning is reported once; a state that is fine gives None."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from envs.sim.instability import InstabilityCheck

ARM = slice(1, 3)  # dofs 1 and 2 are "the arm"; dof 0 is not checked for speed


@pytest.fixture()
def data() -> mujoco.MjData:
    joints = "".join(f'<body><joint type="hinge"/><geom size=".05" pos="0 0 {k}"/>' for k in range(3)) + "</body>" * 3
    model = mujoco.MjModel.from_xml_string(f"<mujoco><worldbody>{joints}</worldbody></mujoco>")
    return mujoco.MjData(model)


def test_a_fine_state_is_none_and_the_arms_speed_is_checked_on_its_dofs_only(data):
    check = InstabilityCheck(data, ARM, max_joint_speed_rad_s=10.0)
    check.reset()
    data.qvel[:] = [50.0, 9.9, -9.9]  # dof 0 is not the arm's
    assert check.check(0.01) is None
    data.qvel[2] = -10.5
    assert check.check(0.02) == "joint speed 10.5 rad/s exceeds 10.0 rad/s at t=0.020 s"


@pytest.mark.parametrize("field", ["qpos", "qvel", "qacc"])
def test_a_non_finite_entry_anywhere_is_reported(data, field):
    check = InstabilityCheck(data, ARM, max_joint_speed_rad_s=10.0)
    check.reset()
    getattr(data, field)[0] = np.inf
    assert check.check(1.5) == "non-finite state at t=1.500 s"


def test_a_bad_state_warning_is_reported_once_and_first(data):
    data.warning[int(mujoco.mjtWarning.mjWARN_BADQACC)].number = 2  # counted before the episode: not reported
    check = InstabilityCheck(data, ARM, max_joint_speed_rad_s=10.0)
    check.reset()
    assert check.check(0.0) is None
    data.warning[int(mujoco.mjtWarning.mjWARN_BADQVEL)].number += 1
    data.qvel[1] = np.nan  # the warning comes first
    assert check.check(0.25) == "MuJoCo warning mjWARN_BADQVEL at t=0.250 s (MuJoCo reset the state)"
    data.qvel[1] = 0.0
    assert check.check(0.26) is None  # the same count is not reported again
    data.warning[int(mujoco.mjtWarning.mjWARN_BADQPOS)].number += 1
    data.warning[int(mujoco.mjtWarning.mjWARN_BADQACC)].number += 1
    assert check.check(0.3) == "MuJoCo warning mjWARN_BADQPOS, mjWARN_BADQACC at t=0.300 s (MuJoCo reset the state)"
