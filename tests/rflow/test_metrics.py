"""Tests of rflow.metrics: DTW against similaritymeasures, RMSE, final error, manifold distances."""

import numpy as np
import pytest
import similaritymeasures

from rflow.errors import RFlowError
from rflow.manifolds import sphere, spd
from rflow.metrics import dtw, final_error, log_euclidean_distances, manifold_distances, quaternion_distances, rmse


@pytest.mark.parametrize("n, m, dim", [(1, 1, 2), (1, 9, 3), (9, 1, 3), (17, 31, 2), (64, 50, 3), (120, 120, 4)])
def test_dtw_equals_similaritymeasures(n: int, m: int, dim: int) -> None:
    rng = np.random.default_rng(n * 1000 + m * 10 + dim)
    a, b = rng.normal(size=(n, dim)), rng.normal(size=(m, dim))
    assert dtw(a, b) == pytest.approx(similaritymeasures.dtw(a, b)[0], abs=1e-9)


def test_dtw_equals_similaritymeasures_on_smooth_curves() -> None:
    t = np.linspace(0.0, 1.0, 200)
    a = np.stack([np.sin(6 * t), np.cos(5 * t), t], axis=1)
    b = np.stack([np.sin(6 * t**1.3), np.cos(5 * t**1.3), t + 0.05], axis=1)[:170]
    assert dtw(a, b) == pytest.approx(similaritymeasures.dtw(a, b)[0], abs=1e-9)


def test_dtw_of_identical_curves_is_zero() -> None:
    a = np.random.default_rng(0).normal(size=(50, 3))
    assert dtw(a, a) == 0.0


def test_dtw_equals_similaritymeasures_for_1000_points() -> None:
    """Long anti-diagonals of unequal length (its speed is `pih bench`'s business, not a test's)."""
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(1000, 3)), rng.normal(size=(300, 3))
    assert dtw(a, b) == pytest.approx(similaritymeasures.dtw(a, b)[0], rel=1e-12)


@pytest.mark.parametrize(
    "a, b",
    [
        (np.zeros((5,)), np.zeros((5, 2))),
        (np.zeros((0, 2)), np.zeros((5, 2))),
        (np.zeros((5, 2)), np.zeros((5, 3))),
        (np.full((5, 2), np.nan), np.zeros((5, 2))),
        (np.zeros((5, 2)), [["a", "b"]]),
    ],
)
def test_dtw_rejects_bad_input(a, b) -> None:
    with pytest.raises(RFlowError):
        dtw(a, b)


def test_rmse_of_constant_offset() -> None:
    a = np.zeros((10, 2))
    assert rmse(a, a + [3.0, 4.0]) == pytest.approx(5.0)


def test_rmse_rejects_different_lengths() -> None:
    with pytest.raises(RFlowError):
        rmse(np.zeros((10, 2)), np.zeros((9, 2)))


def test_final_error_uses_last_points() -> None:
    a = np.zeros((10, 2))
    b = np.ones((7, 2))
    b[-1] = [0.0, 2.0]
    assert final_error(a, b) == pytest.approx(2.0)


def test_log_euclidean_distances_match_manifold_function() -> None:
    rng = np.random.default_rng(2)
    s = spd.exp_map(spd.mandel_inverse(rng.normal(size=(6, 3))), np.eye(2))
    s_hat = spd.exp_map(spd.mandel_inverse(rng.normal(size=(6, 3))), np.eye(2))
    expected = [np.linalg.norm(spd.logm(x) - spd.logm(y)) for x, y in zip(s, s_hat)]
    np.testing.assert_allclose(log_euclidean_distances(s, s_hat), expected, atol=1e-12)


def test_quaternion_distances_are_twice_the_rotation_log() -> None:
    q = sphere.exp_map(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]), np.array([1.0, 0.0, 0.0, 0.0]))
    q_hat = sphere.exp_map(np.array([[0.1, 0.0, 0.0], [0.0, -0.3, 0.0]]), np.array([1.0, 0.0, 0.0, 0.0]))
    np.testing.assert_allclose(quaternion_distances(q, q_hat), [0.2, 0.6], atol=1e-12)


def test_manifold_distances_rejects_unknown_manifold() -> None:
    with pytest.raises(RFlowError):
        manifold_distances("euclidean", np.zeros((3, 2)), np.zeros((3, 2)))


def test_manifold_distances_rejects_length_mismatch() -> None:
    q = np.tile([1.0, 0.0, 0.0, 0.0], (4, 1))
    with pytest.raises(RFlowError):
        manifold_distances("sphere", q, q[:3])
