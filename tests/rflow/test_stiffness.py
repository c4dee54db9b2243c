"""rflow.stiffness: eigenvalue bounds, the variability (minimal-intervention) estimator, Log-Euclidean metrics."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rflow.errors import RFlowError
from rflow.stiffness import (StiffnessBounds, VariabilityConfig, clip_eigenvalues, log_euclidean_mean,
                             log_euclidean_resample, position_covariance, profile_distance, variability_stiffness)

BOUNDS = StiffnessBounds(100.0, 3000.0)


def _spd(eigenvalues, seed=0):
    r = Rotation.random(random_state=seed).as_matrix()
    return r @ np.diag(eigenvalues) @ r.T


def test_clip_is_the_identity_inside_the_bounds():
    k = _spd([150.0, 800.0, 2900.0])
    out, acted = clip_eigenvalues(k, BOUNDS)
    assert not acted and np.array_equal(out, k)


def test_clip_moves_only_the_eigenvalues_outside_and_keeps_the_eigenvectors():
    k = _spd([20.0, 800.0, 9000.0], seed=3)
    out, acted = clip_eigenvalues(k, BOUNDS)
    assert acted
    assert np.allclose(np.linalg.eigvalsh(out), [100.0, 800.0, 3000.0])
    assert np.allclose(out @ k, k @ out, atol=1e-6 * 9000**2)  # same eigenvectors: the matrices commute


def test_bounds_reject_inverted_or_non_positive_ranges():
    for low, high in ((0.0, 10.0), (500.0, 100.0), (-1.0, 5.0), (1.0, float("inf"))):
        with pytest.raises(RFlowError):
            StiffnessBounds(low, high)


def _spread_demos(sigmas_m):
    """Four demos at +-sigma on each axis around the origin, per sample; the last sample coincides."""
    signs = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)  # orthogonal columns
    sig = np.asarray(sigmas_m, float)  # (M, 3)
    return signs[:, None, :] * sig[None, :, :]


def test_covariance_of_aligned_demos():
    pos = _spread_demos([[0.01, 0.02, 0.03], [0.0, 0.0, 0.0]])
    cov = position_covariance(pos)
    assert np.allclose(cov[0], np.diag([0.01, 0.02, 0.03]) ** 2 * 4 / 3)
    assert np.allclose(cov[1], 0.0)


def test_variability_stiffness_is_alpha_times_the_regularised_inverse_covariance():
    config = VariabilityConfig(alpha_n_m=0.25, regularisation_m2=1e-6, bounds=StiffnessBounds(1.0, 1e6))
    pos = _spread_demos([[0.01, 0.02, 0.03], [0.0, 0.0, 0.0]])
    k = variability_stiffness(pos, config)
    var = np.array([0.01, 0.02, 0.03]) ** 2 * 4 / 3
    assert np.allclose(np.diag(k[0]), 0.25 / (var + 1e-6))
    assert np.allclose(k[1], 0.25 / 1e-6 * np.eye(3))  # where the demos coincide: alpha / eps


def test_variability_stiffness_is_compliant_where_demos_spread_and_clipped_to_the_bounds():
    pos = _spread_demos([[0.03, 0.001, 0.01], [0.0, 0.0, 0.0]])
    k = variability_stiffness(pos, VariabilityConfig(bounds=BOUNDS))
    assert k[0, 0, 0] < k[0, 2, 2] < k[0, 1, 1]
    assert BOUNDS.contains(k)
    assert np.allclose(k[-1], 3000.0 * np.eye(3))  # the shared goal stiffness


def test_variability_needs_two_demos():
    with pytest.raises(RFlowError):
        variability_stiffness(np.zeros((1, 5, 3)))


def test_profile_distance_of_scaled_profiles_is_log_of_the_scale():
    a = np.stack([_spd([200.0, 500.0, 1000.0], seed=s) for s in range(4)])
    assert np.allclose(profile_distance(a, a), 0.0, atol=1e-12)
    assert np.isclose(profile_distance(a, 2.0 * a), np.log(2.0) * np.sqrt(3.0))


def test_log_euclidean_mean_of_commuting_matrices_is_the_geometric_mean():
    a, b = np.diag([100.0, 400.0, 900.0]), np.diag([400.0, 100.0, 100.0])
    assert np.allclose(log_euclidean_mean(np.stack([a, b])), np.diag([200.0, 200.0, 300.0]))


def test_log_euclidean_resample_is_exact_at_the_samples_and_geometric_between_them():
    a, b = np.diag([100.0, 400.0, 1000.0]), np.diag([400.0, 100.0, 1000.0])
    out = log_euclidean_resample([0.0, 2.0], np.stack([a, b]), [0.0, 1.0, 2.0, 5.0])
    assert np.allclose(out[0], a) and np.allclose(out[2], b) and np.allclose(out[3], b)  # clipped to the range
    assert np.allclose(out[1], np.diag([200.0, 200.0, 1000.0]))  # sqrt(100 * 400)


def test_log_euclidean_resample_stays_spd_between_non_commuting_samples():
    rng = np.random.default_rng(0)
    basis = [np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(5)]
    k = np.stack([u @ np.diag([100.0, 1000.0, 3000.0]) @ u.T for u in basis])
    out = log_euclidean_resample(np.arange(5.0), k, np.linspace(0.0, 4.0, 97))
    assert np.linalg.eigvalsh(out).min() > 99.0 and np.linalg.eigvalsh(out).max() < 3001.0
    assert np.allclose(out, np.swapaxes(out, -1, -2))


def test_log_euclidean_resample_rejects_unordered_times_and_non_spd():
    k = np.stack([np.eye(3), 2.0 * np.eye(3)])
    with pytest.raises(RFlowError, match="increasing"):
        log_euclidean_resample([1.0, 0.0], k, [0.5])
    with pytest.raises(RFlowError, match="positive definite"):
        log_euclidean_resample([0.0, 1.0], np.stack([np.eye(3), -np.eye(3)]), [0.5])
