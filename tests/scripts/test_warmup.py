"""`pih warmup` runs the code paths of a run on a throw-away skill and writes nothing but numba's cache."""

from __future__ import annotations

from pathlib import Path

import pytest

from scripts.cli import main


def test_warmup_runs_the_kernels_and_leaves_the_working_folder_alone(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["warmup"]) == 0
    assert "numba kernels compiled and cached" in capsys.readouterr().out
    assert list(tmp_path.iterdir()) == []
