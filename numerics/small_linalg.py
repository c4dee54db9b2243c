"""Small dense linear algebra without BLAS or LAPACK: every sum in a fixed order, so results do not depend on the CPU.

This is the BLAS-free half of `numerics.cpu_dispatch`. numpy's ``@``, ``dot``, ``matmul``, ``inner``, ``linalg.norm`` of
a whole vector, ``linalg.solve``/``eigh``/``inv`` and ``scipy.linalg.expm`` call OpenBLAS, which picks its kernels by
the host CPU (or by ``OPENBLAS_CORETYPE``, the machine's own setting that a program must leave alone) and sums in the
order of that kernel: the same product differs in the last bit between an AVX2 and an SSE3 kernel, and the contact
physics of an episode amplifies that into other records. What feeds an episode record or a demo file therefore
computes its matrix products here:

    dot(a, b)    = sum_k a_k b_k                        (k ascending)
    norm(v)      = sqrt(sum_k v_k^2)                    (k ascending)
    matvec(A, x) = [sum_k A_ik x_k]_i
    matmul(A, B) = [sum_k A_ik B_kj]_ij                 (numpy's matmul semantics: 1-D operands, batch broadcast;
                                                         matmul_into writes into a buffer, for compiled callers)
    solve(A, b)  = A^-1 b                               (Gaussian elimination with partial pivoting)
    eigh_sym(A)  = (w, V) with A = V diag(w) V^T        (cyclic Jacobi, w ascending; A's lower triangle is read)
    expm(A)      = (V - U)^-1 (V + U) squared s times   (Pade [13/13] of A / 2^s, Higham 2005)

All are compiled with numba without fast-math (no fused multiply-add, no reassociation: a compiled loop rounds
alike on every x86-64 CPU); the kernels are sized for 2x2 to 12x12 matrices and batches of them, where a loop costs
less than numpy's call into BLAS. Elementwise ufuncs, ``np.add.reduce`` / ``.sum(axis=...)`` and ``np.einsum``
(without ``optimize``) do not call BLAS and need nothing from here; tests/test_blas_free.py keeps BLAS calls off the
modules that feed records.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

from numerics.errors import NumericsError

FloatArray = npt.NDArray[np.float64]

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")
_JACOBI_SWEEPS = 30  # 6x6 converges in ~6 sweeps; the cap only guards against NaN input


# ------------------------------------------------------------------------------------------------- vectors


@_jit
def dot(a: FloatArray, b: FloatArray) -> float:
    """a . b = sum_k a_k b_k of two vectors of one length, summed with k ascending."""
    n = a.shape[0]
    if b.shape[0] != n:
        raise ValueError("dot: the vectors differ in length")
    s = 0.0
    for k in range(n):
        s += a[k] * b[k]
    return s


@_jit
def norm(v: FloatArray) -> float:
    """|v| = sqrt(sum_k v_k^2) of a vector, summed with k ascending (np.linalg.norm(v) without BLAS)."""
    s = 0.0
    for k in range(v.shape[0]):
        s += v[k] * v[k]
    return math.sqrt(s)


@_jit
def matvec(a: FloatArray, x: FloatArray) -> FloatArray:
    """A x = [sum_k A_ik x_k]_i of a matrix (m, n) and a vector (n,) -> new (m,)."""
    m, n = a.shape
    if x.shape[0] != n:
        raise ValueError("matvec: the matrix's columns and the vector's length differ")
    out = np.empty(m)
    for i in range(m):
        s = 0.0
        for k in range(n):
            s += a[i, k] * x[k]
        out[i] = s
    return out


# ------------------------------------------------------------------------------------------------ matrices


@_jit
def matmul_into(a: FloatArray, b: FloatArray, out: FloatArray) -> None:
    """out = A B = [sum_k A_ik B_kj]_ij of matrices (m, n) and (n, p) into out (m, p), no allocation (compiled
    callers; the caller checks the shapes)."""
    m, n = a.shape
    p = b.shape[1]
    for i in range(m):
        for j in range(p):
            s = 0.0
            for k in range(n):
                s += a[i, k] * b[k, j]
            out[i, j] = s


@_jit
def _matmul2(a, b):
    """a b of matrices (m, n) and (n, p) -> new (m, p)."""
    out = np.empty((a.shape[0], b.shape[1]))
    matmul_into(a, b, out)
    return out


@_jit
def _matmul_batch(a, b, out):
    """out[t] = a[t] b[t] for (B, m, n) and (B, n, p) batches."""
    for t in range(a.shape[0]):
        matmul_into(a[t], b[t], out[t])


def matmul(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """a @ b with numpy's matmul semantics (a 1-D operand is a row or column vector, the leading axes of batches
    broadcast), each entry sum_k a_ik b_kj summed with k ascending.

    Raises:
        NumericsError: a scalar operand or inner dimensions that differ.
    """
    x = np.asarray(a, dtype=np.float64)
    y = np.asarray(b, dtype=np.float64)
    if x.ndim == 2 and y.ndim == 2 and x.shape[1] == y.shape[0]:  # the common case, one compiled call
        return _matmul2(x, y)
    if x.ndim == 0 or y.ndim == 0:
        raise NumericsError(f"matmul needs arrays of at least one axis, got shapes {x.shape} and {y.shape}")
    row, col = x.ndim == 1, y.ndim == 1
    x2 = x[None, :] if row else x
    y2 = y[:, None] if col else y
    (m, n), (n2, p) = x2.shape[-2:], y2.shape[-2:]
    if n != n2:
        raise NumericsError(f"matmul: shapes {x.shape} and {y.shape} do not fit (inner dimensions {n} and {n2})")
    if y2.ndim == 2:  # one right matrix: the left batch is one tall matrix
        out = np.empty((1, int(np.prod(x2.shape[:-1])), p))
        _matmul_batch(np.ascontiguousarray(x2).reshape(1, -1, n), np.ascontiguousarray(y2)[None], out)
        out = out.reshape(x2.shape[:-1] + (p,))
    else:
        lead = np.broadcast_shapes(x2.shape[:-2], y2.shape[:-2])
        xb = np.ascontiguousarray(np.broadcast_to(x2, lead + (m, n))).reshape(-1, m, n)
        yb = np.ascontiguousarray(np.broadcast_to(y2, lead + (n, p))).reshape(-1, n, p)
        out = np.empty((xb.shape[0], m, p))
        _matmul_batch(xb, yb, out)
        out = out.reshape(lead + (m, p))
    if col:
        out = out[..., 0]
    if row:
        out = out[..., 0, :] if not col else out[..., 0]
    return out


@_jit
def _solve_into(a, b):
    """Overwrite b (n, k) with a^-1 b by Gaussian elimination with partial pivoting (a (n, n) overwritten);
    False when a pivot is zero or not finite (singular a)."""
    n = a.shape[0]
    cols = b.shape[1]
    for c in range(n):
        pivot = c
        for r in range(c + 1, n):
            if abs(a[r, c]) > abs(a[pivot, c]):
                pivot = r
        if not abs(a[pivot, c]) > 0.0 or not math.isfinite(a[pivot, c]):
            return False
        if pivot != c:
            for j in range(n):
                a[c, j], a[pivot, j] = a[pivot, j], a[c, j]
            for j in range(cols):
                b[c, j], b[pivot, j] = b[pivot, j], b[c, j]
        for r in range(c + 1, n):
            f = a[r, c] / a[c, c]
            if f != 0.0:
                for j in range(c + 1, n):
                    a[r, j] -= f * a[c, j]
                for j in range(cols):
                    b[r, j] -= f * b[c, j]
    for c in range(n - 1, -1, -1):  # back substitution
        for j in range(cols):
            s = b[c, j]
            for k in range(c + 1, n):
                s -= a[c, k] * b[k, j]
            b[c, j] = s / a[c, c]
    return True


def solve(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """x = A^-1 b of a square matrix A (n, n) and b (n,) or (n, k), by Gaussian elimination with partial pivoting.

    Raises:
        NumericsError: shapes that do not fit, or a singular A (a zero pivot).
    """
    m = np.array(a, dtype=np.float64, order="C")
    rhs = np.asarray(b, dtype=np.float64)
    if m.ndim != 2 or m.shape[0] != m.shape[1] or rhs.ndim not in (1, 2) or rhs.shape[0] != m.shape[0]:
        raise NumericsError(f"solve needs a square matrix (n, n) and b (n,) or (n, k), got {m.shape} and {rhs.shape}")
    x = np.array(rhs.reshape(m.shape[0], -1), order="C")
    if not _solve_into(m, x):
        raise NumericsError(f"solve: the {m.shape[0]}x{m.shape[0]} matrix is singular (a zero pivot)")
    return x.reshape(rhs.shape)


# -------------------------------------------------------------------------------------- symmetric eigen


@_jit
def symmetric_eig(a: FloatArray, w: FloatArray, v: FloatArray) -> None:
    """Eigenvalues w (unsorted) and eigenvectors (columns of v) of the symmetric matrix a by cyclic Jacobi rotations.

    Each rotation J (c, s in rows/columns p, q) zeroes a_pq: a <- J^T a J, v <- v J, with t = tan(angle) the
    smaller root of t^2 + 2 theta t - 1 = 0, theta = (a_qq - a_pp) / (2 a_pq). `a` is overwritten.
    """
    n = a.shape[0]
    for i in range(n):
        for j in range(n):
            v[i, j] = 1.0 if i == j else 0.0
    for _ in range(_JACOBI_SWEEPS):
        off = 0.0
        scale = 0.0
        for i in range(n):
            scale += a[i, i] * a[i, i]
            for j in range(i + 1, n):
                off += a[i, j] * a[i, j]
        if not off > 1e-32 * scale:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = a[p, q]
                if apq == 0.0:
                    continue
                theta = (a[q, q] - a[p, p]) / (2.0 * apq)
                t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                if theta < 0.0:
                    t = -t
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):
                    akp, akq = a[k, p], a[k, q]
                    a[k, p] = c * akp - s * akq
                    a[k, q] = s * akp + c * akq
                for k in range(n):
                    apk, aqk = a[p, k], a[q, k]
                    a[p, k] = c * apk - s * aqk
                    a[q, k] = s * apk + c * aqk
                for k in range(n):
                    vkp, vkq = v[k, p], v[k, q]
                    v[k, p] = c * vkp - s * vkq
                    v[k, q] = s * vkp + c * vkq
    for i in range(n):
        w[i] = a[i, i]


@_jit
def _eigh_batch(a, w, v):
    """w[t] ascending and v[t] of the symmetric matrices whose lower triangles a[t] (B, n, n) hold."""
    batch, n = a.shape[0], a.shape[1]
    work = np.empty((n, n))
    for t in range(batch):
        for i in range(n):
            for j in range(i + 1):
                work[i, j] = a[t, i, j]
                work[j, i] = a[t, i, j]
        wt, vt = w[t], v[t]
        symmetric_eig(work, wt, vt)
        for i in range(1, n):  # insertion sort of the pairs by eigenvalue
            j = i
            while j > 0 and wt[j - 1] > wt[j]:
                wt[j - 1], wt[j] = wt[j], wt[j - 1]
                for k in range(n):
                    vt[k, j - 1], vt[k, j] = vt[k, j], vt[k, j - 1]
                j -= 1


def eigh_sym(a: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Eigenvalues w (..., n), ascending, and eigenvectors V (..., n, n) (columns) of symmetric matrices
    (..., n, n): A = V diag(w) V^T, as np.linalg.eigh (the lower triangle is read), by cyclic Jacobi rotations.

    Raises:
        NumericsError: not square matrices.
    """
    m = np.asarray(a, dtype=np.float64)
    if m.ndim < 2 or m.shape[-1] != m.shape[-2]:
        raise NumericsError(f"eigh_sym needs square matrices (..., n, n), got shape {m.shape}")
    n = m.shape[-1]
    flat = np.ascontiguousarray(m).reshape(-1, n, n)
    w, v = np.empty(flat.shape[:2]), np.empty(flat.shape)
    _eigh_batch(flat, w, v)
    return w.reshape(m.shape[:-1]), v.reshape(m.shape)


# ----------------------------------------------------------------------------------------- exponential

_PADE13 = np.array([64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
                    129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0,
                    40840800.0, 960960.0, 16380.0, 182.0, 1.0])
"""b_0..b_13 of the [13/13] Pade approximant of exp (Higham 2005, Table 2.3)."""
_THETA13 = 5.371920351148152
"""Largest 1-norm for which the [13/13] Pade approximant is exact to double precision (Higham 2005, Table 2.3)."""


@_jit
def _expm(a, coef, theta):
    """exp(A) by scaling and squaring: X = A / 2^s with ||X||_1 <= theta, the Pade [13/13] approximant
        r = (V - U)^-1 (V + U),   U = X [X6 (b13 X6 + b11 X4 + b9 X2) + b7 X6 + b5 X4 + b3 X2 + b1 I],
                                  V = X6 (b12 X6 + b10 X4 + b8 X2) + b6 X6 + b4 X4 + b2 X2 + b0 I   (Xk = X^k),
    then r squared s times."""
    n = a.shape[0]
    norm1 = 0.0
    for j in range(n):
        col = 0.0
        for i in range(n):
            col += abs(a[i, j])
        norm1 = max(norm1, col)
    s = 0
    if norm1 > theta:
        s = int(math.ceil(math.log2(norm1 / theta)))
    x = a * (0.5 ** s)
    x2 = _matmul2(x, x)
    x4 = _matmul2(x2, x2)
    x6 = _matmul2(x4, x2)
    eye = np.eye(n)
    u_inner = _matmul2(x6, coef[13] * x6 + coef[11] * x4 + coef[9] * x2) + coef[7] * x6 + coef[5] * x4 \
        + coef[3] * x2 + coef[1] * eye
    u = _matmul2(x, u_inner)
    v = _matmul2(x6, coef[12] * x6 + coef[10] * x4 + coef[8] * x2) + coef[6] * x6 + coef[4] * x4 + coef[2] * x2 \
        + coef[0] * eye
    den = v - u
    r = v + u
    if not _solve_into(den, r):
        r[:, :] = np.nan
    for _ in range(s):
        r = _matmul2(r, r)
    return r


def expm(a: npt.ArrayLike) -> FloatArray:
    """Matrix exponential exp(A) of a square matrix (n, n): scaling and squaring with the [13/13] Pade approximant
    (Higham, SIAM J. Matrix Anal. Appl. 26(4), 2005), products and the solve from this module.

    Raises:
        NumericsError: not a square matrix, or non-finite entries.
    """
    m = np.array(a, dtype=np.float64, order="C")
    if m.ndim != 2 or m.shape[0] != m.shape[1]:
        raise NumericsError(f"expm needs a square matrix (n, n), got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise NumericsError("expm: the matrix has NaN or inf entries")
    return _expm(m, _PADE13, _THETA13)


__all__ = ["dot", "norm", "matvec", "matmul", "matmul_into", "solve", "symmetric_eig", "eigh_sym", "expm"]
