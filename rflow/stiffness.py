"""Translational stiffness profiles on SPD(3): bounds, the variability estimator, Log-Euclidean metrics.

Arrays only (no simulator). Stiffness matrices K are (..., 3, 3), symmetric positive definite, in N/m.

- Bounds. Every stiffness the skill commands has its eigenvalues in [k_min, k_max]:
      clip(K) = U diag(min(max(lambda_i, k_min), k_max)) U^T,   K = U diag(lambda) U^T,
  which is the identity on matrices already inside the bounds (so a goal stiffness inside them stays the
  goal). `clip_eigenvalues` also says where it acted, so callers can report how often.
- Variability (Calinon's minimal-intervention recipe): with the demos aligned in time (they share length M
  and the scripted expert's timing, so sample m of every demo is the same phase; no DTW), the covariance of
  the N positions at each sample m,
      Sigma_m = 1/(N-1) sum_n (p_nm - mean_m)(p_nm - mean_m)^T,
  gives the stiffness
      K_m = clip(alpha (Sigma_m + eps I)^-1),
  stiff where the demos agree, compliant where they spread. eps (m^2) regularises the inverse where the
  demos coincide (at the goal Sigma = 0 exactly, so K_M = clip(alpha / eps I), the goal stiffness shared by
  every demo). alpha (N m) sets the scale: alpha / sigma^2 N/m for a spread of sigma m per axis.
- Log-Euclidean distance of two stiffness profiles (as on the LASA SPD data):
      d(S, S_hat) = 1/M sum_m ||logm(S_m) - logm(S_hat_m)||_F,
  and resampling in time along Log-Euclidean geodesics (`log_euclidean_resample`, used for recorded demos).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from numerics.small_linalg import eigh_sym, matmul
from pihutil.bounds import STIFFNESS
from rflow.errors import RFlowError
from rflow.manifolds import spd

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class StiffnessBounds:
    """The range of translational stiffness the skill may command, N/m (eigenvalues of K).

    Defaults: 100 N/m (soft enough for the hole's walls to guide the peg, still holding it against small
    disturbances) to 3000 N/m (twice the impedance controller's default of 1500 N/m; the closed loop at
    1 kHz stays well damped with the Panda's Cartesian inertia).
    """

    k_min_n_m: float = 100.0
    k_max_n_m: float = 3000.0

    def __post_init__(self) -> None:
        if not (STIFFNESS.contains(self.k_min_n_m) and STIFFNESS.contains(self.k_max_n_m)
                and self.k_min_n_m < self.k_max_n_m):
            raise RFlowError(f"stiffness bounds need k_min < k_max, both {STIFFNESS.text()} (what the controller "
                             f"commands), got k_min={self.k_min_n_m!r} N/m, k_max={self.k_max_n_m!r} N/m")

    def contains(self, stiffness: npt.ArrayLike, rtol: float = 1e-9) -> bool:
        """True when every eigenvalue of every matrix lies in [k_min, k_max] (relative tolerance ``rtol``)."""
        lam = eigh_sym(np.asarray(stiffness, dtype=np.float64))[0]
        return bool(np.all(lam >= self.k_min_n_m * (1 - rtol)) and np.all(lam <= self.k_max_n_m * (1 + rtol)))


def clip_eigenvalues(stiffness: npt.ArrayLike, bounds: StiffnessBounds) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """clip(K) = U diag(clip(lambda, k_min, k_max)) U^T of symmetric matrices (..., 3, 3).

    Returns:
        (the clipped matrices, (...) bool: where an eigenvalue was outside the bounds and was moved).

    Raises:
        RFlowError: not square symmetric matrices, NaN.
    """
    k = spd.check_symmetric(np.asarray(stiffness, dtype=np.float64), "stiffness")
    lam, u = eigh_sym(k)
    low, high = bounds.k_min_n_m, bounds.k_max_n_m
    acted = np.any((lam < low) | (lam > high), axis=-1)
    out = matmul(u * np.clip(lam, low, high)[..., None, :], np.swapaxes(u, -1, -2))
    out = 0.5 * (out + np.swapaxes(out, -1, -2))
    return np.where(acted[..., None, None], out, k), acted


@dataclass(frozen=True)
class VariabilityConfig:
    """K_m = clip(alpha (Sigma_m + eps I)^-1) from the spread of the demos (module docstring).

    Attributes:
        alpha_n_m: alpha, N m: 0.25 gives 2500 N/m at a spread of 1 cm std per axis and 280 N/m at 3 cm
            (the spread of starts drawn within +-5 cm).
        regularisation_m2: eps, m^2: (1 mm)^2, below the demos' spread except where they converge.
        bounds: eigenvalue range of the result.
    """

    alpha_n_m: float = 0.25
    regularisation_m2: float = 1e-6
    bounds: StiffnessBounds = field(default_factory=StiffnessBounds)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.alpha_n_m) and self.alpha_n_m > 0):
            raise RFlowError(f"variability alpha={self.alpha_n_m!r} N m must be > 0")
        if not (np.isfinite(self.regularisation_m2) and self.regularisation_m2 > 0):
            raise RFlowError(f"variability regularisation={self.regularisation_m2!r} m^2 must be > 0")


def position_covariance(pos: npt.ArrayLike) -> FloatArray:
    """Sigma_m = 1/(N-1) sum_n (p_nm - mean_m)(p_nm - mean_m)^T of time-aligned demos (N, M, 3) -> (M, 3, 3).

    Raises:
        RFlowError: shape not (N, M, 3) with N >= 2, NaN.
    """
    p = np.asarray(pos, dtype=np.float64)
    if p.ndim != 3 or p.shape[-1] != 3 or p.shape[0] < 2 or p.shape[1] < 1:
        raise RFlowError(f"positions have shape {p.shape}, expected (N, M, 3) with N >= 2 demos")
    if not np.all(np.isfinite(p)):
        raise RFlowError("positions contain NaN or inf")
    dev = p - p.mean(axis=0)
    return np.einsum("nmi,nmj->mij", dev, dev) / (p.shape[0] - 1)


def variability_stiffness(pos: npt.ArrayLike, config: VariabilityConfig = VariabilityConfig()) -> FloatArray:
    """The minimal-intervention stiffness profile K_m = clip(alpha (Sigma_m + eps I)^-1) (M, 3, 3), N/m.

    One profile for all demos (they are aligned sample by sample); it ends at clip(alpha / eps I) where
    the demos end at one goal.

    Raises:
        RFlowError: see `position_covariance`.
    """
    lam, u = eigh_sym(position_covariance(pos) + config.regularisation_m2 * np.eye(3))
    precision = matmul(u / lam[..., None, :], np.swapaxes(u, -1, -2))  # (Sigma + eps I)^-1 = U diag(1/lam) U^T
    return clip_eigenvalues(config.alpha_n_m * 0.5 * (precision + np.swapaxes(precision, -1, -2)), config.bounds)[0]


def log_euclidean_mean(stiffness: npt.ArrayLike) -> FloatArray:
    """expm(mean_i logm(K_i)) of SPD matrices (n, d, d) -> (d, d): the Log-Euclidean mean.

    Raises:
        RFlowError: not SPD, NaN, no matrices.
    """
    k = spd.check_spd(np.asarray(stiffness, dtype=np.float64), "stiffness")
    if k.ndim != 3 or k.shape[0] < 1:
        raise RFlowError(f"stiffness has shape {k.shape}, expected (n, d, d) with n >= 1")
    return np.asarray(spd.expm_sym(np.asarray(spd.logm(k)).mean(axis=0)))


def log_euclidean_resample(times: npt.ArrayLike, stiffness: npt.ArrayLike, new_times: npt.ArrayLike) -> FloatArray:
    """Resample a stiffness profile in time along Log-Euclidean geodesics (SPD at every new sample):
        K(t) = expm((1 - s) logm(K_k) + s logm(K_k+1)),   s = (t - t_k) / (t_k+1 - t_k),   t_k <= t <= t_k+1.

    Args:
        times: (K,) strictly increasing sample times, seconds (K >= 2).
        stiffness: (K, d, d) SPD matrices at ``times``.
        new_times: (L,) query times (clipped to [times[0], times[-1]]).

    Returns:
        (L, d, d) SPD matrices.

    Raises:
        RFlowError: mismatched shapes, non-increasing times, a matrix that is not SPD.
    """
    t = np.asarray(times, dtype=np.float64)
    k = spd.check_spd(np.asarray(stiffness, dtype=np.float64), "stiffness")
    if t.ndim != 1 or t.size < 2 or k.ndim != 3 or k.shape[0] != t.size:
        raise RFlowError(f"resampling needs times (K>=2,) and stiffness (K, d, d), got {t.shape} and {k.shape}")
    if np.any(np.diff(t) <= 0.0):
        raise RFlowError("resampling needs strictly increasing times")
    logs = np.asarray(spd.logm(k)).reshape(t.size, -1)
    tn = np.clip(np.asarray(new_times, dtype=np.float64), t[0], t[-1])
    resampled = np.stack([np.interp(tn, t, logs[:, i]) for i in range(logs.shape[1])], axis=-1)
    return np.asarray(spd.expm_sym(resampled.reshape(tn.shape + k.shape[1:])))


def profile_distance(demo: npt.ArrayLike, generated: npt.ArrayLike) -> FloatArray:
    """Mean Log-Euclidean distance 1/M sum_m ||logm(S_m) - logm(S_hat_m)||_F of profiles (..., M, d, d) -> (...).

    Raises:
        RFlowError: shapes differ, not SPD, NaN.
    """
    s, s_hat = np.asarray(demo, dtype=np.float64), np.asarray(generated, dtype=np.float64)
    if s.shape != s_hat.shape or s.ndim < 3:
        raise RFlowError(f"stiffness profiles have shapes {s.shape} and {s_hat.shape}, expected equal (..., M, d, d)")
    return np.asarray(spd.log_euclidean_distance(s, s_hat)).mean(axis=-1)


__all__ = [
    "StiffnessBounds",
    "VariabilityConfig",
    "clip_eigenvalues",
    "position_covariance",
    "variability_stiffness",
    "log_euclidean_mean",
    "log_euclidean_resample",
    "profile_distance",
]
