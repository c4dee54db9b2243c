"""SPD maps of rflow.manifolds.spd: affine-invariant Log/Exp, Mandel notation, Higham projection, LED."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from rflow.errors import RFlowError
from rflow.manifolds import spd

entries = st.floats(-3.0, 3.0, allow_nan=False)
small = st.floats(-1.0, 1.0, allow_nan=False)  # tangent entries: keeps expm well-conditioned in float64


def make_spd(a: np.ndarray) -> np.ndarray:
    return a @ a.T + 0.1 * np.eye(a.shape[0])


def make_sym(a: np.ndarray) -> np.ndarray:
    return 0.5 * (a + a.T)


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, (3, 3), elements=entries), arrays(np.float64, (3, 3), elements=entries))
def test_exp_inverts_log(a, b):
    p, g = make_spd(a), make_spd(b)
    assert np.allclose(spd.exp_map(spd.log_map(p, g), g), p, rtol=1e-6, atol=1e-8)


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, (2, 2), elements=small), arrays(np.float64, (2, 2), elements=entries))
def test_log_inverts_exp(a, b):
    v, g = make_sym(a), make_spd(b) + np.eye(2)
    assert np.allclose(spd.log_map(spd.exp_map(v, g), g), v, rtol=1e-6, atol=1e-8)


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, (2, 2), elements=small), arrays(np.float64, (2, 2), elements=entries))
def test_exp_gives_symmetric_positive_definite(a, b):
    p = spd.exp_map(make_sym(a), make_spd(b) + np.eye(2))
    assert np.allclose(p, p.T)
    assert np.linalg.eigvalsh(p).min() > 0


def test_log_matches_the_paper_formula():
    g = np.array([[2.0, 0.5], [0.5, 1.0]])
    p = np.array([[1.0, -0.2], [-0.2, 3.0]])
    lam, u = np.linalg.eigh(g)
    half, inv_half = u @ np.diag(lam**0.5) @ u.T, u @ np.diag(lam**-0.5) @ u.T
    lam_in, u_in = np.linalg.eigh(inv_half @ p @ inv_half)
    expected = half @ (u_in @ np.diag(np.log(lam_in)) @ u_in.T) @ half
    assert np.allclose(spd.log_map(p, g), expected)


def test_mandel_2x2_order():
    v = np.array([[1.0, 2.0], [2.0, 3.0]])
    assert np.allclose(spd.mandel(v), [1.0, 3.0, np.sqrt(2) * 2.0])


def test_mandel_3x3_order_is_diagonal_then_upper_row_major():
    v = np.array([[1.0, 4.0, 5.0], [4.0, 2.0, 6.0], [5.0, 6.0, 3.0]])
    assert np.allclose(spd.mandel(v), [1, 2, 3, 4 * np.sqrt(2), 5 * np.sqrt(2), 6 * np.sqrt(2)])


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, 10, elements=entries))
def test_mandel_inverse_round_trip_and_norm(x):
    v = spd.mandel_inverse(x)
    assert np.allclose(spd.mandel(v), x)
    assert np.isclose(np.linalg.norm(x), np.linalg.norm(v))


def test_nearest_spd_keeps_spd_input():
    p = make_spd(np.array([[1.0, 0.3], [0.2, 0.5]]))
    assert np.allclose(spd.nearest_spd(p), p)


def test_nearest_spd_projects_an_indefinite_matrix():
    a = np.array([[1.0, 2.0], [0.0, -1.0]])
    p = spd.nearest_spd(a)
    b = 0.5 * (a + a.T)
    lam, u = np.linalg.eigh(b)
    assert np.linalg.eigvalsh(p).min() > 0
    assert np.allclose(p, u @ np.diag(np.maximum(lam, 0)) @ u.T, atol=1e-8)


def test_log_euclidean_distance():
    s = np.diag([np.e, 1.0])
    assert np.isclose(spd.log_euclidean_distance(s, np.eye(2)), 1.0)
    assert np.isclose(spd.log_euclidean_distance(s, s), 0.0)


def test_numpy_equals_torch():
    rng = np.random.default_rng(0)
    p = np.stack([make_spd(rng.normal(size=(2, 2))) for _ in range(5)])
    g = make_spd(rng.normal(size=(2, 2)))
    v = spd.log_map(p, g)
    assert np.allclose(spd.log_map(torch.tensor(p), torch.tensor(g)).numpy(), v)
    assert np.allclose(spd.exp_map(torch.tensor(v), torch.tensor(g)).numpy(), spd.exp_map(v, g))
    assert np.allclose(spd.mandel(torch.tensor(v)).numpy(), spd.mandel(v))


@pytest.mark.parametrize(
    "p, message",
    [
        (np.array([[1.0, 0.5], [0.0, 1.0]]), "not symmetric"),
        (np.array([[1.0, 0.0], [0.0, -1.0]]), "not positive definite"),
        (np.array([[np.nan, 0.0], [0.0, 1.0]]), "NaN"),
        (np.ones((2, 3)), "shape"),
    ],
)
def test_bad_matrices_raise(p, message):
    with pytest.raises(RFlowError, match=message):
        spd.log_map(p, np.eye(2))


def test_mandel_length_must_be_triangular():
    with pytest.raises(RFlowError, match="d\\(d\\+1\\)/2"):
        spd.mandel_inverse(np.ones(4))
