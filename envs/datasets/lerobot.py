"""LeRobot dataset v3.0 written with pyarrow and read back, following the layout `lerobot` documents and reads
(lerobot/datasets/utils.py, io_utils.py, dataset_metadata.py, dataset_writer.py):

    meta/info.json                                  codebase_version "v3.0", fps, features (dtype, shape, names),
                                                    counts, chunks_size, file size limits, data_path/video_path
    meta/stats.json                                 per feature: min, max, mean, std, count, q01 q10 q50 q90 q99
    meta/tasks.parquet                              task (the index) -> task_index
    meta/episodes/chunk-000/file-000.parquet        one row per episode: episode_index, tasks, length,
                                                    data/chunk_index, data/file_index, dataset_from_index,
                                                    dataset_to_index, videos/<key>/{chunk_index, file_index,
                                                    from_timestamp, to_timestamp}, meta/episodes/{chunk_index,
                                                    file_index}, stats/<feature>/<stat>, and ours: source_index,
                                                    success, end_reason, the perturbation, ...
    data/chunk-CCC/file-FFF.parquet                 one row per frame, one row group per episode: the features
                                                    and timestamp (float32, s), frame_index, episode_index, index,
                                                    task_index (int64); a new file past DATA_FILE_SIZE_MB, a new
                                                    chunk every CHUNKS_SIZE files
    videos/observation.images.<camera>/chunk-000/file-000.mp4   all episodes' frames one after another (H.264)
    pih_export.json                                 our metadata (envs.datasets.features.ExportMeta): the task,
                                                    the source's configuration, the features absent and why

A vector feature of n > 1 components is a fixed-size list column of n values (LeRobot's datasets.Sequence of
that length), a feature of one component a scalar column. Poses and every other float feature are float64.
The statistics are exact (numpy over all frames; LeRobot approximates quantiles with histograms); a video's are
per channel over evenly spaced frames (envs.datasets.frame_sample: downsampled as LeRobot does), scaled to [0, 1],
of shape (3, 1, 1), as LeRobot keeps them.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from envs.datasets.features import (FEATURE_BY_KEY, MARKER_FILE, ExportEpisode, ExportMeta, fps_of, read_meta,
                                    recorded_from_poses)
from envs.datasets.frame_sample import FrameSample
from envs.demos.importing import RecordedDemos
from envs.errors import EnvError
from envs.io.owned_output import write_json

CODEBASE_VERSION: str = "v3.0"
ROBOT_TYPE: str = "franka_panda"
CHUNKS_SIZE: int = 1000
DATA_FILE_SIZE_MB: int = 100
VIDEO_FILE_SIZE_MB: int = 200
DATA_PATH: str = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH: str = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH: str = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
TASKS_PATH: str = "meta/tasks.parquet"
QUANTILES: tuple[float, ...] = (0.01, 0.10, 0.50, 0.90, 0.99)
#: LeRobot's own per-frame columns.
INDEX_FEATURES: dict[str, dict[str, Any]] = {
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}


@dataclass(frozen=True)
class LeRobotVideo:
    """The video stream written beside the data (by the caller, at ``video_file(root, key)``).

    Attributes:
        key: the feature key, ``observation.images.<camera>``.
        height, width: frame size in pixels.
        frames: frames of each episode, in export order (must equal the episodes' lengths).
        sample: evenly spaced frames of the stream, taken as they were rendered, for the statistics.
    """

    key: str
    height: int
    width: int
    frames: tuple[int, ...]
    sample: FrameSample


def video_key(camera: str) -> str:
    """LeRobot's feature key of a camera's frames."""
    return f"observation.images.{camera}"


def video_file(root: Path, key: str) -> Path:
    """Where the (single) video file of ``key`` goes."""
    return root / VIDEO_PATH.format(video_key=key, chunk_index=0, file_index=0)


# ------------------------------------------------------------------------------------------------ writing


def info_features(meta: ExportMeta, video: LeRobotVideo | None, fps: int | float) -> dict[str, dict[str, Any]]:
    """The ``features`` of info.json: ours, LeRobot's index columns and the video stream."""
    out: dict[str, dict[str, Any]] = {}
    for key in meta.features:
        f = FEATURE_BY_KEY[key]
        out[f.lerobot] = {"dtype": f.dtype, "shape": [len(f.names)], "names": list(f.names) if len(f.names) > 1 else None}
    if video is not None:
        out[video.key] = {"dtype": "video", "shape": [video.height, video.width, 3],
                          "names": ["height", "width", "channels"],
                          "info": {"video.height": video.height, "video.width": video.width, "video.codec": "h264",
                                   "video.pix_fmt": "yuv420p", "video.fps": fps, "is_depth_map": False,
                                   "video.channels": 3, "has_audio": False}}
    out.update({k: dict(v) for k, v in INDEX_FEATURES.items()})
    return out


def feature_stats(values: np.ndarray) -> dict[str, list[float]]:
    """min, max, mean, std, count and the QUANTILES of (T, n) values per component (NaN ignored)."""
    x = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
    stats = {"min": np.nanmin(x, axis=0), "max": np.nanmax(x, axis=0), "mean": np.nanmean(x, axis=0),
             "std": np.nanstd(x, axis=0)}
    out = {k: v.tolist() for k, v in stats.items()}
    out["count"] = [int(x.shape[0])]
    for q, value in zip(QUANTILES, np.nanquantile(x, QUANTILES, axis=0)):
        out[f"q{int(round(q * 100)):02d}"] = value.tolist()
    return out


def _frame_columns(episodes: Sequence[ExportEpisode], meta: ExportMeta, dt: float) -> list[dict[str, np.ndarray]]:
    """Per episode, every column of its data rows (feature columns by LeRobot key, then the index columns)."""
    out, first = [], 0
    for e, episode in enumerate(episodes):
        t = episode.num_frames
        columns = {FEATURE_BY_KEY[k].lerobot: np.asarray(episode.data[k]) for k in meta.features}
        columns.update(timestamp=(np.arange(t) * dt).astype(np.float32), frame_index=np.arange(t, dtype=np.int64),
                       episode_index=np.full(t, e, dtype=np.int64), index=np.arange(first, first + t, dtype=np.int64),
                       task_index=np.zeros(t, dtype=np.int64))
        out.append(columns)
        first += t
    return out


def _arrow_table(columns: dict[str, np.ndarray], schema: Any) -> Any:
    arrays = []
    for name in schema.names:
        value, kind = columns[name], schema.field(name).type
        if pa.types.is_fixed_size_list(kind):
            arrays.append(pa.FixedSizeListArray.from_arrays(pa.array(value.reshape(-1), kind.value_type),
                                                            kind.list_size))
        else:
            arrays.append(pa.array(value.reshape(-1), kind))
    return pa.Table.from_arrays(arrays, schema=schema)


def _data_schema(features: dict[str, dict[str, Any]]) -> Any:
    fields = []
    for name, ft in features.items():
        if ft["dtype"] == "video":
            continue
        kind = pa.from_numpy_dtype(np.dtype(ft["dtype"]))
        fields.append(pa.field(name, kind if ft["shape"] == [1] else pa.list_(kind, ft["shape"][0])))
    return pa.schema(fields)


def _file_groups(lengths: Sequence[int], row_bytes: int) -> list[tuple[int, int]]:
    """(chunk_index, file_index) of each episode: a new file when the next episode would take the current one
    past DATA_FILE_SIZE_MB (of uncompressed rows), a new chunk every CHUNKS_SIZE files."""
    out, number, size = [], 0, 0
    for t in lengths:
        if size and size + t * row_bytes > DATA_FILE_SIZE_MB * 2**20:
            number, size = number + 1, 0
        size += t * row_bytes
        out.append(divmod(number, CHUNKS_SIZE))
    return out


def _video_stats(sample: FrameSample) -> dict[str, list[Any]]:
    """Per-channel statistics of a video's sampled frames, scaled to [0, 1], shaped (3, 1, 1) as LeRobot keeps
    them (computed from the rendered frames, as LeRobot computes them from the images before encoding)."""
    flat = feature_stats(sample.pixels())
    return {k: ([[[v]] for v in values] if k != "count" else [len(sample.kept)]) for k, values in flat.items()}


def write_lerobot(root: Path, meta: ExportMeta, episodes: Sequence[ExportEpisode],
                  video: LeRobotVideo | None = None) -> dict[str, Any]:
    """Write ``episodes`` as a LeRobot v3.0 dataset into the folder ``root`` (module docstring); a video stream
    must already be at ``video_file(root, video.key)``.

    Returns:
        the info.json written.

    Raises:
        EnvError: no episodes, or video frame counts that differ from the episodes' lengths.
    """
    if not episodes:
        raise EnvError("nothing to export: no episodes")
    lengths = [e.num_frames for e in episodes]
    if video is not None and list(video.frames) != lengths:
        raise EnvError(f"video {video.key}: {list(video.frames)} frames per episode, but the episodes have {lengths}")
    fps = fps_of(meta.dt_s)
    features = info_features(meta, video, fps)
    schema = _data_schema(features)
    per_episode = _frame_columns(episodes, meta, meta.dt_s)
    row_bytes = sum(np.asarray(v[:1]).nbytes for v in per_episode[0].values())
    groups = _file_groups(lengths, row_bytes)
    writers: dict[tuple[int, int], Any] = {}
    try:
        for (chunk, file), columns in zip(groups, per_episode):
            if (chunk, file) not in writers:
                path = root / DATA_PATH.format(chunk_index=chunk, file_index=file)
                path.parent.mkdir(parents=True, exist_ok=True)
                writers[(chunk, file)] = pq.ParquetWriter(path, schema, compression="snappy")
            writers[(chunk, file)].write_table(_arrow_table(columns, schema))  # one row group per episode
    finally:
        for writer in writers.values():
            writer.close()
    stats = {name: feature_stats(np.concatenate([c[name] for c in per_episode])) for name in schema.names}
    if video is not None:
        stats[video.key] = _video_stats(video.sample)
    _write_episodes(root, meta, episodes, per_episode, groups, schema.names, video)
    tasks_path = root / TASKS_PATH
    tasks_path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(_tasks_table(meta.task), tasks_path)
    total = sum(lengths)
    info = {"codebase_version": CODEBASE_VERSION, "robot_type": ROBOT_TYPE, "total_episodes": len(episodes),
            "total_frames": total, "total_tasks": 1, "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": DATA_FILE_SIZE_MB, "video_files_size_in_mb": VIDEO_FILE_SIZE_MB, "fps": fps,
            "splits": {"train": f"0:{len(episodes)}"}, "data_path": DATA_PATH,
            "video_path": VIDEO_PATH if video is not None else None, "features": features}
    write_json(root / "meta" / "info.json", info, mark=False)  # LeRobot's own format
    write_json(root / "meta" / "stats.json", stats, mark=False)
    write_json(root / MARKER_FILE, meta.to_json("lerobot"))
    return info


def _tasks_table(task: str) -> Any:
    """meta/tasks.parquet as pandas writes it (LeRobot reads it with pandas.read_parquet: the index is "task")."""
    import pandas as pd

    frame = pd.DataFrame({"task_index": np.array([0], dtype=np.int64)}, index=pd.Index([task], name="task"))
    return pa.Table.from_pandas(frame)


def _write_episodes(root: Path, meta: ExportMeta, episodes: Sequence[ExportEpisode],
                    per_episode: list[dict[str, np.ndarray]], groups: list[tuple[int, int]], columns: Sequence[str],
                    video: LeRobotVideo | None) -> None:
    """meta/episodes/chunk-000/file-000.parquet (module docstring)."""
    rows: list[dict[str, Any]] = []
    first, video_start = 0, 0.0
    extra_keys = sorted({k for e in episodes for k in e.extra})
    for e, (episode, data, (chunk, file)) in enumerate(zip(episodes, per_episode, groups)):
        t = episode.num_frames
        row: dict[str, Any] = {"episode_index": e, "tasks": [meta.task], "length": t, "data/chunk_index": chunk,
                               "data/file_index": file, "dataset_from_index": first, "dataset_to_index": first + t}
        if video is not None:
            duration = t * meta.dt_s
            row.update({f"videos/{video.key}/chunk_index": 0, f"videos/{video.key}/file_index": 0,
                        f"videos/{video.key}/from_timestamp": video_start,
                        f"videos/{video.key}/to_timestamp": video_start + duration})
            video_start += duration
        row.update({"meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0})
        for name in columns:
            for stat, value in feature_stats(data[name]).items():
                row[f"stats/{name}/{stat}"] = value
        row.update({"source_index": episode.index, "success": episode.success, "end_reason": episode.end_reason})
        row.update({k: episode.extra.get(k) for k in extra_keys})
        rows.append(row)
        first += t
    path = root / EPISODES_PATH.format(chunk_index=0, file_index=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(rows), path)


# ------------------------------------------------------------------------------------------------ reading


def _read_json(path: Path, source: str) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise EnvError(f"{source}: {path.name} is not readable JSON ({type(err).__name__}: {err})") from None


def _read_parquet(path: Path, columns: Sequence[str] | None, root: Path) -> Any:
    source = str(root)
    if not path.is_file():
        raise EnvError(f"{source}: {path.relative_to(root)} is missing")
    try:
        if columns is not None:  # a readable file without a column the dataset should hold is not a corrupt file
            present = set(pq.read_schema(path).names)
            missing = [name for name in columns if name not in present]
            if missing:
                raise EnvError(f"{source}: {path.relative_to(root)} has no column {missing[0]!r} (its columns: "
                               f"{', '.join(sorted(present))[:200]})")
        return pq.read_table(path, columns=list(columns) if columns is not None else None)
    except (OSError, ValueError, KeyError) as err:  # pyarrow.ArrowInvalid is a ValueError
        raise EnvError(f"{source}: {path.name} is not a readable Parquet file, truncated or corrupt "
                       f"({type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''})") from None


def _vectors(table: Any, column: str, width: int, source: str) -> np.ndarray:
    """A column of ``width``-vectors (or scalars for width 1) as a (rows, width) float array."""
    col = table.column(column).combine_chunks()
    if col.null_count:
        raise EnvError(f"{source}: column {column!r} has missing values")
    if pa.types.is_list(col.type) or pa.types.is_fixed_size_list(col.type) or pa.types.is_large_list(col.type):
        if np.any(pc.list_value_length(col).to_numpy(zero_copy_only=False) != width):
            raise EnvError(f"{source}: column {column!r} must hold {width} values per frame")
        values = col.flatten().to_numpy(zero_copy_only=False)
    else:
        values = col.to_numpy(zero_copy_only=False)
    try:
        return np.asarray(values, dtype=np.float64).reshape(len(col), width)
    except (TypeError, ValueError):
        raise EnvError(f"{source}: column {column!r} must hold {width} numbers per frame, got type {col.type}") from None


def _data_columns(path: Path, columns: Sequence[str], root: Path) -> dict[str, np.ndarray]:
    """The ``columns`` of a data file as arrays: the index columns (rows,), the vectors (rows, width)."""
    table = _read_parquet(path, columns, root)
    missing = [c for c in columns if c not in table.column_names]
    if missing:
        raise EnvError(f"{root}: {path.name} lacks columns {missing}")
    widths = {"observation.state": 7, "action.stiffness": 9}
    return {c: _vectors(table, c, widths[c], str(root)) if c in widths else table.column(c).to_numpy()
            for c in columns}


def _feature_width(features: dict[str, Any], key: str, source: str, required: bool) -> int | None:
    ft = features.get(key)
    if ft is None:
        if required:
            raise EnvError(f"{source}: meta/info.json has no feature {key!r} (the tcp pose [x, y, z, qw, qx, qy, qz])")
        return None
    shape = ft.get("shape") if isinstance(ft, dict) else None
    if not isinstance(shape, list) or len(shape) != 1 or not isinstance(shape[0], int):
        raise EnvError(f"{source}: feature {key!r} must have a shape [n], got {shape!r}")
    return shape[0]


def read_lerobot(path: str | Path) -> RecordedDemos:
    """Read the tcp poses (``observation.state``) and, when present, the stiffness (``action.stiffness``) of every
    episode of a LeRobot v3 dataset folder, to import as demos.

    Raises:
        EnvError: no folder or no meta/info.json; another codebase version; missing or
            misshapen features; a missing, truncated or corrupt Parquet file; episodes whose rows are missing
            or out of order; NaN; non-unit quaternions.
    """
    root = Path(path)
    source = str(root)
    if not (root / "meta" / "info.json").is_file():
        raise EnvError(f"{source} is not a LeRobot dataset folder (no meta/info.json)")
    info = _read_json(root / "meta" / "info.json", source)
    if not isinstance(info, dict) or not str(info.get("codebase_version", "")).startswith("v3."):
        version = info.get("codebase_version") if isinstance(info, dict) else None
        raise EnvError(f"{source}: codebase_version {version!r}; only LeRobot v3 datasets are read")
    features, fps, data_path = info.get("features"), info.get("fps"), info.get("data_path")
    if not isinstance(features, dict) or not isinstance(data_path, str):
        raise EnvError(f"{source}: meta/info.json needs 'features' (an object) and 'data_path' (a template)")
    if _feature_width(features, "observation.state", source, required=True) != 7:
        raise EnvError(f"{source}: feature 'observation.state' must be the tcp pose of shape [7]")
    has_k = _feature_width(features, "action.stiffness", source, required=False)
    if has_k not in (None, 9):
        raise EnvError(f"{source}: feature 'action.stiffness' must have shape [9], got [{has_k}]")
    meta = read_meta(_read_json(root / MARKER_FILE, source), source) if (root / MARKER_FILE).is_file() else None
    if meta is not None:
        dt = float(meta["dt_s"])
    elif isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0:
        dt = 1.0 / fps
    else:
        raise EnvError(f"{source}: meta/info.json's fps={fps!r} must be a positive number")
    episode_files = sorted((root / "meta" / "episodes").glob("*/*.parquet"))
    if not episode_files:
        raise EnvError(f"{source}: no episodes table (meta/episodes/chunk-*/file-*.parquet)")
    wanted = ["episode_index", "length", "data/chunk_index", "data/file_index"]
    episodes = [_read_parquet(f, None, root) for f in episode_files]
    for table in episodes:
        absent = [c for c in wanted if c not in table.column_names]
        if absent:
            raise EnvError(f"{source}: the episodes table lacks columns {absent}")
    rows = [r for t in episodes for r in t.select(wanted).to_pylist()]
    if not all(isinstance(r[c], int) for r in rows for c in wanted):
        raise EnvError(f"{source}: the episodes table's {wanted} must be integers in every row")
    rows.sort(key=lambda r: r["episode_index"])
    columns = ["episode_index", "frame_index", "observation.state"] + (["action.stiffness"] if has_k else [])
    files: dict[tuple[int, int], dict[str, np.ndarray]] = {}
    poses, stiffness = [], []
    for row in rows:
        key = (int(row["data/chunk_index"]), int(row["data/file_index"]))
        if key not in files:
            files[key] = _data_columns(root / data_path.format(chunk_index=key[0], file_index=key[1]), columns, root)
        data = files[key]
        mask = data["episode_index"] == row["episode_index"]
        frames = data["frame_index"][mask]
        if len(frames) != row["length"] or np.any(frames != np.arange(len(frames))):
            raise EnvError(f"{source}: episode {row['episode_index']} has {len(frames)} rows, not its length "
                           f"{row['length']} in frame order")
        poses.append(data["observation.state"][mask])
        if has_k:
            stiffness.append(data["action.stiffness"][mask])
    return recorded_from_poses(poses, stiffness if has_k else None, dt, meta, "lerobot", source)
