"""ImitationFlow with the exact goal, and RiemannianFlow persistence (rflow.model)."""

import numpy as np
import pytest
import torch

from rflow.errors import RFlowError
from rflow.model import ImitationFlow, ModelConfig, RiemannianFlow
from rflow.normalise import Normalisation


def random_model(manifold: str = "sphere", seed: int = 0) -> RiemannianFlow:
    torch.manual_seed(seed)
    norm = Normalisation(np.array([0.1, -0.2, 0.05]), np.array([0.3, 0.2, 0.1]))
    config = ModelConfig(layers=4, width=16)
    net = ImitationFlow(3, config, norm.goal)
    with torch.no_grad():
        for p in net.parameters():
            p.normal_(0.0, 0.3)
    goal = {"sphere": np.array([0.0, 1.0, 0.0, 0.0]), "euclidean": np.array([0.5, -0.1, 0.2])}[manifold]
    return RiemannianFlow(manifold, goal, norm, 0.01, config, net)


def test_latent_origin_maps_exactly_to_the_goal():
    model = random_model()
    with torch.no_grad():
        p, _ = model.network.observe(torch.zeros(1, 3, dtype=torch.float64))
    assert torch.allclose(p[0], torch.as_tensor(model.normalisation.goal), atol=1e-12)
    assert np.allclose(model.denormalise(p.numpy()), 0.0, atol=1e-12)


def test_latent_inverts_observe():
    model = random_model()
    x = torch.randn(20, 3, dtype=torch.float64)
    with torch.no_grad():
        q, _ = model.network.latent(x)
        back, _ = model.network.observe(q)
    assert torch.allclose(back, x, atol=1e-10)


def test_tangent_round_trip():
    model = random_model()
    points = model.from_tangent(np.array([[0.1, 0.2, -0.3], [0.0, 0.0, 0.0]]))
    assert np.allclose(model.to_tangent(points), [[0.1, 0.2, -0.3], [0, 0, 0]])
    assert np.allclose(points[1], model.goal)


def test_save_load_round_trip(tmp_path):
    model = random_model()
    model.save(tmp_path / "m")
    loaded = RiemannianFlow.load(tmp_path / "m")
    x = torch.randn(5, 3, dtype=torch.float64)
    with torch.no_grad():
        assert torch.equal(loaded.network.latent(x)[0], model.network.latent(x)[0])
    assert loaded.manifold.name == "sphere" and loaded.dt == model.dt and loaded.config == model.config
    assert np.array_equal(loaded.goal, model.goal)


def test_missing_model_raises(tmp_path):
    with pytest.raises(RFlowError, match="no model.json"):
        RiemannianFlow.load(tmp_path)


def test_corrupt_weights_raise(tmp_path):
    random_model().save(tmp_path)
    (tmp_path / "weights.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(RFlowError, match="corrupt .*weights.pt"):
        RiemannianFlow.load(tmp_path)


def test_corrupt_config_raises(tmp_path):
    random_model().save(tmp_path)
    (tmp_path / "model.json").write_text("{")
    with pytest.raises(RFlowError, match="corrupt .*model.json"):
        RiemannianFlow.load(tmp_path)


def test_weights_of_another_architecture_raise(tmp_path):
    random_model().save(tmp_path)
    text = (tmp_path / "model.json").read_text().replace('"width": 16', '"width": 8')
    (tmp_path / "model.json").write_text(text)
    with pytest.raises(RFlowError, match="does not fit"):
        RiemannianFlow.load(tmp_path)


def test_bad_config_raises():
    with pytest.raises(RFlowError, match="activation"):
        ModelConfig(activation="sigmoid")
