"""numerics.quaternion, the one definition of the quaternion algebra, against scipy's Rotation and its own
identities."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from numerics.errors import NumericsError
from numerics.quaternion import (mat_to_quat, quat_angle_rad, quat_conj, quat_from_rotvec, quat_mul, quat_mul_one,
                                 quat_to_mat, quat_to_rotvec, rotate, slerp)

rotvecs = st.lists(st.floats(-1.8, 1.8), min_size=3, max_size=3).map(np.array)
unit = st.floats(-1.0, 1.0, allow_nan=False)
quats = st.tuples(unit, unit, unit, unit).filter(lambda q: np.linalg.norm(q) > 0.1).map(
    lambda q: np.asarray(q) / np.linalg.norm(q))


def scipy_rotation(q: np.ndarray) -> Rotation:
    """scipy orders quaternions (x, y, z, w)."""
    return Rotation.from_quat(np.roll(q, -1))


@given(quats, quats)
def test_product_is_scipys_composition(a: np.ndarray, b: np.ndarray) -> None:
    want = (scipy_rotation(a) * scipy_rotation(b)).as_matrix()
    np.testing.assert_allclose(quat_to_mat(quat_mul(a, b)), want, atol=1e-12)


@given(quats)
def test_matrix_is_scipys(q: np.ndarray) -> None:
    np.testing.assert_allclose(quat_to_mat(q), scipy_rotation(q).as_matrix(), atol=1e-12)


@given(quats)
def test_matrix_to_quaternion_is_scipys_on_the_w_positive_hemisphere(q: np.ndarray) -> None:
    got = mat_to_quat(scipy_rotation(q).as_matrix())
    want = np.roll(scipy_rotation(q).as_quat(), 1)
    want = want if want[0] >= 0.0 else -want
    assert got[0] >= 0.0
    if abs(want[0]) > 1e-9:  # at w = 0, q and -q are both on the hemisphere's edge
        np.testing.assert_allclose(got, want, atol=1e-12)


@given(rotvecs)
def test_rotation_vector_is_scipys(r: np.ndarray) -> None:
    np.testing.assert_allclose(quat_to_mat(quat_from_rotvec(r)), Rotation.from_rotvec(r).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(quat_to_rotvec(quat_from_rotvec(r)), r, atol=1e-9)


@given(rotvecs)
def test_quaternion_times_conjugate_is_identity(r: np.ndarray) -> None:
    q = quat_from_rotvec(r)
    np.testing.assert_allclose(quat_mul(q, quat_conj(q)), [1.0, 0.0, 0.0, 0.0], atol=1e-12)


def test_rotate_quarter_turn_about_z() -> None:
    q = quat_from_rotvec([0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(rotate(q, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-12)


@given(rotvecs, rotvecs, st.floats(0.0, 1.0))
def test_slerp_splits_the_angle(a: np.ndarray, b: np.ndarray, s: float) -> None:
    q0, q1 = quat_from_rotvec(a), quat_from_rotvec(b)
    total = quat_angle_rad(q0, q1)
    mid = slerp(q0, q1, s)
    assert quat_angle_rad(q0, mid) == pytest.approx(s * total, abs=1e-7)


def test_one_product_for_arrays_tensors_and_python_floats() -> None:
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(5, 4)), rng.normal(size=(5, 4))
    arrays = quat_mul(a, b)
    tensors = quat_mul(torch.tensor(a), torch.tensor(b))
    assert isinstance(tensors, torch.Tensor)
    assert np.array_equal(tensors.numpy(), arrays)
    assert np.array_equal([quat_mul_one(list(x), list(y)) for x, y in zip(a, b)], arrays)
    assert np.array_equal(quat_mul(a[0], b), quat_mul(np.broadcast_to(a[0], (5, 4)), b))  # broadcast


def test_a_zero_quaternion_has_no_matrix() -> None:
    with pytest.raises(NumericsError, match="zero norm"):
        quat_to_mat([0.0, 0.0, 0.0, 0.0])


def test_a_matrix_must_be_three_by_three_and_finite() -> None:
    with pytest.raises(NumericsError, match="3x3"):
        mat_to_quat(np.eye(4))
    with pytest.raises(NumericsError, match="3x3"):
        mat_to_quat(np.full((3, 3), np.nan))


@pytest.mark.parametrize("q0, q1, s, words", [
    ([0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], 0.5, "q0 is not a unit quaternion: norm 0"),  # returned zeros
    ([1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], 0.5, "q1 is not a unit quaternion"),  # returned q0
    ([2.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], 0.5, "q0 is not a unit quaternion: norm 2"),  # returned (2, 0, 0, 0)
    ([[1.0, 0.0, 0.0, 0.0], [np.nan, 0.0, 0.0, 1.0]], [1.0, 0.0, 0.0, 0.0], 0.5, r"q0 at \[1\] contains NaN"),
    ([1.0, 0.0, 0.0, 0.0], [np.inf, 0.0, 0.0, 0.0], 0.5, "q1 contains NaN or inf"),
    ([1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], np.nan, "s contains NaN"),  # returned NaN
    ([1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], 0.5, r"q0 has shape \(3,\)"),  # numpy's broadcasting error
    ("abcd", [1.0, 0.0, 0.0, 0.0], 0.5, "q0 is not an array of numbers"),
    (np.tile([1.0, 0.0, 0.0, 0.0], (3, 1)), [1.0, 0.0, 0.0, 0.0], [0.1, 0.2], "do not broadcast"),
])
def test_slerp_refuses_what_is_no_unit_quaternion_or_finite_fraction_by_name(q0, q1, s, words) -> None:
    with pytest.raises(NumericsError, match=words):
        slerp(q0, q1, s)


@pytest.mark.parametrize("matrix, words", [
    (np.ones((3, 3)), "no rotation"),  # Shepperd's method returned (1, 0, 0, 0)
    (np.zeros((3, 3)), "no rotation"),
    (2.0 * np.eye(3), "no rotation"),  # scaled
    (np.diag([1.0, 1.0, -1.0]), "det R = -1"),  # a reflection
    ([[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "no rotation"),  # sheared
    ("abc", "3x3 numbers"),  # numpy's ValueError
])
def test_a_matrix_that_is_no_rotation_has_no_quaternion(matrix, words) -> None:
    with pytest.raises(NumericsError, match=words):
        mat_to_quat(matrix)


def test_rotations_and_quaternions_rounded_to_float32_are_still_taken() -> None:
    """The refusals above leave room for data stored in float32 (a recording, a dataset): 500 random rotations
    rounded to float32 have a quaternion, and their float32 quaternions interpolate (the tolerances, 1e-5 on
    ||R^T R - I|| and 1e-3 on ||q||, lie far above float32's 1e-7)."""
    rotations = Rotation.random(500, random_state=7)
    for matrix in rotations.as_matrix().astype(np.float32):
        q = mat_to_quat(matrix)
        assert abs(np.linalg.norm(q) - 1.0) < 1e-6
    quats = rotations.as_quat(scalar_first=True).astype(np.float32)
    out = slerp(quats[:-1], quats[1:], np.full(499, 0.3))
    assert out.shape == (499, 4) and np.all(np.isfinite(out))
