"""Tests of envs.task.success: insertion state in the hole frame, seated inside the walls at rest, wrong hole, hold."""

import numpy as np
import pytest

from envs.cell.hole import HoleSpec
from envs.cell.shapes import hole_inradius_m, hole_polygon, peg_cross_section
from envs.errors import EnvError
from envs.geometry import R_FLIP_X, rot_z
from envs.task.success import (
    EpisodeHoles,
    PegFootprint,
    SuccessConfig,
    SuccessTracker,
    assess_insertion,
    insertion_state,
    wrap_symmetric_deg,
)
from numerics.quaternion import mat_to_quat, quat_to_mat

YAW = np.deg2rad(-14.4)
HOLE_QUAT = tuple(mat_to_quat(rot_z(YAW)))
TARGET_DEPTH_M = 0.03
CLEARANCE_M = 0.001
SQUARE = peg_cross_section("square")
CONFIG = SuccessConfig()


def hole(shape="square", pos=(0.675, -0.051, 0.233), order=4, clearance_m=CLEARANCE_M, chamfer_m=0.0):
    polygon = hole_polygon(shape, clearance_m)
    return HoleSpec(shape, pos, HOLE_QUAT, order, hole_inradius_m(shape, clearance_m), 0.04, clearance_m,
                    tuple(map(tuple, polygon)), chamfer_m)


HOLES = {"square": hole(), "triangle": hole("triangle", (0.675 + 0.2, -0.051, 0.233), 3)}


def peg_tip(hole_spec, offset_in_hole=(0.0, 0.0, -TARGET_DEPTH_M), tilt_deg=0.0, yaw_deg=0.0):
    """peg_tip pose at ``offset_in_hole`` (hole frame), turned by yaw about and tilted about x from the goal."""
    rot_hole = quat_to_mat(hole_spec.quat)
    tilt = np.deg2rad(tilt_deg)
    rot_x = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
    rot = rot_hole @ rot_z(np.deg2rad(yaw_deg)) @ rot_x @ R_FLIP_X
    return np.asarray(hole_spec.pos) + rot_hole @ np.asarray(offset_in_hole), mat_to_quat(rot)


def assess(pos_quat, target="square", speed=0.0, peg=SQUARE):
    return assess_insertion(*pos_quat, HOLES, target, TARGET_DEPTH_M, CONFIG, peg, speed)


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


def test_lateral_offset_the_walls_allow_is_inserted():
    assert assess(peg_tip(HOLES["square"], (0.0, 0.00049, -TARGET_DEPTH_M))).inserted


def test_lateral_offset_that_needs_wall_penetration_is_not_inserted():
    """0.9 mm off the axis in a 1 mm clearance: the peg would sit 0.4 mm inside a wall."""
    result = assess(peg_tip(HOLES["square"], (0.0009, 0.0, -TARGET_DEPTH_M)))
    assert result.hole == "square" and not result.inserted
    assert result.state.wall_penetration_m == pytest.approx(0.0009 - CLEARANCE_M / 2, abs=1e-9)


def test_tilt_the_walls_allow_is_inserted():
    """A 0.5 deg tilt about the tip moves the peg's edge at the opening by 30 mm x tan(0.5 deg) = 0.26 mm."""
    assert assess(peg_tip(HOLES["square"], tilt_deg=0.5)).inserted


def test_tilt_that_needs_wall_penetration_is_not_inserted():
    """2.5 deg in a 1 mm clearance: the side at the opening would be 1.3 mm off, 0.8 mm into the wall."""
    state = assess(peg_tip(HOLES["square"], tilt_deg=2.5)).state
    assert not assess(peg_tip(HOLES["square"], tilt_deg=2.5)).inserted
    expected = (np.cos(np.deg2rad(2.5)) - 1) * 0.015 + TARGET_DEPTH_M * np.tan(np.deg2rad(2.5)) - CLEARANCE_M / 2
    assert state.wall_penetration_m > 0.0005 and state.wall_penetration_m == pytest.approx(expected, rel=0.1)


def test_tilt_is_measured_against_the_hole_axis():
    state = insertion_state(*peg_tip(HOLES["square"], tilt_deg=10.0), HOLES["square"])
    assert np.isclose(state.tilt_deg, 10.0)


def test_yaw_the_walls_forbid_is_not_inserted():
    """A square turned 3 deg reaches 15 mm (cos 3 + sin 3) = 15.77 mm, past the hole's 15.5 mm."""
    assert not assess(peg_tip(HOLES["square"], yaw_deg=3.0)).inserted


def test_quarter_turn_of_a_square_peg_is_inserted():
    assert assess(peg_tip(HOLES["square"], yaw_deg=90.0)).inserted


def test_seated_within_a_millimetre_is_inserted():
    assert assess(peg_tip(HOLES["square"], (0.0, 0.0, -(TARGET_DEPTH_M - 0.0009)))).inserted


def test_still_descending_is_not_inserted():
    """27.4 mm of a 30 mm target (what the old criterion accepted) is not seated."""
    assert not assess(peg_tip(HOLES["square"], (0.0, 0.0, -0.0274))).inserted


def test_a_moving_peg_is_not_at_rest():
    assert not assess(peg_tip(HOLES["square"]), speed=0.02).inserted
    assert not assess(peg_tip(HOLES["square"]), speed=float("nan")).inserted


def test_round_peg_penetration_uses_its_radius():
    round_hole = hole("circle", order=0)
    circle = peg_cross_section("circle")
    inside = insertion_state(*peg_tip(round_hole, (0.0004, 0.0, -TARGET_DEPTH_M)), round_hole, circle, 0.0)
    outside = insertion_state(*peg_tip(round_hole, (0.0007, 0.0, -TARGET_DEPTH_M)), round_hole, circle, 0.0)
    assert inside.wall_penetration_m < 0.0 < outside.wall_penetration_m


def test_chamfer_moves_the_wall_check_below_the_bevel():
    """A 1.02 deg tilt puts the peg's side 30 mm x tan(1.02 deg) = 0.534 mm off at the opening (past the 0.5 mm
    gap) but 27 mm x tan(1.02 deg) = 0.481 mm off where 3 mm bevels end: allowed with them, not without."""
    chamfered = hole(chamfer_m=0.003)
    pose = peg_tip(chamfered, tilt_deg=1.02)
    plain = insertion_state(*pose, hole(), SQUARE, 0.0).wall_penetration_m
    bevelled = insertion_state(*pose, chamfered, SQUARE, 0.0).wall_penetration_m
    assert bevelled < plain and bevelled < CONFIG.penetration_tolerance_m < plain


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


@pytest.mark.parametrize("field", ["seat_tolerance_m", "penetration_tolerance_m", "max_speed_m_s", "hold_s"])
def test_bad_success_config_is_rejected(field):
    with pytest.raises(EnvError, match=field):
        SuccessConfig(**{field: -1.0})
    with pytest.raises(EnvError, match=field):
        SuccessConfig(**{field: float("nan")})


def test_the_episode_holes_score_like_assess_insertion_above_and_in_the_holes():
    """EpisodeHoles' shortcut (only the holes whose opening the peg_tip is below) finds the same hole, insertion and
    depth as assess_insertion over every hole, above the openings, in the target hole and in another one."""
    holes = EpisodeHoles(HOLES, "square", TARGET_DEPTH_M, CONFIG, PegFootprint.of(SQUARE))
    rng = np.random.default_rng(5)
    for shape in ("square", "triangle"):
        for _ in range(40):
            offset = rng.uniform([-0.002, -0.002, -0.045], [0.002, 0.002, 0.02])
            pos, quat = peg_tip(HOLES[shape], offset, rng.uniform(0, 3), rng.uniform(-20, 20))
            expected = assess((pos, quat), speed=0.001)
            got = holes.assess(pos, quat_to_mat(quat), 0.001)
            assert (got.hole, got.inserted, got.state.depth_m) == (expected.hole, expected.inserted,
                                                                   expected.state.depth_m)


def test_wrap_symmetric_deg_matches_numpy_mod_and_isclose_bit_for_bit():
    """The scalar wrap equals np.mod(a + p/2, p) - p/2 with the -p/2 -> p/2 rule of np.isclose."""
    rng = np.random.default_rng(4)
    for order in (1, 3, 4, 6):
        period = 360.0 / order
        for angle in np.concatenate([rng.uniform(-720.0, 720.0, 500), period * np.arange(-4, 5) / 2.0 + 1e-9]):
            wrapped = float(np.mod(angle + period / 2.0, period) - period / 2.0)
            expected = period / 2.0 if np.isclose(wrapped, -period / 2.0) else wrapped
            assert wrap_symmetric_deg(float(angle), order) == expected
