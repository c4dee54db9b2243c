"""Tests of envs.cell.sorter: the plate is tiled exactly by boxes around the holes, holes are where the sites say."""

import mujoco
import numpy as np
import pytest

from envs.cell.contact import ContactConfig
from envs.cell.shapes import SHAPES
from envs.cell.sorter import BASE_HEIGHT_M, LAYOUT_ORDER, build_sorter, sorter_layout
from envs.errors import EnvError
from envs.geometry import edge_lines, polygon_area

EPS = 1e-7


def inside_boxes(points, boxes, margin):
    """Mask of points inside any box shrunk by ``margin`` (negative margin grows the boxes)."""
    hit = np.zeros(len(points), dtype=bool)
    for box in boxes:
        c, s = np.cos(box.yaw_rad), np.sin(box.yaw_rad)
        local = (points - np.asarray(box.centre_xy)) @ np.array([[c, -s], [s, c]])
        hit |= np.all(np.abs(local) < np.asarray(box.half_size_xy) - margin, axis=1)
    return hit


def hole_distance(points, layout):
    """Signed distance-like value to the nearest hole: < 0 inside a hole (max over its edges of n.p - d)."""
    values = []
    for shape in LAYOUT_ORDER:
        normals, offsets = edge_lines(layout.hole_polygons[shape])
        local = points - np.asarray(layout.hole_xy[shape])
        values.append(np.max(local @ normals.T - offsets, axis=1))
    return np.min(values, axis=0)


def sample_plate(layout, count=40000):
    half = np.asarray(layout.size_xy_m) / 2.0
    return np.random.default_rng(0).uniform(-half, half, size=(count, 2))


def all_boxes(layout):
    return list(layout.plate_boxes) + [box for shape in LAYOUT_ORDER for box in layout.wall_boxes[shape]]


@pytest.mark.parametrize("clearance_m", [0.0002, 0.001, 0.005])
def test_no_box_enters_a_hole(clearance_m):
    layout = sorter_layout(clearance_m, 0.04)
    points = sample_plate(layout)
    in_hole = hole_distance(points, layout) < -EPS
    assert in_hole.sum() > 1000
    assert not np.any(inside_boxes(points[in_hole], all_boxes(layout), margin=EPS))


@pytest.mark.parametrize("clearance_m", [0.0002, 0.001, 0.005])
def test_boxes_cover_the_plate_outside_the_holes(clearance_m):
    layout = sorter_layout(clearance_m, 0.04)
    points = sample_plate(layout)
    solid = hole_distance(points, layout) > EPS
    assert np.all(inside_boxes(points[solid], all_boxes(layout), margin=-EPS))


def test_boxes_stay_inside_the_footprint():
    layout = sorter_layout(0.001, 0.04)
    corners = np.vstack([box.corners() for box in all_boxes(layout)])
    assert np.all(np.abs(corners) <= np.asarray(layout.size_xy_m) / 2.0 + 1e-12)


def test_every_hole_edge_is_backed_by_a_wall_face():
    """The midpoint of each hole edge, nudged outwards, lies in a wall box of that hole."""
    layout = sorter_layout(0.001, 0.04)
    for shape in LAYOUT_ORDER:
        polygon = layout.hole_polygons[shape]
        normals, _ = edge_lines(polygon)
        midpoints = (polygon + np.roll(polygon, -1, axis=0)) / 2.0 + 1e-5 * normals + layout.hole_xy[shape]
        assert np.all(inside_boxes(midpoints, layout.wall_boxes[shape], margin=0.0)), shape


def test_round_hole_has_one_wall_box_per_segment():
    assert len(sorter_layout(0.001, 0.04).wall_boxes["circle"]) == 32


def test_square_hole_is_four_boxes():
    assert len(sorter_layout(0.001, 0.04).wall_boxes["square"]) == 4


def test_hole_sites_sit_on_the_top_face():
    layout = sorter_layout(0.001, 0.035)
    assert np.isclose(layout.hole_position("square")[2], BASE_HEIGHT_M + 0.035)


def test_layout_holds_every_shape_once():
    assert sorted(sorter_layout(0.001, 0.04).hole_xy) == sorted(SHAPES)


def compiled_sorter(layout):
    sorter = build_sorter(layout, ContactConfig())
    return mujoco.MjModel.from_xml_string(sorter.to_xml_string(), sorter.get_assets())


def colliding(model):
    return (model.geom_contype | model.geom_conaffinity) > 0


def test_sorter_model_collides_with_one_geom_per_box():
    layout = sorter_layout(0.001, 0.04)
    assert colliding(compiled_sorter(layout)).sum() == 1 + len(all_boxes(layout))


def test_sorter_hole_sites_are_at_the_layout_holes():
    layout = sorter_layout(0.001, 0.04)
    assert np.allclose(compiled_sorter(layout).site("hole_triangle").pos, layout.hole_position("triangle"))


def test_all_colliding_sorter_geoms_are_boxes():
    model = compiled_sorter(sorter_layout(0.001, 0.04))
    assert np.all(model.geom_type[colliding(model)] == mujoco.mjtGeom.mjGEOM_BOX)


def test_visible_skin_tiles_the_plate_without_overlap():
    """Plate boxes plus wall pieces cover the plate minus the holes with area to spare for nothing."""
    layout = sorter_layout(0.001, 0.04)
    size_x, size_y = layout.size_xy_m
    plate_area = sum(4.0 * box.half_size_xy[0] * box.half_size_xy[1] for box in layout.plate_boxes)
    piece_area = sum(polygon_area(piece) for shape in LAYOUT_ORDER for piece in layout.wall_pieces[shape])
    hole_area = sum(polygon_area(polygon) for polygon in layout.hole_polygons.values())
    assert np.isclose(plate_area + piece_area + hole_area, size_x * size_y, rtol=1e-9)


def test_wall_boxes_are_hidden_and_the_skin_does_not_collide():
    model = compiled_sorter(sorter_layout(0.001, 0.04))
    walls = [model.geom(i).name.startswith("wall_") for i in range(model.ngeom)]
    skin = [model.geom(i).name.startswith("skin_") for i in range(model.ngeom)]
    assert np.all(model.geom_group[walls] == 3) and not np.any(colliding(model)[skin])


@pytest.mark.parametrize("clearance_m", [5e-5, 0.006, float("nan")])
def test_clearance_out_of_range_is_rejected(clearance_m):
    with pytest.raises(EnvError, match="clearance_m"):
        sorter_layout(clearance_m, 0.04)


def test_hole_depth_out_of_range_is_rejected():
    with pytest.raises(EnvError, match="hole_depth_m"):
        sorter_layout(0.001, 0.001)
