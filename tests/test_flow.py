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
