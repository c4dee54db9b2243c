"""Unit quaternion maps of rflow.manifolds.sphere: the paper's Log/Exp (no factor 2) and helpers."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from numerics.quaternion import quat_conj, quat_mul
from rflow.errors import RFlowError
from rflow.manifolds import sphere

finite = st.floats(-1.0, 1.0, allow_nan=False)
vec4 = arrays(np.float64, 4, elements=finite).filter(lambda v: np.linalg.norm(v) > 0.1)
vec3 = arrays(np.float64, 3, elements=finite)


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


@settings(max_examples=100, deadline=None)
@given(vec4, vec4)
def test_exp_inverts_log(q, base):
    q, base = unit(q), unit(base)
    assert np.allclose(sphere.exp_map(sphere.log_map(q, base), base), q, atol=1e-9)


@settings(max_examples=100, deadline=None)
@given(vec3, vec4, st.floats(0.0, np.pi - 1e-3))
def test_log_inverts_exp_inside_injectivity_radius(direction, base, length):
    norm = np.linalg.norm(direction)
    v = direction / norm * length if norm > 1e-6 else 0 * direction
    assert np.allclose(sphere.log_map(sphere.exp_map(v, unit(base)), unit(base)), v, atol=1e-8)


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, 3, elements=st.floats(-10, 10)), vec4)
def test_exp_gives_unit_quaternions(v, base):
    assert np.isclose(np.linalg.norm(sphere.exp_map(v, unit(base))), 1.0, atol=1e-12)


def test_log_has_no_factor_two():
    angle = 0.7  # q = cos(a) + sin(a) x  ->  Log(q) = a x
    q = np.array([np.cos(angle), np.sin(angle), 0.0, 0.0])
    assert np.allclose(sphere.log_map(q, np.array([1.0, 0, 0, 0])), [angle, 0, 0])


def test_log_uses_q_times_conj_base():
    rng = np.random.default_rng(1)
    q, g = unit(rng.normal(size=4)), unit(rng.normal(size=4))
    expected = sphere.quat_log(quat_mul(q, quat_conj(g)))
    assert np.allclose(sphere.log_map(q, g), expected)
    assert not np.allclose(sphere.log_map(q, g), sphere.quat_log(quat_mul(quat_conj(g), q)))


def test_log_is_accurate_near_the_base():
    v = np.array([1e-9, -2e-9, 3e-10])
    g = unit(np.array([0.3, -0.2, 0.9, 0.1]))
    assert np.allclose(sphere.log_map(sphere.exp_map(v, g), g), v, rtol=1e-6, atol=1e-20)


def test_log_is_finite_near_the_antipode():
    v = np.array([0.0, np.pi - 1e-7, 0.0])
    g = np.array([1.0, 0, 0, 0])
    assert np.allclose(sphere.log_map(sphere.exp_map(v, g), g), v, atol=1e-6)
    assert np.allclose(np.linalg.norm(sphere.log_map(-g, g)), np.pi)


def test_distance_is_twice_the_log_norm():
    g = unit(np.array([0.1, 0.2, 0.3, 0.9]))
    v = np.array([0.1, -0.2, 0.3])
    assert np.isclose(sphere.distance(sphere.exp_map(v, g), g), 2 * np.linalg.norm(v))


def test_make_continuous_removes_sign_flips():
    rng = np.random.default_rng(2)
    path = sphere.exp_map(np.linspace(0, 1, 50)[:, None] * rng.normal(size=3), np.array([1.0, 0, 0, 0]))
    flipped = path * rng.choice([-1.0, 1.0], size=(50, 1))
    fixed = sphere.make_continuous(flipped)
    assert np.all(np.sum(fixed[1:] * fixed[:-1], axis=-1) >= 0)
    assert np.allclose(np.abs(np.sum(fixed * path, axis=-1)), 1.0)


def test_numpy_equals_torch():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(20, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    g = q[0]
    v = sphere.log_map(q, g)
    vt = sphere.log_map(torch.tensor(q), torch.tensor(g))
    assert isinstance(vt, torch.Tensor)
    assert np.allclose(vt.numpy(), v, atol=1e-12)
    assert np.allclose(sphere.exp_map(torch.tensor(v), torch.tensor(g)).numpy(), sphere.exp_map(v, g), atol=1e-12)


def test_torch_gradients_are_finite_at_the_base():
    v = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    sphere.exp_map(v, torch.tensor([1.0, 0, 0, 0], dtype=torch.float64)).sum().backward()
    assert torch.isfinite(v.grad).all()


@pytest.mark.parametrize(
    "q, message",
    [
        (np.array([1.0, 0.1, 0.0, 0.0]), "not a unit quaternion"),
        (np.array([np.nan, 0.0, 0.0, 0.0]), "NaN"),
        (np.array([1.0, 0.0, 0.0]), "shape"),
    ],
)
def test_bad_quaternions_raise(q, message):
    with pytest.raises(RFlowError, match=message):
        sphere.log_map(q, np.array([1.0, 0, 0, 0]))
