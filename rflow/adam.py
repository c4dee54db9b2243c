"""Adam (Kingma and Ba, 2015) on torch's fused CPU kernel, without `torch.optim`.

For every parameter p with gradient g, at step t (from 1) with learning rate lr:
    m <- b1 m + (1 - b1) g,   v <- b2 v + (1 - b2) g^2,
    p <- p - lr (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps).
`FusedAdam.step` hands all parameters to ``torch._fused_adam_``, the kernel `torch.optim.Adam(fused=True)` runs,
with the same state (m and v zero-initialised like the parameters, t a float32 scalar tensor) and arguments, so the
weights equal torch.optim's bit for bit (`tests/rflow/test_adam.py`). Why not torch.optim itself: constructing any
`torch.optim.Optimizer` imports torch._dynamo (about 1.5 s of a training process's start, each time a training
process starts), and Adam is all that training the skill needs. The other optimizers of the search space
(`rflow.train.OPTIMIZERS`) still come from torch.optim.
"""

from __future__ import annotations

from typing import Iterable

import torch

from rflow.errors import RFlowError


class FusedAdam:
    """Adam over ``params`` (module docstring); ``lr`` may be changed between steps (the lr schedule).

    Args:
        params: the parameters (tensors with requires_grad).
        lr: learning rate (> 0).
        betas: (b1, b2), each in [0, 1).
        eps: the denominator's epsilon (> 0).

    Raises:
        RFlowError: no parameters, or hyperparameters out of range.
    """

    def __init__(self, params: Iterable[torch.Tensor], lr: float, betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8):
        self.params = list(params)
        if not self.params:
            raise RFlowError("FusedAdam needs at least one parameter")
        if not (lr > 0 and 0 <= betas[0] < 1 and 0 <= betas[1] < 1 and eps > 0):
            raise RFlowError(f"FusedAdam needs lr > 0, betas in [0, 1) and eps > 0, got {lr}, {betas}, {eps}")
        self.lr = float(lr)
        self.betas = (float(betas[0]), float(betas[1]))
        self.eps = float(eps)
        self._exp_avg = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self._exp_avg_sq = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self._step = [torch.zeros((), dtype=torch.float32, device=p.device) for p in self.params]

    def zero_grad(self) -> None:
        """Drop every parameter's gradient (set to None, as ``zero_grad(set_to_none=True)``)."""
        for p in self.params:
            p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One Adam update of the parameters that have a gradient (the others, and their state, stay)."""
        live = [i for i, p in enumerate(self.params) if p.grad is not None]
        if not live:
            return
        steps = [self._step[i] for i in live]
        torch._foreach_add_(steps, 1)
        torch._fused_adam_([self.params[i] for i in live], [self.params[i].grad for i in live],
                           [self._exp_avg[i] for i in live], [self._exp_avg_sq[i] for i in live], [], steps,
                           amsgrad=False, lr=self.lr, beta1=self.betas[0], beta2=self.betas[1], weight_decay=0.0,
                           eps=self.eps, maximize=False, grad_scale=None, found_inf=None)


__all__ = ["FusedAdam"]
