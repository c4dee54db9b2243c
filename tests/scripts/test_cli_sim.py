"""`pih demos`, `pih render` and `pih bench` from the command line (in process)."""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest

from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.demos.file import DemoSet, load_demos, save_demos
from scripts.cli import main


def test_demos_with_bad_shape_exits_2_with_one_line_and_no_file(tmp_path: Path, capsys) -> None:
    out = tmp_path / "demos.npz"
    assert main(["demos", "--num", "1", "--out", str(out), "--shape", "blob"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "blob" in err
    assert not out.exists()


def test_demos_without_out_exits_2(capsys) -> None:
    assert main(["demos", "--num", "1"]) == 2
    assert "--out" in capsys.readouterr().err


def test_demos_writes_a_valid_file(tmp_path: Path) -> None:
    out = tmp_path / "demos.npz"
    assert main(["demos", "--num", "1", "--seed", "1", "--samples", "100", "--out", str(out)]) == 0
    demos = load_demos(out)
    assert demos.pos.shape == (1, 100, 3) and demos.config["seed"] == 1


def test_demos_record_the_asked_expert_stiffness(tmp_path: Path, capsys) -> None:
    """--expert-stiffness sets the schedule the expert commands: the file records it, every demo ends at its goal
    stiffness (300 N/m across and along the axis here, not the default 1000 along it); a bad one is a usage error."""
    out = tmp_path / "demos.npz"
    assert main(["demos", "--num", "1", "--seed", "1", "--samples", "100", "--expert-stiffness", "1500/300/300",
                 "--out", str(out)]) == 0
    demos = load_demos(out)
    assert demos.config["expert"]["stiffness"]["axial_hole_n_m"] == 300.0
    np.testing.assert_allclose(np.linalg.eigvalsh(demos.goal_stiffness), [300.0] * 3)
    np.testing.assert_allclose(demos.stiffness[0, -1], demos.goal_stiffness)
    assert main(["demos", "--num", "1", "--expert-stiffness", "1500/300", "--out", str(tmp_path / "x.npz")]) == 2
    assert "FREE/LATERAL/AXIAL" in capsys.readouterr().err and not (tmp_path / "x.npz").exists()


def test_render_missing_demo_file_exits_2(tmp_path: Path, capsys) -> None:
    assert main(["render", "--demos", str(tmp_path / "nope.npz"), "--out", str(tmp_path / "x.mp4")]) == 2
    assert "not found" in capsys.readouterr().err


@pytest.fixture(scope="module")
def short_demo_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One 0.4 s free-space demo, 3 cm sideways 6 cm above the goal (rendering, not insertion, is tested)."""
    scene = build_scene(SceneConfig())
    goal_pos, goal_quat = scene.goal_pose()
    s = np.linspace(0.0, 1.0, 41)[:, None]
    start = goal_pos + [0.0, -0.03, 0.06]
    goal_pos = goal_pos + [0.0, 0.0, 0.06]
    demos = DemoSet(pos=(start + s * (goal_pos - start))[None], quat=np.tile(goal_quat, (1, 41, 1)), dt=0.01,
                    goal_pos=goal_pos, goal_quat=goal_quat, shape="square", clearance_m=0.001)
    return save_demos(tmp_path_factory.mktemp("demos") / "short.npz", demos)


def test_render_writes_the_requested_video(short_demo_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "demo.mp4"
    args = ["render", "--demos", str(short_demo_file), "--out", str(out), "--width-px", "160", "--height-px", "120",
            "--hold-s", "0", "--camera", "top"]
    assert main(args) == 0
    reader = imageio.get_reader(out)
    assert reader.get_meta_data()["size"] == (160, 120)
    assert sum(1 for _ in reader) == 13  # floor(0.4 s * 30 fps) + 1


def test_render_index_out_of_range_exits_2(short_demo_file: Path, tmp_path: Path, capsys) -> None:
    assert main(["render", "--demos", str(short_demo_file), "--index", "3", "--out", str(tmp_path / "x.mp4")]) == 2
    assert "out of range" in capsys.readouterr().err


def test_bench_writes_json(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    assert main(["bench", "--quick", "--only", "ik", "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert figures["ik"]["ik_solves_per_s"] > 0 and "machine" in figures


def test_bench_unknown_name_exits_2(capsys) -> None:
    assert main(["bench", "--only", "nope"]) == 2
    assert "unknown benchmark" in capsys.readouterr().err
