"""Training (rflow.train): a small end-to-end fit, input checks, determinism, divergence handling."""

import numpy as np
import pytest
import torch

from rflow.errors import RFlowError
from rflow.generate import rollout
from rflow.manifolds import sphere
from rflow.model import ImitationFlow, ModelConfig
from rflow.train import TrainConfig, TrainHistory, fit, identity_prior

GOAL = np.array([0.5, -0.1, 0.2])
TINY = TrainConfig(model=ModelConfig(width=32), epochs=10, transitions_per_epoch=1024, horizon=100, threads=1)


def simple_demos(m: int = 200) -> np.ndarray:
    """Three curved 3-D demos (N=3, M=m) from different starts to GOAL."""
    s = np.linspace(0, 1, m)[None, :, None]
    starts = np.array([[0.3, 0.2, 0.1], [0.35, 0.1, 0.15], [0.25, 0.25, 0.05]])[:, None, :]
    return (1 - s) ** 2 * starts + np.sin(np.pi * s) * (1 - s) * np.array([0.0, 0.0, 0.08]) + GOAL


@pytest.fixture(scope="module")
def trained():
    demos = simple_demos()
    model, history = fit(demos, "euclidean", 0.01, TINY, progress=False)
    return demos, model, history


def test_config_defaults_follow_the_paper():
    c = TrainConfig()
    assert (c.model.layers, c.model.activation, c.optimizer, c.lr, c.batch_size) == (11, "relu", "adam", 1e-3, 128)


def test_loss_decreases(trained):
    _, _, history = trained
    assert len(history.train_loss) == TINY.epochs and len(history.val_loss) == TINY.epochs
    assert history.train_loss[-1] < history.train_loss[0] - 0.5
    assert history.val_loss[-1] < history.val_loss[0]


def test_generation_follows_the_demos(trained):
    demos, model, _ = trained
    gen = rollout(model, demos[:, 0], steps=demos.shape[1] - 1, xi=1e-6)
    extent = np.linalg.norm(demos[:, 0] - GOAL, axis=-1)
    error = np.linalg.norm(gen.points - demos, axis=-1).max(axis=1)
    assert np.all(error < 0.15 * extent)


def test_goal_is_the_shared_end(trained):
    _, model, _ = trained
    assert np.allclose(model.goal, GOAL)


def test_demos_without_a_shared_goal_raise():
    demos = simple_demos()
    demos[1] += np.linspace(0, 0.1, demos.shape[1])[:, None]
    with pytest.raises(RFlowError, match="demos do not share a goal"):
        fit(demos, "euclidean", 0.01, TINY, progress=False)


@pytest.mark.parametrize("shape", [(200, 3), (3, 1, 3), (3, 200, 4, 4)])
def test_bad_demo_shapes_raise(shape):
    with pytest.raises(RFlowError, match="demos have shape"):
        fit(np.zeros(shape), "euclidean", 0.01, TINY, progress=False)


def test_nan_demos_raise():
    demos = simple_demos()
    demos[0, 5, 1] = np.nan
    with pytest.raises(RFlowError, match="NaN"):
        fit(demos, "euclidean", 0.01, TINY, progress=False)


def test_training_is_deterministic():
    config = TrainConfig(model=ModelConfig(layers=3, width=8), epochs=1, transitions_per_epoch=256, threads=1)
    a, _ = fit(simple_demos(50), "euclidean", 0.01, config, progress=False)
    b, _ = fit(simple_demos(50), "euclidean", 0.01, config, progress=False)
    for (name, pa), pb in zip(a.network.state_dict().items(), b.network.state_dict().values()):
        assert torch.equal(pa, pb), name


def test_nan_loss_stops_and_keeps_the_last_good_weights(monkeypatch):
    original = ImitationFlow.transition_log_prob
    calls = {"n": 0}

    def poisoned(self, p0, p1, tau):
        calls["n"] += 1
        out = original(self, p0, p1, tau)
        return out * float("nan") if calls["n"] > 2 else out

    monkeypatch.setattr(ImitationFlow, "transition_log_prob", poisoned)
    config = TrainConfig(model=ModelConfig(layers=3, width=8), epochs=5, transitions_per_epoch=128, batch_size=128,
                         val_fraction=0.0)
    with pytest.raises(RFlowError, match="non-finite loss at epoch 3") as info:
        fit(simple_demos(50), "euclidean", 0.01, config, progress=False)
    assert len(info.value.history.train_loss) == 2
    assert all(torch.isfinite(p).all() for p in info.value.model.network.parameters())


def test_a_covariance_that_is_no_longer_positive_definite_is_a_divergence(monkeypatch):
    """High learning rates (as a hyperparameter search tries) can break the latent covariance's Cholesky factor:
    that must end training like a non-finite loss, with the last good weights, not crash the caller."""
    original = ImitationFlow.transition_log_prob
    calls = {"n": 0}

    def broken(self, p0, p1, tau):
        calls["n"] += 1
        if calls["n"] > 2:
            raise torch.linalg.LinAlgError("linalg.cholesky: the input is not positive-definite")
        return original(self, p0, p1, tau)

    monkeypatch.setattr(ImitationFlow, "transition_log_prob", broken)
    config = TrainConfig(model=ModelConfig(layers=3, width=8), epochs=5, transitions_per_epoch=128, batch_size=128,
                         val_fraction=0.0)
    with pytest.raises(RFlowError, match="diverged"):
        fit(simple_demos(50), "euclidean", 0.01, config, progress=False)


def test_quaternion_demos_with_sign_flips_train():
    g = np.array([0.022, 0.991, -0.125, 0.035])
    g /= np.linalg.norm(g)
    tangent = (simple_demos(60) - GOAL)  # (3, 60, 3), ends at 0
    q = sphere.exp_map(tangent, g)
    q[1, ::2] *= -1  # sign flips inside one demo
    q[2] *= -1  # a whole demo on the other hemisphere
    config = TrainConfig(model=ModelConfig(layers=3, width=8), epochs=1, transitions_per_epoch=128)
    model, _ = fit(q, "sphere", 0.01, config, progress=False)
    assert np.allclose(model.goal, g)
    assert np.allclose(model.to_tangent(q[0]), tangent[0], atol=1e-9)


def test_history_round_trip(tmp_path, trained):
    _, _, history = trained
    history.save(tmp_path / "h.json")
    assert TrainHistory.load(tmp_path / "h.json") == history


def test_bad_config_raises():
    with pytest.raises(RFlowError, match="optimizer"):
        TrainConfig(optimizer="lbfgs")  # sgd and rmsprop are valid: the paper's search space
    with pytest.raises(RFlowError, match="prior_weight"):
        TrainConfig(prior_weight=-1.0)
    with pytest.raises(RFlowError, match="prior_radius"):
        TrainConfig(prior_radius=0.0)


def test_identity_prior_vanishes_for_a_fresh_flow():
    """A fresh flow is the identity, so b^-1(z) = z - z_g exactly and the prior is 0."""
    torch.manual_seed(0)
    network = ImitationFlow(3, TINY.model, np.array([0.3, -0.2, 0.1]))
    with torch.no_grad():
        assert identity_prior(network, torch.full((3,), 4.0), 256).item() < 1e-12


def off_data_deviation(model, radius: float = 3.0, num: int = 2000) -> float:
    """RMS of b^-1(z) - (z - z_g) over points uniform in [-r, r]^D x the demos' normalised extent."""
    rng = np.random.default_rng(0)
    demos = model.normalise(model.to_tangent(simple_demos()))
    box = radius * np.abs(demos).max(axis=(0, 1))
    z = torch.as_tensor(rng.uniform(-1, 1, (num, box.size)) * box, dtype=torch.float32)
    network = model.network
    with torch.no_grad():
        q, _ = network.latent(z)
        return float(((q - (z - network.goal)) ** 2).sum(-1).mean().sqrt())


def test_identity_prior_keeps_the_flow_near_identity_off_the_demos(trained):
    """With the prior the latent coordinates off the demos stay much closer to the tangent coordinates,
    and the fit to the demos stays as good."""
    from dataclasses import replace

    demos, plain, _ = trained
    with_prior, history = fit(demos, "euclidean", 0.01, replace(TINY, prior_weight=1.0), progress=False)
    assert off_data_deviation(with_prior) < 0.5 * off_data_deviation(plain)
    gen = rollout(with_prior, demos[:, 0], steps=demos.shape[1] - 1, xi=1e-6)
    extent = np.linalg.norm(demos[:, 0] - GOAL, axis=-1)
    assert np.all(np.linalg.norm(gen.points - demos, axis=-1).max(axis=1) < 0.15 * extent)


def test_sampled_transitions_stay_inside_demos_and_split():
    from rflow.train import _sample, _split_starts

    rng = np.random.default_rng(0)
    held_out = _split_starts(3, 100, 0.2, rng)
    start, h = _sample(~held_out, 3, 100, batches=20, batch_size=64, horizon=500, groups=4, rng=rng)
    assert start.size > 0 and np.all(~held_out[start])
    assert np.all((h >= 1) & ((start % 100) + h <= 99))
    assert np.unique(h[:64]).size <= 4  # few distinct horizons per batch
