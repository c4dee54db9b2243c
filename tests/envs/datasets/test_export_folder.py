"""envs.datasets.export_folder: the export folder is staged and renamed; only an export of ours is replaced."""

from __future__ import annotations

from pathlib import Path

import pytest

from envs.datasets.export_folder import staged_folder
from envs.datasets.features import MARKER_FILE
from envs.errors import EnvError


def export(out: Path, overwrite: bool = False, content: str = "new") -> None:
    with staged_folder(out, overwrite) as root:
        (root / "data.txt").write_text(content)
        (root / MARKER_FILE).write_text("{}")


def test_export_appears_under_its_name_and_nothing_else(tmp_path: Path) -> None:
    export(tmp_path / "ds")
    assert [p.name for p in tmp_path.iterdir()] == ["ds"] and (tmp_path / "ds" / "data.txt").read_text() == "new"


def test_a_failure_leaves_no_folder(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError):
        with staged_folder(tmp_path / "ds", False) as root:
            (root / "half").write_text("x")
            raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []


def test_a_failure_keeps_the_earlier_export(tmp_path: Path) -> None:
    export(tmp_path / "ds", content="old")
    with pytest.raises(RuntimeError):
        with staged_folder(tmp_path / "ds", True):
            raise RuntimeError("interrupted")
    assert (tmp_path / "ds" / "data.txt").read_text() == "old" and len(list(tmp_path.iterdir())) == 1


def test_an_export_is_replaced_only_with_overwrite(tmp_path: Path) -> None:
    export(tmp_path / "ds", content="old")
    with pytest.raises(EnvError, match="--overwrite"):
        export(tmp_path / "ds")
    export(tmp_path / "ds", overwrite=True)
    assert (tmp_path / "ds" / "data.txt").read_text() == "new" and len(list(tmp_path.iterdir())) == 1


def test_a_folder_that_is_not_an_export_is_never_replaced(tmp_path: Path) -> None:
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    with pytest.raises(EnvError, match="not a `pih export` output"):
        export(tmp_path / "mine", overwrite=True)
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep"


def test_an_export_without_its_marker_is_not_renamed_into_place(tmp_path: Path) -> None:
    with pytest.raises(EnvError, match="no pih_export.json"):
        with staged_folder(tmp_path / "ds", False) as root:
            (root / "data.txt").write_text("x")
    assert list(tmp_path.iterdir()) == []
