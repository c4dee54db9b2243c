"""Tests of rflow.fdm: locally weighted translations, their inverse, the matching and the pulled-back system."""

import math

import numpy as np
import pytest

from rflow.errors import RFlowError
from rflow.fdm import FDMConfig, fit_fdm, match, translate, untranslate
from rflow.manifolds import get_manifold

GOAL = np.array([[3.0, 0.2], [0.2, 1.5]])


def test_untranslate_inverts_translate_under_the_bound() -> None:
    rng = np.random.default_rng(0)
    centre, v = np.array([0.2, -0.1, 0.3]), np.array([0.5, 0.4, -0.2])
    rho = 0.95 * math.sqrt(math.e / 2) / np.linalg.norm(v)
    x = rng.normal(size=(200, 3))
    np.testing.assert_allclose(untranslate(translate(x, centre, rho, v), centre, rho, v), x, atol=1e-12)


def test_matching_a_curve_makes_the_source_land_on_it() -> None:
    s = np.linspace(0.0, 1.0, 300)
    target = np.stack([np.sin(np.pi * s), 1.0 - s, 0.3 * np.sin(2 * np.pi * s)], axis=-1)  # ends at 0
    source = target[0] * np.exp(-4.0 * s)[:, None]
    before = np.abs(source - target).max()
    phi = match(source, target, FDMConfig(iterations=150))
    after = np.abs(phi(source) - target).max()
    assert after < 0.02 * before
    # every translation respects the diffeomorphism bound rho ||v|| < sqrt(e / 2)
    assert np.all(phi.rhos * np.linalg.norm(phi.translations, axis=1) < math.sqrt(math.e / 2))


def _demos_of_tangent(tangent: np.ndarray) -> np.ndarray:
    return np.asarray(get_manifold("spd").exp(tangent, GOAL))


def test_a_demo_that_is_the_linear_system_needs_no_translation_and_is_reproduced() -> None:
    # the source is the linear system from the mean start; a demo equal to it is matched with J = 0 and the
    # pulled-back system is the linear system itself, reproducing the demo exactly
    m, dt = 200, 0.01
    alpha = -math.log(1e-2) / ((m - 1) * dt)
    start = np.array([2.0, -1.0, 0.5])
    tangent = start * np.exp(-alpha * dt * np.arange(m))[:, None]
    tangent[-1] = 0.0  # end exactly at the goal: the one point off the linear system, by 1 % of the start
    demos = _demos_of_tangent(tangent)[None]
    model = fit_fdm(demos, "spd", dt, FDMConfig(tolerance=0.1))  # above that 0.07 (scaled units), below the rest
    assert model.phi.rhos.size == 0
    out = model.generate(demos[:, 0], m - 2)
    np.testing.assert_allclose(out[0], demos[0, :-1], atol=1e-9)


def test_generated_trajectories_start_at_the_start_and_converge_to_the_goal() -> None:
    s = np.linspace(0.0, 1.0, 200)[:, None]
    tangent = np.concatenate([(1 - s) * 2.0, np.sin(np.pi * s), (1 - s) ** 2], axis=-1)
    demos = np.stack([_demos_of_tangent(tangent), _demos_of_tangent(tangent * 1.1)])
    model = fit_fdm(demos, "spd", 0.01)
    starts = np.asarray(get_manifold("spd").exp(np.array([[2.0, 0.1, 1.0], [-1.0, 3.0, 0.5]]), GOAL))
    out = model.generate(starts, 5000)
    np.testing.assert_allclose(out[:, 0], starts, atol=1e-9)
    assert float(np.max(get_manifold("spd").distance(out[:, -1], GOAL))) < 1e-6


@pytest.mark.parametrize("config", [dict(beta=0.0), dict(iterations=-1), dict(tolerance=0.0)])
def test_bad_config_raises(config: dict) -> None:
    with pytest.raises(RFlowError):
        FDMConfig(**config)
