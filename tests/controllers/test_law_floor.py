"""controllers.law_floor: the reference periods `pih bench` times against the law of record run the law of record
where they say so (bit for bit), hold its factors where they say so, and the spring-damper law is its formula."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from controllers.impedance import ImpedanceConfig
from controllers.impedance_kernel import pose_error_into
from controllers.law_floor import (LAW_HELD_FACTORS, LAW_OF_RECORD, LAW_SPRING_DAMPER, reference_period,
                                   spring_damper_torque)
from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.poses import Pose
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.sim.period_kernel import controlled_period
from envs.task.perturbation import Perturbation


@pytest.fixture(scope="module")
def periods():
    """The env in the middle of a descent onto the chamfer beside the hole (walls in contact), and the prepared
    arguments of its next period; its controller without the friction observer, which the reference laws leave out."""
    env = PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=1.5), scene=build_scene(SceneConfig()),
                       controller_config=ImpedanceConfig(friction_observer_time_s=0.0))
    env.reset(start_pose=Pose(env.nominal_goal.pos + 0.006 * env.hole_axis, env.nominal_goal.quat),
              perturbation=Perturbation(hole_dx_m=0.001))
    for k in range(12):
        env.step(Pose(env.nominal_goal.pos + (0.006 - 0.0008 * k) * env.hole_axis, env.nominal_goal.quat))
    assert not env.done and env.data.ncon > 2
    period = env.prepare_period(Pose(env.nominal_goal.pos - 0.002 * env.hole_axis, env.nominal_goal.quat),
                                np.diag([300.0, 800.0, 1500.0, 30.0, 30.0, 30.0]))
    return env, period.arguments


def _run(env, args, law, n):
    """The physics state after ``n`` steps of ``law`` (None: the compiled period of record), from the saved state."""
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    before = mujoco.MjData(env.model)
    mujoco.mj_copyData(before, env.model, env.data)  # the kinematics too: the tool load reads them before mj_step1
    saved = [(a, a.copy()) for a in args if isinstance(a, np.ndarray) and a.flags.writeable]
    if law is None:
        ran, status, limit = controlled_period(n, *args)
        assert (ran, status, limit) == (n, 0, False)
    else:
        assert reference_period(n, law, *args[:23])
    after = np.empty(mujoco.mj_stateSize(env.model, spec))
    mujoco.mj_getState(env.model, env.data, after, spec)
    mujoco.mj_copyData(env.data, env.model, before)
    for array, copy in saved:
        np.copyto(array, copy)
    return after


def test_the_law_of_record_reference_is_the_compiled_period_s_physics_bit_for_bit(periods):
    env, args = periods
    assert np.array_equal(_run(env, args, LAW_OF_RECORD, env.n_substeps), _run(env, args, None, env.n_substeps))


def test_held_factors_are_the_law_of_record_at_the_first_step_and_held_after_it(periods):
    env, args = periods
    assert np.array_equal(_run(env, args, LAW_HELD_FACTORS, 1), _run(env, args, LAW_OF_RECORD, 1))
    held, record = _run(env, args, LAW_HELD_FACTORS, 10), _run(env, args, LAW_OF_RECORD, 10)
    assert not np.array_equal(held, record)  # the factors are not recomputed: a different (if close) law
    assert np.allclose(held, record, rtol=0.0, atol=1e-3)


def test_the_spring_damper_law_is_its_formula(periods):
    env, args = periods
    rng = np.random.default_rng(3)
    jac = 0.5 * rng.normal(size=(6, env.model.nv))
    qvel = 0.2 * rng.normal(size=env.model.nv)
    bias = rng.normal(size=7)
    target = args[11].copy()
    site_mat = np.empty(9)
    quat = target[3:7] + 0.02 * rng.normal(size=4)
    mujoco.mju_quat2Mat(site_mat, quat / np.linalg.norm(quat))  # about 2 deg off the target
    site_pos = target[0:3] + 0.01 * rng.normal(size=3)
    k = np.diag([300.0, 800.0, 1500.0, 30.0, 30.0, 30.0])
    params = args[13]
    ctrl, vec = np.empty(7), np.zeros((8, 9))
    spring_damper_torque(jac, qvel, bias, site_pos, site_mat, target, k, params, ctrl, vec)
    error = np.empty(6)
    pose_error_into(target[0:3], target[3:7], site_pos, site_mat, error, np.empty(4))
    damping = np.diag(np.sqrt(np.diag(k) * params[1]))  # 2 zeta sqrt(K_ii)
    dof0 = int(params[5])
    expected = bias + jac[:, dof0:dof0 + 7].T @ (k @ error - damping @ (jac @ qvel))
    limit = params[6:13]
    assert np.allclose(ctrl, np.clip(expected, -limit, limit), rtol=1e-12, atol=1e-9)
    assert np.all(np.abs(expected) < limit)  # no joint clipped: the formula itself is seen
    assert np.all(np.abs(error) > 1e-4)


def test_the_spring_damper_period_is_another_law_than_the_one_of_record(periods):
    env, args = periods
    assert not np.array_equal(_run(env, args, LAW_SPRING_DAMPER, 10), _run(env, args, LAW_OF_RECORD, 10))
