"""The compiled impedance law against a plain numpy/LAPACK evaluation of the same equations."""

import numpy as np
import pytest
import scipy.linalg

from controllers import impedance_kernel as kernel

N_JOINTS, NV = 7, 9  # two extra dofs (e.g. fingers) that the law must read through J but never command


def _spd(rng, n, scale):
    basis, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return basis @ np.diag(scale * rng.uniform(0.1, 1.0, n)) @ basis.T


def _reference(jac, jac_minv, qpos, qvel, bias, site_pos, site_rot, pos, quat, k, q_ref, params, last):
    """The law of controllers/impedance.py in numpy: eigh for the modal damping, scipy for the rotation error."""
    reg, four_zeta_sq, k_n, d_n, rate, dof0 = params[:6]
    dof0 = int(dof0)
    tau_max = params[6:]
    lambda_inv = jac_minv @ jac.T + reg * np.eye(6)
    chol = np.linalg.cholesky(lambda_inv)
    w, u = np.linalg.eigh(chol.T @ k @ chol)
    p = np.linalg.solve(chol.T, u)
    rot_d = scipy.spatial.transform.Rotation.from_quat(quat, scalar_first=True)
    rot = scipy.spatial.transform.Rotation.from_matrix(site_rot)
    error = np.concatenate([pos - site_pos, (rot_d * rot.inv()).as_rotvec()])
    arm = slice(dof0, dof0 + N_JOINTS)
    tau0 = -d_n * qvel[arm] + (0.0 if q_ref is None else k_n * (q_ref - qpos))
    damping = p @ np.diag(np.sqrt(four_zeta_sq * w)) @ p.T
    force = k @ error - damping @ (jac @ qvel) - p @ p.T @ (jac_minv[:, arm] @ tau0)
    tau = jac[:, arm].T @ force + tau0 + bias
    tau = np.clip(tau, last - rate, last + rate)
    return np.clip(tau, -tau_max, tau_max)


@pytest.mark.parametrize("seed", range(20))
def test_kernel_torque_equals_numpy_law(seed):
    rng = np.random.default_rng(seed)
    jac = rng.normal(size=(6, NV))
    jac_minv = jac @ np.linalg.inv(_spd(rng, NV, 5.0))  # J M^-1 of an SPD mass matrix
    qpos, qvel = rng.normal(size=N_JOINTS), rng.normal(size=NV)
    bias = rng.normal(0.0, 5.0, N_JOINTS)
    site_pos = rng.normal(size=3)
    site_rot = scipy.spatial.transform.Rotation.random(random_state=seed).as_matrix()
    pos = site_pos + rng.normal(0.0, 0.05, 3)
    quat = rng.normal(size=4)
    quat /= np.linalg.norm(quat)
    k = _spd(rng, 6, 1000.0) if seed % 2 else np.diag([1500.0] * 3 + [80.0] * 3)
    q_ref = None if seed % 3 == 0 else rng.normal(size=N_JOINTS)
    params = np.concatenate([[1e-6, 4.0 * rng.uniform(0.5, 1.5) ** 2, 10.0, 3.0, 1e3, 1.0],
                             rng.uniform(5.0, 90.0, N_JOINTS)])  # arm dofs 1..7, as if a free dof came first
    last = rng.normal(0.0, 10.0, N_JOINTS)
    target = np.concatenate([pos, quat, np.zeros(N_JOINTS) if q_ref is None else q_ref, [q_ref is not None]])
    want = _reference(jac, jac_minv, qpos, qvel, bias, site_pos, site_rot, pos, quat, k, q_ref, params, last)
    work, vec = kernel.work_buffers(N_JOINTS)
    ctrl, last_tau = np.zeros(N_JOINTS), last.copy()
    status = kernel.impedance_torque(jac, jac_minv, qpos, qvel, bias, site_pos, site_rot.ravel(), target, k,
                                     params, last_tau, ctrl, work, vec, np.zeros(N_JOINTS))
    assert status == kernel.STATUS_OK
    np.testing.assert_allclose(ctrl, want, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(last_tau, ctrl)


def test_kernel_reports_a_singular_inertia_and_writes_nothing():
    jac = np.zeros((6, NV))  # J = 0: J M^-1 J^T + eps I has eps on the diagonal, so make it negative instead
    params = np.concatenate([[-1e-6, 4.0, 10.0, 3.0, 1.0, 0.0], np.full(N_JOINTS, 87.0)])
    work, vec = kernel.work_buffers(N_JOINTS)
    ctrl = np.full(N_JOINTS, 7.0)
    status = kernel.impedance_torque(jac, jac, np.zeros(N_JOINTS), np.zeros(NV), np.zeros(N_JOINTS), np.zeros(3),
                                     np.eye(3).ravel(), np.r_[np.zeros(3), 1.0, np.zeros(N_JOINTS + 4)],
                                     np.eye(6), params, np.zeros(N_JOINTS), ctrl, work, vec, np.zeros(N_JOINTS))
    assert status == kernel.STATUS_NOT_POSITIVE_DEFINITE
    assert np.all(ctrl == 7.0)


def test_cholesky_rejects_an_indefinite_matrix():
    c = np.zeros((6, 6))
    assert kernel.cholesky_lower(np.eye(6), c)
    assert not kernel.cholesky_lower(np.diag([1.0, 1.0, -1.0, 1.0, 1.0, 1.0]), c)
    assert not kernel.cholesky_lower(np.full((6, 6), np.nan), c)
