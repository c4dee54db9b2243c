"""batch.lifetime: a batch's worker processes (spawned or forked) die with the process that runs the batch, whatever
ends it (SIGKILL included); the reaper of a local Ray instance ends, once its driver is gone, the processes descended
from the driver that outlived it (as Ray's agents do when the raylet dies with its driver)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from tests.helpers import REPO
from tests.helpers.procfs import process_group

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

GONE_WITHIN_S = 10.0

DRIVER = """
import sys
from batch import BatchConfig, run_batch
from tests.helpers.batch_units import failure, init, units, work
todo = units(4, {i: {"do": "meet", "folder": sys.argv[2], "count": 99, "seconds": 120.0} for i in range(4)})
run_batch(todo, {"offset": 0}, init, work, failure, BatchConfig(workers=2, start_method=sys.argv[1]))
"""

ORPHANING_DRIVER = """
import os, subprocess, sys, time
from batch.lifetime import Reaper
with Reaper():
    # a child that starts a grandchild and ends: the grandchild is orphaned, as Ray's agents are by a dead raylet
    subprocess.run([sys.executable, "-c", "import subprocess, sys, time; "
                    "subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(120)']); time.sleep(1)"])
    print("started", flush=True)
    time.sleep(120)
"""



def killed_and_gone(proc: subprocess.Popen, ready: callable) -> list[int]:
    """SIGKILL ``proc`` once ``ready()``, then what is left of its process group after GONE_WITHIN_S (at most)."""
    try:
        deadline = time.monotonic() + 120.0  # hang guard
        while not ready() and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + GONE_WITHIN_S
        while process_group(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        return process_group(proc.pid)
    finally:
        for pid in process_group(proc.pid):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.parametrize("start", ["spawn", "fork"])
def test_workers_die_with_a_sigkilled_supervisor(start, tmp_path):
    """Killed while both workers run a unit (each unit leaves a file in ``tmp_path`` as it starts, then waits)."""
    proc = subprocess.Popen([sys.executable, "-c", DRIVER, start, str(tmp_path)], cwd=REPO, stderr=subprocess.PIPE,
                            start_new_session=True)
    assert killed_and_gone(proc, lambda: len(list(tmp_path.iterdir())) >= 2) == []


def test_the_reaper_ends_what_outlived_its_sigkilled_driver():
    proc = subprocess.Popen([sys.executable, "-c", ORPHANING_DRIVER], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, start_new_session=True)
    assert proc.stdout.readline() == b"started\n"
    assert len(process_group(proc.pid)) == 3  # the driver, its reaper and the orphan
    assert killed_and_gone(proc, lambda: True) == []


def test_the_reaper_leaves_alone_what_was_not_started_under_it():
    """A process descended from the driver but started before the reaper stays when the driver returns."""
    from batch.lifetime import Reaper

    before = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        with Reaper():
            time.sleep(0.5)
        assert before.poll() is None
    finally:
        before.kill()
        before.wait()
