"""`pih sensitivity` interrupted by SIGINT at three different moments (as the first, the second and the last variant
start), each time exit 130 with the command that continues, then finished with --resume: the table and the JSON are
those of an uninterrupted run."""

from __future__ import annotations

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
def setup(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    tmp = tmp_path_factory.mktemp("sensitivity")
    model = save_skill(tmp / "model", tiny_skill())
    (tmp / "short.toml").write_text("version = 1\ntime_limit_s = 0.5\n")
    return tmp, ["sensitivity", "--model", str(model), "--episodes", "2", "--seed", "3", "--workers", "1",
                 "--only", "friction", "payload", "--task", str(tmp / "short.toml")]


def interrupted(argv: list[str], moment: str) -> tuple[int, str]:
    """Run `pih` with ``argv``, SIGINT it once its stderr says ``moment``; (exit status, stderr)."""
    proc = subprocess.Popen([sys.executable, "-m", "scripts.cli", *argv], cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(REPO)})
    lines = []
    try:
        deadline = time.monotonic() + HANG_GUARD_S
        while time.monotonic() < deadline:
            line = proc.stderr.readline()
            if not line:
                break
            lines.append(line)
            if line.strip() == moment:  # the variant's journal and episodes come next
                proc.send_signal(signal.SIGINT)
                break
        lines += proc.stderr.readlines()
        return proc.wait(HANG_GUARD_S), "".join(lines)
    finally:
        if proc.poll() is None:
            proc.kill()


@pytest.mark.slow
def test_three_interruptions_then_resume_give_the_uninterrupted_table(setup) -> None:
    tmp, argv = setup
    assert main([*argv, "--out", str(tmp / "whole")]) == 0
    out = ["--out", str(tmp / "cut")]
    for moment, resume in (("evaluating: ideal", []), ("evaluating: friction", ["--resume"]),
                           ("evaluating: all", ["--resume"])):
        status, err = interrupted([*argv, *out, *resume], moment)
        assert status == 130, err
        assert "continue with: pih sensitivity" in err and err.rstrip().endswith("--resume"), err
        assert "Traceback" not in err and not (tmp / "cut" / "sensitivity.md").exists(), err
    assert main([*argv, *out, "--resume"]) == 0
    for name in ("sensitivity.md", "sensitivity.json"):
        assert (tmp / "cut" / name).read_text() == (tmp / "whole" / name).read_text(), name


def test_a_plain_rerun_over_an_unfinished_run_is_refused(setup, capsys) -> None:
    tmp, argv = setup
    journals = tmp / "plain" / "journals"
    journals.mkdir(parents=True)
    (journals / "ideal.jsonl").write_text('{"kind": "header", "run": {}}\n')
    assert main([*argv, "--out", str(tmp / "plain")]) == 2
    err = capsys.readouterr().err
    assert "--resume" in err and err.count("\n") == 1
