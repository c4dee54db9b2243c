"""batch on Ray: a real two-node local cluster (head + one worker node on 127.0.0.1) runs a small batch with
the same records as the process backend, and a killed actor is recorded "worker_died"."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from batch import BatchConfig, run_batch
from batch_units import failure, init, units, work

ray = pytest.importorskip("ray", reason="the ray backend needs the [cluster] extra")

pytestmark = pytest.mark.slow
RAY = str(Path(sys.executable).with_name("ray"))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(args: list[str], env: dict[str, str]) -> subprocess.Popen:
    """`ray start ... --block` in a session of its own, so the test can stop exactly these processes."""
    return subprocess.Popen([RAY, "start", "--block", "--disable-usage-stats", *args], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


def _stop(proc: subprocess.Popen) -> None:
    for sig, wait_s in ((signal.SIGTERM, 20.0), (signal.SIGKILL, 10.0)):
        if proc.poll() is not None:
            break
        try:
            os.killpg(proc.pid, sig)
            proc.wait(wait_s)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            pass


@pytest.fixture(scope="module")
def cluster():
    """HOST:PORT of a head node and one worker node, both stopped after the tests even on failure."""
    port = _free_port()
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # short: Ray's socket paths must stay < 108 bytes
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent), os.environ.get("PYTHONPATH", "")]),
           "RAY_USAGE_STATS_ENABLED": "0", "HOME": temp}  # no ~/.ray/auth_token of another cluster is read
    patch = pytest.MonkeyPatch()
    patch.setenv("HOME", temp)  # the same for the driver in this process
    address = f"127.0.0.1:{port}"
    nodes = [_start(["--head", f"--port={port}", "--node-ip-address=127.0.0.1", "--num-cpus=1",
                     "--include-dashboard=false", f"--temp-dir={temp}"], env)]
    try:
        _wait_for_nodes(address, 0, nodes)  # the head is up before the worker node joins it
        nodes.append(_start([f"--address={address}", "--node-ip-address=127.0.0.1", "--num-cpus=1"], env))
        _wait_for_nodes(address, 2, nodes)
        yield address
    finally:
        for proc in reversed(nodes):
            _stop(proc)
        patch.undo()
        shutil.rmtree(temp, ignore_errors=True)


def _wait_for_nodes(address: str, count: int, nodes: list[subprocess.Popen], limit_s: float = 300.0) -> None:
    """Wait until a driver can join the cluster at ``address`` and sees ``count`` alive nodes (0: just joins).
    The limit is generous: a busy 2-core machine is slow to bring a head up."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        if any(p.poll() is not None for p in nodes):
            pytest.fail(f"a `ray start` exited with {[p.poll() for p in nodes]}")
        try:
            probe = subprocess.run([sys.executable, "-c", (
                "import ray; ray.init(address=%r, log_to_driver=False, configure_logging=False); "
                "print(sum(n['Alive'] for n in ray.nodes()))") % address], capture_output=True, text=True,
                timeout=max(1.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            break
        if probe.returncode == 0 and int(probe.stdout.split()[-1]) >= count:
            return
        time.sleep(1.0)
    pytest.fail(f"the Ray cluster at {address} did not come up with {count} nodes")


def test_a_two_node_cluster_gives_the_records_of_the_process_backend(cluster):
    todo = units(6)
    local = run_batch(todo, {"offset": 3}, init, work, failure, BatchConfig(workers=2))
    on_ray = run_batch(todo, {"offset": 3}, init, work, failure,
                       BatchConfig(workers=2, backend="ray", ray_address=cluster))
    assert on_ray.complete and on_ray.records == local.records


def test_a_killed_actor_is_recorded_and_the_batch_goes_on(cluster):
    todo = units(5, {1: {"do": "kill"}})
    outcome = run_batch(todo, {"offset": 0}, init, work, failure,
                        BatchConfig(workers=2, backend="ray", ray_address=cluster))
    assert outcome.complete
    assert [r["reason"] for r in outcome.records.values()] == ["ok", "worker_died", "ok", "ok", "ok"]


def test_a_unit_over_the_wall_time_limit_has_its_actor_killed(cluster):
    todo = units(3, {0: {"do": "sleep", "seconds": 600.0}})
    outcome = run_batch(todo, {"offset": 0}, init, work, failure,
                        BatchConfig(workers=2, unit_timeout_s=5.0, backend="ray", ray_address=cluster))
    assert [r["reason"] for r in outcome.records.values()] == ["wall_timeout", "ok", "ok"]


def test_a_failing_init_on_the_cluster_is_a_batch_error(cluster):
    from batch import BatchError

    with pytest.raises(BatchError, match="init was told to fail"):
        run_batch(units(2), {"fail_init": True}, init, work, failure,
                  BatchConfig(workers=2, backend="ray", ray_address=cluster))
