"""pihutil.atomic, the one atomic write: an output appears whole under its name or not at all."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from pihutil.atomic import AtomicFile, atomic_folder, umask, write_atomic


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".tmp" in p.name or ".old-" in p.name)


def test_a_written_file_replaces_the_old_one_with_the_umasks_mode(tmp_path: Path) -> None:
    out = tmp_path / "a.json"
    out.write_text("old")
    write_atomic(out, lambda handle: handle.write("new"))
    assert out.read_text() == "new"
    assert stat.S_IMODE(out.stat().st_mode) == 0o666 & ~umask()
    assert leftovers(tmp_path) == []


def test_a_failing_writer_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    out = tmp_path / "a.json"
    out.write_text("old")

    def fail(handle) -> None:
        handle.write("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        write_atomic(out, fail)
    assert out.read_text() == "old"
    assert leftovers(tmp_path) == []


def test_the_temporary_name_keeps_the_suffix(tmp_path: Path) -> None:
    with AtomicFile(tmp_path / "video.mp4") as out:
        assert out.temporary.suffix == ".mp4" and out.temporary.parent == tmp_path
        out.temporary.write_bytes(b"x")
    assert (tmp_path / "video.mp4").read_bytes() == b"x"


def test_a_folder_that_cannot_be_written_is_named_in_the_error(tmp_path: Path) -> None:
    with pytest.raises(OSError) as info:
        write_atomic(tmp_path / "missing" / "a.json", lambda handle: handle.write("x"))
    assert info.value.filename == str(tmp_path / "missing" / "a.json")


def test_a_folder_is_swapped_in_whole(tmp_path: Path) -> None:
    out = tmp_path / "model"
    out.mkdir()
    (out / "old.txt").write_text("old")
    with atomic_folder(out) as staging:
        assert not out.joinpath("new.txt").exists()
        (staging / "new.txt").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == ["new.txt"]
    assert stat.S_IMODE(out.stat().st_mode) == 0o777 & ~umask()
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("where", ["body", "before_swap"])
def test_a_failed_folder_write_keeps_the_old_folder(tmp_path: Path, where: str) -> None:
    out = tmp_path / "model"
    out.mkdir()
    (out / "old.txt").write_text("old")

    def refuse() -> None:
        raise RuntimeError("not ours any more")

    with pytest.raises(RuntimeError):
        with atomic_folder(out, before_swap=refuse if where == "before_swap" else None) as staging:
            (staging / "new.txt").write_text("new")
            if where == "body":
                raise RuntimeError("writer failed")
    assert sorted(p.name for p in out.iterdir()) == ["old.txt"]
    assert leftovers(tmp_path) == []


def test_a_failed_rename_puts_the_old_folder_back(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "model"
    out.mkdir()
    (out / "old.txt").write_text("old")
    real_replace = os.replace

    def replace(src, dst) -> None:
        if ".tmp-" in Path(src).name:  # the new folder's rename into place
            raise OSError(28, "No space left on device")
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(OSError):
        with atomic_folder(out) as staging:
            (staging / "new.txt").write_text("new")
    monkeypatch.undo()
    assert sorted(p.name for p in out.iterdir()) == ["old.txt"]
    assert leftovers(tmp_path) == []


def test_a_file_that_appears_between_the_check_and_the_swap_is_kept(tmp_path: Path, capsys) -> None:
    out = tmp_path / "ck"
    out.mkdir()
    (out / "ours.txt").write_text("old")

    def late_check() -> None:  # the caller's check passes, then somebody writes into the folder
        (out / "theirs.txt").write_text("keep me")

    with atomic_folder(out, before_swap=late_check,
                       keep_replaced=lambda old: (old / "theirs.txt").exists()) as tmp:
        (tmp / "ours.txt").write_text("new")
    assert (out / "ours.txt").read_text() == "new" and not (out / "theirs.txt").exists()
    kept = [p for p in tmp_path.glob(".ck.old-*/ck/theirs.txt")]
    assert len(kept) == 1 and kept[0].read_text() == "keep me"
    assert "kept the replaced" in capsys.readouterr().err


# ---- what a killed writer leaves: removed by the next write of the same output, a live writer's left alone ------

KILLED_WRITER = """
import sys, time
from pathlib import Path
from pihutil.atomic import AtomicFile, atomic_folder
out = Path(sys.argv[1])
if sys.argv[2] == "folder":
    with atomic_folder(out) as staging:
        (staging / "half.txt").write_text("half")
        print("writing", flush=True)
        time.sleep(60)
else:
    with AtomicFile(out) as tmp:
        tmp.temporary.write_text("half")
        print("writing", flush=True)
        time.sleep(60)
"""


def _killed_while_writing(out: Path, kind: str) -> None:
    import signal
    import subprocess
    import sys

    from tests.helpers import REPO

    proc = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(out), kind], cwd=REPO, stdout=subprocess.PIPE)
    assert proc.stdout.readline() == b"writing\n"
    proc.send_signal(signal.SIGKILL)
    proc.wait()


@pytest.mark.parametrize("kind", ["folder", "file"])
def test_what_a_killed_writer_left_is_removed_by_the_next_write(tmp_path: Path, capsys, kind: str) -> None:
    out = tmp_path / ("model" if kind == "folder" else "a.json")
    _killed_while_writing(out, kind)
    assert leftovers(tmp_path) != []
    if kind == "folder":
        with atomic_folder(out) as staging:
            (staging / "x.txt").write_text("x")
    else:
        write_atomic(out, lambda handle: handle.write("x"))
    assert leftovers(tmp_path) == [] and sorted(p.name for p in tmp_path.iterdir()) == [out.name]
    assert "left by a run that was killed" in capsys.readouterr().err


def test_a_live_writers_staging_folder_is_left_alone(tmp_path: Path) -> None:
    out = tmp_path / "model"
    with atomic_folder(out) as first:
        (first / "a.txt").write_text("a")
        with pytest.raises(RuntimeError):
            with atomic_folder(out):  # another writer of the same output, while the first one lives
                raise RuntimeError("stop")
        assert (first / "a.txt").read_text() == "a"
    assert (out / "a.txt").read_text() == "a" and leftovers(tmp_path) == []
    assert not any(".lock-" in p.name for p in tmp_path.iterdir())
