"""Every tool for every policy: a `--policy` evaluation's video and figures, its episodes recorded as they run and
exported as a dataset a trainer loads (Hugging Face `datasets`, a torch DataLoader), `pih sensitivity --policy`,
`pih compare --sequential` with policies and `pih benchmark --policy` (the factory given each replicate's demo seed
and demos). Tiny episodes: synthetic demos, starts within 10 mm, sub-second time limits."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from scripts.cli import main
from tests.helpers.skill_fixtures import write_demo_file

POLICIES = "tests.helpers.policies_for_tests"
SHORT = ["--pos-range-mm", "10", "--quiet"]


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> Path:
    return write_demo_file(tmp_path_factory.mktemp("demos"))


@pytest.fixture(scope="module")
def expert_run(demos, tmp_path_factory) -> Path:
    """The privileged expert as a --policy: two 0.6 s episodes, recorded as they run, with a video and figures."""
    folder = tmp_path_factory.mktemp("expert")
    argv = ["evaluate", "--policy", "envs.policies.expert:make", "--privileged", "--demos", str(demos),
            "--episodes", "2", *SHORT, "--time-limit-s", "0.6", "--video", str(folder / "v.mp4"),
            "--video-episodes", "0,1", "--figure", str(folder / "f.png"), "--force-figure", str(folder / "force.png"),
            "--stiffness-figure", str(folder / "k.png"), "--json", str(folder / "e.json"),
            "--record-episodes", str(folder / "episodes")]
    assert main(argv) == 0
    return folder


def test_a_policy_evaluation_has_a_video_and_figures_of_its_recorded_episodes(expert_run) -> None:
    from envs.media.video import check_mp4

    assert check_mp4(expert_run / "v.mp4") is None
    import imageio.v2 as imageio

    frames = imageio.get_reader(expert_run / "v.mp4").count_frames()
    assert frames == 2 * (int(0.6 * 30) + 1)  # both episodes, 30 frames a second of their time
    for name in ("f.png", "force.png", "k.png"):
        assert (expert_run / name).stat().st_size > 10_000
    data = json.loads((expert_run / "e.json").read_text())
    assert data["recorded_episodes"]["folder"] == str((expert_run / "episodes").resolve())
    assert sorted(p.name for p in (expert_run / "episodes").iterdir()) == [
        "episode-000000.npz", "episode-000001.npz", "pih_recording.json"]


def test_a_policy_evaluation_exports_to_a_dataset_a_trainer_loads(expert_run, tmp_path) -> None:
    import datasets
    import torch

    out = tmp_path / "ds"
    assert main(["export", "--episodes", str(expert_run / "e.json"), "--format", "lerobot", "--fps", "50",
                 "--out", str(out)]) == 0
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["fps"] == 50 and isinstance(info["fps"], int) and info["total_episodes"] == 2
    assert info["total_frames"] == 2 * (int(0.6 * 50) + 1)
    meta = json.loads((out / "pih_export.json").read_text())
    assert meta["config"]["policy"]["spec"] == "envs.policies.expert:make" and meta["absent"] == {}
    data = datasets.load_dataset("parquet", data_files=str(out / "data" / "*" / "*.parquet"), split="train",
                                 cache_dir=str(tmp_path / "cache"))
    batch = next(iter(torch.utils.data.DataLoader(data.with_format("torch"), batch_size=8)))
    assert batch["action"].shape == (8, 17) and batch["observation.joint_pos"].shape == (8, 7)
    assert batch["observation.wrist_wrench"].shape == (8, 6) and batch["action.stiffness"].shape == (8, 9)
    k = batch["action"][:, 7:16].numpy().reshape(8, 3, 3)
    assert np.all(np.linalg.eigvalsh(k) > 0.0)  # the commanded stiffness, as the expert commanded it


def test_a_recorded_episode_that_does_not_match_its_record_is_refused(expert_run, tmp_path, capsys) -> None:
    data = json.loads((expert_run / "e.json").read_text())
    data["per_episode"][1]["steps"] += 1
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(data))
    assert main(["export", "--episodes", str(edited), "--format", "lerobot", "--out", str(tmp_path / "ds")]) == 2
    err = capsys.readouterr().err
    assert "recorded episode 1 differs from its record (steps" in err and err.count("\n") == 1


@pytest.fixture(scope="module")
def short_task(tmp_path_factory) -> Path:
    """The contact preset (the ideal cell of `pih sensitivity`) with a 0.3 s time limit."""
    from envs.task.task import preset

    path = tmp_path_factory.mktemp("task") / "short.toml"
    path.write_text(preset("contact").override(time_limit_s=0.3).to_toml())
    return path


def test_sensitivity_runs_a_policy_on_every_variant_paired_with_the_ideal_cell(demos, short_task, tmp_path) -> None:
    out = tmp_path / "sens"
    assert main(["sensitivity", "--policy", f"{POLICIES}:hold", "--demos", str(demos), "--only", "payload",
                 "--episodes", "2", "--workers", "1", "--task", str(short_task), "--out", str(out)]) == 0
    data = json.loads((out / "sensitivity.json").read_text())
    assert data["policy"]["spec"] == f"{POLICIES}:hold" and data["demos"] == str(demos)
    assert [r["name"] for r in data["rows"]] == ["ideal", "payload"]
    assert all(r["episodes"] == 2 and r["successes"] == 0 for r in data["rows"])
    assert data["rows"][1]["paired_with_ideal"] is not None


def test_sensitivity_stops_at_a_policy_error(demos, short_task, tmp_path, capsys) -> None:
    assert main(["sensitivity", "--policy", f"{POLICIES}:typo", "--demos", str(demos), "--only", "payload",
                 "--episodes", "2", "--workers", "1", "--task", str(short_task), "--out", str(tmp_path / "s")]) == 4
    err = capsys.readouterr().err
    assert "AttributeError: 'Typo' object has no attribute 'gaol'" in err
    assert not (tmp_path / "s" / "sensitivity.json").exists()


def test_sequential_compare_runs_policies_on_the_same_starts(demos, tmp_path, capsys) -> None:
    """The nominal-goal policy against the one that holds its start: the candidate never seats."""
    out = tmp_path / "cmp.json"
    status = main(["compare", "--sequential", "--base-policy", f"{POLICIES}:goal", "--base-policy-option",
                   "duration_s=0.5", "--cand-policy", f"{POLICIES}:hold", "--demos", str(demos), "--max-episodes", "4",
                   "--chunk", "2", "--time-limit-s", "1.5", "--pos-range-mm", "10", "--quiet", "--json", str(out)])
    data = json.loads(out.read_text())
    base, cand = data["base_evaluation"], data["candidate_evaluation"]
    assert base["policy"]["spec"] == f"{POLICIES}:goal" and cand["policy"]["spec"] == f"{POLICIES}:hold"
    assert data["episodes_run"] == 4 and cand["successes"] == 0
    assert [r["start_pos"] for r in base["per_episode"]] == [r["start_pos"] for r in cand["per_episode"]]
    assert status in (0, 1)


@pytest.mark.slow
def test_benchmark_gives_a_policys_factory_each_replicates_demo_seed_and_demos(tmp_path) -> None:
    out = tmp_path / "bench"
    assert main(["benchmark", "--policy", f"{POLICIES}:seeded", "--demo-seeds", "3,4", "--demos", "1",
                 "--episodes", "2", "--time-limit-s", "0.3", "--workers", "1", "--quiet", "--out", str(out)]) == 0
    protocol = json.loads((out / "protocol.json").read_text())
    assert protocol["policy"]["spec"] == f"{POLICIES}:seeded"
    for seed in (3, 4):
        folder = out / f"seed-{seed}"
        assert not (folder / "model").exists()  # no skill trained: the factory learns
        options = json.loads((folder / "eval.json").read_text())["policy"]["options"]
        assert options == {"demo_seed": str(seed), "demo_file": str((folder / "demos.npz").resolve())}
    summary = json.loads((out / "benchmark.json").read_text())
    assert summary["complete"] and summary["pooled"]["episodes"] == 4


@pytest.mark.parametrize("argv,words", [
    (["sensitivity", "--model", "MODEL", "--policy", f"{POLICIES}:hold", "--demos", "DEMOS", "--out", "OUT"],
     "--model and --policy: give one"),
    (["sensitivity", "--policy", f"{POLICIES}:hold", "--out", "OUT"], "--policy needs --demos"),
    (["compare", "--sequential", "--base-policy", f"{POLICIES}:hold", "--cand-policy", f"{POLICIES}:goal"],
     "needs --demos"),
    (["compare", "--sequential", "--base-model", "MODEL", "--cand-model", "MODEL", "--cand-policy-option", "a=b"],
     "--cand-policy-option: only with --cand-policy"),
    (["benchmark", "--policy", f"{POLICIES}:seeded", "--policy-option", "demo_seed=3", "--out", "OUT"],
     "--policy-option demo_seed: the protocol gives the factory this option itself"),
    (["benchmark", "--policy", f"{POLICIES}:seeded", "--epochs", "3", "--out", "OUT"], "--epochs: not with --policy"),
    (["evaluate", "--policy", f"{POLICIES}:hold", "--demos", "DEMOS", "--record-episodes", "DEMOS"],
     "is a file, not a folder"),
])
def test_the_policy_options_of_every_tool_are_checked_before_any_work(demos, tmp_path, capsys, argv, words) -> None:
    (tmp_path / "model").mkdir()
    names = {"MODEL": str(tmp_path / "model"), "DEMOS": str(demos), "OUT": str(tmp_path / "out")}
    assert main([names.get(a, a) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model"]  # nothing written
