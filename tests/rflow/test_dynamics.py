"""Latent stable dynamics of rflow.dynamics: stability by construction and the exact discretisation."""

import numpy as np
import scipy.linalg
import scipy.stats
import torch

from rflow.dynamics import StableLinearDynamics


def randomised(dim: int, scale: float, seed: int) -> StableLinearDynamics:
    torch.manual_seed(seed)
    dyn = StableLinearDynamics(dim, min_rate=0.1).double()
    with torch.no_grad():
        for p in dyn.parameters():
            p.normal_(0.0, scale)
    return dyn


def test_every_eigenvalue_has_negative_real_part_for_any_parameters():
    worst = -np.inf
    for seed in range(300):
        for dim, scale in ((2, 1.0), (3, 30.0), (6, 1000.0)):
            v = randomised(dim, scale, seed).drift_matrix().detach().numpy()
            worst = max(worst, np.linalg.eigvals(v).real.max())
    assert worst < 0


def test_symmetric_part_is_bounded_by_min_rate():
    v = randomised(3, 5.0, 1).drift_matrix().detach().numpy()
    assert np.linalg.eigvalsh(v + v.T).max() <= -2 * 0.1 + 1e-9


def test_transition_mean_is_the_matrix_exponential():
    dyn = randomised(3, 1.0, 2)
    phi, _ = dyn.transition(torch.tensor([0.05, 0.7], dtype=torch.float64))
    v = dyn.drift_matrix().detach().numpy()
    assert np.allclose(phi[1].detach().numpy(), scipy.linalg.expm(0.7 * v), atol=1e-7)


def test_transition_covariance_solves_the_lyapunov_equation():
    dyn = randomised(3, 1.0, 3)
    tau = 0.4
    _, sigma = dyn.transition(torch.tensor([tau], dtype=torch.float64))
    v = dyn.drift_matrix().detach().numpy()
    q = np.diag(dyn.noise_std().detach().numpy() ** 2)
    stationary = scipy.linalg.solve_continuous_lyapunov(v, -q)
    phi = scipy.linalg.expm(tau * v)
    assert np.allclose(sigma[0].detach().numpy(), stationary - phi @ stationary @ phi.T, atol=1e-7)


def test_log_prob_is_the_gaussian_density():
    dyn = randomised(3, 0.5, 4)
    phi, sigma = dyn.transition(torch.tensor([0.3], dtype=torch.float64))
    q0 = torch.tensor([[0.2, -0.1, 0.4]], dtype=torch.float64)
    q1 = torch.tensor([[0.1, 0.0, 0.3]], dtype=torch.float64)
    got = dyn.log_prob(q0, q1, phi, sigma).item()
    mean = (phi[0] @ q0[0]).detach().numpy()
    assert np.isclose(got, scipy.stats.multivariate_normal(mean, sigma[0].detach().numpy()).logpdf(q1[0].numpy()))


def test_float32_transitions_stay_positive_definite_over_long_horizons():
    # rates of 3-5 /s over 9 s: expm(-V tau) ~ e^40 inside the block exponential; float32 arithmetic there gave
    # an indefinite Sigma (min eigenvalue -3.7) and a failed Cholesky in training
    torch.manual_seed(0)
    dyn = StableLinearDynamics(12, 0.05, 3.0, 0.3)
    with torch.no_grad():
        dyn.skew.normal_(0.0, 0.5)
        dyn.tril.add_(0.3 * torch.randn_like(dyn.tril))
    dyn = dyn.float()
    phi, sigma = dyn.transition(torch.linspace(0.1, 9.0, 30))
    assert sigma.dtype == torch.float32 and phi.dtype == torch.float32
    torch.linalg.cholesky(sigma)  # raises if not positive definite
    reference = dyn.double().transition(torch.linspace(0.1, 9.0, 30, dtype=torch.float64))[1]
    assert torch.allclose(sigma.double(), reference, rtol=1e-4, atol=1e-6)
