"""Affine coupling flow of rflow.flow: exact inverse, exact log-determinant, masks covering all coordinates."""

import pytest
import torch

from rflow.errors import RFlowError
from rflow.flow import CouplingFlow, coupling_masks


def random_flow(dim: int, activation: str = "relu", seed: int = 0) -> CouplingFlow:
    torch.manual_seed(seed)
    flow = CouplingFlow(dim, layers=11, width=16, activation=activation).double()
    with torch.no_grad():
        for p in flow.parameters():
            p.normal_(0.0, 0.5)
    return flow


@pytest.mark.parametrize("dim, activation", [(2, "relu"), (3, "relu"), (3, "tanh"), (4, "relu"), (6, "tanh")])
def test_inverse_undoes_forward(dim, activation):
    flow = random_flow(dim, activation)
    x = torch.randn(200, dim, dtype=torch.float64)
    y, logdet = flow(x)
    back, inv_logdet = flow.inverse(y)
    assert torch.allclose(back, x, atol=1e-5)
    assert torch.allclose(logdet, -inv_logdet, atol=1e-8)


def test_log_determinant_is_exact():
    flow = random_flow(3)
    x = torch.randn(3, dtype=torch.float64)
    jac = torch.autograd.functional.jacobian(lambda v: flow(v)[0], x)
    assert torch.isclose(flow(x)[1], torch.linalg.slogdet(jac)[1], atol=1e-8)


def test_fresh_flow_is_identity():
    flow = CouplingFlow(3).double()
    x = torch.randn(10, 3, dtype=torch.float64)
    y, logdet = flow(x)
    assert torch.equal(y, x) and torch.equal(logdet, torch.zeros(10, dtype=torch.float64))


@pytest.mark.parametrize("dim", [2, 3, 4, 5])
def test_every_coordinate_is_moved_and_conditions(dim):
    masks = coupling_masks(dim, 11)
    assert bool((masks == 0).any(0).all()), "a coordinate is never transformed"
    assert bool((masks == 1).any(0).all()), "a coordinate never conditions a layer"
    assert bool(((masks.sum(1) > 0) & (masks.sum(1) < dim)).all()), "a layer conditions on all or none"


def test_three_dims_condition_on_each_single_coordinate():
    masks = coupling_masks(3, 6)
    singles = {int(m.argmax()) for m in masks if m.sum() == 1}
    assert singles == {0, 1, 2}


def test_one_dimension_is_rejected():
    with pytest.raises(RFlowError, match="at least two"):
        CouplingFlow(1)


def test_wrong_input_width_is_rejected():
    with pytest.raises(RFlowError, match="expected"):
        CouplingFlow(3)(torch.zeros(4, 2))


def _module_scale_shift(layer, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The layer's log-scale and shift as its modules compute them (calling ``net``), the definition
    `AffineCoupling.scale_shift` must equal."""
    raw, shift = layer.net(x * layer.mask).chunk(2, dim=-1)
    free = 1.0 - layer.mask
    c = layer.log_scale_clamp
    return c * torch.tanh(raw / c) * free, shift * free


@pytest.mark.parametrize("activation", ["relu", "tanh"])
@pytest.mark.parametrize("hidden_layers", [1, 2])
@pytest.mark.parametrize("clamp", [0.5, 0.7])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_scale_shift_equals_the_modules_bit_for_bit(activation, hidden_layers, clamp, dtype):
    """The functional pass (no module calls, c free cached per dtype) is the modules' arithmetic, bit for bit, in
    both dtypes and for a clamp that float32 cannot hold (0.7), after the module changed dtype; and so are the
    layer's inverse and its log-determinant. A wrong layer index, a missed hidden layer or a clamp cached in
    the first dtype only would differ."""
    torch.manual_seed(3)
    flow = CouplingFlow(3, layers=2, width=16, hidden_layers=hidden_layers, activation=activation,
                        log_scale_clamp=clamp)
    with torch.no_grad():
        for p in flow.parameters():
            p.normal_(0.0, 0.8)  # not the identity
    x = torch.randn(50, 3, dtype=torch.float32)
    flow.layers[0].scale_shift(x)  # cache the float32 clamp first
    flow.to(dtype)
    x = x.to(dtype)
    for layer in flow.layers:
        s, t = layer.scale_shift(x)
        s_ref, t_ref = _module_scale_shift(layer, x)
        assert torch.equal(s, s_ref) and torch.equal(t, t_ref)
        y, ld = layer.inverse(x)
        assert torch.equal(y, (x - t_ref) * torch.exp(-s_ref)) and torch.equal(ld, -s_ref.sum(-1))
