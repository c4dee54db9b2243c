"""The compiled coupling passes (rflow.flow_kernel) equal the torch flow in float64, in blocks and one by one.

Random weights (std 0.3) amplify rounding through the layers, so equality is to 1e-10 relative here; a trained
model's 100 x 1000-step rollouts agree with the previous numpy export to ~3e-15.
"""

import numpy as np
import pytest
import torch

from rflow.model import ImitationFlow, ModelConfig, RiemannianFlow
from rflow.normalise import Normalisation

CONFIGS = [ModelConfig(layers=11, width=64, hidden_layers=1), ModelConfig(layers=4, width=16, hidden_layers=3),
           ModelConfig(layers=5, width=8, activation="tanh")]


@pytest.fixture(params=CONFIGS, ids=["paper", "deep", "tanh"])
def model(request):
    torch.manual_seed(1)
    norm = Normalisation(np.array([0.1, -0.2, 0.05, 0.0]), np.array([0.3, 0.2, 0.1, 0.5]))
    net = ImitationFlow(4, request.param, norm.goal)
    with torch.no_grad():
        for p in net.parameters():
            p.normal_(0.0, 0.3)
    return RiemannianFlow("euclidean", np.zeros(4), norm, 0.01, request.param, net)


@pytest.mark.parametrize("n", [1, 127, 128, 129, 300])  # partial, exact and several blocks
def test_forward_and_inverse_equal_torch_in_float64(model, n):
    x = np.random.default_rng(n).normal(size=(n, 4))
    with torch.no_grad():
        p_torch = model.network.observe(torch.as_tensor(x))[0].numpy()
        q_torch = model.network.latent(torch.as_tensor(x))[0].numpy()
    np.testing.assert_allclose(model.inference.forward(x), p_torch, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(model.inference.inverse(x), q_torch, rtol=1e-10, atol=1e-10)


def test_batch_passes_leave_their_input_unchanged(model):
    x = np.random.default_rng(0).normal(size=(70, 4))
    before = x.copy()
    model.inference.forward(x)
    model.inference.inverse(x)
    np.testing.assert_array_equal(x, before)


def test_single_step_equals_batch_step(model):
    x = np.random.default_rng(2).normal(size=(5, 4))
    batch = model.inference.step(x, 0.05)
    single = np.array([model.inference.step_single(row, 0.05) for row in x])
    np.testing.assert_allclose(single, batch, rtol=1e-10, atol=1e-10)


def test_parallel_pass_of_a_large_batch_equals_the_serial_pass(model):
    net = model.inference
    x = np.random.default_rng(3).normal(size=(net.PARALLEL_MIN_POINTS + 37, 4))
    whole = net.forward(x)  # all cores
    halves = np.vstack([net.forward(x[: x.shape[0] // 2]), net.forward(x[x.shape[0] // 2 :])])  # one core each
    np.testing.assert_array_equal(whole, halves)


@pytest.mark.parametrize("clamp", [0.5, 2.0, 9.0, -2.0])  # several halvings of the exp; -c: the inverse pass
def test_block_exp_of_clamped_tanh_equals_libm(clamp):
    from rflow.flow_kernel import BLOCK_POINTS, _exp_clamped_tanh, _halvings

    rng = np.random.default_rng(4)
    u = np.concatenate([[0.0, -0.0, 1e-300, -1e-9, 19.99, 20.0, -25.0, 1e6], rng.normal(0.0, 3.0, BLOCK_POINTS - 8)])
    out = np.empty(BLOCK_POINTS)
    _exp_clamped_tanh(u, out, clamp, _halvings(abs(clamp)))
    np.testing.assert_allclose(out, np.exp(clamp * np.tanh(u)), rtol=1e-14, atol=0.0)
