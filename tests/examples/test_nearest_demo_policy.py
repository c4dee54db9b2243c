"""The README's "Evaluate your own policy" example: demos exported to LeRobot, read back by examples/nearest_demo_policy.py
and scored through `pih evaluate --policy` from the repository root, as the README runs it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from scripts.cli import main
from tests.helpers import REPO



@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> tuple[Path, Path]:
    """Two scripted demos (400 samples) and their LeRobot export."""
    from envs.demos.file import save_demos
    from envs.demos.record import collect_demos
    from envs.policies.expert_plan import ExpertConfig

    folder = tmp_path_factory.mktemp("example")
    demos = save_demos(folder / "demos.npz", collect_demos(2, seed=0, expert=ExpertConfig(num_samples=400)).demos)
    assert main(["export", "--demos", str(demos), "--format", "lerobot", "--out", str(folder / "ds")]) == 0
    return demos, folder / "ds"


def test_the_example_reads_the_demos_back_from_the_parquet(exported, monkeypatch) -> None:
    from envs.demos.file import load_demos

    monkeypatch.syspath_prepend(str(REPO))  # examples/ is not installed with the package
    from examples.nearest_demo_policy import read_demos

    from envs.datasets.features import episodes_from_demos

    demos_path, dataset = exported
    demos = load_demos(demos_path)
    fps, read = read_demos(dataset)
    assert fps == 100 and len(read) == demos.num_demos  # the export's frame rate: the control rate
    _, exported_episodes = episodes_from_demos(demos, str(demos_path), fps=100)
    for n, demo in enumerate(read):
        frames = exported_episodes[n].data
        np.testing.assert_array_equal(demo["pos"], frames["tcp_pose"][:, :3])
        np.testing.assert_array_equal(demo["quat"], frames["tcp_pose"][:, 3:])
        np.testing.assert_array_equal(demo["stiffness"].reshape(-1, 9), frames["action_stiffness"])
        np.testing.assert_allclose(demo["times"], np.arange(round(demos.duration_s * 100) + 1) / 100, atol=1e-12)
        np.testing.assert_array_equal(demo["pos"][[0, -1]], demos.pos[n][[0, -1]])  # the demo's ends, as recorded


def test_the_readme_command_scores_the_example_policy_in_physics(exported, tmp_path, monkeypatch) -> None:
    demos, dataset = exported
    monkeypatch.chdir(REPO)  # `pih evaluate` imports the policy's module from the current folder, as in the README
    out = tmp_path / "mine.json"
    assert main(["evaluate", "--policy", "examples.nearest_demo_policy:make", "--policy-option", f"dataset={dataset}",
                 "--demos", str(demos), "--episodes", "3", "--time-limit-s", "10", "--json", str(out), "--quiet"]) == 0
    data = json.loads(out.read_text())
    assert data["policy"]["spec"] == "examples.nearest_demo_policy:make" and data["episodes"] == 3
    for record in data["per_episode"]:
        assert record["reason"].split(" ")[0] in ("success", "time_limit", "force_limit")
        assert record["touched"] and record["steps"] > 100  # it reached the sorter and physics ended the episode
        assert (record["success"] and record["insertion_depth_mm"] > 28.0) or not record["success"]
