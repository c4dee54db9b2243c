"""`pih export` of an evaluation: SIGTERM stops it as Ctrl-C does (exit 130, no staging folder left), what a killed
export left is removed by the next export to the same folder, and a hand-edited evaluation JSON is checked field by
field against its own counts and its replay before anything is written."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rflow.skill_io import save_skill
from scripts.cli import main
from tests.helpers import REPO
from tests.helpers.skill_fixtures import tiny_skill

HANG_GUARD_S = 240.0


@pytest.fixture(scope="module")
def evaluation(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real evaluation JSON of a tiny skill: 3 episodes of 0.5 s."""
    tmp = tmp_path_factory.mktemp("export")
    model = save_skill(tmp / "model", tiny_skill())
    out = tmp / "eval.json"
    assert main(["evaluate", "--model", str(model), "--episodes", "3", "--time-limit-s", "0.5", "--quiet",
                 "--json", str(out)]) == 0
    return out


def leftovers(folder: Path) -> list[str]:
    """What an export to ``folder / "ds"`` leaves beside it: staging folders and their lock files."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(".ds."))


def staging(folder: Path) -> bool:
    """Whether an export's staging folder exists in ``folder`` (its lock file is made first, alone it is no sign
    that the export is writing)."""
    return any(p.name.startswith(".ds.tmp-") and p.is_dir() for p in folder.iterdir())


def stopped_while_staging(evaluation: Path, out: Path, sig: int) -> tuple[int, str]:
    """Start `pih export --episodes ... --video` into ``out``, send ``sig`` once its staging folder exists."""
    proc = subprocess.Popen([sys.executable, "-m", "scripts.cli", "export", "--episodes", str(evaluation), "--format",
                             "robomimic", "--video", "--out", str(out)], cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        deadline = time.monotonic() + HANG_GUARD_S
        while not staging(out.parent) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert proc.poll() is None, f"ended before its staging folder was seen: {proc.stderr.read()}"
        proc.send_signal(sig)
        return proc.wait(HANG_GUARD_S), proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()


def test_sigterm_stops_an_export_as_ctrl_c_does(evaluation: Path, tmp_path: Path) -> None:
    status, err = stopped_while_staging(evaluation, tmp_path / "ds", signal.SIGTERM)
    assert status == 130 and err.strip() == "pih export: interrupted", err
    assert leftovers(tmp_path) == [] and not (tmp_path / "ds").exists()


def test_what_a_killed_export_left_is_removed_by_the_next_one(evaluation: Path, tmp_path: Path, capsys) -> None:
    status, _ = stopped_while_staging(evaluation, tmp_path / "ds", signal.SIGKILL)
    assert status == -signal.SIGKILL and leftovers(tmp_path) != []
    assert main(["export", "--episodes", str(evaluation), "--format", "lerobot", "--out", str(tmp_path / "ds")]) == 0
    assert leftovers(tmp_path) == [] and (tmp_path / "ds").is_dir()
    assert "left by a run that was killed" in capsys.readouterr().err


def _edited(evaluation: Path, folder: Path, edit) -> Path:
    data = json.loads(evaluation.read_text())
    edit(data)
    path = folder / "edited.json"
    path.write_text(json.dumps(data))
    return path


def _set(*keys, value):
    def edit(data):
        target = data
        for key in keys[:-1]:
            target = target[key]
        target[keys[-1]] = value
    return edit


EDITS = {
    "index 2**40": (_set("per_episode", 0, "index", value=2**40), "record 0 has index 1099511627776, not an episode"),
    "index twice": (_set("per_episode", 1, "index", value=0), "episode 0 is recorded twice"),
    "hole offset 50 mm": (_set("per_episode", 1, "perturbation", "hole_offset_mm", value=50.0),
                          "episode 1's perturbation hole_offset_mm = 50.0 differs from the one its seed draws"),
    "seed -5": (_set("config", "seed", value=-5), "seed=-5 must be an integer in 0..4,294,967,295"),
    "episodes text": (_set("config", "episodes", value="3"), "episodes='3' must be an integer"),
    "episodes 10**400": (_set("config", "episodes", value=10**400), "episodes=10000000000"),
    "start moved": (_set("per_episode", 2, "start_pos", 0, value=0.7), "episode 2's start pose differs"),
    "count": (_set("episodes", value=99), "it holds 3 episode records but says 99"),
}


@pytest.mark.parametrize("name", list(EDITS))
def test_a_hand_edited_evaluation_is_refused_by_export_and_compare(evaluation, tmp_path, capsys, name) -> None:
    edit, message = EDITS[name]
    path = _edited(evaluation, tmp_path, edit)
    for argv in (["export", "--episodes", str(path), "--format", "lerobot", "--out", str(tmp_path / "ds")],
                 ["compare", str(evaluation), str(path)]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["edited.json"]  # no dataset, no staging folder


def test_the_evaluation_as_written_is_taken(evaluation, tmp_path, capsys) -> None:
    assert main(["compare", str(evaluation), str(evaluation)]) == 0
