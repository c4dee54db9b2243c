"""`rflow.adam.FusedAdam` is torch.optim.Adam(fused=True) to the last bit, and training does not import
torch._dynamo (what it saves: the import, about 1.5 s per training process)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from rflow.adam import FusedAdam
from rflow.errors import RFlowError


def _net(seed: int) -> torch.nn.Module:
    torch.manual_seed(seed)
    return torch.nn.Sequential(torch.nn.Linear(3, 16), torch.nn.ReLU(), torch.nn.Linear(16, 2), torch.nn.Linear(2, 4))


def test_fused_adam_equals_torch_adam_bit_for_bit_with_a_changing_lr_and_a_parameter_without_gradient():
    ours, theirs = _net(0), _net(0)
    for net in (ours, theirs):
        net[3].weight.requires_grad_(True)  # the last layer stays out of the loss: its gradient is None
    a = FusedAdam(ours.parameters(), lr=1e-2)
    b = torch.optim.Adam(theirs.parameters(), lr=1e-2, fused=True)
    x = torch.randn(64, 3, generator=torch.Generator().manual_seed(1))
    for k in range(25):
        lr = 1e-2 * (0.5 + 0.5 * np.cos(np.pi * k / 25))
        a.lr = lr
        for group in b.param_groups:
            group["lr"] = lr
        for net, opt in ((ours, a), (theirs, b)):
            opt.zero_grad()
            loss = (net[:3](x) ** 2).sum() + net[0].bias.abs().sum()
            loss.backward()
            opt.step()
    for p, q in zip(ours.parameters(), theirs.parameters()):
        assert torch.equal(p, q)
    assert torch.equal(ours[3].weight, _net(0)[3].weight)  # never had a gradient: unchanged
    assert not torch.equal(ours[0].weight, _net(0)[0].weight)


def test_fused_adam_rejects_bad_hyperparameters():
    p = [torch.zeros(2, requires_grad=True)]
    for kwargs in ({"lr": 0.0}, {"lr": 1e-3, "betas": (1.0, 0.999)}, {"lr": 1e-3, "eps": 0.0}):
        with pytest.raises(RFlowError):
            FusedAdam(p, **kwargs)
    with pytest.raises(RFlowError):
        FusedAdam([], lr=1e-3)


def test_training_does_not_import_torch_dynamo():
    code = ("import sys, numpy as np\n"
            "from rflow.train import TrainConfig, fit\n"
            "from rflow.model import ModelConfig\n"
            "t = np.linspace(0, 1, 20)\n"
            "demos = np.stack([np.stack([1 - t, (1 - t) * s, 0 * t], -1) for s in (0.5, 1.0)])\n"
            "fit(demos, 'euclidean', 0.05, TrainConfig(model=ModelConfig(layers=2, width=8), epochs=1,\n"
            "    transitions_per_epoch=64, horizon=3), progress=False)\n"
            "print('torch._dynamo' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "False"
