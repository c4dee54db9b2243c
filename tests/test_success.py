"""Tests of envs.success: insertion state in the hole frame, criteria, wrong hole, hold time."""

import numpy as np
import pytest

from envs.errors import EnvError
from envs.geometry import R_FLIP_X, mat_to_quat, quat_to_mat, rot_z
from envs.success import (
    HoleSpec,
    SuccessConfig,
    SuccessTracker,
    assess_insertion,
    insertion_state,
    wrap_symmetric_deg,
)

YAW = np.deg2rad(-14.4)
HOLE_QUAT = tuple(mat_to_quat(rot_z(YAW)))
TARGET_DEPTH_M = 0.03


def hole(shape="square", pos=(0.675, -0.051, 0.233), order=4, clearance_m=0.001):
    return HoleSpec(shape, pos, HOLE_QUAT, order, 0.0155, 0.04, clearance_m)


HOLES = {"square": hole(), "triangle": hole("triangle", (0.675 + 0.2, -0.051, 0.233), 3)}


def peg_tip(hole_spec, offset_in_hole=(0.0, 0.0, -TARGET_DEPTH_M), tilt_deg=0.0, yaw_deg=0.0):
    """peg_tip pose at ``offset_in_hole`` (hole frame), turned by yaw about and tilted about x from the goal."""
    rot_hole = quat_to_mat(hole_spec.quat)
    tilt = np.deg2rad(tilt_deg)
    rot_x = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
    rot = rot_hole @ rot_z(np.deg2rad(yaw_deg)) @ rot_x @ R_FLIP_X
    return np.asarray(hole_spec.pos) + rot_hole @ np.asarray(offset_in_hole), mat_to_quat(rot)


def assess(pos_quat, target="square"):
    return assess_insertion(*pos_quat, HOLES, target, TARGET_DEPTH_M)


def test_goal_pose_has_target_depth_and_no_error():
    state = insertion_state(*peg_tip(HOLES["square"]), HOLES["square"])
    assert np.allclose([state.depth_m, state.lateral_m, state.tilt_deg, state.yaw_error_deg], [0.03, 0, 0, 0])


def test_goal_pose_is_inserted():
    assert assess(peg_tip(HOLES["square"])).inserted


def test_above_the_hole_is_not_inserted():
    result = assess(peg_tip(HOLES["square"], (0.0, 0.0, 0.01)))
    assert result.hole is None and not result.inserted


def test_shallow_insertion_is_not_inserted():
    result = assess(peg_tip(HOLES["square"], (0.0, 0.0, -0.8 * TARGET_DEPTH_M)))
    assert result.hole == "square" and not result.inserted


def test_beside_the_hole_is_not_in_it():
    assert assess(peg_tip(HOLES["square"], (0.05, 0.0, -TARGET_DEPTH_M))).hole is None


def test_lateral_offset_beyond_tolerance_is_not_inserted():
    result = assess(peg_tip(HOLES["square"], (0.0012, 0.0, -TARGET_DEPTH_M)))
    assert result.hole == "square" and not result.inserted


def test_lateral_offset_within_half_clearance_is_inserted():
    assert assess(peg_tip(HOLES["square"], (0.0, 0.0005, -TARGET_DEPTH_M))).inserted


def test_tilted_peg_is_not_inserted():
    assert not assess(peg_tip(HOLES["square"], tilt_deg=10.0)).inserted


def test_tilt_is_measured_against_the_hole_axis():
    state = insertion_state(*peg_tip(HOLES["square"], tilt_deg=10.0), HOLES["square"])
    assert np.isclose(state.tilt_deg, 10.0)


def test_yaw_error_is_not_inserted():
    assert not assess(peg_tip(HOLES["square"], yaw_deg=20.0)).inserted


def test_quarter_turn_of_a_square_peg_is_inserted():
    assert assess(peg_tip(HOLES["square"], yaw_deg=90.0)).inserted


def test_round_hole_ignores_yaw():
    round_hole = hole("circle", order=0)
    assert insertion_state(*peg_tip(round_hole, yaw_deg=37.0), round_hole).yaw_error_deg == 0.0


def test_wrong_hole_is_reported_and_not_inserted():
    result = assess(peg_tip(HOLES["triangle"]), target="square")
    assert result.hole == "triangle" and not result.inserted


def test_peg_lying_on_the_top_is_in_no_hole():
    """A square peg resting over the triangle hole sinks by contact penetration only."""
    assert assess(peg_tip(HOLES["triangle"], (0.0, 0.0, -1e-5))).hole is None


def test_peg_through_the_floor_is_in_no_hole():
    assert assess(peg_tip(HOLES["square"], (0.0, 0.0, -0.05))).hole is None


def test_unknown_target_is_rejected():
    with pytest.raises(EnvError, match="hexagon"):
        assess(peg_tip(HOLES["square"]), target="hexagon")


@pytest.mark.parametrize("angle, order, expected", [(95.0, 4, 5.0), (-125.0, 3, -5.0), (180.0, 2, 0.0), (45.0, 4, 45.0)])
def test_wrap_symmetric(angle, order, expected):
    assert np.isclose(wrap_symmetric_deg(angle, order), expected)


def test_tracker_needs_the_full_hold_time():
    tracker = SuccessTracker(SuccessConfig(hold_s=0.2))
    assert not any(tracker.update(t, True) for t in np.arange(0.0, 0.19, 0.01))


def test_tracker_succeeds_after_the_hold_time():
    tracker = SuccessTracker(SuccessConfig(hold_s=0.2))
    results = [tracker.update(t, True) for t in np.arange(0.0, 0.25, 0.01)]
    assert results[-1] and np.isclose(tracker.success_time_s, 0.2)


def test_tracker_restarts_the_clock_after_an_interruption():
    tracker = SuccessTracker(SuccessConfig(hold_s=0.2))
    for t in np.arange(0.0, 0.15, 0.01):
        tracker.update(t, True)
    tracker.update(0.15, False)
    assert not any(tracker.update(t, True) for t in np.arange(0.16, 0.35, 0.01))


def test_tracker_success_latches():
    tracker = SuccessTracker(SuccessConfig(hold_s=0.0))
    tracker.update(0.0, True)
    assert tracker.update(0.1, False)


def test_tracker_rejects_time_running_backwards():
    tracker = SuccessTracker()
    tracker.update(1.0, False)
    with pytest.raises(EnvError, match="reset"):
        tracker.update(0.5, False)


def test_bad_success_config_is_rejected():
    with pytest.raises(EnvError, match="depth_fraction"):
        SuccessConfig(depth_fraction=1.5)
