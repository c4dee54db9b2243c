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


def test_early_stopping_stops_once_the_validation_loss_stops_improving_and_keeps_the_best_weights(monkeypatch):
    """patience=2: the validation losses below have their best at epoch 3, epochs 4 and 5 do not beat it, so training
    stops after epoch 5 (of 20) and returns the weights of epoch 3, not those of the last epoch."""
    scripted = [5.0, 4.0, 3.0, 3.5, 3.2, 1.0, 1.0]  # epochs 6 and 7 would improve: they must never run
    original = ImitationFlow.transition_log_prob
    epochs_validated = {"n": 0}

    def scripted_validation(self, p0, p1, tau):
        out = original(self, p0, p1, tau)
        if torch.is_grad_enabled():  # a training step
            return out
        epochs_validated["n"] += 1
        return torch.full_like(out, -scripted[epochs_validated["n"] - 1] * self.dim)  # val loss = scripted value

    monkeypatch.setattr(ImitationFlow, "transition_log_prob", scripted_validation)
    snapshots = {}

    def keep(epoch, model, history):
        snapshots[epoch] = {k: v.clone() for k, v in model.network.state_dict().items()}

    config = TrainConfig(model=ModelConfig(layers=3, width=8), epochs=20, transitions_per_epoch=256, patience=2,
                         threads=1)
    model, history = fit(simple_demos(50), "euclidean", 0.01, config, progress=False, on_epoch=keep)
    assert history.val_loss == pytest.approx(scripted[:5])
    assert len(history.train_loss) == 5 and sorted(snapshots) == [1, 2, 3, 4, 5]
    final = model.network.state_dict()
    assert all(torch.equal(final[k], snapshots[3][k]) for k in final)
    assert not all(torch.equal(final[k], snapshots[5][k]) for k in final)


def test_without_patience_training_runs_every_epoch_and_keeps_the_last_weights(monkeypatch):
    config = TrainConfig(model=ModelConfig(layers=3, width=8), epochs=4, transitions_per_epoch=256, threads=1)
    snapshots = {}

    def keep(epoch, model, history):
        snapshots[epoch] = {k: v.clone() for k, v in model.network.state_dict().items()}

    model, history = fit(simple_demos(50), "euclidean", 0.01, config, progress=False, on_epoch=keep)
    assert len(history.val_loss) == 4
    final = model.network.state_dict()
    assert all(torch.equal(final[k], snapshots[4][k]) for k in final)


def test_patience_needs_a_validation_split_and_a_positive_count():
    with pytest.raises(RFlowError, match="val_fraction"):
        TrainConfig(patience=3, val_fraction=0.0)
    for bad in (0, -1, 2.5):
        with pytest.raises(RFlowError, match="patience"):
            TrainConfig(patience=bad)


def test_the_prior_in_the_likelihood_pass_is_the_separate_prior():
    """fit takes b^-1 of the prior's points in the likelihood's inverse pass: the same log-densities and the same prior
    value as `transition_log_prob` and `identity_prior` on the same points (up to float32 rounding)."""
    from rflow.train import prior_deviation, prior_points

    torch.manual_seed(0)
    network = ImitationFlow(3, ModelConfig(layers=3, width=8), np.array([0.3, -0.2, 0.1]))
    with torch.no_grad():
        for layer in network.flow.layers:  # a flow that is not the identity
            layer.net[-1].weight.normal_(0.0, 0.3)
    p0, p1 = torch.randn(64, 3), torch.randn(64, 3)
    tau = torch.linspace(0.01, 1.0, 64)
    box = torch.full((3,), 4.0)
    torch.manual_seed(1)
    z = prior_points(box, 32)
    with torch.no_grad():
        log_prob, q = network.transition_log_prob_and_latent(p0, p1, tau, z)
        torch.manual_seed(1)
        separate = identity_prior(network, box, 32)
        torch.testing.assert_close(log_prob, network.transition_log_prob(p0, p1, tau), rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(q, network.latent(z)[0], rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(prior_deviation(network, z, q), separate, rtol=1e-5, atol=1e-6)


def test_horizon_groups_past_their_bound_are_refused_and_small_batches_still_train() -> None:
    from rflow.errors import RFlowError
    from rflow.train import MAX_HORIZON_GROUPS, TrainConfig

    with pytest.raises(RFlowError, match="horizon_groups 1025 must be in 1..1024"):
        TrainConfig(horizon_groups=MAX_HORIZON_GROUPS + 1)
    TrainConfig(batch_size=4)  # fewer transitions than the default 8 horizon groups: allowed, as before
