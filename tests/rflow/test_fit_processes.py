"""Training a skill's models in parallel processes (rflow.fit_processes): same weights, clear failures."""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from rflow.errors import RFlowError
from rflow.fit_processes import _start, fit_in_processes
from rflow.skill_io import fit_pose_skill
from tests.helpers.procfs import worker_processes
from tests.helpers.skill_fixtures import TINY, synthetic_demos, write_demo_file


def _weights(skill) -> dict[str, torch.Tensor]:
    return {f"{name}.{key}": value for name, model in skill.models.items()
            for key, value in model.network.state_dict().items()}


def test_parallel_training_gives_the_sequential_weights_bit_for_bit() -> None:
    demos = synthetic_demos()
    one_by_one = fit_pose_skill(demos.pos, demos.quat, demos.dt, TINY, "separate", progress=False, workers=1)
    parallel = fit_pose_skill(demos.pos, demos.quat, demos.dt, TINY, "separate", progress=False, workers=2)
    a, b = _weights(one_by_one), _weights(parallel)
    assert a.keys() == b.keys() and len(a) > 0
    for key in a:
        assert torch.equal(a[key], b[key]), key
    for name in ("position", "orientation"):
        assert (one_by_one.training[name]["history"]["train_loss"]
                == parallel.training[name]["history"]["train_loss"])
        np.testing.assert_array_equal(one_by_one.models[name].goal, parallel.models[name].goal)


def test_workers_training_on_one_thread_are_forked_and_others_spawned() -> None:
    """A forked child that enters its parent's OpenMP pool hangs: only one-thread training forks."""
    assert TINY.threads == 1 and _start(TINY) == "fork"
    assert _start(dataclasses.replace(TINY, threads=2)) == _start(dataclasses.replace(TINY, threads=None)) == "spawn"


def test_a_model_that_fails_to_train_is_named_in_the_error() -> None:
    demos = synthetic_demos()
    pos = demos.pos.copy()
    pos[0, -1] += 0.05  # one demo ends 5 cm from the others: no shared goal
    with pytest.raises(RFlowError, match=r"^position model: .*goal"):
        fit_in_processes({"position": (pos, "euclidean"), "orientation": (demos.quat, "sphere")},
                         demos.dt, TINY, workers=2, progress=False)


def test_workers_must_be_a_positive_integer() -> None:
    demos = synthetic_demos()
    with pytest.raises(RFlowError, match="workers=0"):
        fit_in_processes({"position": (demos.pos, "euclidean")}, demos.dt, TINY, workers=0)


@pytest.mark.slow
def test_sigint_during_parallel_training_stops_the_workers_and_writes_nothing(tmp_path: Path) -> None:
    demos = write_demo_file(tmp_path)
    out = tmp_path / "model"
    pih = str(Path(sys.executable).with_name("pih"))
    proc = subprocess.Popen([pih, "train", "--demos", str(demos), "--out", str(out), "--workers", "2", "--epochs",
                             "100000", "--layers", "2", "--width", "16", "--quiet"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while len(worker_processes(proc.pid)) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        workers = worker_processes(proc.pid)
        assert len(workers) == 2, proc.poll()
        time.sleep(6.0)  # both are training
        os.kill(proc.pid, signal.SIGINT)  # to the parent only (`kill -INT`): it must stop its workers itself
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, stderr
    assert "interrupted" in stderr and "leaked" not in stderr and "Traceback" not in stderr
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["demos.npz"]
    assert not any(Path(f"/proc/{pid}").exists() for pid in workers)
