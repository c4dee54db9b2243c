"""R-GMM baseline (Calinon 2020, "Gaussian distributions on Riemannian manifolds for robotics", IEEE RAM):
a Gaussian mixture on time x manifold fitted by EM with the manifold's log/exp maps, and Gaussian mixture
regression (GMR) on time to retrieve one trajectory.

Each component k has a prior pi_k, a centre (tau_k, mu_k) in R x M and a covariance Sigma_k of the
(1 + D)-vector u_k(t, x) = [t - tau_k, Log_{mu_k}(x)] (D: the tangent dimension, 3 for S^3 and SPD(2)).

EM (`fit_mixture`):
    E-step   h_nk = pi_k N(u_k(t_n, x_n); 0, Sigma_k) / sum_j pi_j N(u_j(t_n, x_n); 0, Sigma_j)
    M-step   pi_k = sum_n h_nk / N,   tau_k = sum_n h_nk t_n / sum_n h_nk,
             mu_k <- Exp_{mu_k}( sum_n h_nk Log_{mu_k}(x_n) / sum_n h_nk )   (Gauss-Newton, repeated),
             Sigma_k = sum_n h_nk u_k u_k^T / sum_n h_nk + R,
with R = REG_FRACTION x diag(variance of the data per dimension), started from equal time bins.

Number of components (`RGMMConfig.components`): the K of the range with the lowest Bayesian information
criterion BIC = -2 log L + P ln N, P = (K - 1) + K ((1 + D) + (1 + D)(2 + D) / 2).

GMR (`RGMM.retrieve`): at time t, h_k(t) = pi_k N(t; tau_k, Sigma_k^tt) / sum_j ..., each component
predicts the point p_k(t) = Exp_{mu_k}(Sigma_k^xt / Sigma_k^tt (t - tau_k)), and the output is their
h-weighted Frechet mean, by Gauss-Newton x <- Exp_x(sum_k h_k(t) Log_x(p_k(t))). (Calinon's GMR iterates
the same fixed point with the components' covariances parallel-transported to x; the two agree to first
order in the spread of the p_k and coincide where one component dominates. Working with the p_k avoids a
parallel transport per manifold.)

As in the RiemannianFlow paper's comparison, the model regresses a time-indexed motion, so it reproduces
the same trajectory from every start point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rflow.errors import RFlowError
from rflow.manifolds import Manifold, get_manifold, prepare_demos

REG_FRACTION = 1e-4  # covariance regularisation as a fraction of the data's variance per dimension
_LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class RGMMConfig:
    """Settings of the R-GMM baseline.

    Attributes:
        components: candidate numbers of Gaussians; the one with the lowest BIC is kept.
        fit_points: points per demo used by EM, evenly subsampled (the first and last kept).
        em_iterations: EM iterations at most.
        em_tolerance: stop EM when the mean log-likelihood per point improves by less than this.
        gauss_newton_iterations: Gauss-Newton steps of each weighted mean per M-step (warm-started from the
            previous means) and of the GMR output.
        gauss_newton_tolerance: stop Gauss-Newton when the tangent update is shorter than this.
    """

    components: tuple[int, ...] = tuple(range(2, 13))
    fit_points: int = 200
    em_iterations: int = 100
    em_tolerance: float = 1e-4
    gauss_newton_iterations: int = 3
    gauss_newton_tolerance: float = 1e-9

    def __post_init__(self) -> None:
        if not self.components or min(self.components) < 1:
            raise RFlowError(f"components {self.components} must be a non-empty tuple of integers >= 1")
        if self.fit_points < 2 or self.em_iterations < 1 or self.gauss_newton_iterations < 1:
            raise RFlowError("fit_points must be >= 2, em_iterations and gauss_newton_iterations >= 1")
        if not (self.em_tolerance > 0 and self.gauss_newton_tolerance > 0):
            raise RFlowError("em_tolerance and gauss_newton_tolerance must be > 0")


@dataclass(frozen=True)
class Mixture:
    """A Gaussian mixture on R x M.

    Attributes:
        priors: (K,) pi_k, summing to 1.
        times: (K,) tau_k (s).
        means: (K, *point_shape) mu_k on the manifold.
        covariances: (K, 1 + D, 1 + D) Sigma_k of [t - tau_k, Log_{mu_k}(x)].
        log_likelihood: total log-likelihood of the fitted data.
        bic: Bayesian information criterion of the fit.
    """

    priors: np.ndarray
    times: np.ndarray
    means: np.ndarray
    covariances: np.ndarray
    log_likelihood: float
    bic: float


def weighted_mean(manifold: Manifold, points: np.ndarray, weights: np.ndarray, start: np.ndarray,
                  iterations: int = 10, tolerance: float = 1e-10) -> np.ndarray:
    """Weighted Frechet (Karcher) means by Gauss-Newton: mu <- Exp_mu(sum_n w_n Log_mu(x_n) / sum_n w_n).

    Args:
        manifold: the manifold.
        points: (N, *point_shape) data points.
        weights: (K, N) non-negative weights, one row per mean.
        start: (K, *point_shape) initial means.
        iterations: Gauss-Newton steps at most.
        tolerance: stop when every update is shorter than this (tangent norm).

    Returns:
        (K, *point_shape) means.
    """
    w = weights / np.maximum(weights.sum(axis=1, keepdims=True), 1e-300)
    mean = np.asarray(start, dtype=np.float64)
    for _ in range(iterations):
        tangent = np.asarray(manifold.log(points[None], mean[:, None]))  # (K, N, D)
        step = np.einsum("kn,knd->kd", w, tangent)
        mean = np.asarray(manifold.exp(step, mean))
        if float(np.linalg.norm(step, axis=-1).max()) < tolerance:
            break
    return mean


def _log_gaussian(u: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """log N(u; 0, Sigma_k) for u (K, N, d) and Sigma (K, d, d) -> (K, N)."""
    chol = np.linalg.cholesky(covariances)
    solved = np.linalg.solve(chol[:, None], u[..., None])[..., 0]  # L^-1 u
    log_det = 2.0 * np.log(np.diagonal(chol, axis1=-2, axis2=-1)).sum(-1)
    d = u.shape[-1]
    return -0.5 * ((solved ** 2).sum(-1) + log_det[:, None] + d * _LOG_2PI)


def _log_sum_exp(a: np.ndarray, axis: int) -> np.ndarray:
    top = a.max(axis=axis, keepdims=True)
    return (top + np.log(np.exp(a - top).sum(axis=axis, keepdims=True))).squeeze(axis)


def _offsets(manifold: Manifold, times: np.ndarray, points: np.ndarray, tau: np.ndarray,
             means: np.ndarray) -> np.ndarray:
    """u_k(t_n, x_n) = [t_n - tau_k, Log_{mu_k}(x_n)] -> (K, N, 1 + D)."""
    tangent = np.asarray(manifold.log(points[None], means[:, None]))
    dt = (times[None, :] - tau[:, None])[..., None]
    return np.concatenate([dt, tangent], axis=-1)


def fit_mixture(manifold: str | Manifold, times: npt.ArrayLike, points: npt.ArrayLike, components: int,
                config: RGMMConfig = RGMMConfig()) -> Mixture:
    """Fit a K-component Gaussian mixture on R x M by Riemannian EM (module docstring), from equal time bins.

    Args:
        manifold: "sphere", "spd" or "euclidean" (or a Manifold).
        times: (N,) times t_n.
        points: (N, *point_shape) points x_n on the manifold.
        components: K >= 1 (at most the number of distinct times).
        config: iteration limits and tolerances.

    Returns:
        The fitted mixture with its log-likelihood and BIC.

    Raises:
        RFlowError: bad shapes, points off the manifold, or K larger than the data supports.
    """
    man = get_manifold(manifold)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    x = np.asarray(man.check_points(points, "R-GMM points"), dtype=np.float64)
    n = t.size
    if x.shape[0] != n or x.ndim != 1 + man.point_ndim:
        raise RFlowError(f"R-GMM: {n} times but points of shape {x.shape}")
    if not 1 <= components <= n // 2:
        raise RFlowError(f"R-GMM: {components} components for {n} points (need 1 <= K <= N / 2)")
    k = components
    # equal time bins: each component starts as the Frechet mean and covariance of its bin
    order = np.argsort(t, kind="stable")
    bins = np.array_split(order, k)
    resp = np.zeros((k, n))
    for j, idx in enumerate(bins):
        resp[j, idx] = 1.0
    means = weighted_mean(man, x, resp, x[[idx[0] for idx in bins]], config.gauss_newton_iterations,
                          config.gauss_newton_tolerance)
    global_mean = weighted_mean(man, x, np.ones((1, n)), x[:1], config.gauss_newton_iterations,
                                config.gauss_newton_tolerance)
    spread = _offsets(man, t, x, np.array([t.mean()]), global_mean)[0]
    reg = REG_FRACTION * np.diag(np.maximum(spread.var(axis=0), 1e-12))
    previous = -np.inf
    log_lik = -np.inf
    for iteration in range(config.em_iterations + 1):
        # M-step (from the current responsibilities)
        mass = np.maximum(resp.sum(axis=1), 1e-300)
        priors = mass / n
        tau = resp @ t / mass
        means = weighted_mean(man, x, resp, means, config.gauss_newton_iterations, config.gauss_newton_tolerance)
        u = _offsets(man, t, x, tau, means)
        covariances = np.einsum("kn,kni,knj->kij", resp, u, u) / mass[:, None, None] + reg
        # E-step
        joint = np.log(np.maximum(priors, 1e-300))[:, None] + _log_gaussian(u, covariances)
        total = _log_sum_exp(joint, axis=0)
        log_lik = float(total.sum())
        resp = np.exp(joint - total[None])
        if log_lik - previous < config.em_tolerance * n or iteration == config.em_iterations:
            break
        previous = log_lik
    d = u.shape[-1]
    params = (k - 1) + k * (d + d * (d + 1) // 2)
    return Mixture(priors=priors, times=tau, means=means, covariances=covariances, log_likelihood=log_lik,
                   bic=-2.0 * log_lik + params * np.log(n))


def select_mixture(manifold: str | Manifold, times: npt.ArrayLike, points: npt.ArrayLike,
                   config: RGMMConfig = RGMMConfig()) -> Mixture:
    """The mixture with the lowest BIC over ``config.components`` (ties: fewer components).

    Raises:
        RFlowError: as `fit_mixture`, or no candidate K fits the data.
    """
    n = np.asarray(times).size
    candidates = [k for k in sorted(set(config.components)) if k <= n // 2]
    if not candidates:
        raise RFlowError(f"R-GMM: none of the component counts {config.components} fits {n} points")
    fits = [fit_mixture(manifold, times, points, k, config) for k in candidates]
    return min(fits, key=lambda m: m.bic)


@dataclass(frozen=True)
class RGMM:
    """A fitted R-GMM skill: the mixture and the time grid of the demonstrations.

    Attributes:
        manifold: rflow manifold name.
        mixture: the Gaussian mixture on time x manifold.
        dt: sampling time (s) of the demonstrations.
        config: the settings it was fitted with.
    """

    manifold: str
    mixture: Mixture
    dt: float
    config: RGMMConfig

    @property
    def components(self) -> int:
        """Number of Gaussians K."""
        return int(self.mixture.priors.size)

    def retrieve(self, times: npt.ArrayLike) -> np.ndarray:
        """GMR on time: the h-weighted Frechet mean of the components' conditional points (module docstring).

        Args:
            times: (T,) query times (s).

        Returns:
            (T, *point_shape) points on the manifold.
        """
        man = get_manifold(self.manifold)
        mix = self.mixture
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        var_t = mix.covariances[:, 0, 0]
        dt = t[None, :] - mix.times[:, None]  # (K, T)
        log_h = np.log(np.maximum(mix.priors, 1e-300))[:, None] - 0.5 * (dt ** 2 / var_t[:, None]
                                                                         + np.log(2 * np.pi * var_t)[:, None])
        h = np.exp(log_h - _log_sum_exp(log_h, axis=0)[None])  # (K, T)
        slope = mix.covariances[:, 1:, 0] / var_t[:, None]  # Sigma^xt / Sigma^tt, (K, D)
        predicted = np.asarray(man.exp(dt[..., None] * slope[:, None, :], mix.means[:, None]))  # (K, T, *pt)
        estimate = predicted[np.argmax(h, axis=0), np.arange(t.size)]  # (T, *pt): the dominant component's point
        for _ in range(self.config.gauss_newton_iterations):
            step = np.einsum("kt,ktd->td", h, np.asarray(man.log(predicted, estimate[None])))
            estimate = np.asarray(man.exp(step, estimate))
            if float(np.linalg.norm(step, axis=-1).max()) < self.config.gauss_newton_tolerance:
                break
        return estimate

    def generate(self, starts: npt.ArrayLike, steps: int) -> np.ndarray:
        """The retrieved trajectory at t = 0, dt, ..., steps dt, the same for every start.

        Args:
            starts: (B, *point_shape) start points (only their number is used: R-GMM is time-indexed).
            steps: steps after the first point (>= 0).

        Returns:
            (B, steps + 1, *point_shape) points.

        Raises:
            RFlowError: steps < 0 or starts of the wrong shape.
        """
        man = get_manifold(self.manifold)
        starts = np.asarray(man.check_points(starts, "starts"))
        if steps < 0 or starts.ndim != 1 + man.point_ndim:
            raise RFlowError(f"R-GMM: need steps >= 0 and a batch of start points, got {steps} and {starts.shape}")
        path = self.retrieve(self.dt * np.arange(steps + 1))
        return np.broadcast_to(path, (starts.shape[0],) + path.shape).copy()


def fit_rgmm(demos: npt.ArrayLike, manifold: str, dt: float, config: RGMMConfig = RGMMConfig()) -> RGMM:
    """Fit R-GMM to demonstrations: points (t_m = m dt, x_nm), subsampled to ``config.fit_points`` per demo.

    Args:
        demos: (N, M, *point_shape) trajectories on the manifold with a common sampling time.
        manifold: "sphere", "spd" or "euclidean".
        dt: sampling time (s).
        config: settings.

    Returns:
        The fitted model (K chosen by BIC).

    Raises:
        RFlowError: bad shapes, points off the manifold, dt <= 0.
    """
    man, data = prepare_demos(demos, manifold, dt, "R-GMM")
    n, m = data.shape[:2]
    keep = np.unique(np.round(np.linspace(0, m - 1, min(m, config.fit_points))).astype(int))
    times = np.tile(keep * dt, n)
    points = data[:, keep].reshape((n * keep.size,) + data.shape[2:])
    return RGMM(manifold=man.name, mixture=select_mixture(man, times, points, config), dt=float(dt), config=config)
