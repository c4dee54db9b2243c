"""The diffeomorphism b_theta of ImitationFlow: a normalizing flow of affine coupling layers.

Each layer keeps a conditioner set a of coordinates and transforms the others (b) with a scale and shift
computed by one MLP from x_a (the MLP has 2 D outputs: raw log-scales and shifts):
    y_a = x_a,   y_b = x_b * exp(s(x_a)) + t(x_a),   s = c tanh(s_raw / c)   (soft-clamped, |s| < c),
    log|det dy/dx| = sum_b s_b.
The conditioner sets rotate from layer to layer (see `coupling_masks`) so that every coordinate is
transformed and conditions the others, also for D = 3. The last linear layer of every MLP starts at zero,
so a fresh flow is the identity. Direction: `forward` maps latent q to observation p, `inverse` back.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional

from rflow.errors import RFlowError

ACTIVATIONS = {"relu": nn.ReLU, "tanh": nn.Tanh}
_FUNCTIONS = {"relu": torch.relu, "tanh": torch.tanh}  # what each ACTIVATIONS module computes


def coupling_masks(dim: int, layers: int) -> torch.Tensor:
    """Conditioner masks (layers, dim), 1 for the coordinates a layer conditions on, 0 for those it moves.

    Layer i conditions on n_i consecutive coordinates (cyclically) starting at i mod dim, with n_i = floor(D/2)
    for even i and ceil(D/2) for odd i; for D = 3: {0}, {1,2}, {2}, {0,1}, {1}, {2,0}, ...

    Raises:
        RFlowError: dim < 2 (a coupling layer needs two coordinates) or layers < 1.
    """
    if dim < 2:
        raise RFlowError(f"flow dimension {dim} < 2: affine coupling needs at least two coordinates")
    if layers < 1:
        raise RFlowError(f"number of coupling layers {layers} < 1")
    masks = torch.zeros(layers, dim)
    for i in range(layers):
        n_a = dim // 2 if i % 2 == 0 else dim - dim // 2
        for k in range(n_a):
            masks[i, (i + k) % dim] = 1.0
    return masks


class AffineCoupling(nn.Module):
    """One affine coupling layer with a soft-clamped log-scale (see module docstring)."""

    def __init__(self, mask: torch.Tensor, width: int, hidden_layers: int, activation: str, log_scale_clamp: float):
        super().__init__()
        dim = int(mask.numel())
        if activation not in ACTIVATIONS:
            raise RFlowError(f"unknown activation {activation!r}; expected one of {sorted(ACTIVATIONS)}")
        if width < 1 or hidden_layers < 1:
            raise RFlowError(f"MLP width {width} and hidden layers {hidden_layers} must be >= 1")
        if not log_scale_clamp > 0:
            raise RFlowError(f"log_scale_clamp {log_scale_clamp} must be > 0")
        self.register_buffer("mask", mask.clone())
        self.register_buffer("free", 1.0 - mask, persistent=False)  # the coordinates the layer moves
        self.log_scale_clamp = float(log_scale_clamp)
        self._clamp_free: dict[tuple[torch.dtype, torch.device], torch.Tensor] = {}  # c free, `scale_shift`
        self.activation = activation
        act = ACTIVATIONS[activation]
        mods: list[nn.Module] = [nn.Linear(dim, width), act()]
        for _ in range(hidden_layers - 1):
            mods += [nn.Linear(width, width), act()]
        last = nn.Linear(width, 2 * dim)
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)
        mods.append(last)
        self.net = nn.Sequential(*mods)

    def scale_shift(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Log-scale s and shift t (both zero on the conditioner coordinates) from x_a.

        The MLP's layers are applied as functions of their parameters: the operations of calling the modules,
        without a module call's Python per layer, which at these sizes is a large part of a training step."""
        modules = self.net
        activation = _FUNCTIONS[self.activation]
        h = x * self.mask
        for i in range(0, len(modules) - 1, 2):
            h = activation(functional.linear(h, modules[i].weight, modules[i].bias))
        out = functional.linear(h, modules[-1].weight, modules[-1].bias)
        raw, shift = out.chunk(2, dim=-1)
        c = self.log_scale_clamp
        clamp_free = self._clamp_free.get((x.dtype, x.device))
        if clamp_free is None:  # c rounded to x's dtype, as a Python float times a tensor is
            clamp_free = self._clamp_free[(x.dtype, x.device)] = self.free.to(x.dtype) * c
        # tanh(raw / c) * (c free) = c tanh(raw / c) free bit for bit: free is 0 or 1
        return torch.tanh(raw / c) * clamp_free, shift * self.free

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """y = x * exp(s) + t; returns (y, log|det dy/dx|)."""
        s, t = self.scale_shift(x)
        return x * torch.exp(s) + t, s.sum(-1)

    def inverse(self, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x = (y - t) * exp(-s); returns (x, log|det dx/dy|)."""
        s, t = self.scale_shift(y)
        minus_s = -s  # sum(-s) = -sum(s) exactly (rounding is symmetric), one negation for both
        return (y - t) * torch.exp(minus_s), minus_s.sum(-1)


class CouplingFlow(nn.Module):
    """b_theta: a stack of `AffineCoupling` layers with rotating conditioner sets.

    Args:
        dim: dimension D of the tangent space (>= 2).
        layers: number of coupling layers (paper: 10-11).
        width: hidden units of each MLP.
        hidden_layers: hidden layers of each MLP.
        activation: "relu" (paper) or "tanh".
        log_scale_clamp: c of the soft clamp s = c tanh(s_raw / c).

    Raises:
        RFlowError: invalid sizes or activation.
    """

    def __init__(
        self,
        dim: int,
        layers: int = 11,
        width: int = 64,
        hidden_layers: int = 2,
        activation: str = "relu",
        log_scale_clamp: float = 2.0,
    ):
        super().__init__()
        self.dim = int(dim)
        masks = coupling_masks(self.dim, layers)
        self.layers = nn.ModuleList(
            AffineCoupling(m, width, hidden_layers, activation, log_scale_clamp) for m in masks
        )

    def _check(self, x: torch.Tensor, name: str) -> None:
        if x.ndim < 1 or x.shape[-1] != self.dim:
            raise RFlowError(f"{name} has shape {tuple(x.shape)}, expected (..., {self.dim})")

    def forward(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """p = b(q) for latent points (..., D); returns (p, log|det dp/dq|)."""
        self._check(q, "latent state")
        logdet = None
        for layer in self.layers:
            q, ld = layer(q)
            logdet = ld if logdet is None else logdet + ld  # 0 + ld = ld: no zeros to start from
        return q, logdet

    def inverse(self, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """q = b^-1(p) for observations (..., D); returns (q, log|det dq/dp|)."""
        self._check(p, "observation")
        logdet = None
        for layer in reversed(self.layers):
            p, ld = layer.inverse(p)
            logdet = ld if logdet is None else logdet + ld
        return p, logdet
