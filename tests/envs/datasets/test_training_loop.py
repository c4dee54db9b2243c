"""Datasets ready for training: demos recorded in physics, exported by `pih export --demos --format lerobot --fps 50`,
hold an action, the joints and the wrench at an integer frame rate, and the training loop of docs/datasets.md (Hugging
Face `datasets` and a torch DataLoader) runs on the export as it is shown there."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from envs.datasets.features import ACTION_NAMES
from scripts.cli import main

DOCS = Path(__file__).resolve().parents[3] / "docs" / "datasets.md"


@pytest.fixture(scope="module")
def export(tmp_path_factory) -> Path:
    from envs.demos.file import save_demos
    from envs.demos.record import collect_demos
    from envs.policies.expert_plan import ExpertConfig

    folder = tmp_path_factory.mktemp("export")
    demos = save_demos(folder / "demos.npz", collect_demos(2, seed=0, expert=ExpertConfig(num_samples=300)).demos)
    assert main(["export", "--demos", str(demos), "--format", "lerobot", "--fps", "50", "--out",
                 str(folder / "ds50")]) == 0
    return folder / "ds50"


@pytest.mark.slow
def test_a_demo_export_has_an_action_joints_and_wrench_at_an_integer_frame_rate(export: Path) -> None:
    info = json.loads((export / "meta" / "info.json").read_text())
    assert info["fps"] == 50 and isinstance(info["fps"], int)
    assert info["total_frames"] == 2 * 351  # 7 s at 50 fps, both ends included
    features = info["features"]
    assert features["action"]["names"] == list(ACTION_NAMES) and features["action"]["shape"] == [17]
    for key, width in (("observation.state", 7), ("observation.joint_pos", 7), ("observation.joint_vel", 7),
                       ("observation.wrist_wrench", 6), ("action.stiffness", 9)):
        assert features[key]["shape"] == [width], key
    absent = json.loads((export / "pih_export.json").read_text())["absent"]
    assert set(absent) == {"peg_tip_pose", "success"}


def _docs_training_loop() -> str:
    """The python block of docs/datasets.md's "Training on an export"."""
    section = DOCS.read_text().split("## Training on an export", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.mark.slow
def test_the_docs_training_loop_runs_on_the_export(export: Path) -> None:
    import datasets
    import torch

    code = _docs_training_loop()
    assert 'ROOT = "ds50"' in code
    namespace: dict = {}
    exec(compile(code.replace('ROOT = "ds50"', f'ROOT = {str(export)!r}'), str(DOCS), "exec"), namespace)
    losses = namespace["losses"]
    assert len(losses) == 3 * int(np.ceil(702 / 64)) and all(np.isfinite(losses))
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:5])  # it learns: the data are what a trainer needs
    data = datasets.load_dataset("parquet", data_files=str(export / "data" / "*" / "*.parquet"), split="train")
    batch = next(iter(torch.utils.data.DataLoader(data.with_format("torch"), batch_size=8)))
    assert batch["action"].shape == (8, 17) and batch["observation.joint_pos"].shape == (8, 7)
