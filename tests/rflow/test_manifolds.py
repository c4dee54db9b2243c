"""The manifold registry of rflow.manifolds and the Euclidean maps."""

import numpy as np
import pytest

from rflow.errors import RFlowError
from rflow.manifolds import MANIFOLDS, euclidean, get_manifold, sphere, spd


def test_registry_names():
    assert set(MANIFOLDS) == {"euclidean", "sphere", "spd", "spd_normal"}


def test_unknown_manifold_raises():
    with pytest.raises(RFlowError, match="unknown manifold 'torus'"):
        get_manifold("torus")


def test_euclidean_maps():
    g = np.array([0.5, -0.1, 0.2])
    x = np.array([[1.0, 2.0, 3.0]])
    assert np.allclose(euclidean.log_map(x, g), x - g)
    assert np.allclose(euclidean.exp_map(x - g, g), x)


@pytest.mark.parametrize(
    "name, point, goal",
    [
        ("euclidean", np.array([1.0, 2.0, 3.0]), np.array([0.0, 1.0, 0.0])),
        ("sphere", sphere.exp_map(np.array([0.3, -0.2, 0.1]), np.array([0.0, 1.0, 0, 0])), np.array([0.0, 1.0, 0, 0])),
        ("spd", spd.exp_map(np.array([[0.2, 0.1], [0.1, -0.3]]), 2 * np.eye(2)), 2 * np.eye(2)),
    ],
)
def test_flat_tangent_round_trip(name, point, goal):
    m = get_manifold(name)
    v = m.log(point, goal)
    assert v.shape == (m.tangent_dim(goal.shape),)
    assert np.allclose(m.exp(v, goal), point)


def test_spd_tangent_is_the_mandel_vector():
    g = 100 * np.eye(2)
    v = np.array([3.0, -4.0, 5.0])
    assert np.allclose(get_manifold("spd").log(spd.exp_map(spd.mandel_inverse(v), g), g), v)


def test_sphere_prepare_puts_all_ends_on_one_hemisphere():
    g = np.array([0.0, 0.0, 1.0, 0.0])
    path = sphere.exp_map(np.linspace(1, 0, 20)[:, None] * np.array([0.4, 0.1, -0.2]), g)
    demos = np.stack([path, -path])
    prepared = get_manifold("sphere").prepare(demos)
    assert np.allclose(prepared[0, -1], prepared[1, -1])


@pytest.mark.parametrize("name, tangent, goal", [
    ("sphere", [1e155, 1e155, 0.0], [1.0, 0.0, 0.0, 0.0]),
    ("spd_normal", [800.0, 800.0, 800.0, 0.0, 0.0, 0.0], np.eye(3)),
])
def test_an_exponential_map_that_overflows_is_refused_not_nan(name, tangent, goal) -> None:
    import warnings

    from rflow.errors import RFlowError
    from rflow.manifolds import get_manifold

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # NumPy's overflow warnings on the way
        with pytest.raises(RFlowError, match="overflowed"):
            get_manifold(name).exp(np.asarray(tangent), np.asarray(goal, dtype=float))
