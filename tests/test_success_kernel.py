"""The compiled scoring of a peg_tip (envs.success_kernel, behind `EpisodeHoles.assess`) equals the scoring in numpy
(`envs.success.frame_state` / `frame_assessment` with EpisodeHoles' shortcut) bit for bit: the hole, the insertion and
every field of the state, for prism and round pegs, above the openings, on the chamfer, deep in the target hole and in
another hole, tilted and turned past the symmetry's wrap."""

from __future__ import annotations

from dataclasses import astuple

import numpy as np
import pytest

from envs.errors import EnvError
from envs.geometry import R_FLIP_X, rot_z
from envs.shapes import hole_inradius_m, hole_polygon, peg_cross_section
from envs.success import (MIN_ENTRY_DEPTH_M, Assessment, EpisodeHoles, HoleSpec, PegFootprint, SuccessConfig,
                          frame_assessment, frame_state)
from rflow.quaternion import mat_to_quat, quat_to_mat

CONFIG = SuccessConfig()
TARGET_DEPTH_M = 0.03
SHAPES = {"square": 4, "triangle": 3, "circle": 0, "hexagon": 6}


def fixture_holes(yaw_deg: float, chamfer_m: float) -> dict[str, HoleSpec]:
    quat = tuple(mat_to_quat(rot_z(np.deg2rad(yaw_deg))))
    return {shape: HoleSpec(shape, (0.6 + 0.08 * k, -0.05, 0.23), quat, order, hole_inradius_m(shape, 2e-4), 0.04,
                            2e-4, tuple(map(tuple, hole_polygon(shape, 2e-4))), chamfer_m)
            for k, (shape, order) in enumerate(SHAPES.items())}


def reference(holes: EpisodeHoles, pos: np.ndarray, rot: np.ndarray, speed: float) -> Assessment:
    """EpisodeHoles.assess as it was in numpy: the target's state alone while above every opening, else
    frame_assessment over the holes the tip is below the opening of."""
    depths = np.array([-np.dot(pos - f.pos, quat_to_mat(f.spec.quat)[:, 2]) for f in holes.frames.values()])
    if np.all(depths <= MIN_ENTRY_DEPTH_M):
        return Assessment(None, frame_state(pos, rot, holes.frames[holes.target], speed_m_s=speed), False)
    candidates = {shape: frame for (shape, frame), depth in zip(holes.frames.items(), depths)
                  if depth > MIN_ENTRY_DEPTH_M or shape == holes.target}
    return frame_assessment(pos, rot, candidates, holes.target, holes.target_depth_m, holes.config, holes.peg, speed)


@pytest.mark.parametrize("target", list(SHAPES))
def test_compiled_scoring_equals_numpy_bit_for_bit(target):
    """Over 400 peg_tip poses near every hole (numpy pinned as `pih` pins it, by tests/conftest.py: numpy's own
    AVX-512 arctan2 rounds otherwise than libm's, which the kernel and a pinned numpy both call)."""
    rng = np.random.default_rng(len(target))
    specs = fixture_holes(yaw_deg=-14.4, chamfer_m=1e-3)
    holes = EpisodeHoles(specs, target, TARGET_DEPTH_M, CONFIG, PegFootprint.of(peg_cross_section(target)))
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
        rot = rot_hole @ rot_z(yaw) @ rot_x @ R_FLIP_X
        rot = quat_to_mat(mat_to_quat(rot))  # a rotation matrix as the observation builds it
        pos = np.asarray(at.pos) + rot_hole @ offset
        speed = float(rng.choice([0.001, 0.01]))
        want, got = reference(holes, pos, rot, speed), holes.assess(pos, rot, speed)
        assert (got.hole, got.inserted) == (want.hole, want.inserted)
        assert np.array_equal(np.array(astuple(got.state), dtype=float), np.array(astuple(want.state), dtype=float),
                              equal_nan=True)
        kinds["none" if got.hole is None else "target" if got.hole == target else "other"] += 1
        kinds["inserted"] += got.inserted
        kinds["penetration"] += bool(np.isfinite(got.state.wall_penetration_m))
    assert min(kinds.values()) > 0, kinds  # every branch was taken


def test_a_target_without_walls_below_its_chamfer_is_one_error_line():
    specs = fixture_holes(yaw_deg=0.0, chamfer_m=1e-3)
    specs["square"] = HoleSpec(**{**specs["square"].__dict__, "polygon": ()})
    holes = EpisodeHoles(specs, "square", TARGET_DEPTH_M, CONFIG, PegFootprint.of(peg_cross_section("square")))
    pos = np.asarray(specs["square"].pos) + np.array([0.0, 0.0, -0.02])
    with pytest.raises(EnvError, match="'square' has no polygon"):
        holes.assess(pos, R_FLIP_X.astype(float), 0.0)
