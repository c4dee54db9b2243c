"""Tests of envs.geometry: rotations, the z-down projection of the paper's goal, polygons, camera aiming."""

import numpy as np
import pytest

from envs.errors import EnvError
from envs.geometry import (
    as_vector,
    clip_polygon,
    look_at_xyaxes,
    offset_convex_polygon,
    polygon_area,
    rectangle,
    regular_polygon,
    tilt_from_down_deg,
    z_down_rotation,
    z_down_yaw_deg,
)
from numerics.quaternion import mat_to_quat, quat_to_mat

PAPER_QUAT = (0.022, 0.991, -0.125, 0.035)

@pytest.mark.parametrize("yaw_deg", [-170.0, -14.4, 0.0, 33.0, 179.0])
def test_z_down_yaw_inverts_z_down_rotation(yaw_deg):
    assert np.isclose(z_down_yaw_deg(mat_to_quat(z_down_rotation(yaw_deg))), yaw_deg)


def test_z_down_rotation_points_z_down():
    assert np.allclose(z_down_rotation(27.0)[:, 2], [0.0, 0.0, -1.0])


def test_paper_goal_projection_is_the_nearest_z_down_orientation():
    """Brute force over headings: no z-down orientation is closer (geodesic angle) to g_q than the projection."""
    target = quat_to_mat(PAPER_QUAT)

    def angle(rot):
        return np.arccos(np.clip((np.trace(rot.T @ target) - 1.0) / 2.0, -1.0, 1.0))

    yaw = z_down_yaw_deg(PAPER_QUAT)
    best = min(angle(z_down_rotation(y)) for y in np.arange(-180.0, 180.0, 0.01))
    assert angle(z_down_rotation(yaw)) <= best + 1e-9
    assert -15.0 < yaw < -14.0


def test_paper_goal_is_tilted_less_than_five_degrees():
    assert 4.0 < tilt_from_down_deg(quat_to_mat(PAPER_QUAT)) < 5.0


def test_z_down_yaw_rejects_z_up():
    with pytest.raises(EnvError, match="up"):
        z_down_yaw_deg((1.0, 0.0, 0.0, 0.0))


def test_offset_square_grows_each_side():
    grown = offset_convex_polygon(rectangle(-1.0, 1.0, -1.0, 1.0), 0.5)
    assert np.allclose(np.sort(np.abs(grown).ravel()), 1.5)


def test_offset_triangle_moves_every_edge_by_the_distance():
    triangle = regular_polygon(3, 1.0)
    grown = offset_convex_polygon(triangle, 0.25)
    assert np.isclose(np.min(np.linalg.norm(grown, axis=1)), 2.0 * 1.25)


def test_clip_polygon_halves_a_square():
    half = clip_polygon(rectangle(-1.0, 1.0, -1.0, 1.0), np.array([1.0, 0.0]), 0.0)
    assert np.isclose(polygon_area(half), 2.0)


def test_look_at_points_the_camera_minus_z_at_the_target():
    xyaxes = look_at_xyaxes([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    viewing = -np.cross(xyaxes[:3], xyaxes[3:])
    assert np.allclose(viewing, -np.array([1.0, 2.0, 3.0]) / np.linalg.norm([1.0, 2.0, 3.0]))


def test_as_vector_rejects_wrong_length():
    with pytest.raises(EnvError, match="goal_pos"):
        as_vector([1.0, 2.0], 3, "goal_pos")
