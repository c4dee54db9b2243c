"""Symmetric positive definite matrices SPD(d) with the affine-invariant log and exp maps.

    Log_G(P) = G^1/2 logm(G^-1/2 P G^-1/2) G^1/2,
    Exp_G(V) = G^1/2 expm(G^-1/2 V G^-1/2) G^1/2,
all matrix functions through the symmetric eigendecomposition (eigh). Tangent matrices are vectorised with
Mandel's notation: the diagonal first, then sqrt(2) times the upper off-diagonal entries in row-major order,
    2x2: [V11, V22, sqrt2 V12],   3x3: [V11, V22, V33, sqrt2 V12, sqrt2 V13, sqrt2 V23],
so that ||mandel(V)|| = ||V||_F. Functions take numpy arrays or torch tensors, batched over leading axes
(torch: forward values only; eigh gradients are unstable at repeated eigenvalues such as G = 100 I).
"""

from __future__ import annotations

import math

import numpy as np

from rflow.errors import RFlowError
from rflow.manifolds._backend import Array, as_array, eigh, is_torch, matmul, max_abs, swap_last, xp

SYMMETRY_TOLERANCE = 1e-8  # |P - P^T| allowed, relative to max |P|


def _sym_fn(p: Array, fn) -> Array:
    """U fn(lambda) U^T of symmetric matrices (..., d, d)."""
    lam, u = eigh(p)
    return matmul(u * fn(lam)[..., None, :], swap_last(u))


def check_symmetric(p: Array, name: str = "matrix") -> Array:
    """Validate square symmetric matrices (..., d, d).

    Raises:
        RFlowError: not square, NaN/inf, or asymmetric beyond SYMMETRY_TOLERANCE (relative).
    """
    p = as_array(p, name)
    shape = tuple(p.shape)
    if len(shape) < 2 or shape[-1] != shape[-2] or shape[-1] < 1:
        raise RFlowError(f"{name} has shape {shape}, expected square matrices (..., d, d)")
    scale = max(max_abs(p), 1.0)
    asym = max_abs(p - swap_last(p))
    if asym > SYMMETRY_TOLERANCE * scale:
        raise RFlowError(f"{name} is not symmetric: max |P - P^T| = {asym:.3g}")
    return 0.5 * (p + swap_last(p))


def check_spd(p: Array, name: str = "SPD matrix") -> Array:
    """Validate symmetric positive definite matrices (..., d, d); returns the symmetrised input.

    Raises:
        RFlowError: not square/symmetric, NaN/inf, or an eigenvalue <= 0.
    """
    p = check_symmetric(p, name)
    lam = eigh(p)[0]
    low = float(lam.min()) if (lam.numel() if is_torch(lam) else lam.size) else 1.0
    if low <= 0.0:
        raise RFlowError(f"{name} is not positive definite: smallest eigenvalue {low:.3g}")
    return p


def sqrtm(p: Array) -> Array:
    """Principal square root P^1/2 of SPD matrices."""
    return _sym_fn(p, xp(p).sqrt)


def logm(p: Array) -> Array:
    """Principal matrix logarithm of SPD matrices (symmetric result)."""
    return _sym_fn(p, xp(p).log)


def expm_sym(v: Array) -> Array:
    """Matrix exponential of symmetric matrices (SPD result)."""
    return _sym_fn(v, xp(v).exp)


def _half_powers(g: Array) -> tuple[Array, Array]:
    """G^1/2 and G^-1/2 from one eigendecomposition."""
    m = xp(g)
    lam, u = eigh(g)
    root = m.sqrt(lam)
    ut = swap_last(u)
    return matmul(u * root[..., None, :], ut), matmul(u * (1.0 / root)[..., None, :], ut)


def _checked_pair(matrix: Array, base: Array, what: str) -> tuple[Array, Array]:
    """``matrix`` (already checked) and the SPD ``base``, checked to share the size d.

    Raises:
        RFlowError: base not SPD, or sizes that differ.
    """
    base = check_spd(base, "base SPD matrix")
    if matrix.shape[-1] != base.shape[-1]:
        raise RFlowError(f"{what} is {matrix.shape[-1]}x{matrix.shape[-1]} but base is "
                         f"{base.shape[-1]}x{base.shape[-1]}")
    return matrix, base


def log_map(p: Array, base: Array) -> Array:
    """Log_G(P) = G^1/2 logm(G^-1/2 P G^-1/2) G^1/2 -> symmetric tangent matrices (..., d, d).

    Raises:
        RFlowError: P or G not SPD, shapes differ in d, NaN.
    """
    p, base = _checked_pair(check_spd(p, "SPD matrix"), base, "SPD matrix")
    half, inv_half = _half_powers(base)
    inner = matmul(matmul(inv_half, p), inv_half)
    return matmul(matmul(half, logm(0.5 * (inner + swap_last(inner)))), half)


def exp_map(v: Array, base: Array) -> Array:
    """Exp_G(V) = G^1/2 expm(G^-1/2 V G^-1/2) G^1/2 of symmetric V (..., d, d) -> SPD (..., d, d).

    Raises:
        RFlowError: V not symmetric, G not SPD, shapes differ in d, NaN.
    """
    v, base = _checked_pair(check_symmetric(v, "tangent matrix"), base, "tangent matrix")
    half, inv_half = _half_powers(base)
    inner = matmul(matmul(inv_half, v), inv_half)
    out = matmul(matmul(half, expm_sym(0.5 * (inner + swap_last(inner)))), half)
    return 0.5 * (out + swap_last(out))


def normal_log_map(p: Array, base: Array) -> Array:
    """Log_G(P) in normal coordinates at G: G^-1/2 Log_G(P) G^-1/2 = logm(G^-1/2 P G^-1/2) (symmetric, (..., d, d)).

    The affine-invariant metric at G is <U, V>_G = tr(G^-1 U G^-1 V), so the whitened tangent matrix has the
    Euclidean (Frobenius) norm of the Riemannian distance d(G, P) and is dimensionless: a stiffness in N/m and
    a position in m can then share one normalised tangent vector without one unit swamping the other.

    Raises:
        RFlowError: P or G not SPD, shapes differ in d, NaN.
    """
    p, base = _checked_pair(check_spd(p, "SPD matrix"), base, "SPD matrix")
    _, inv_half = _half_powers(base)
    inner = matmul(matmul(inv_half, p), inv_half)
    return logm(0.5 * (inner + swap_last(inner)))


def normal_exp_map(v: Array, base: Array) -> Array:
    """Exp_G of a tangent matrix given in normal coordinates at G: G^1/2 expm(V) G^1/2 -> SPD (..., d, d).

    The inverse of `normal_log_map`; SPD for every symmetric V (the exponential of a symmetric matrix is SPD).

    Raises:
        RFlowError: V not symmetric, G not SPD, shapes differ in d, NaN.
    """
    v, base = _checked_pair(check_symmetric(v, "tangent matrix"), base, "tangent matrix")
    half, _ = _half_powers(base)
    out = matmul(matmul(half, expm_sym(v)), half)
    return 0.5 * (out + swap_last(out))


def mandel_dim(d: int) -> int:
    """Length d(d+1)/2 of the Mandel vector of a d x d symmetric matrix."""
    return d * (d + 1) // 2


def matrix_dim(n: int) -> int:
    """Side d of the symmetric matrix whose Mandel vector has length n = d(d+1)/2.

    Raises:
        RFlowError: n is not a triangular number.
    """
    d = int(round((math.sqrt(8 * n + 1) - 1) / 2))
    if d < 1 or mandel_dim(d) != n:
        raise RFlowError(f"Mandel vector length {n} is not d(d+1)/2 for any d")
    return d


def _off_diagonal(d: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of the upper off-diagonal entries, row-major."""
    rows, cols = np.triu_indices(d, k=1)
    return rows, cols


def mandel(v: Array) -> Array:
    """Mandel vector [diag(V), sqrt2 * upper off-diagonals row-major] of symmetric V (..., d, d) -> (..., d(d+1)/2).

    Raises:
        RFlowError: V not square or not symmetric.
    """
    v = check_symmetric(v, "symmetric matrix")
    d = v.shape[-1]
    rows, cols = _off_diagonal(d)
    diag = v[..., np.arange(d), np.arange(d)]
    off = math.sqrt(2.0) * v[..., rows, cols]
    if is_torch(v):
        return xp(v).cat([diag, off], -1)
    return np.concatenate([diag, off], axis=-1)


def mandel_inverse(x: Array) -> Array:
    """Symmetric matrices (..., d, d) from Mandel vectors (..., d(d+1)/2); inverse of `mandel`.

    Raises:
        RFlowError: the length is not d(d+1)/2, NaN.
    """
    x = as_array(x, "Mandel vector")
    if x.ndim < 1:
        raise RFlowError("Mandel vector must have at least one dimension")
    d = matrix_dim(x.shape[-1])
    rows, cols = _off_diagonal(d)
    m = xp(x)
    out = m.zeros(tuple(x.shape[:-1]) + (d, d), dtype=x.dtype)
    idx = np.arange(d)
    out[..., idx, idx] = x[..., :d]
    off = x[..., d:] / math.sqrt(2.0)
    out[..., rows, cols] = off
    out[..., cols, rows] = off
    return out


def nearest_spd(a: Array, min_eigenvalue: float = 1e-9) -> Array:
    """Nearest SPD matrix in the Frobenius norm (Higham 1988) of square matrices (..., d, d).

    Higham: the nearest symmetric positive semidefinite matrix to A is (B + H)/2 with B = (A + A^T)/2 and
    H the symmetric polar factor of B, i.e. U max(lambda, 0) U^T for B = U diag(lambda) U^T. Eigenvalues are
    floored at ``min_eigenvalue`` times max(1, max |lambda|) so the result is strictly positive definite.

    Raises:
        RFlowError: not square, NaN/inf, or a floor that is not a positive number.
    """
    if isinstance(min_eigenvalue, bool) or not (isinstance(min_eigenvalue, (int, float)) and min_eigenvalue > 0.0
                                                 and math.isfinite(min_eigenvalue)):
        raise RFlowError(f"min_eigenvalue={min_eigenvalue!r} must be a positive number (the result is SPD)")
    a = as_array(a, "matrix")
    shape = tuple(a.shape)
    if len(shape) < 2 or shape[-1] != shape[-2]:
        raise RFlowError(f"matrix has shape {shape}, expected square matrices (..., d, d)")
    b = 0.5 * (a + swap_last(a))
    lam, u = eigh(b)
    floor = min_eigenvalue * max(max_abs(lam), 1.0)
    lam = xp(b).clip(lam, floor, None) if not is_torch(b) else lam.clamp(min=floor)
    out = matmul(u * lam[..., None, :], swap_last(u))
    return 0.5 * (out + swap_last(out))


def log_euclidean_distance(s: Array, s_hat: Array) -> Array:
    """Log-Euclidean distance ||logm(S) - logm(S_hat)||_F of SPD matrices, batched -> (...).

    Raises:
        RFlowError: inputs not SPD, NaN.
    """
    s = check_spd(s, "S")
    s_hat = check_spd(s_hat, "S_hat")
    diff = logm(s) - logm(s_hat)
    if is_torch(diff):
        return xp(diff).linalg.matrix_norm(diff)
    return np.linalg.norm(diff, axis=(-2, -1))
