"""No process a `pih` command starts outlives it (batch.lifetime): `pih evaluate --workers 2`, `pih train` and
`pih benchmark`, each SIGKILLed (what the OOM killer, a CI time-out or a scheduler sends) once its worker processes
run, leave an empty process group within 10 s. The three run at the same time, each in a session of its own."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rflow.skill_io import save_skill
from tests.helpers import REPO
from tests.helpers.procfs import process_group, worker_processes
from tests.helpers.skill_fixtures import TINY_ARGS, tiny_skill, write_demo_file

GONE_WITHIN_S = 10.0
START_LIMIT_S = 240.0
"""Hang guard: how long a command may take to start its workers on a busy machine."""


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigkill_of_evaluate_train_and_benchmark_leaves_no_process(tmp_path: Path) -> None:
    model = save_skill(tmp_path / "model", tiny_skill())
    demos = write_demo_file(tmp_path)
    long_training = [a if a != "2" or i == 0 or TINY_ARGS[i - 1] != "--epochs" else "100000"
                     for i, a in enumerate(TINY_ARGS)]
    commands = {
        "evaluate": ["evaluate", "--model", str(model), "--episodes", "400", "--workers", "2", "--lockstep", "1",
                     "--quiet"],
        "train": ["train", "--demos", str(demos), "--out", str(tmp_path / "ck"), "--workers", "2", *long_training],
        "benchmark": ["benchmark", "--demo-seeds", "0", "--demos", "2", "--episodes", "20", "--epochs", "100000",
                      "--workers", "2", "--quiet", "--out", str(tmp_path / "bench")],
    }
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    runs = {name: subprocess.Popen([sys.executable, "-m", "scripts.cli", *argv], cwd=REPO, env=env,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
            for name, argv in commands.items()}
    try:
        left = dict(runs)
        deadline = time.monotonic() + START_LIMIT_S
        while left and time.monotonic() < deadline:  # kill each once two workers run
            for name, proc in list(left.items()):
                assert proc.poll() is None, f"pih {name} ended early: {proc.stderr.read().decode()[-2000:]}"
                if len(worker_processes(proc.pid)) >= 2:
                    os.kill(proc.pid, signal.SIGKILL)
                    proc.wait()
                    del left[name]
            time.sleep(0.1)
        assert not left, f"never started two workers: {sorted(left)}"
        deadline = time.monotonic() + GONE_WITHIN_S
        while any(process_group(p.pid) for p in runs.values()) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert {name: process_group(p.pid) for name, p in runs.items()} == {name: [] for name in runs}
    finally:
        for proc in runs.values():
            for pid in process_group(proc.pid):
                os.kill(pid, signal.SIGKILL)
            if proc.poll() is None:
                proc.kill()
                proc.wait()
