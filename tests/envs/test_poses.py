"""Pose validation, trajectory resampling, time scalings and start-pose sampling (the quaternion algebra:
tests/numerics/test_quaternion.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from envs.errors import EnvError
from envs.poses import (
    Pose,
    StartRegion,
    make_continuous,
    minimum_jerk,
    quintic_hermite,
    resample_trajectory,
    sample_start_poses,
    validate_pose,
)
from numerics.quaternion import quat_angle_rad, quat_from_rotvec, quat_to_rotvec


def test_make_continuous_removes_sign_flips_and_ends_on_reference() -> None:
    q = np.array([[1.0, 0, 0, 0], [-1.0, 0, 0, 0], [1.0, 0, 0, 0]])
    out = make_continuous(q, reference=[-1.0, 0, 0, 0])
    assert np.all(out[:, 0] == -1.0)


def test_resample_is_exact_for_linear_motion() -> None:
    t = np.linspace(0.0, 1.0, 11)
    pos = np.outer(t, [1.0, 2.0, 3.0])
    quat = quat_from_rotvec(np.outer(t, [0.0, 0.0, 1.0]))
    new_t = np.linspace(0.0, 1.0, 37)
    new_pos, new_quat = resample_trajectory(t, pos, quat, new_t)
    np.testing.assert_allclose(new_pos, np.outer(new_t, [1.0, 2.0, 3.0]), atol=1e-12)
    np.testing.assert_allclose(quat_to_rotvec(new_quat)[:, 2], new_t, atol=1e-9)


def test_resample_rejects_non_increasing_times() -> None:
    with pytest.raises(EnvError, match="strictly increasing"):
        resample_trajectory([0.0, 0.0], np.zeros((2, 3)), np.tile([1.0, 0, 0, 0], (2, 1)), [0.0])


def test_minimum_jerk_has_zero_end_velocities() -> None:
    s = np.array([0.0, 1e-4, 1.0 - 1e-4, 1.0])
    values = minimum_jerk(s)
    assert values[0] == 0.0 and values[-1] == 1.0
    assert values[1] < 1e-9 and 1.0 - values[2] < 1e-9


def test_quintic_hermite_meets_its_end_velocities() -> None:
    h = 1e-6
    p = lambda s: quintic_hermite(s, 1.0, -0.3, 0.2, -0.5)  # noqa: E731
    assert (p(h) - p(0.0)) / h == pytest.approx(-0.3, abs=1e-4)
    assert (p(1.0) - p(1.0 - h)) / h == pytest.approx(-0.5, abs=1e-4)


def test_validate_pose_rejects_non_unit_quaternion() -> None:
    with pytest.raises(EnvError, match="not unit"):
        validate_pose([0.0, 0.0, 0.0], [1.0, 0.1, 0.0, 0.0])


def test_validate_pose_rejects_nan() -> None:
    with pytest.raises(EnvError, match="NaN"):
        validate_pose([0.0, np.nan, 0.0], [1.0, 0.0, 0.0, 0.0])


@settings(max_examples=20)
@given(st.integers(0, 2**32 - 1))
def test_sampled_starts_lie_in_the_region(seed: int) -> None:
    region = StartRegion()
    nominal = Pose(np.array([0.5, 0.0, 0.4]), np.array([0.0, 1.0, 0.0, 0.0]))
    for pose in sample_start_poses(nominal, region, np.random.default_rng(seed), 20):
        assert np.all(np.abs(pose.pos - nominal.pos) <= np.array(region.pos_half_width_m) + 1e-12)
        assert np.rad2deg(quat_angle_rad(pose.quat, nominal.quat)) <= region.max_angle_deg + 1e-9


def test_start_region_rejects_negative_widths() -> None:
    with pytest.raises(EnvError, match="pos_half_width_m"):
        StartRegion(pos_half_width_m=(0.1, -0.1, 0.1))


@pytest.mark.parametrize("column, value, words", [
    ("quat", [0.0, 0.0, 0.0, 0.0], "quat .* at sample 2 is not a unit quaternion"),  # resampled into NaN before
    ("quat", [np.nan, 0.0, 0.0, 1.0], "quat contains NaN or inf"),
    ("pos", [np.inf, 0.0, 0.0], "pos contains NaN or inf"),
    ("times", np.nan, "times contains NaN or inf"),  # NaN passed the strictly-increasing check
    ("new_times", np.nan, "new_times contains NaN or inf"),
    ("new_times", "x", "new_times must be an array of numbers"),  # numpy's ValueError
])
def test_resample_refuses_a_trajectory_that_is_no_finite_poses_by_name(column, value, words) -> None:
    arrays = {"times": np.linspace(0.0, 1.0, 5), "pos": np.zeros((5, 3)), "quat": np.tile([1.0, 0.0, 0.0, 0.0], (5, 1)),
              "new_times": np.array([0.1, 0.5])}
    if column == "new_times":
        arrays[column] = value if isinstance(value, str) else np.array([0.1, value])
    else:
        arrays[column][2] = value
    with pytest.raises(EnvError, match=f"resample_trajectory: {words}"):
        resample_trajectory(arrays["times"], arrays["pos"], arrays["quat"], arrays["new_times"])
