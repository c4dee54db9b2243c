"""rflow.skill_io never destroys what is not a checkpoint: a file or a foreign folder at the output path is
refused even with overwrite, a checkpoint is replaced only with overwrite; folder modes follow the umask;
weights with NaN are refused at load, naming the file."""

from __future__ import annotations

import os
import stat

import pytest
import torch

from rflow.errors import RFlowError
from rflow.skill_io import load_skill, save_skill
from tests.helpers.skill_fixtures import tiny_skill


@pytest.fixture(scope="module")
def skill():
    return tiny_skill()


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_foreign_folder_is_never_replaced(skill, tmp_path, overwrite):
    data = tmp_path / "data"
    data.mkdir()
    (data / "precious.txt").write_text("keep me")
    with pytest.raises(RFlowError, match="not a checkpoint"):
        save_skill(data, skill, overwrite=overwrite)
    assert (data / "precious.txt").read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data"]


def test_a_plain_file_is_never_replaced(skill, tmp_path):
    target = tmp_path / "notes"
    target.write_text("keep me")
    with pytest.raises(RFlowError, match="file that is not a checkpoint"):
        save_skill(target, skill, overwrite=True)
    assert target.read_text() == "keep me"


def test_the_working_directory_is_never_replaced(skill, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.txt").write_text("keep me")
    with pytest.raises(RFlowError):
        save_skill(".", skill, overwrite=True)
    assert (tmp_path / "mine.txt").read_text() == "keep me"


def test_a_checkpoint_is_replaced_only_with_overwrite(skill, tmp_path):
    save_skill(tmp_path / "ck", skill)
    with pytest.raises(RFlowError, match="--overwrite"):
        save_skill(tmp_path / "ck", skill)
    save_skill(tmp_path / "ck", tiny_skill(layout="joint"), overwrite=True)
    assert load_skill(tmp_path / "ck").layout == "joint"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ck"]


def test_checkpoint_folder_mode_follows_the_umask(skill, tmp_path):
    old = os.umask(0o022)
    try:
        out = save_skill(tmp_path / "ck", skill)
    finally:
        os.umask(old)
    assert stat.S_IMODE(out.stat().st_mode) == 0o755


@pytest.mark.parametrize("which", [0, -1])
def test_nan_weights_are_refused_naming_the_file(skill, tmp_path, which):
    out = save_skill(tmp_path / "ck", skill)
    weights = out / "position" / "weights.pt"
    state = torch.load(weights, weights_only=True)
    key = [k for k, v in state.items() if v.is_floating_point() and v.numel() > 1][which]
    state[key].view(-1)[0] = float("nan")
    torch.save(state, weights)
    with pytest.raises(RFlowError, match="position/weights.pt"):
        load_skill(out)


@pytest.mark.parametrize("change", ["added file", "edited weights", "new folder", "symlink", "legacy added",
                                    "fifo for weights"])
def test_overwrite_never_deletes_what_somebody_put_into_a_checkpoint(skill, tmp_path, change):
    out = tmp_path / "model"
    save_skill(out, skill)
    save_skill(out, skill, overwrite=True)  # an untouched checkpoint of ours is replaced
    if change == "added file":
        (out / "notes.txt").write_text("keep me")
    elif change == "edited weights":
        with open(out / "position" / "weights.pt", "ab") as handle:
            handle.write(b"\0")
    elif change == "new folder":
        (out / "mine").mkdir()
    elif change == "symlink":
        os.symlink(tmp_path, out / "link")
    elif change == "fifo for weights":  # a listed name that is now a FIFO: refused, never opened (no hang)
        (out / "position" / "weights.pt").unlink()
        os.mkfifo(out / "position" / "weights.pt")
    else:  # a checkpoint from before the file list: its known files only
        from pihutil.manifest import MANIFEST_NAME

        (out / MANIFEST_NAME).unlink()
        save_skill(out, skill, overwrite=True)
        (out / MANIFEST_NAME).unlink()
        (out / "position" / "notes.txt").write_text("keep me")
    before = sorted(str(p.relative_to(out)) for p in out.rglob("*"))
    with pytest.raises(RFlowError, match="did not write or that changed since"):
        save_skill(out, skill, overwrite=True)
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model"]  # no staging folder left


def test_a_checkpoint_from_before_the_file_lists_is_still_replaced(skill, tmp_path):
    """`pih train` wrote skill.json, the models, the demo preview, the loss figure and its registry: all known."""
    from pihutil.manifest import MANIFEST_NAME

    out = tmp_path / "model"
    save_skill(out, skill, {"demos.npz": lambda p: p.write_bytes(b"x"), "loss.png": lambda p: p.write_bytes(b"x"),
                            ".pih-outputs.json": lambda p: p.write_text("{}")})
    (out / MANIFEST_NAME).unlink()
    save_skill(out, skill, overwrite=True)
    assert (out / MANIFEST_NAME).is_file()
