"""controllers.mujoco_c: MuJoCo's C functions called from a compiled kernel give exactly what the Python bindings
give (a wrong signature or address would corrupt the state or crash)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numba
import numpy as np

from controllers.mujoco_c import (FN_COM_POS, FN_INTEGRATE_POS, FN_JAC, FN_JAC_SITE, FN_KINEMATICS, FN_MAT2QUAT,
                                  FN_OBJECT_VELOCITY, FN_SOLVE_M, FN_STEP1, FN_STEP2, call_integrate_pos, call_jac,
                                  call_md, call_mdppi, call_object_velocity, FUNCTIONS, library_path)
from tests.helpers.panda_fixtures import arm_model


@numba.njit(cache=False)
def _compiled_step(fns, m, d, jac, jac_minv, jac_point, point, site, body):
    call_md(fns[FN_STEP1], m, d)
    call_mdppi(fns[FN_JAC_SITE], m, d, jac.ctypes.data, jac.ctypes.data + 3 * jac.shape[1] * 8, site)
    call_mdppi(fns[FN_SOLVE_M], m, d, jac_minv.ctypes.data, jac.ctypes.data, 6)
    call_jac(fns[FN_JAC], m, d, jac_point.ctypes.data, 0, point.ctypes.data, body)
    call_md(fns[FN_STEP2], m, d)


@numba.njit(cache=False)
def _compiled_kinematics(fns, m, d, qpos, dq, dt):
    call_integrate_pos(fns[FN_INTEGRATE_POS], m, qpos.ctypes.data, dq.ctypes.data, dt)
    call_md(fns[FN_KINEMATICS], m, d)
    call_md(fns[FN_COM_POS], m, d)


def test_the_library_is_the_packages():
    assert library_path().parent.samefile(Path(mujoco.__file__).parent)
    assert np.all(FUNCTIONS != 0) and len(set(FUNCTIONS.tolist())) == len(FUNCTIONS)


def test_compiled_calls_equal_the_bindings():
    model = arm_model()
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "flange")
    body = int(model.site_bodyid[site])
    rng = np.random.default_rng(0)
    fns = FUNCTIONS
    for _ in range(5):
        ours, theirs = mujoco.MjData(model), mujoco.MjData(model)
        q, v, tau = (rng.uniform(-0.5, 0.5, model.nq), rng.uniform(-1, 1, model.nv), rng.uniform(-5, 5, model.nu))
        for data in (ours, theirs):
            data.qpos[:], data.qvel[:], data.ctrl[:] = model.qpos0 + q, v, tau
        point = rng.uniform(-0.5, 0.5, 3)
        jac, jac_minv, jac_point = np.zeros((6, model.nv)), np.zeros((6, model.nv)), np.zeros((3, model.nv))
        _compiled_step(fns, model._address, ours._address, jac, jac_minv, jac_point, point, site, body)
        want_jac, want_minv, want_point = np.zeros((6, model.nv)), np.zeros((6, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_step1(model, theirs)
        mujoco.mj_jacSite(model, theirs, want_jac[:3], want_jac[3:], site)
        mujoco.mj_solveM(model, theirs, want_minv, want_jac)
        mujoco.mj_jac(model, theirs, want_point, None, point, body)
        mujoco.mj_step2(model, theirs)
        for got, want in ((jac, want_jac), (jac_minv, want_minv), (jac_point, want_point), (ours.qpos, theirs.qpos),
                          (ours.qvel, theirs.qvel), (ours.qacc, theirs.qacc)):
            np.testing.assert_array_equal(got, want)
        assert np.abs(jac).max() > 0.1 and ours.time == theirs.time > 0.0


def test_compiled_integration_and_kinematics_equal_the_bindings():
    model = arm_model()
    rng = np.random.default_rng(1)
    ours, theirs = mujoco.MjData(model), mujoco.MjData(model)
    q, dq = model.qpos0 + rng.uniform(-0.5, 0.5, model.nq), rng.uniform(-0.3, 0.3, model.nv)
    ours.qpos[:], theirs.qpos[:] = q, q
    _compiled_kinematics(FUNCTIONS, model._address, ours._address, ours.qpos, dq, 0.7)
    mujoco.mj_integratePos(model, theirs.qpos, dq, 0.7)
    mujoco.mj_kinematics(model, theirs)
    mujoco.mj_comPos(model, theirs)
    for got, want in ((ours.qpos, theirs.qpos), (ours.xpos, theirs.xpos), (ours.site_xmat, theirs.site_xmat),
                      (ours.cdof, theirs.cdof), (ours.subtree_com, theirs.subtree_com)):
        np.testing.assert_array_equal(got, want)
    assert not np.array_equal(ours.qpos, q) and np.abs(ours.cdof).max() > 0.0


@numba.njit(cache=False)
def _compiled_site_reads(fns, m, d, xmat, sites, quats, velocities, local):
    for i in range(sites.shape[0]):
        call_md(fns[FN_MAT2QUAT], quats[i].ctypes.data, xmat.ctypes.data + sites[i] * 9 * 8)
        call_object_velocity(fns[FN_OBJECT_VELOCITY], m, d, 6, sites[i], velocities[i].ctypes.data, local)


def test_compiled_rotations_and_velocities_equal_the_bindings():
    """mju_mat2Quat of every site's rotation and mj_objectVelocity of every site (world and local frame) at random
    moving states, against the bindings (6 is mjOBJ_SITE)."""
    model = arm_model()
    assert int(mujoco.mjtObj.mjOBJ_SITE) == 6
    rng = np.random.default_rng(2)
    sites = np.arange(model.nsite, dtype=np.int64)
    for trial in range(4):
        data = mujoco.MjData(model)
        data.qpos[:] = model.qpos0 + rng.uniform(-1.0, 1.0, model.nq)
        data.qvel[:] = rng.uniform(-2.0, 2.0, model.nv)
        mujoco.mj_forward(model, data)
        local = trial % 2
        quats, velocities = np.zeros((model.nsite, 4)), np.zeros((model.nsite, 6))
        _compiled_site_reads(FUNCTIONS, model._address, data._address, data.site_xmat, sites, quats, velocities, local)
        for i in range(model.nsite):
            want_q, want_v = np.zeros(4), np.zeros(6)
            mujoco.mju_mat2Quat(want_q, data.site_xmat[i])
            mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_SITE, i, want_v, local)
            np.testing.assert_array_equal(quats[i], want_q)
            np.testing.assert_array_equal(velocities[i], want_v)
        assert np.abs(velocities).max() > 0.1
