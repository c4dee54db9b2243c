"""rflow.manifolds: SPD in normal coordinates and the product manifold R^3 x S^3 x SPD(3)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from rflow.errors import RFlowError
from rflow.manifolds import (EuclideanSpace, ProductManifold, SPDNormalMatrices, UnitQuaternions, get_manifold, spd,
                             sphere)
from rflow.skill_io import POSE, POSE_STIFFNESS

SPD_N = SPDNormalMatrices()


def _spd(eigenvalues, seed):
    r = Rotation.random(random_state=seed).as_matrix()
    return r @ np.diag(eigenvalues) @ r.T


GOAL_K = _spd([300.0, 300.0, 1000.0], 1)


def test_normal_log_is_the_whitened_affine_invariant_log():
    p = _spd([1500.0, 200.0, 700.0], 2)
    inv_half = np.linalg.inv(spd.sqrtm(GOAL_K))
    assert np.allclose(spd.normal_log_map(p, GOAL_K), inv_half @ spd.log_map(p, GOAL_K) @ inv_half, atol=1e-10)


def test_normal_tangent_norm_is_the_riemannian_distance():
    p = _spd([1500.0, 200.0, 700.0], 2)
    lam = np.linalg.eigvals(np.linalg.solve(GOAL_K, p)).real  # generalised eigenvalues of (P, G)
    assert np.isclose(np.linalg.norm(SPD_N.log(p, GOAL_K)), np.sqrt(np.sum(np.log(lam) ** 2)))


def test_normal_exp_inverts_log_and_is_spd_for_any_tangent():
    rng = np.random.default_rng(0)
    v = rng.normal(0.0, 2.0, (200, 6))
    k = SPD_N.exp(v, GOAL_K)
    assert np.linalg.eigvalsh(k).min() > 0
    assert np.allclose(SPD_N.log(k, GOAL_K), v, atol=1e-8)
    assert get_manifold("spd_normal").name == "spd_normal"


def _point(pos, quat, k):
    return np.concatenate([pos, quat, k.reshape(-1)])


GOAL = _point(np.array([0.6, 0.0, 0.2]), np.array([0.0, 1.0, 0.0, 0.0]), GOAL_K)


def test_product_log_of_goal_is_zero_and_exp_inverts_log():
    assert POSE_STIFFNESS.tangent_dim((16,)) == 12
    assert np.allclose(POSE_STIFFNESS.log(GOAL, GOAL), 0.0)
    v = np.array([[0.01, -0.02, 0.03, 0.1, -0.2, 0.05, 0.3, -0.2, 0.1, 0.05, -0.1, 0.2]])
    assert np.allclose(POSE_STIFFNESS.log(POSE_STIFFNESS.exp(v, GOAL), GOAL), v, atol=1e-10)


def test_product_factors_are_the_factor_maps():
    x = _point(np.array([0.5, 0.1, 0.3]), sphere.exp_map(np.array([0.1, 0.2, -0.1]), GOAL[3:7]), _spd([900, 400, 200], 5))
    v = POSE_STIFFNESS.log(x, GOAL)
    assert np.allclose(v[:3], x[:3] - GOAL[:3])
    assert np.allclose(v[3:6], sphere.log_map(x[3:7], GOAL[3:7]))
    assert np.allclose(v[6:], spd.mandel(spd.normal_log_map(x[7:].reshape(3, 3), GOAL_K)))


def test_product_works_on_torch_tensors():
    v = torch.tensor([[0.01, -0.02, 0.03, 0.1, -0.2, 0.05, 0.3, -0.2, 0.1, 0.05, -0.1, 0.2]], dtype=torch.float64)
    x = POSE_STIFFNESS.exp(v, torch.as_tensor(GOAL))
    assert isinstance(x, torch.Tensor) and x.shape == (1, 16)


def test_product_rejects_a_non_spd_stiffness_part():
    bad = GOAL.copy()
    bad[7:] = np.diag([300.0, -1.0, 300.0]).reshape(-1)
    with pytest.raises(RFlowError, match="spd_normal"):
        POSE_STIFFNESS.check_points(bad)


def test_pose_product_keeps_the_old_pose_manifold_maps():
    goal = GOAL[:7]
    q = sphere.exp_map(np.array([0.3, -0.1, 0.2]), goal[3:])
    x = np.concatenate([[0.1, 0.2, 0.3], q])
    assert POSE.name == "pose" and POSE.tangent_dim((7,)) == 6
    assert np.allclose(POSE.log(x, goal), np.concatenate([x[:3] - goal[:3], sphere.log_map(q, goal[3:])]))


def test_prepare_flips_quaternion_hemispheres_only():
    demos = np.stack([np.stack([GOAL, GOAL])] * 2)
    demos[1, :, 3:7] *= -1.0
    out = POSE_STIFFNESS.prepare(demos)
    assert np.allclose(out[1, :, 3:7], GOAL[3:7]) and np.allclose(out[..., 7:], demos[..., 7:])


def test_product_needs_factors():
    with pytest.raises(RFlowError):
        ProductManifold("empty", ())
    assert ProductManifold("r3s3", ((EuclideanSpace(), (3,)), (UnitQuaternions(), (4,)))).point_size == 7
