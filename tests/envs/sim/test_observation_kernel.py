"""The compiled read of an observation (envs.sim.observation_kernel) equals, bit for bit, the reads it replaced: the
three site poses by mju_mat2Quat through the bindings (`envs.sim.observation.site_pose`), the peg tip's rotation matrix
by `numerics.quaternion.quat_to_mat` and its speed by mj_objectVelocity (`Observer.peg_speed_m_s`), over the states of
episodes moved by random commands; and it says so when the peg tip's pose is not finite."""

from __future__ import annotations

import numpy as np
import pytest

from controllers.mujoco_c import FUNCTIONS
from envs.sim import observation_kernel as kernel
from envs.sim.env import PegInHoleEnv
from envs.sim.observation import site_pose
from numerics.quaternion import quat_to_mat
from tests.helpers.env_states import wandering_states


@pytest.fixture(scope="module")
def env():
    return PegInHoleEnv()


def _read(env):
    observer, data = env.observer, env.data
    poses, rotation, velocity = np.empty((3, 7)), np.full((3, 3), np.nan), np.empty(6)
    sites = np.array([observer.flange_site, observer.tcp_site, observer.peg_tip_site], dtype=np.int64)
    speed = kernel.read_sites_into(FUNCTIONS, env.model._address, data._address, sites, data.site_xpos,
                                   data.site_xmat, poses, rotation, velocity)
    return sites, poses, rotation, speed


def test_the_compiled_read_equals_the_bindings_bit_for_bit(env) -> None:
    checked = 0
    for _ in wandering_states(env, np.random.default_rng(3), episodes=4, periods=30, step_m=0.004):
        sites, poses, rotation, speed = _read(env)
        for row, site in zip(poses, sites):
            want = site_pose(env.data, int(site))
            assert np.array_equal(row[:3], want.pos) and np.array_equal(row[3:], want.quat)
        assert np.array_equal(rotation, quat_to_mat(poses[2, 3:]))
        assert speed == env.observer.peg_speed_m_s()
        checked += 1
    assert checked >= 60


def test_a_peg_tip_pose_that_is_not_finite_reads_nan(env) -> None:
    env.reset(seed=0)
    env.data.site_xpos[env.observer.peg_tip_site, 1] = np.nan
    _, poses, rotation, speed = _read(env)
    assert speed == kernel.NOT_FINITE and np.isnan(poses[2, 1]) and np.all(np.isnan(rotation))
    env.reset(seed=0)
