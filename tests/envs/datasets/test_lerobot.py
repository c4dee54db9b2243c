"""envs.datasets.lerobot: the LeRobot v3.0 layout (conformance with what lerobot reads) and its read-back."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from envs.datasets.features import ExportEpisode, FEATURES, evaluation_meta
from envs.datasets.frame_sample import FrameSample
from envs.datasets.lerobot import LeRobotVideo, read_lerobot, video_file, video_key, write_lerobot
from envs.errors import EnvError
from envs.media.video import Mp4Writer
from tests.helpers import dataset_fixtures
from tests.helpers.dataset_fixtures import assert_read_back


def export_demos(root: Path) -> tuple[Any, dict[str, Any]]:
    """Three stiffness demos written as a LeRobot dataset into ``root``; (demos, info.json)."""
    demos, info = dataset_fixtures.export_demos(root, "lerobot")
    return demos, json.loads(info.read_text())


def data_table(root: Path) -> pa.Table:
    return pq.read_table(root / "data" / "chunk-000" / "file-000.parquet")


def hf_features(info: dict[str, Any]) -> Any:
    """The datasets.Features LeRobot builds from info.json (lerobot.datasets.feature_utils.get_hf_features_from_features)."""
    import datasets

    out = {}
    for key, ft in info["features"].items():
        if ft["dtype"] == "video":
            continue
        if tuple(ft["shape"]) == (1,):
            out[key] = datasets.Value(ft["dtype"])
        else:
            out[key] = datasets.Sequence(length=ft["shape"][0], feature=datasets.Value(ft["dtype"]))
    return datasets.Features(out)


def test_poses_and_stiffness_read_back_to_float64_precision(tmp_path: Path) -> None:
    demos, _ = export_demos(tmp_path / "ds")
    assert_read_back(read_lerobot(tmp_path / "ds"), demos)


def test_info_features_match_the_parquet_schema(tmp_path: Path) -> None:
    _, info = export_demos(tmp_path / "ds")
    schema = data_table(tmp_path / "ds").schema
    assert set(schema.names) == {k for k, ft in info["features"].items() if ft["dtype"] != "video"}
    for name in schema.names:
        ft, kind = info["features"][name], schema.field(name).type
        value = kind.value_type if pa.types.is_fixed_size_list(kind) else kind
        assert value == pa.from_numpy_dtype(np.dtype(ft["dtype"])), name
        assert (kind.list_size if pa.types.is_fixed_size_list(kind) else 1) == ft["shape"][0], name
        names = ft["names"]
        assert names is None or len(names) == ft["shape"][0], name


def test_info_json_has_the_v3_keys_and_counts(tmp_path: Path) -> None:
    _, info = export_demos(tmp_path / "ds")
    assert info["codebase_version"] == "v3.0" and info["fps"] == 20 and info["total_episodes"] == 3
    assert info["total_frames"] == data_table(tmp_path / "ds").num_rows == 90
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    assert info["video_path"] is None and info["splits"] == {"train": "0:3"}
    assert json.loads((tmp_path / "ds" / "meta" / "info.json").read_text()) == info


def test_tasks_table_is_indexed_by_the_task_as_lerobot_reads_it(tmp_path: Path) -> None:
    export_demos(tmp_path / "ds")
    tasks = pd.read_parquet(tmp_path / "ds" / "meta" / "tasks.parquet")
    assert tasks.index.name == "task" and list(tasks["task_index"]) == [0]
    assert "square peg" in tasks.index[0]


def test_episodes_table_indexes_the_data_rows(tmp_path: Path) -> None:
    export_demos(tmp_path / "ds")
    data = data_table(tmp_path / "ds").to_pydict()
    episodes = pq.read_table(tmp_path / "ds" / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    for row in episodes:
        rows = [i for i, e in enumerate(data["episode_index"]) if e == row["episode_index"]]
        assert [data["index"][i] for i in rows] == list(range(row["dataset_from_index"], row["dataset_to_index"]))
        assert len(rows) == row["length"] and (row["data/chunk_index"], row["data/file_index"]) == (0, 0)
        assert row["success"] and row["end_reason"] == "demonstration"


def test_stats_json_holds_the_data_statistics(tmp_path: Path) -> None:
    export_demos(tmp_path / "ds")
    stats = json.loads((tmp_path / "ds" / "meta" / "stats.json").read_text())
    state = np.array(data_table(tmp_path / "ds").column("observation.state").to_pylist())
    np.testing.assert_allclose(stats["observation.state"]["mean"], state.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(stats["observation.state"]["q50"], np.median(state, axis=0), rtol=1e-12)
    assert stats["observation.state"]["count"] == [90]
    assert set(stats) == set(data_table(tmp_path / "ds").schema.names)


def test_hugging_face_datasets_loads_the_data_with_lerobots_features(tmp_path: Path) -> None:
    import datasets

    _, info = export_demos(tmp_path / "ds")
    files = sorted(str(p) for p in (tmp_path / "ds" / "data").glob("*/*.parquet"))
    loaded = datasets.Dataset.from_parquet(files, features=hf_features(info), cache_dir=str(tmp_path / "cache"))
    plain = datasets.load_dataset("parquet", data_files=files, split="train", cache_dir=str(tmp_path / "cache"))
    assert len(loaded) == len(plain) == info["total_frames"]
    assert loaded.features == hf_features(info)
    np.testing.assert_array_equal(np.array(loaded["observation.state"]), np.array(plain["observation.state"]))


def fake_episode(index: int, frames: int) -> ExportEpisode:
    """An episode with every feature (arbitrary values, unit quaternions)."""
    rng = np.random.default_rng(index)
    data: dict[str, np.ndarray] = {}
    for f in FEATURES:
        data[f.key] = rng.random((frames, len(f.names))) if f.dtype == "float64" else np.zeros(frames, bool)
    for key in ("tcp_pose", "peg_tip_pose", "action"):
        data[key][:, 3:7] = [1.0, 0.0, 0.0, 0.0]
    return ExportEpisode(index, data, False, "time_limit", {"perturbation.hole_dx_mm": 0.5})


def write_with_video(root: Path, lengths: tuple[int, ...], video_frames: tuple[int, ...]) -> dict[str, Any]:
    """Episodes of ``lengths`` frames at 100 fps and an MP4 of sum(video_frames) grey 32x32 frames."""
    root.mkdir()
    meta = evaluation_meta("eval.json", 0.01, "square", 0.0002, {}, camera="front")
    path = video_file(root, video_key("front"))
    path.parent.mkdir(parents=True)
    writer, sample = Mp4Writer(path, fps=100), FrameSample()
    for _ in range(sum(video_frames)):
        frame = np.full((32, 32, 3), 128, np.uint8)
        writer.append(frame)
        sample.add(frame)
    writer.close()
    episodes = [fake_episode(i, t) for i, t in enumerate(lengths)]
    return write_lerobot(root, meta, episodes, LeRobotVideo(video_key("front"), 32, 32, video_frames, sample))


def test_video_stream_is_declared_and_located_by_timestamps(tmp_path: Path) -> None:
    info = write_with_video(tmp_path / "ds", (5, 7), (5, 7))
    key = "observation.images.front"
    assert info["features"][key]["shape"] == [32, 32, 3] and info["features"][key]["info"]["video.fps"] == 100
    assert info["video_path"].format(video_key=key, chunk_index=0, file_index=0) == \
        f"videos/{key}/chunk-000/file-000.mp4"
    rows = pq.read_table(tmp_path / "ds" / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    starts = [r[f"videos/{key}/from_timestamp"] for r in rows]
    ends = [r[f"videos/{key}/to_timestamp"] for r in rows]
    assert starts == pytest.approx([0.0, 0.05]) and ends == pytest.approx([0.05, 0.12])
    stats = json.loads((tmp_path / "ds" / "meta" / "stats.json").read_text())[key]
    assert np.array(stats["mean"]).shape == (3, 1, 1) and np.allclose(stats["mean"], 128 / 255, atol=0.02)


def test_video_with_other_frame_counts_than_the_data_is_refused(tmp_path: Path) -> None:
    with pytest.raises(EnvError, match="frames per episode"):
        write_with_video(tmp_path / "ds", (5, 7), (5, 6))


def truncate_data(root: Path) -> None:
    path = root / "data" / "chunk-000" / "file-000.parquet"
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def nan_pose(root: Path) -> None:
    path = root / "data" / "chunk-000" / "file-000.parquet"
    table = pq.read_table(path)
    state = np.array(table.column("observation.state").to_pylist())
    state[4, 1] = np.nan
    column = pa.FixedSizeListArray.from_arrays(pa.array(state.reshape(-1)), 7)
    pq.write_table(table.set_column(table.schema.get_field_index("observation.state"), "observation.state", column),
                   path)


def drop_state_column(root: Path) -> None:
    """The data file without the observation.state column that info.json lists: a readable file missing a column."""
    path = root / "data" / "chunk-000" / "file-000.parquet"
    pq.write_table(pq.read_table(path).drop_columns(["observation.state"]), path)


def edit_info(change: Callable[[dict[str, Any]], None]) -> Callable[[Path], None]:
    def edit(root: Path) -> None:
        path = root / "meta" / "info.json"
        info = json.loads(path.read_text())
        change(info)
        path.write_text(json.dumps(info))
    return edit


@pytest.mark.parametrize("damage, message", [
    (truncate_data, "not a readable Parquet file"),
    (nan_pose, "NaN"),
    (drop_state_column, "file-000.parquet has no column 'observation.state'"),
    (lambda root: (root / "meta" / "info.json").unlink(), "no meta/info.json"),
    (lambda root: (root / "data" / "chunk-000" / "file-000.parquet").unlink(), "is missing"),
    (edit_info(lambda info: info["features"]["observation.state"].update(shape=[6])), "shape \\[7\\]"),
    (edit_info(lambda info: info.update(codebase_version="v2.1")), "only LeRobot v3"),
    (edit_info(lambda info: info["features"].pop("observation.state")), "no feature 'observation.state'"),
])
def test_malformed_dataset_is_one_clear_error(tmp_path: Path, damage: Callable[[Path], None], message: str) -> None:
    export_demos(tmp_path / "ds")
    damage(tmp_path / "ds")
    with pytest.raises(EnvError, match=message):
        read_lerobot(tmp_path / "ds")


def test_data_past_the_file_size_limit_goes_to_further_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import envs.datasets.lerobot as lerobot

    monkeypatch.setattr(lerobot, "DATA_FILE_SIZE_MB", 0.001)  # ~1 kB: one 30-frame demo per file
    demos, _ = export_demos(tmp_path / "ds")
    episodes = pq.read_table(tmp_path / "ds" / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    assert [(e["data/chunk_index"], e["data/file_index"]) for e in episodes] == [(0, 0), (0, 1), (0, 2)]
    assert sorted(p.name for p in (tmp_path / "ds" / "data" / "chunk-000").iterdir()) == \
        ["file-000.parquet", "file-001.parquet", "file-002.parquet"]
    assert_read_back(read_lerobot(tmp_path / "ds"), demos)
