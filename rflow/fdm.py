"""FDM baseline (Perrin and Schlehuber-Caissier 2016, "Fast diffeomorphic matching to learn globally
asymptotically stable nonlinear dynamical systems", Systems & Control Letters), in the tangent space at the
goal as the RiemannianFlow paper applies it.

Data: the demos are mapped to the tangent space at the goal, v = Log_g(x), scaled per dimension by their
standard deviation s (y = v / s: the goal stays at the origin), and averaged over the demos into one mean
demonstration Y_0..Y_{M-1} (ending at 0).

Source: the trajectory of the stable linear system  dx/dt = -alpha x  from Y_0, X_m = Y_0 exp(-alpha m dt),
a straight line to the origin, with alpha = -ln(SOURCE_END_RATIO) / ((M - 1) dt).

Matching: a diffeomorphism Phi = psi_J o ... o psi_1 of locally weighted translations
    psi_j(x) = x + exp(-rho_j^2 ||x - c_j||^2) v_j,
built greedily: at step j the source point X_m farthest from its target Y_m is the centre c_j, the
translation is v_j = beta (Y_m - X_m), and rho_j minimises sum_m ||psi_j(X_m) - Y_m||^2 over
0 < rho_j <= RHO_MARGIN sqrt(e / 2) / ||v_j||, the bound under which psi_j is a diffeomorphism
(||grad k|| ||v|| < 1 for the kernel k); then X <- psi_j(X).

Dynamics: the linear system pulled through Phi, with its equilibrium moved to x* = Phi^-1(0) so that the
goal is reached exactly: x(t) = x* + (x_0 - x*) exp(-alpha t) with x_0 = Phi^-1(y_0), y(t) = Phi(x(t)),
globally asymptotically stable at y = 0 (the goal) for any start. Each psi_j is inverted exactly along v_j:
x = y - s v_j with s the unique root in [0, 1] of s = exp(-rho_j^2 ||y - c_j - s v_j||^2) (bisection).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import minimize_scalar

from rflow.errors import RFlowError
from rflow.manifolds import get_manifold, prepare_demos
from rflow.train import shared_goal

SOURCE_END_RATIO = 1e-2  # the source line ends at 1 % of its start after the demo's duration
RHO_MARGIN = 0.9  # rho stays this fraction below the diffeomorphism bound sqrt(e/2) / ||v||
_BISECTION_STEPS = 60  # halvings of [0, 1] when inverting one translation (2^-60: machine precision)


@dataclass(frozen=True)
class FDMConfig:
    """Settings of the FDM baseline (J = 150, beta = 0.5 and the margin 0.9: the values usual with FDM).

    Attributes:
        iterations: translations J at most.
        beta: fraction of the largest residual each translation removes (0 < beta <= 1).
        tolerance: stop when every residual ||Phi(X_m) - Y_m|| is below this (scaled tangent units).
        goal_tolerance: demo ends may differ from their mean by this fraction of the demos' extent.
    """

    iterations: int = 150
    beta: float = 0.5
    tolerance: float = 1e-9
    goal_tolerance: float = 0.01

    def __post_init__(self) -> None:
        if self.iterations < 0 or not 0 < self.beta <= 1 or not self.tolerance > 0 or self.goal_tolerance < 0:
            raise RFlowError(f"FDM needs iterations >= 0, 0 < beta <= 1, tolerance > 0 and goal_tolerance >= 0, "
                             f"got {self.iterations}, {self.beta}, {self.tolerance}, {self.goal_tolerance}")


@dataclass(frozen=True)
class Diffeomorphism:
    """Phi = psi_J o ... o psi_1, psi_j(x) = x + exp(-rho_j^2 ||x - c_j||^2) v_j.

    Attributes:
        centres: (J, D) c_j.
        rhos: (J,) rho_j (> 0).
        translations: (J, D) v_j.
    """

    centres: np.ndarray
    rhos: np.ndarray
    translations: np.ndarray

    def __call__(self, x: npt.ArrayLike) -> np.ndarray:
        """Phi(x) for points (..., D)."""
        y = np.array(x, dtype=np.float64)
        for c, rho, v in zip(self.centres, self.rhos, self.translations):
            y = translate(y, c, rho, v)
        return y

    def inverse(self, y: npt.ArrayLike) -> np.ndarray:
        """Phi^-1(y) for points (..., D): the translations inverted in reverse order."""
        x = np.array(y, dtype=np.float64)
        for c, rho, v in zip(self.centres[::-1], self.rhos[::-1], self.translations[::-1]):
            x = untranslate(x, c, rho, v)
        return x


def translate(x: np.ndarray, centre: np.ndarray, rho: float, v: np.ndarray) -> np.ndarray:
    """psi(x) = x + exp(-rho^2 ||x - c||^2) v for points (..., D)."""
    weight = np.exp(-(rho ** 2) * ((x - centre) ** 2).sum(-1, keepdims=True))
    return x + weight * v


def untranslate(y: np.ndarray, centre: np.ndarray, rho: float, v: np.ndarray) -> np.ndarray:
    """psi^-1(y) for points (..., D), valid when rho ||v|| < sqrt(e / 2).

    psi moves a point along v only, so x = y - s v with f(s) = s - exp(-rho^2 ||y - c - s v||^2) = 0;
    f(0) <= 0 <= f(1) and f' > 0 under the bound, so the root in [0, 1] is unique (bisection).
    """
    low = np.zeros(y.shape[:-1] + (1,))
    high = np.ones_like(low)
    for _ in range(_BISECTION_STEPS):
        mid = 0.5 * (low + high)
        f = mid - np.exp(-(rho ** 2) * ((y - centre - mid * v) ** 2).sum(-1, keepdims=True))
        low = np.where(f < 0, mid, low)
        high = np.where(f < 0, high, mid)
    return y - 0.5 * (low + high) * v


def match(source: npt.ArrayLike, target: npt.ArrayLike, config: FDMConfig = FDMConfig()) -> Diffeomorphism:
    """Perrin's greedy matching (module docstring): translations until Phi(source) ~ target.

    Args:
        source: (M, D) points X_m.
        target: (M, D) points Y_m.
        config: iterations, beta, tolerance.

    Returns:
        The diffeomorphism (J <= config.iterations translations).

    Raises:
        RFlowError: shapes differ or values are not finite.
    """
    x = np.array(source, dtype=np.float64)
    y = np.asarray(target, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise RFlowError(f"FDM: source {x.shape} and target {y.shape} must be equal finite (M, D) arrays")
    centres, rhos, translations = [], [], []
    for _ in range(config.iterations):
        residual = np.linalg.norm(y - x, axis=-1)
        worst = int(np.argmax(residual))
        if residual[worst] < config.tolerance:
            break
        centre = x[worst].copy()
        v = config.beta * (y[worst] - x[worst])
        rho_max = RHO_MARGIN * math.sqrt(math.e / 2.0) / float(np.linalg.norm(v))

        def cost(log_rho: float) -> float:
            return float(((translate(x, centre, math.exp(log_rho), v) - y) ** 2).sum())

        best = minimize_scalar(cost, bounds=(math.log(rho_max) - 12.0, math.log(rho_max)), method="bounded")
        rho = math.exp(float(best.x))
        x = translate(x, centre, rho, v)
        centres.append(centre)
        rhos.append(rho)
        translations.append(v)
    dim = x.shape[-1]
    return Diffeomorphism(np.array(centres).reshape(-1, dim), np.array(rhos), np.array(translations).reshape(-1, dim))


@dataclass(frozen=True)
class FDM:
    """A fitted FDM skill in the scaled tangent space at the goal.

    Attributes:
        manifold: rflow manifold name.
        goal: the goal point g.
        scale: (D,) per-dimension scale s of the tangent vectors (y = Log_g(x) / s).
        phi: the diffeomorphism from the source space to the scaled tangent space.
        alpha: rate of the linear system (1/s).
        dt: sampling time (s).
    """

    manifold: str
    goal: np.ndarray
    scale: np.ndarray
    phi: Diffeomorphism
    alpha: float
    dt: float

    def generate(self, starts: npt.ArrayLike, steps: int) -> np.ndarray:
        """Trajectories of the pulled-back linear system from each start: y(t_m) = Phi(x* + (x_0 - x*) e^(-alpha t_m)).

        Args:
            starts: (B, *point_shape) start points on the manifold.
            steps: steps after the start (>= 0), t_m = m dt.

        Returns:
            (B, steps + 1, *point_shape) points; the first is the start (to the inversion's precision).

        Raises:
            RFlowError: steps < 0, starts off the manifold or of the wrong shape.
        """
        man = get_manifold(self.manifold)
        starts = np.asarray(man.check_points(starts, "starts"), dtype=np.float64)
        if steps < 0 or starts.ndim != 1 + man.point_ndim:
            raise RFlowError(f"FDM: need steps >= 0 and a batch of start points, got {steps} and {starts.shape}")
        y0 = np.asarray(man.log(starts, self.goal)) / self.scale
        x0 = self.phi.inverse(y0)
        x_star = self.phi.inverse(np.zeros_like(self.scale))
        decay = np.exp(-self.alpha * self.dt * np.arange(steps + 1))
        x = x_star + (x0[:, None, :] - x_star) * decay[None, :, None]
        return np.asarray(man.exp(self.phi(x) * self.scale, self.goal))


def fit_fdm(demos: npt.ArrayLike, manifold: str, dt: float, config: FDMConfig = FDMConfig()) -> FDM:
    """Fit FDM to demonstrations sharing a goal (module docstring).

    Args:
        demos: (N, M, *point_shape) trajectories on the manifold, all ending at one goal.
        manifold: "sphere", "spd" or "euclidean".
        dt: sampling time (s).
        config: settings.

    Returns:
        The fitted model.

    Raises:
        RFlowError: bad shapes, points off the manifold, demos without a shared goal, dt <= 0.
    """
    man, data = prepare_demos(demos, manifold, dt, "FDM")
    goal = shared_goal(data, man, config.goal_tolerance)
    tangent = np.asarray(man.log(data, goal))
    scale = np.maximum(tangent.reshape(-1, tangent.shape[-1]).std(axis=0), 1e-12)
    target = (tangent / scale).mean(axis=0)
    m = target.shape[0]
    alpha = -math.log(SOURCE_END_RATIO) / ((m - 1) * dt)
    source = target[0] * np.exp(-alpha * dt * np.arange(m))[:, None]
    return FDM(manifold=man.name, goal=goal, scale=scale, phi=match(source, target, config), alpha=alpha, dt=float(dt))
