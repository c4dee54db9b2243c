"""The compiled scoring of a peg_tip (envs.task.success_kernel, behind `EpisodeHoles.assess`, `assess_insertion` and
`insertion_state`) equals the numpy scoring it replaced (kept below as the reference) bit for bit: the hole, the
insertion and every field of the state, for prism and round pegs, above the openings, on the chamfer, deep in the
target hole and in another hole, tilted and turned past the symmetry's wrap; with the episode's shortcut and without
it (a pose scored alone)."""

from __future__ import annotations

from dataclasses import astuple

import numpy as np
import pytest

from envs.cell.hole import HoleSpec
from envs.cell.shapes import hole_inradius_m, hole_polygon, peg_cross_section
from envs.errors import EnvError
from envs.geometry import R_FLIP_X, rot_z, twist_angle_deg
from envs.task.success import (FLOOR_SLACK_M, MIN_ENTRY_DEPTH_M, Assessment, EpisodeHoles, HoleFrame, InsertionState,
                               PegFootprint, SuccessConfig, assess_insertion, insertion_state, wall_penetration_m,
                               wrap_symmetric_deg)
from numerics.quaternion import mat_to_quat, quat_to_mat
from numerics.small_linalg import matmul, matvec

CONFIG = SuccessConfig()
TARGET_DEPTH_M = 0.03
SHAPES = {"square": 4, "triangle": 3, "circle": 0, "hexagon": 6}


# ----------------------------------------------------------------- the numpy scoring the kernel replaced (reference)


def _offset(pos, frame):
    return matvec(frame.rot.T, pos - frame.pos)


def _inside(offset, hole):
    depth = float(-offset[2])
    lateral = float(np.hypot(offset[0], offset[1]))
    return depth, lateral, MIN_ENTRY_DEPTH_M < depth <= hole.depth_m + FLOOR_SLACK_M and lateral <= hole.inradius_m


def _penetration(tip, rot_peg, frame, peg):
    hole, section = frame.spec, peg.section
    up = -rot_peg[:, 2]
    level = -hole.chamfer_m
    if up[2] <= 1e-9:
        return float("inf")
    if section.is_round:
        crossing = tip + up * (level - tip[2]) / up[2]
        radial = max(float(np.hypot(*tip[:2])), float(np.hypot(*crossing[:2])))
        return radial + section.radius_m / up[2] - hole.inradius_m
    corners = tip + matmul(peg.corners, rot_peg.T)
    rise = np.maximum(level - corners[:, 2], 0.0) / up[2]
    points = np.vstack([corners, corners + rise[:, None] * up])[:, :2]
    return float(np.max(matmul(points, frame.wall_normals.T) - frame.wall_offsets))


def reference_state(pos, rot, frame, peg, speed):
    hole = frame.spec
    rot_peg = matmul(frame.rot.T, rot)
    rot_rel = matmul(rot_peg, R_FLIP_X)
    offset = _offset(pos, frame)
    depth, lateral, in_hole = _inside(offset, hole)
    tilt = float(np.rad2deg(np.arccos(min(max(float(rot_rel[2, 2]), -1.0), 1.0))))
    yaw = wrap_symmetric_deg(twist_angle_deg(rot_rel), hole.symmetry_order)
    penetration = float("nan")
    if peg is not None and depth > hole.chamfer_m:
        penetration = _penetration(offset, rot_peg, frame, peg)
    return InsertionState(depth, lateral, tilt, yaw, bool(in_hole), penetration, float(speed))


def reference(holes: EpisodeHoles, pos, rot, speed, shortcut: bool = True) -> Assessment:
    """The target's state alone while above every opening (with the shortcut), else every hole the tip is below the
    opening of (all holes without the shortcut), the target first."""
    depths = np.array([-np.dot(pos - f.pos, quat_to_mat(f.spec.quat)[:, 2]) for f in holes.frames.values()])
    if shortcut and np.all(depths <= MIN_ENTRY_DEPTH_M):
        return Assessment(None, reference_state(pos, rot, holes.frames[holes.target], None, speed), False)
    frames = {shape: frame for (shape, frame), depth in zip(holes.frames.items(), depths)
              if not shortcut or depth > MIN_ENTRY_DEPTH_M or shape == holes.target}
    state = reference_state(pos, rot, frames[holes.target], holes.peg, speed)
    hole = holes.target if state.in_hole else next(
        (shape for shape, frame in frames.items() if shape != holes.target and _inside(_offset(pos, frame),
                                                                                      frame.spec)[2]), None)
    inserted = bool(hole == holes.target and state.in_hole
                    and abs(state.depth_m - holes.target_depth_m) <= holes.config.seat_tolerance_m
                    and state.wall_penetration_m <= holes.config.penetration_tolerance_m
                    and state.speed_m_s <= holes.config.max_speed_m_s)
    return Assessment(hole, state, inserted)


# ------------------------------------------------------------------------------------------------------------ tests


def fixture_holes(yaw_deg: float, chamfer_m: float) -> dict[str, HoleSpec]:
    quat = tuple(mat_to_quat(rot_z(np.deg2rad(yaw_deg))))
    return {shape: HoleSpec(shape, (0.6 + 0.08 * k, -0.05, 0.23), quat, order, hole_inradius_m(shape, 2e-4), 0.04,
                            2e-4, tuple(map(tuple, hole_polygon(shape, 2e-4))), chamfer_m)
            for k, (shape, order) in enumerate(SHAPES.items())}


def same(got: Assessment, want: Assessment) -> None:
    assert (got.hole, got.inserted) == (want.hole, want.inserted)
    assert np.array_equal(np.array(astuple(got.state), dtype=float), np.array(astuple(want.state), dtype=float),
                          equal_nan=True)


@pytest.mark.parametrize("target", list(SHAPES))
def test_compiled_scoring_equals_numpy_bit_for_bit(target):
    """Over 400 peg_tip poses near every hole (numpy pinned as `pih` pins it, by tests/conftest.py: numpy's own
    AVX-512 arctan2 rounds otherwise than libm's, which the kernel and a pinned numpy both call)."""
    rng = np.random.default_rng(len(target))
    specs = fixture_holes(yaw_deg=-14.4, chamfer_m=1e-3)
    peg = peg_cross_section(target)
    holes = EpisodeHoles(specs, target, TARGET_DEPTH_M, CONFIG, PegFootprint.of(peg))
    kinds = {"none": 0, "target": 0, "other": 0, "inserted": 0, "penetration": 0}
    for _ in range(400):
        at = specs[rng.choice(list(SHAPES))] if rng.random() < 0.7 else specs[target]
        rot_hole = quat_to_mat(at.quat)
        offset = rng.uniform([-2e-3, -2e-3, -0.045], [2e-3, 2e-3, 0.01])
        tilt, yaw = np.deg2rad(rng.uniform(0, 4)), np.deg2rad(rng.uniform(-200, 200))
        if rng.random() < 0.3:  # seated, straight, turned by a symmetry: the success criteria decide
            offset = np.array([rng.normal(0, 2e-5), rng.normal(0, 2e-5), -TARGET_DEPTH_M + rng.normal(0, 5e-4)])
            step = 360.0 / max(SHAPES[target], 1)
            tilt, yaw = np.deg2rad(rng.uniform(0, 0.02)), np.deg2rad(step * rng.integers(-3, 4) + rng.normal(0, 0.01))
        rot_x = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
        quat = mat_to_quat(rot_hole @ rot_z(yaw) @ rot_x @ R_FLIP_X)
        rot = quat_to_mat(quat)  # a rotation matrix as the observation builds it
        pos = np.asarray(at.pos) + rot_hole @ offset
        speed = float(rng.choice([0.001, 0.01]))
        got = holes.assess(pos, rot, speed)
        same(got, reference(holes, pos, rot, speed))
        same(assess_insertion(pos, quat, specs, target, TARGET_DEPTH_M, CONFIG, peg, speed),
             reference(holes, pos, rot, speed, shortcut=False))
        alone = HoleFrame.of(specs[target])
        assert np.array_equal(np.array(astuple(insertion_state(pos, quat, specs[target], None, speed)), dtype=float),
                              np.array(astuple(reference_state(pos, rot, alone, None, speed)), dtype=float),
                              equal_nan=True)
        kinds["none" if got.hole is None else "target" if got.hole == target else "other"] += 1
        kinds["inserted"] += got.inserted
        kinds["penetration"] += bool(np.isfinite(got.state.wall_penetration_m))
    assert min(kinds.values()) > 0, kinds  # every branch was taken


@pytest.mark.parametrize("shape", list(SHAPES))
def test_wall_penetration_equals_numpy_bit_for_bit(shape):
    rng = np.random.default_rng(7)
    spec = fixture_holes(yaw_deg=0.0, chamfer_m=1e-3)[shape]
    peg = peg_cross_section(shape)
    for _ in range(200):
        tip = rng.uniform([-1e-3, -1e-3, -0.03], [1e-3, 1e-3, -2e-3])
        rot_peg = quat_to_mat(mat_to_quat(rot_z(rng.uniform(-3, 3)) @ rot_z(0.0)))
        tilt = np.deg2rad(rng.uniform(-3, 3))
        rot_peg = rot_peg @ np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
        rot_peg = rot_peg @ R_FLIP_X  # pointing down into the hole
        want = _penetration(tip, rot_peg, HoleFrame.of(spec), PegFootprint.of(peg))
        assert wall_penetration_m(tip, rot_peg, spec, peg) == want


def test_a_target_without_walls_below_its_chamfer_is_one_error_line():
    specs = fixture_holes(yaw_deg=0.0, chamfer_m=1e-3)
    specs["square"] = HoleSpec(**{**specs["square"].__dict__, "polygon": ()})
    holes = EpisodeHoles(specs, "square", TARGET_DEPTH_M, CONFIG, PegFootprint.of(peg_cross_section("square")))
    pos = np.asarray(specs["square"].pos) + np.array([0.0, 0.0, -0.02])
    with pytest.raises(EnvError, match="'square' has no polygon"):
        holes.assess(pos, R_FLIP_X.astype(float), 0.0)
    with pytest.raises(EnvError, match="'square' has no polygon"):
        wall_penetration_m(np.array([0.0, 0.0, -0.02]), R_FLIP_X.astype(float), specs["square"],
                           peg_cross_section("square"))
