"""Stable latent dynamics of ImitationFlow: the linear SDE dq = V q dt + F dbeta.

V is stable BY CONSTRUCTION for every parameter value:
    V = -(L L^T + eps I) + (S - S^T),   L lower-triangular, S arbitrary, eps = min_rate > 0,
so V + V^T = -2 (L L^T + eps I) < 0, hence d||q||^2/dt = q^T (V + V^T) q <= -2 eps ||q||^2 and every
eigenvalue of V has real part <= -eps. F = diag(exp(log_noise)) is the learned diffusion.

Exact discretisation over a time tau = h dt (Van Loan 1978):
    q(t + tau) | q(t) ~ N(Phi q(t), Sigma),   Phi = expm(V tau),   Sigma = int_0^tau e^{Vs} F F^T e^{V^T s} ds,
with expm([[-V, F F^T], [0, V^T]] tau) = [[., X], [0, Phi^T]] and Sigma = Phi X.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from rflow.errors import RFlowError

LOG_2PI = math.log(2.0 * math.pi)


class StableLinearDynamics(nn.Module):
    """dq = V q dt + F dbeta with Re(eig V) <= -min_rate for all parameters (see module docstring).

    Args:
        dim: latent dimension D.
        min_rate: eps, the slowest allowed convergence rate (1/s), > 0.
        init_rate: V starts as -init_rate I (>= min_rate).
        init_noise: F starts as init_noise I (> 0).

    Raises:
        RFlowError: non-positive rates or noise, dim < 1.
    """

    def __init__(self, dim: int, min_rate: float = 0.1, init_rate: float = 1.0, init_noise: float = 0.5):
        super().__init__()
        if dim < 1:
            raise RFlowError(f"latent dimension {dim} < 1")
        if not min_rate > 0 or not init_rate >= min_rate:
            raise RFlowError(f"need 0 < min_rate <= init_rate, got min_rate={min_rate}, init_rate={init_rate}")
        if not init_noise > 0:
            raise RFlowError(f"init_noise {init_noise} must be > 0")
        self.dim = int(dim)
        self.min_rate = float(min_rate)
        rows, cols = torch.tril_indices(dim, dim)
        self.register_buffer("tril_rows", rows)
        self.register_buffer("tril_cols", cols)
        init_l = torch.zeros(rows.numel())
        init_l[rows == cols] = math.sqrt(init_rate - min_rate)
        self.tril = nn.Parameter(init_l)
        self.skew = nn.Parameter(torch.zeros(dim, dim))
        self.log_noise = nn.Parameter(torch.full((dim,), math.log(init_noise)))

    def drift_matrix(self) -> torch.Tensor:
        """V = -(L L^T + eps I) + (S - S^T), (D, D)."""
        lower = self.tril.new_zeros(self.dim, self.dim)
        lower = lower.index_put((self.tril_rows, self.tril_cols), self.tril)
        eye = torch.eye(self.dim, dtype=lower.dtype, device=lower.device)
        return -(lower @ lower.T + self.min_rate * eye) + (self.skew - self.skew.T)

    def noise_std(self) -> torch.Tensor:
        """Diagonal of F, (D,)."""
        return torch.exp(self.log_noise)

    def transition(self, tau: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Exact transition over times ``tau`` (K,) in seconds: Phi (K, D, D) and Sigma (K, D, D), in the
        parameters' dtype.

        Computed in float64 whatever the parameters' dtype: the block exponential holds expm(-V tau), which
        grows like exp(rate tau), and Sigma = Phi X cancels it; in float32 a latent rate of 3/s over a 9 s
        horizon (e^27) already left Sigma indefinite (a 12-D pose + stiffness model, rflow.skill_io).
        """
        v = self.drift_matrix()
        d = self.dim
        v64 = v.double()
        q = torch.diag(self.noise_std().double() ** 2)
        block = v64.new_zeros(2 * d, 2 * d)
        block[:d, :d] = -v64
        block[:d, d:] = q
        block[d:, d:] = v64.T
        big = torch.linalg.matrix_exp(tau.reshape(-1, 1, 1).double() * block)
        phi = big[:, d:, d:].transpose(-1, -2)
        sigma = phi @ big[:, :d, d:]
        return phi.to(v.dtype), (0.5 * (sigma + sigma.transpose(-1, -2))).to(v.dtype)

    def log_prob(self, q0: torch.Tensor, q1: torch.Tensor, phi: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        """log N(q1; Phi q0, Sigma) for pairs (B, D) with per-pair Phi, Sigma (B, D, D) -> (B,)."""
        mean = (phi @ q0.unsqueeze(-1)).squeeze(-1)
        chol = torch.linalg.cholesky(sigma)
        white = torch.linalg.solve_triangular(chol, (q1 - mean).unsqueeze(-1), upper=False).squeeze(-1)
        half_logdet = torch.log(torch.diagonal(chol, dim1=-2, dim2=-1)).sum(-1)
        return -0.5 * (white**2).sum(-1) - half_logdet - 0.5 * self.dim * LOG_2PI
