"""Trajectory metrics of the Riemannian LASA benchmark: DTW, RMSE, final error, manifold distances.

Trajectories are arrays of shape (M, D): M points of D coordinates (tangent vectors, or flattened
manifold points). Distances on the manifolds are delegated to `rflow.manifolds`.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.spatial.distance import cdist

from rflow.errors import RFlowError
from rflow.manifolds import sphere, spd


def _to_float(name: str, values: npt.ArrayLike) -> np.ndarray:
    """Return `values` as a float64 array, or raise RFlowError if it is not numeric."""
    try:
        return np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise RFlowError(f"{name}: not a numeric array ({err})") from None


def _as_trajectory(name: str, values: npt.ArrayLike) -> np.ndarray:
    """Return `values` as a finite float64 (M, D) array with M >= 1, else raise RFlowError."""
    array = _to_float(name, values)
    if array.ndim != 2 or array.shape[0] < 1 or array.shape[1] < 1:
        raise RFlowError(f"{name}: expected a trajectory of shape (M, D), got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise RFlowError(f"{name}: contains NaN or infinite values")
    return array


def _as_pair(a: npt.ArrayLike, b: npt.ArrayLike, same_length: bool) -> tuple[np.ndarray, np.ndarray]:
    """Validate two trajectories of equal dimension (and equal length if `same_length`)."""
    a_arr, b_arr = _as_trajectory("a", a), _as_trajectory("b", b)
    if a_arr.shape[1] != b_arr.shape[1]:
        raise RFlowError(f"a and b: dimensions differ ({a_arr.shape[1]} vs {b_arr.shape[1]})")
    if same_length and a_arr.shape[0] != b_arr.shape[0]:
        raise RFlowError(f"a and b: lengths differ ({a_arr.shape[0]} vs {b_arr.shape[0]})")
    return a_arr, b_arr


def dtw(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """Dynamic time warping distance: the unnormalised sum of Euclidean point distances along the best path.

    With c[i, j] = ||a_i - b_j|| the cumulative cost is
        D[0, 0] = c[0, 0],  D[i, j] = c[i, j] + min(D[i-1, j], D[i, j-1], D[i-1, j-1]),
    and the distance is D[n-1, m-1] (the same value as `similaritymeasures.dtw(a, b)[0]`).
    All cells on one anti-diagonal i + j = k depend only on the two previous anti-diagonals, so the
    recursion runs as n + m - 1 vectorised steps.

    Args:
        a: first trajectory, shape (n, D).
        b: second trajectory, shape (m, D).

    Returns:
        The DTW distance D[n-1, m-1].

    Raises:
        RFlowError: if a or b is not a non-empty 2-D array, dimensions differ, or values are not finite.
    """
    a_arr, b_arr = _as_pair(a, b, same_length=False)
    cost = cdist(a_arr, b_arr)
    n, m = cost.shape
    # Anti-diagonal k is stored by row index i in slot i + 1; slot 0 and invalid slots hold +inf.
    before_previous = np.full(n + 1, np.inf)
    previous = np.full(n + 1, np.inf)
    current = np.full(n + 1, np.inf)
    previous[1] = cost[0, 0]
    for k in range(1, n + m - 1):
        lo, hi = max(0, k - m + 1), min(k, n - 1)
        rows = np.arange(lo, hi + 1)
        up = previous[lo : hi + 1]  # D[i-1, j]
        left = previous[lo + 1 : hi + 2]  # D[i, j-1]
        diagonal = before_previous[lo : hi + 1]  # D[i-1, j-1]
        current.fill(np.inf)
        current[lo + 1 : hi + 2] = cost[rows, k - rows] + np.minimum(np.minimum(up, left), diagonal)
        before_previous, previous, current = previous, current, before_previous
    return float(previous[n])


def rmse(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """Root mean square of the point-wise Euclidean error, sqrt(1/M sum_m ||a_m - b_m||^2).

    Args:
        a: first trajectory, shape (M, D).
        b: second trajectory, shape (M, D).

    Returns:
        The RMSE.

    Raises:
        RFlowError: if the shapes differ or values are not finite.
    """
    a_arr, b_arr = _as_pair(a, b, same_length=True)
    return float(np.sqrt(np.mean(np.sum((a_arr - b_arr) ** 2, axis=1))))


def final_error(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """Euclidean distance between the last points, ||a_M - b_M'|| (lengths may differ).

    Args:
        a: first trajectory, shape (M, D).
        b: second trajectory, shape (M', D).

    Returns:
        The distance between a[-1] and b[-1].

    Raises:
        RFlowError: if dimensions differ or values are not finite.
    """
    a_arr, b_arr = _as_pair(a, b, same_length=False)
    return float(np.linalg.norm(a_arr[-1] - b_arr[-1]))


def _as_sequences(a: npt.ArrayLike, b: npt.ArrayLike, point_ndim: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Validate two sequences of manifold points of the same shape (M, *point_shape), M >= 1."""
    a_arr, b_arr = _to_float("a", a), _to_float("b", b)
    for name, arr in (("a", a_arr), ("b", b_arr)):
        if arr.ndim != 1 + point_ndim or arr.shape[0] < 1:
            raise RFlowError(f"{name}: expected a sequence of {what}, got shape {arr.shape}")
    if a_arr.shape != b_arr.shape:
        raise RFlowError(f"a and b: shapes differ ({a_arr.shape} vs {b_arr.shape})")
    return a_arr, b_arr


def log_euclidean_distances(s: npt.ArrayLike, s_hat: npt.ArrayLike) -> np.ndarray:
    """Log-Euclidean distance ||logm(S_m) - logm(S_hat_m)||_F at every step of two SPD sequences.

    Args:
        s: reference SPD matrices, shape (M, d, d).
        s_hat: reproduced SPD matrices, shape (M, d, d).

    Returns:
        (M,) distances (`rflow.manifolds.spd.log_euclidean_distance`).

    Raises:
        RFlowError: shapes differ, matrices are not SPD, or values are not finite.
    """
    s_arr, s_hat_arr = _as_sequences(s, s_hat, 2, "SPD matrices (M, d, d)")
    return np.asarray(spd.log_euclidean_distance(s_arr, s_hat_arr), dtype=np.float64)


def quaternion_distances(q: npt.ArrayLike, q_hat: npt.ArrayLike) -> np.ndarray:
    """The paper's orientation error ||2 Log(q_m * conj(q_hat_m))|| (rad) at every step of two sequences.

    Args:
        q: reference unit quaternions (w, x, y, z), shape (M, 4).
        q_hat: reproduced unit quaternions, shape (M, 4).

    Returns:
        (M,) distances (`rflow.manifolds.sphere.distance`).

    Raises:
        RFlowError: shapes differ, quaternions are not unit, or values are not finite.
    """
    q_arr, q_hat_arr = _as_sequences(q, q_hat, 1, "unit quaternions (M, 4)")
    return np.asarray(sphere.distance(q_arr, q_hat_arr), dtype=np.float64)


def manifold_distances(manifold: str, a: npt.ArrayLike, b: npt.ArrayLike) -> np.ndarray:
    """Step-wise manifold distance of two equally long sequences: Log-Euclidean (SPD) or quaternion error.

    Args:
        manifold: "spd" or "sphere" (unit quaternions).
        a: reference sequence, (M, d, d) or (M, 4).
        b: reproduced sequence of the same shape.

    Returns:
        (M,) distances.

    Raises:
        RFlowError: unknown manifold or invalid sequences.
    """
    if manifold == "spd":
        return log_euclidean_distances(a, b)
    if manifold == "sphere":
        return quaternion_distances(a, b)
    raise RFlowError(f"manifold {manifold!r}: no sequence distance; expected 'spd' or 'sphere'")
