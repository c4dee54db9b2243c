"""numerics.small_linalg against numpy's BLAS/LAPACK and scipy on random inputs (equal to rounding)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from numerics import small_linalg as sl
from numerics.errors import NumericsError

RTOL = 1e-13


def _close(actual, expected, rtol=RTOL):
    """|actual - expected| <= rtol max |expected| entrywise (a relative bound that tolerates entries near 0)."""
    expected = np.asarray(expected)
    assert np.shape(actual) == expected.shape
    np.testing.assert_allclose(actual, expected, rtol=0.0, atol=rtol * max(float(np.abs(expected).max()), 1e-300))


@pytest.mark.parametrize("n", [2, 3, 4, 6, 12])
def test_dot_norm_and_matvec_equal_numpy(n):
    rng = np.random.default_rng(n)
    a, b, c, m = rng.normal(size=n), rng.normal(size=n), rng.normal(size=n + 1), rng.normal(size=(n + 1, n))
    assert sl.dot(a, b) == pytest.approx(float(np.dot(a, b)), rel=RTOL, abs=RTOL)
    assert sl.norm(a) == pytest.approx(float(np.linalg.norm(a)), rel=RTOL)
    _close(sl.matvec(m, b), m @ b)
    _close(sl.matvec(m.T, c), m.T @ c)  # a transposed (strided) matrix


def test_matvec_and_dot_refuse_mismatched_lengths():
    with pytest.raises(ValueError):
        sl.matvec(np.eye(3), np.ones(4))
    with pytest.raises(ValueError):
        sl.dot(np.ones(3), np.ones(2))


@pytest.mark.parametrize("shape_a, shape_b", [
    ((3, 3), (3, 3)), ((6, 4), (4, 2)), ((4,), (4, 3)), ((3, 4), (4,)), ((5,), (5,)),
    ((7, 5, 3), (3, 3)),          # a batch times one matrix (the latent rollouts)
    ((3, 3), (2, 5, 3, 4)),       # one matrix times a batch
    ((5, 1, 3, 3), (4, 3, 3)),    # broadcast leading axes
])
def test_matmul_equals_numpy_matmul_with_its_shapes(shape_a, shape_b):
    rng = np.random.default_rng(len(shape_a) * 10 + len(shape_b))
    a, b = rng.normal(size=shape_a), rng.normal(size=shape_b)
    _close(sl.matmul(a, b), np.matmul(a, b))


def test_matmul_refuses_inner_dimensions_that_differ():
    with pytest.raises(NumericsError, match="inner dimensions"):
        sl.matmul(np.ones((2, 3)), np.ones((4, 2)))


@pytest.mark.parametrize("n", [2, 3, 6, 12])
def test_solve_equals_numpy_for_vectors_and_matrices(n):
    rng = np.random.default_rng(n)
    a = rng.normal(size=(n, n)) + n * np.eye(n)
    b, c = rng.normal(size=n), rng.normal(size=(n, 3))
    _close(sl.solve(a, b), np.linalg.solve(a, b), 1e-12)
    _close(sl.solve(a, c), np.linalg.solve(a, c), 1e-12)
    p = np.roll(np.eye(n), 1, axis=0) + 1e-3 * a  # a zero diagonal: only pivoting solves it
    _close(sl.solve(p, b), np.linalg.solve(p, b), 1e-12)


def test_solve_refuses_a_singular_matrix():
    with pytest.raises(NumericsError, match="singular"):
        sl.solve(np.array([[1.0, 2.0], [2.0, 4.0]]), np.ones(2))


@pytest.mark.parametrize("seed", range(6))
def test_eigh_sym_equals_numpy_eigh(seed):
    rng = np.random.default_rng(seed)
    n = (2, 3, 6)[seed % 3]
    x = rng.normal(size=(4, n, n))
    a = x + np.swapaxes(x, -1, -2)  # indefinite symmetric, batched
    if seed == 0:
        a[0] = np.diag([3.0, 3.0, 1.0, 1.0, 1.0, 1.0][:n])  # repeated eigenvalues
    w, v = sl.eigh_sym(a)
    _close(w, np.linalg.eigvalsh(a), 1e-12)
    assert np.all(np.diff(w, axis=-1) >= 0.0)  # ascending, as eigh
    _close(v @ (w[..., None] * np.swapaxes(v, -1, -2)), a, 1e-12)
    _close(np.swapaxes(v, -1, -2) @ v, np.broadcast_to(np.eye(n), a.shape), 1e-12)


def test_eigh_sym_reads_the_lower_triangle_as_numpy_does():
    a = np.array([[2.0, 99.0], [1.0, 3.0]])  # only the lower triangle is the matrix [[2, 1], [1, 3]]
    _close(sl.eigh_sym(a)[0], np.linalg.eigvalsh(a))


@pytest.mark.parametrize("scale", [1e-3, 0.3, 3.0, 40.0])
def test_expm_equals_scipy(scale):
    rng = np.random.default_rng(int(scale * 1000))
    n = 12
    a = scale * rng.normal(size=(n, n)) / np.sqrt(n)  # 1-norms from ~1e-3 to ~150: with and without squaring
    _close(sl.expm(a), scipy.linalg.expm(a))


def test_expm_of_a_stable_drift_equals_scipy():
    rng = np.random.default_rng(0)
    lower, skew = np.tril(rng.normal(size=(6, 6))), rng.normal(size=(6, 6))
    drift = -(lower @ lower.T + 0.1 * np.eye(6)) + (skew - skew.T)  # the form of rflow.dynamics' drift matrix
    for dt in (0.001, 0.01, 0.05, 1.0):
        _close(sl.expm(drift * dt), scipy.linalg.expm(drift * dt))


def test_expm_refuses_non_finite_and_non_square_input():
    with pytest.raises(NumericsError, match="NaN"):
        sl.expm(np.full((2, 2), np.nan))
    with pytest.raises(NumericsError, match="square"):
        sl.expm(np.ones((2, 3)))
