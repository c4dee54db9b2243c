"""Signals resampled onto a dataset's integer frame rate (envs/datasets/resample.py): the frame count, samples copied
where a frame meets them, measurements interpolated, commands held, quaternions by slerp."""

from __future__ import annotations

import numpy as np
import pytest

from envs.datasets.resample import frame_times, held, interpolated, interpolated_pose
from envs.errors import EnvError
from envs.poses import quat_angle_rad, quat_from_rotvec


def test_the_frames_of_a_7_s_signal_at_integer_rates() -> None:
    assert len(frame_times(7.0, 100)) == 701 and len(frame_times(7.0, 50)) == 351 and len(frame_times(7.0, 30)) == 211
    assert len(frame_times(3999 * (7.0 / 3999), 100)) == 701  # the duration of 4000 samples 7 / 3999 s apart
    with pytest.raises(EnvError, match="integer"):
        frame_times(7.0, 571.4)


def test_a_frame_on_a_sample_copies_it_bit_for_bit() -> None:
    rng = np.random.default_rng(0)
    values = rng.normal(size=(701, 6))
    times = frame_times(7.0, 50)
    np.testing.assert_array_equal(interpolated(values, 0.01, times), values[::2])
    np.testing.assert_array_equal(held(values, 0.01, times), values[::2])


def test_measurements_are_interpolated_and_commands_held_between_samples() -> None:
    values = np.arange(5.0)[:, None] * [1.0, 10.0]  # samples 0.1 s apart
    times = np.array([0.05, 0.25, 0.4])
    np.testing.assert_allclose(interpolated(values, 0.1, times), [[0.5, 5.0], [2.5, 25.0], [4.0, 40.0]])
    np.testing.assert_array_equal(held(values, 0.1, times), values[[0, 2, 4]])


def test_orientations_are_slerped_and_stay_unit() -> None:
    q0 = np.array([1.0, 0.0, 0.0, 0.0])
    q1 = quat_from_rotvec([0.0, 0.0, 0.4])
    pose = np.array([[0.0, 0.0, 0.0, *q0], [1.0, 0.0, 0.0, *(-q1)]])  # the second on the other hemisphere
    out = interpolated_pose(pose, 1.0, np.array([0.0, 0.25, 1.0]))
    np.testing.assert_allclose(np.linalg.norm(out[:, 3:], axis=1), 1.0, atol=1e-15)
    assert quat_angle_rad(out[1, 3:], quat_from_rotvec([0.0, 0.0, 0.1])) < 1e-12 and out[1, 0] == 0.25
