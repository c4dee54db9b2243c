"""robomimic's HDF5 layout written with h5py and read back (robomimic/utils/dataset.py and file_utils.py read
it so):

    <kind>.hdf5                 kind = "demos" or "episodes"
      data/                     attrs: total (frames of all demos), env_args (JSON: env_name "pih/PegInHole-v1",
                                type 2 (robomimic's EnvType.GYM_TYPE), env_kwargs: the shape, clearance and the
                                scene's other scalar settings, as `gymnasium.make` takes them), pih_export (JSON:
                                our metadata, envs.datasets.features.ExportMeta)
        demo_<e>/               e = 0, 1, ... in export order; attrs: num_samples (T), source_index, success,
                                end_reason and the episode's other metadata (perturbation, ...)
          obs/<key>             (T, n) float64: tcp_pose, peg_tip_pose, joint_pos, joint_vel, wrist_wrench (those
                                present), <camera>_image (T, H, W, 3) uint8 with --video
          actions               (T, 7) commanded tcp pose (absent in demos: a demo file has none)
          action_stiffness      (T, 9) commanded translational stiffness, 3x3 row-major, N/m
          rewards               (T,) float64: 1 where the simulator declares success, else 0 (episodes)
          dones                 (T,) int64: 1 at the last frame
      mask/successful           names of the successful demos (bytes), a robomimic filter key
    pih_export.json             the same metadata, the export folder's marker

No ``states``: a MuJoCo state of this scene does not restore an episode without its perturbation and grasp.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from envs.datasets.features import (FEATURE_BY_KEY, MARKER_FILE, ExportEpisode, ExportMeta, read_meta,
                                    recorded_from_poses)
from envs.demos.importing import RecordedDemos
from envs.errors import EnvError
from envs.io.owned_output import write_json

ENV_NAME: str = "pih/PegInHole-v1"
GYM_TYPE: int = 2  # robomimic.envs.env_base.EnvType.GYM_TYPE


def image_key(camera: str) -> str:
    """robomimic's observation key of a camera's frames."""
    return f"{camera}_image"


def env_args(meta: ExportMeta) -> dict[str, Any]:
    """robomimic's env metadata (env_name, type, env_kwargs) of the export."""
    scene = meta.config.get("scene") if isinstance(meta.config.get("scene"), dict) else {}
    kwargs = {k: v for k, v in scene.items() if isinstance(v, (bool, int, float, str))}
    kwargs.update(shape=meta.shape, clearance_m=meta.clearance_m)
    return {"env_name": ENV_NAME, "type": GYM_TYPE, "env_kwargs": kwargs}


class RobomimicWriter:
    """Writes episodes one at a time into ``root / f"{meta.kind}.hdf5"`` (module docstring); `close` finishes it."""

    def __init__(self, root: Path, meta: ExportMeta):
        self.root, self.meta = root, meta
        self.path = root / f"{meta.kind}.hdf5"
        self._file = h5py.File(self.path, "w")
        self._data = self._file.create_group("data")
        self._total = 0
        self._successful: list[str] = []

    def add(self, episode: ExportEpisode) -> None:
        """Write ``episode`` as the next demo_<e> group (its frames too, when it has them)."""
        name = f"demo_{len(self._data)}"
        group = self._data.create_group(name)
        for key in self.meta.features:
            path, value = FEATURE_BY_KEY[key].robomimic, np.asarray(episode.data[key])
            if key == "success":
                value = value.astype(np.float64)
            elif key == "done":
                value = value.astype(np.int64)
            group.create_dataset(path, data=value)
        if episode.frames is not None and self.meta.camera is not None:
            group.create_dataset(f"obs/{image_key(self.meta.camera)}", data=episode.frames, compression="gzip",
                                 chunks=(1, *episode.frames.shape[1:]))
        group.attrs["num_samples"] = episode.num_frames
        group.attrs["source_index"] = episode.index
        group.attrs["success"] = episode.success
        group.attrs["end_reason"] = episode.end_reason
        for key, value in episode.extra.items():
            group.attrs[key] = value
        self._total += episode.num_frames
        if episode.success:
            self._successful.append(name)

    def close(self) -> Path:
        """Write the data attributes, the successful filter key and the marker; close the file."""
        self._data.attrs["total"] = self._total
        self._data.attrs["env_args"] = json.dumps(env_args(self.meta))
        self._data.attrs["pih_export"] = json.dumps(self.meta.to_json("robomimic"))
        self._file.create_dataset("mask/successful", data=np.array(self._successful, dtype="S"))
        self._file.close()
        write_json(self.root / MARKER_FILE, self.meta.to_json("robomimic"))
        return self.path

    def abort(self) -> None:
        """Close the file (the staged folder is deleted by its owner)."""
        self._file.close()


def _demo_names(data: Any, source: str) -> list[str]:
    names = [k for k in data.keys() if k.startswith("demo_") and k[5:].isdigit()]
    if not names:
        raise EnvError(f"{source}: the 'data' group holds no demo_<n> groups")
    return sorted(names, key=lambda k: int(k[5:]))


def hdf5_file(path: str | Path) -> Path:
    """The HDF5 file of ``path``: the file itself, or the single .hdf5 in the folder.

    Raises:
        EnvError: nothing there, or a folder without exactly one .hdf5 file.
    """
    p = Path(path)
    if p.is_file():
        return p
    if not p.is_dir():
        raise EnvError(f"robomimic file {p} not found")
    files = sorted(p.glob("*.hdf5"))
    if len(files) != 1:
        raise EnvError(f"{p}: expected one .hdf5 file in the folder, found {[f.name for f in files]}")
    return files[0]


def read_robomimic(path: str | Path) -> RecordedDemos:
    """Read the tcp poses (``obs/tcp_pose``) and, when every demo has it, the stiffness (``action_stiffness``) of
    every demo of a robomimic HDF5 file (or of the folder holding one), to import as demos.

    Raises:
        EnvError: no file; not a readable HDF5 file (e.g. truncated); no data group or demos;
            a demo without obs/tcp_pose; num_samples different from the data; wrong shapes; NaN; non-unit
            quaternions; stiffness in some demos only.
    """
    file = hdf5_file(path)
    source = str(file)
    try:
        with h5py.File(file, "r") as handle:
            if "data" not in handle:
                raise EnvError(f"{source}: no 'data' group (not a robomimic dataset)")
            data = handle["data"]
            meta = read_meta(data.attrs["pih_export"], source) if "pih_export" in data.attrs else None
            names = _demo_names(data, source)
            has_k = ["action_stiffness" in data[n] for n in names]
            if any(has_k) and not all(has_k):
                raise EnvError(f"{source}: 'action_stiffness' is in {sum(has_k)} of {len(names)} demos; need all or none")
            poses, stiffness = [], []
            for name in names:
                group = data[name]
                if "obs" not in group or "tcp_pose" not in group["obs"]:
                    raise EnvError(f"{source}: {name} has no obs/tcp_pose (the tcp pose [x, y, z, qw, qx, qy, qz])")
                pose = np.asarray(group["obs/tcp_pose"][()])
                count = group.attrs.get("num_samples")
                if count is not None and int(count) != pose.shape[0]:
                    raise EnvError(f"{source}: {name} says num_samples={int(count)} but holds {pose.shape[0]} poses")
                poses.append(pose)
                if all(has_k):
                    stiffness.append(np.asarray(group["action_stiffness"][()]))
    except EnvError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as err:
        raise EnvError(f"{source}: not a readable robomimic HDF5 file, truncated or corrupt "
                       f"({type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''})") from None
    dt = float(meta["dt_s"]) if meta is not None else None
    return recorded_from_poses(poses, stiffness if all(has_k) else None, dt, meta, "robomimic", source)
