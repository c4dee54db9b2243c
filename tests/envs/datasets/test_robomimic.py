"""envs.datasets.robomimic: robomimic's HDF5 layout, read as robomimic reads it (h5py), and its read-back.

robomimic itself is not installed (it requires torchvision and tensorboard); the layout checks below follow
robomimic.utils.file_utils.get_env_metadata_from_dataset / get_shape_metadata_from_dataset and
robomimic.utils.dataset.SequenceDataset: data.attrs["env_args"] JSON, demos by data/demo_N with attrs
num_samples, obs/<key> arrays of N rows, filter keys under mask/ as byte strings.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

import h5py
import numpy as np
import pytest

from envs.datasets.robomimic import GYM_TYPE, read_robomimic
from envs.errors import EnvError
from tests.helpers import dataset_fixtures
from tests.helpers.dataset_fixtures import assert_read_back


def export_demos(root: Path) -> tuple[Any, Path]:
    """Three stiffness demos written as robomimic HDF5 into ``root``; (demos, the file)."""
    return dataset_fixtures.export_demos(root, "robomimic")


def test_poses_and_stiffness_read_back_to_float64_precision(tmp_path: Path) -> None:
    demos, _ = export_demos(tmp_path / "ds")
    assert_read_back(read_robomimic(tmp_path / "ds"), demos)


def test_env_metadata_reads_as_robomimic_reads_it(tmp_path: Path) -> None:
    demos, path = export_demos(tmp_path / "ds")
    with h5py.File(path, "r") as f:
        env_meta = json.loads(f["data"].attrs["env_args"])
    assert env_meta["env_name"] == "pih/PegInHole-v1" and env_meta["type"] == GYM_TYPE
    assert env_meta["env_kwargs"]["shape"] == demos.shape
    assert env_meta["env_kwargs"]["clearance_m"] == demos.clearance_m


def test_demo_groups_follow_the_layout(tmp_path: Path) -> None:
    demos, path = export_demos(tmp_path / "ds")
    with h5py.File(path, "r") as f:
        names = sorted(f["data"].keys(), key=lambda k: int(k[5:]))
        assert names == ["demo_0", "demo_1", "demo_2"]
        assert f["data"].attrs["total"] == sum(f[f"data/{n}"].attrs["num_samples"] for n in names) == 90
        for n in names:
            group = f[f"data/{n}"]
            rows = group.attrs["num_samples"]
            assert all(group[f"obs/{k}"].shape[0] == rows for k in group["obs"])
            assert group["action_stiffness"].shape == (rows, 9) and group["dones"][-1] == 1
            assert "actions" not in group  # a demo file records no commanded pose
        assert sorted(v.decode() for v in f["mask/successful"][()]) == names


def truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def edit(change: Callable[[h5py.File], None]) -> Callable[[Path], None]:
    def apply(path: Path) -> None:
        with h5py.File(path, "r+") as f:
            change(f)
    return apply


def put_nan(f: h5py.File) -> None:
    f["data/demo_1/obs/tcp_pose"][3, 2] = np.nan


@pytest.mark.parametrize("damage, message", [
    (truncate, "not a readable robomimic HDF5 file"),
    (edit(lambda f: f.__delitem__("data/demo_2/obs/tcp_pose")), "demo_2 has no obs/tcp_pose"),
    (edit(put_nan), "NaN"),
    (edit(lambda f: f["data/demo_0"].attrs.__setitem__("num_samples", 29)), "num_samples=29"),
    (edit(lambda f: f.__delitem__("data/demo_1/action_stiffness")), "in 2 of 3 demos"),
    (edit(lambda f: f.__delitem__("data")), "no 'data' group"),
])
def test_malformed_file_is_one_clear_error(tmp_path: Path, damage: Callable[[Path], None], message: str) -> None:
    _, path = export_demos(tmp_path / "ds")
    damage(path)
    with pytest.raises(EnvError, match=message):
        read_robomimic(path)


def test_wrong_pose_shape_is_refused(tmp_path: Path) -> None:
    _, path = export_demos(tmp_path / "ds")
    with h5py.File(path, "r+") as f:
        pose = f["data/demo_0/obs/tcp_pose"][()]
        del f["data/demo_0/obs/tcp_pose"]
        f["data/demo_0/obs/tcp_pose"] = pose[:, :6]
    with pytest.raises(EnvError, match="shape \\(T, 7\\)"):
        read_robomimic(path)
