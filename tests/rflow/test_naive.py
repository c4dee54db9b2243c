"""Tests of rflow.naive: Euclidean features of manifold points, the projection back, a tiny training."""

import numpy as np
import pytest

from rflow.errors import RFlowError
from rflow.lasa import riemannian_lasa
from rflow.model import ModelConfig
from rflow.naive import fit_naive, to_features, to_points
from rflow.train import TrainConfig


def test_spd_features_are_mandel_vectors() -> None:
    s = np.array([[4.0, 1.0], [1.0, 3.0]])
    np.testing.assert_allclose(to_features(s, "spd"), [4.0, 3.0, np.sqrt(2.0)])


def test_projection_of_indefinite_matrix_is_spd() -> None:
    features = np.array([[1.0, 1.0, 3.0 * np.sqrt(2.0)], [-2.0, 0.5, 0.0]])  # eigenvalues 4, -2 and -2, 0.5
    assert np.linalg.eigvalsh(to_points(features, "spd")).min() > 0


def test_projection_keeps_spd_matrices() -> None:
    s = np.array([[4.0, 1.0], [1.0, 3.0]])
    np.testing.assert_allclose(to_points(to_features(s, "spd"), "spd"), s, atol=1e-12)


def test_quaternion_projection_is_unit_and_keeps_direction() -> None:
    q = to_points(np.array([[2.0, 0.0, 0.0, 0.0], [0.3, -0.4, 1.2, 0.0]]), "sphere")
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-15)
    np.testing.assert_allclose(q[1] * 1.3, [0.3, -0.4, 1.2, 0.0], atol=1e-12)


def test_zero_quaternion_vector_raises() -> None:
    with pytest.raises(RFlowError):
        to_points(np.zeros((2, 4)), "sphere")


def test_unknown_manifold_raises() -> None:
    with pytest.raises(RFlowError):
        to_features(np.zeros((2, 3)), "euclidean")


def test_non_unit_quaternion_features_raise() -> None:
    with pytest.raises(RFlowError):
        to_features(np.array([2.0, 0.0, 0.0, 0.0]), "sphere")


TINY = TrainConfig(model=ModelConfig(layers=2, width=8), epochs=1, transitions_per_epoch=128, horizon=3)


@pytest.mark.parametrize("manifold", ["sphere", "spd"])
def test_tiny_naive_model_generates_points_on_the_manifold(manifold: str) -> None:
    data = riemannian_lasa("Angle", manifold, n_points=30)
    model, _ = fit_naive(data.demos, manifold, data.dt, TINY, progress=False)
    generated = model.generate(data.demos[:, 0], 29)
    assert generated.shape == data.demos.shape
    if manifold == "sphere":
        np.testing.assert_allclose(np.linalg.norm(generated, axis=-1), 1.0, atol=1e-12)
    else:
        assert np.linalg.eigvalsh(generated).min() > 0
