"""Outputs never destroy what is not ours, and inputs are checked before work: `pih train --out` on a file or
a foreign folder exits 2 with nothing deleted; an earlier checkpoint needs --overwrite; demo files of an
unknown shape or a bad clearance are refused before training; demo files follow the umask; `pih run`
replaces only its own earlier outputs, and only with --overwrite."""

from __future__ import annotations

import dataclasses
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from envs.demos.file import save_demos
from envs.errors import EnvError
from envs.io.owned_output import write_json
from envs.media.video import Mp4Writer
from scripts.cli import main
from scripts.run import check_run_folder
from tests.helpers.skill_fixtures import synthetic_demos, write_demo_file

TINY_ARGS = ["--epochs", "1", "--layers", "2", "--width", "16", "--subsample", "1", "--horizon", "5",
             "--transitions-per-epoch", "128", "--threads", "1", "--quiet"]


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    return err


@pytest.mark.parametrize("kind", ["file", "folder", "cwd"])
def test_train_out_on_something_not_a_checkpoint_deletes_nothing(tmp_path, capsys, monkeypatch, kind):
    demos = write_demo_file(tmp_path)
    target = tmp_path / "target"
    if kind == "file":
        target.write_text("keep me")
    else:
        target.mkdir()
        (target / "data.txt").write_text("keep me")
    if kind == "cwd":
        monkeypatch.chdir(target)
        target = Path(".")
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    assert main(["train", "--demos", str(demos), "--out", str(target), "--overwrite", *TINY_ARGS]) == 2
    assert "not a checkpoint" in _error(capsys)
    assert sorted(str(p) for p in tmp_path.rglob("*")) == before


def test_train_replaces_its_checkpoint_only_with_overwrite(tmp_path, capsys):
    demos = write_demo_file(tmp_path)
    args = ["train", "--demos", str(demos), "--out", str(tmp_path / "ck"), *TINY_ARGS]
    assert main(args) == 0
    assert main(args) == 2 and "--overwrite" in _error(capsys)
    assert main(args + ["--overwrite"]) == 0


@pytest.mark.parametrize("change, message", [({"shape": "dodecahedron"}, "dodecahedron"),
                                             ({"clearance_m": 0.0}, "clearance")])
def test_train_checks_the_demos_scene_before_training(tmp_path, capsys, change, message):
    demos = dataclasses.replace(synthetic_demos(), **change)
    path = tmp_path / "demos.npz"
    try:
        save_demos(path, demos)
    except EnvError:
        pytest.skip("save_demos already refuses these demos")
    assert main(["train", "--demos", str(path), "--out", str(tmp_path / "ck"), *TINY_ARGS]) == 2
    assert message in _error(capsys) and not (tmp_path / "ck").exists()


def test_demo_file_mode_follows_the_umask(tmp_path):
    old = os.umask(0o022)
    try:
        path = write_demo_file(tmp_path)
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644


def test_run_folder_outputs_are_replaced_only_when_pih_wrote_them(tmp_path):
    write_json(tmp_path / "eval.json", {"episodes": 1})
    (tmp_path / "thesis.tex").write_text("keep me")  # not an output of `pih run`: left alone
    check_run_folder(tmp_path, overwrite=True, video=True)
    with pytest.raises(EnvError, match="--overwrite"):
        check_run_folder(tmp_path, overwrite=False, video=True)
    (tmp_path / "eval.json").write_text("{}")  # the user's own eval.json
    with pytest.raises(EnvError, match="not written by pih"):
        check_run_folder(tmp_path, overwrite=True, video=True)


def test_a_video_cut_off_mid_write_leaves_nothing(tmp_path):
    writer = Mp4Writer(tmp_path / "episodes.mp4", fps=30)
    writer.append(np.zeros((64, 64, 3), dtype=np.uint8))
    assert writer.temporary_path.parent == tmp_path and writer.temporary_path.name.startswith(".episodes.mp4.")
    writer.abort()
    assert not any(tmp_path.iterdir())
