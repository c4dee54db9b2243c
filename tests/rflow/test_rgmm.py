"""Tests of rflow.rgmm: Riemannian EM and GMR on time x manifold, on synthetic data with a known answer."""

import numpy as np
import pytest

from rflow.errors import RFlowError
from rflow.manifolds import get_manifold
from rflow.rgmm import RGMMConfig, fit_mixture, fit_rgmm, select_mixture, weighted_mean

GOALS = {"sphere": np.array([0.6, 0.0, 0.8, 0.0]), "spd": np.array([[2.0, 0.5], [0.5, 1.0]])}


def _geodesic(manifold: str, m: int, angle: float, end: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A geodesic Exp_g(s w) with s linear in time from `angle` down to `end`: (times, points)."""
    man = get_manifold(manifold)
    w = np.array([0.6, -0.48, 0.64])  # unit tangent direction
    s = np.linspace(angle, end, m)
    return np.linspace(0.0, 1.0, m), np.asarray(man.exp(s[:, None] * w, GOALS[manifold]))


@pytest.mark.parametrize("manifold", ["sphere", "spd"])
def test_weighted_mean_of_symmetric_points_is_their_centre(manifold: str) -> None:
    man = get_manifold(manifold)
    centre = GOALS[manifold]
    v = np.array([[0.3, 0.1, -0.2], [-0.3, -0.1, 0.2], [0.1, 0.4, 0.0], [-0.1, -0.4, 0.0]])
    points = np.asarray(man.exp(v, centre))  # symmetric about the centre in its tangent space
    start = points[:1]
    mean = weighted_mean(man, points, np.ones((1, 4)), start, iterations=50, tolerance=1e-13)
    assert float(man.distance(mean[0], centre)) < 1e-8


@pytest.mark.parametrize("manifold, end", [("sphere", -2.5), ("spd", -2.0)])
def test_gmr_reproduces_a_long_geodesic(manifold: str, end: float) -> None:
    # Along Exp_g(s w) every Log_{mu_k} is linear in s, so each component predicts the path exactly up to the
    # covariance regularisation. On S^3 the path spans 5.5 rad: from its end, its start lies beyond the cut
    # locus (pi), so a GMM in one tangent space (at the goal or the end) wraps and cannot follow it.
    times, points = _geodesic(manifold, 200, angle=3.0 if manifold == "sphere" else 2.0, end=end)
    demos = np.stack([points, points])
    model = fit_rgmm(demos, manifold, dt=times[1], config=RGMMConfig(components=(4,)))
    retrieved = model.generate(demos[:, 0], steps=199)
    man = get_manifold(manifold)
    assert retrieved.shape == demos.shape
    assert float(np.max(man.distance(retrieved, demos))) < 0.02


def test_bic_picks_two_components_for_two_separated_clusters() -> None:
    rng = np.random.default_rng(0)
    man = get_manifold("sphere")
    goal = GOALS["sphere"]
    centres = np.array([[0.5, 0.0, 0.0], [-0.2, 0.6, 0.1]])
    times = np.concatenate([rng.normal(0.0, 0.05, 150), rng.normal(1.0, 0.05, 150)])
    tangent = np.concatenate([centres[0] + 0.03 * rng.normal(size=(150, 3)),
                              centres[1] + 0.03 * rng.normal(size=(150, 3))])
    points = np.asarray(man.exp(tangent, goal))
    best = select_mixture("sphere", times, points, RGMMConfig(components=(1, 2, 3, 4, 5)))
    assert best.priors.size == 2
    order = np.argsort(best.times)
    np.testing.assert_allclose(best.times[order], [0.0, 1.0], atol=0.03)
    # each component's mean is the Frechet mean of its cluster, near the cluster's centre
    for k, c in zip(order, centres):
        assert float(man.distance(best.means[k], man.exp(c, goal))) < 0.02


def test_em_does_not_lower_the_likelihood_of_the_initial_bins() -> None:
    times, points = _geodesic("spd", 120, angle=1.0)
    one_step = fit_mixture("spd", times, points, 3, RGMMConfig(em_iterations=1))
    converged = fit_mixture("spd", times, points, 3, RGMMConfig(em_iterations=50))
    assert converged.log_likelihood >= one_step.log_likelihood - 1e-6


def test_same_trajectory_from_every_start() -> None:
    times, points = _geodesic("sphere", 50, angle=0.5)
    model = fit_rgmm(points[None], "sphere", dt=times[1], config=RGMMConfig(components=(2,)))
    starts = np.asarray(get_manifold("sphere").exp(np.array([[0.1, 0, 0], [0, 0.9, 0]]), GOALS["sphere"]))
    out = model.generate(starts, 49)
    np.testing.assert_array_equal(out[0], out[1])


def test_too_many_components_raise() -> None:
    times, points = _geodesic("sphere", 10, angle=0.5)
    with pytest.raises(RFlowError):
        fit_mixture("sphere", times, points, 6)


def test_bad_config_raises() -> None:
    with pytest.raises(RFlowError):
        RGMMConfig(components=())
