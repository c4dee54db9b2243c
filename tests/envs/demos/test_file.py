"""The demo file schema: atomic save, validating load."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from envs.demos.file import DemoSet, load_demos, save_demos
from envs.errors import EnvError
from envs.poses import quat_from_rotvec, quat_mul, slerp

GOAL_POS = np.array([0.675, -0.051, 0.203])
GOAL_QUAT = np.array([0.0, 1.0, 0.0, 0.0])


def make_demos(n: int = 3, m: int = 20) -> DemoSet:
    """N straight-line demos ending at the goal."""
    rng = np.random.default_rng(0)
    s = np.linspace(0.0, 1.0, m)
    pos, quat = [], []
    for _ in range(n):
        start = GOAL_POS + rng.uniform(-0.1, 0.1, 3)
        q0 = quat_mul(quat_from_rotvec(rng.uniform(-0.3, 0.3, 3)), GOAL_QUAT)
        pos.append(start + s[:, None] * (GOAL_POS - start))
        q = slerp(q0, GOAL_QUAT, s)
        q[-1] = GOAL_QUAT
        quat.append(q)
    return DemoSet(pos=np.stack(pos), quat=np.stack(quat), dt=0.01, goal_pos=GOAL_POS, goal_quat=GOAL_QUAT,
                   shape="square", clearance_m=0.001, config={"seed": 0},
                   residual_pos_m=np.zeros(n), residual_rot_deg=np.zeros(n))


def test_round_trip_preserves_arrays(tmp_path: Path) -> None:
    demos = make_demos()
    loaded = load_demos(save_demos(tmp_path / "d.npz", demos))
    np.testing.assert_array_equal(loaded.pos, demos.pos)
    np.testing.assert_array_equal(loaded.quat, demos.quat)
    assert (loaded.dt, loaded.shape, loaded.clearance_m, loaded.config) == (0.01, "square", 0.001, {"seed": 0})


def test_save_leaves_no_temporary_file(tmp_path: Path) -> None:
    save_demos(tmp_path / "d.npz", make_demos())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.npz"]


def test_invalid_demos_are_not_written(tmp_path: Path) -> None:
    demos = make_demos()
    bad = dataclasses.replace(demos, pos=demos.pos + 0.01)  # no longer ends at the goal
    with pytest.raises(EnvError, match="does not end at the goal"):
        save_demos(tmp_path / "d.npz", bad)
    assert list(tmp_path.iterdir()) == []


def test_missing_file_is_rejected(tmp_path: Path) -> None:
    with pytest.raises(EnvError, match="not found"):
        load_demos(tmp_path / "nope.npz")


def test_corrupt_file_is_rejected(tmp_path: Path) -> None:
    path = tmp_path / "bad.npz"
    path.write_bytes(b"this is not a zip archive")
    with pytest.raises(EnvError, match="not a readable"):
        load_demos(path)


def test_missing_key_is_named(tmp_path: Path) -> None:
    demos = make_demos()
    path = tmp_path / "d.npz"
    np.savez(path, pos=demos.pos, quat=demos.quat, dt=0.01)
    with pytest.raises(EnvError, match="goal_pos"):
        load_demos(path)


def _rewrite(path: Path, **changes: np.ndarray) -> Path:
    with np.load(path) as archive:
        arrays = {k: archive[k] for k in archive.files}
    arrays.update(changes)
    np.savez(path, **arrays)
    return path


def test_wrong_quaternion_shape_is_rejected(tmp_path: Path) -> None:
    demos = make_demos()
    path = _rewrite(save_demos(tmp_path / "d.npz", demos), quat=demos.quat[:, :, :3])
    with pytest.raises(EnvError, match="'quat' must have shape"):
        load_demos(path)


def test_nan_is_rejected(tmp_path: Path) -> None:
    demos = make_demos()
    pos = demos.pos.copy()
    pos[1, 5, 2] = np.nan
    path = _rewrite(save_demos(tmp_path / "d.npz", demos), pos=pos)
    with pytest.raises(EnvError, match="NaN"):
        load_demos(path)


def test_non_unit_quaternion_is_rejected(tmp_path: Path) -> None:
    demos = make_demos()
    quat = demos.quat.copy()
    quat[0, 3] *= 1.01
    path = _rewrite(save_demos(tmp_path / "d.npz", demos), quat=quat)
    with pytest.raises(EnvError, match="not unit"):
        load_demos(path)


def test_demo_not_ending_at_goal_is_rejected(tmp_path: Path) -> None:
    demos = make_demos()
    path = _rewrite(save_demos(tmp_path / "d.npz", demos), goal_pos=GOAL_POS + [0.0, 0.0, 0.002])
    with pytest.raises(EnvError, match="demo 0 does not end at the goal"):
        load_demos(path)


def test_pickled_object_arrays_are_refused(tmp_path: Path) -> None:
    demos = make_demos()
    path = _rewrite(save_demos(tmp_path / "d.npz", demos), config_json=np.array([{"a": 1}], dtype=object))
    with pytest.raises(EnvError):
        load_demos(path)
