"""Tests of envs.cell.shapes: peg cross-sections, holes = peg + clearance, grip widths."""

import numpy as np
import pytest

from envs.cell.shapes import (
    SHAPES,
    SQUARE_SIDE_M,
    check_shape,
    grip_half_width_m,
    hole_inradius_m,
    hole_polygon,
    peg_cross_section,
)
from envs.errors import EnvError
from envs.geometry import edge_lines, mirror_y


@pytest.mark.parametrize("shape", ["square", "triangle", "rectangle", "hexagon"])
@pytest.mark.parametrize("clearance_m", [0.0002, 0.001, 0.005])
def test_every_hole_face_is_half_the_clearance_from_the_peg_face(shape, clearance_m):
    _, peg_offsets = edge_lines(mirror_y(peg_cross_section(shape).polygon))
    _, hole_offsets = edge_lines(hole_polygon(shape, clearance_m))
    assert np.allclose(hole_offsets - peg_offsets, clearance_m / 2.0)


def test_square_hole_side_is_peg_side_plus_clearance():
    hole = hole_polygon("square", 0.001)
    assert np.allclose(np.ptp(hole, axis=0), SQUARE_SIDE_M + 0.001)


def test_round_hole_inradius_is_peg_radius_plus_half_clearance():
    assert np.isclose(hole_inradius_m("circle", 0.0002), peg_cross_section("circle").radius_m + 0.0001)


@pytest.mark.parametrize("shape", SHAPES)
def test_hole_polygons_are_counter_clockwise_around_the_axis(shape):
    normals, offsets = edge_lines(hole_polygon(shape, 0.001))
    assert np.all(offsets > 0.0)


@pytest.mark.parametrize("shape", ["square", "triangle", "rectangle", "hexagon"])
def test_symmetry_order_maps_the_peg_onto_itself(shape):
    section = peg_cross_section(shape)
    angle = 2.0 * np.pi / section.symmetry_order
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    turned = section.polygon @ rot.T
    distances = np.linalg.norm(turned[:, None, :] - section.polygon[None, :, :], axis=2)
    assert np.allclose(distances.min(axis=1), 0.0, atol=1e-12)


def test_square_grip_is_half_the_side():
    assert np.isclose(grip_half_width_m("square", 0.01), SQUARE_SIDE_M / 2.0)


def test_triangle_grip_is_the_widest_point_under_the_pads():
    """Vertex at +x: the slanted edges y = +-(R - x)/sqrt(3) are widest at the pads' back end x = -0.01."""
    circumradius = peg_cross_section("triangle").radius_m
    assert np.isclose(grip_half_width_m("triangle", 0.01), (circumradius + 0.01) / np.sqrt(3.0))


def test_unknown_shape_is_rejected():
    with pytest.raises(EnvError, match="star"):
        check_shape("star")
