"""batch on Ray: a real two-node local cluster (head + one worker node on 127.0.0.1) runs a small batch with
the same records as the process backend; a killed actor process or a lost worker node changes no record (the
unit runs again) and is listed; Ray's messages stay off stdout; a lost head ends the batch with a one-line
fault instead of Ray's silent exit a minute later. The tests that kill a node come last in this file."""

from __future__ import annotations

import json
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
from tests.helpers import REPO
from tests.helpers.batch_units import failure, init, units, work

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
    """End every process of the node's session, also when its `ray start` already ended (its raylet killed)."""
    for sig, wait_s in ((signal.SIGTERM, 20.0), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break  # none left
        try:
            proc.wait(wait_s)
        except subprocess.TimeoutExpired:
            pass


class Cluster:
    """A local cluster: the head's address, the `ray start` processes of the head and the worker node, and the
    environment its drivers run in."""

    def __init__(self, address: str, nodes: list[subprocess.Popen], env: dict[str, str]):
        self.address, self.nodes, self.env = address, nodes, env

    def pids(self, node: int, *names: str) -> list[int]:
        """The pids of the processes called ``names`` (e.g. "raylet", "gcs_server") that node ``node``'s
        `ray start` started."""
        found = []
        for entry in Path("/proc").iterdir():
            try:
                comm, rest = (entry / "stat").read_text().split(") ", 1)
            except (OSError, ValueError):
                continue
            if int(rest.split()[1]) == self.nodes[node].pid and comm.split("(", 1)[1] in names:
                found.append(int(entry.name))
        assert len(found) == len(names), f"expected {names} under node {node}, found pids {found}"
        return found


@pytest.fixture(scope="module")
def cluster():
    """A head node and one worker node (Cluster), both stopped after the tests even on failure."""
    port = _free_port()
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # short: Ray's socket paths must stay < 108 bytes
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
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
        yield Cluster(address, nodes, env)
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


def on_ray(cluster: Cluster, **config) -> BatchConfig:
    return BatchConfig(backend="ray", ray_address=cluster.address, **{"workers": 2, **config})


def test_a_two_node_cluster_gives_the_records_of_the_process_backend(cluster, tmp_path):
    """The first two units run at the same time, so both actors take part."""
    meet = {"do": "meet", "folder": str(tmp_path), "count": 2}
    outcome = run_batch(units(6, {0: meet, 1: meet}), {"offset": 3}, init, work, failure, on_ray(cluster, workers=1))
    local = run_batch(units(6), {"offset": 3}, init, work, failure, BatchConfig(workers=2))
    assert outcome.complete and outcome.records == local.records
    assert outcome.workers == 2  # workers=1: one actor per CPU of the cluster


def test_a_killed_actor_process_changes_no_record_and_is_listed(cluster, tmp_path):
    todo = units(5, {1: {"do": "kill_first", "counter": str(tmp_path / "c")}})
    outcome = run_batch(todo, {"offset": 0}, init, work, failure, on_ray(cluster))
    assert outcome.complete and outcome.records == run_batch(units(5), {"offset": 0}, init, work, failure).records
    (event,) = outcome.events
    assert (event["event"], event["unit"], event["unit_action"]) == ("worker_lost", "u001", "retried")
    assert {"actor", "node", "pid"} <= set(event["where"])


def test_a_unit_over_the_wall_time_limit_has_its_actor_killed(cluster):
    todo = units(3, {0: {"do": "sleep", "seconds": 600.0}})
    outcome = run_batch(todo, {"offset": 0}, init, work, failure, on_ray(cluster, unit_timeout_s=5.0))
    assert [r["reason"] for r in outcome.records.values()] == ["wall_timeout", "ok", "ok"]


def test_the_named_environment_of_the_driver_reaches_every_actor(cluster, monkeypatch):
    """The nodes were started before the driver set the variable: only BatchConfig.worker_environment brings it
    to the actors (as it brings the CPU dispatch that rflow pins, which is read once when a process starts)."""
    monkeypatch.setenv("PIH_TEST_FORWARDED", "42")
    todo = units(2, {i: {"do": "environ", "name": "PIH_TEST_FORWARDED"} for i in range(2)})
    plain = run_batch(todo, {"offset": 0}, init, work, failure, on_ray(cluster))
    sent = run_batch(todo, {"offset": 0}, init, work, failure,
                     on_ray(cluster, worker_environment=("PIH_TEST_FORWARDED", "PIH_TEST_UNSET")))
    assert [r["value"] for r in plain.records.values()] == [None, None]
    assert [r["value"] for r in sent.records.values()] == ["42", "42"]


def test_a_failing_init_on_the_cluster_is_a_batch_error(cluster):
    from batch import BatchError

    with pytest.raises(BatchError, match="init was told to fail"):
        run_batch(units(2), {"fail_init": True}, init, work, failure, on_ray(cluster))


DRIVER = """
import json, os, signal, sys
from batch import BatchConfig, run_batch
from tests.helpers.batch_units import failure, init, units, work
victims = [int(pid) for pid in sys.argv[2].split(",")]
def kill_after_the_first_record(key, record):
    while victims:
        os.kill(victims.pop(), signal.SIGKILL)
todo = units(6, {i: {"do": "sleep", "seconds": 1.5} for i in range(6)})
if sys.argv[3]:  # the first two units run at the same time, so both actors take part
    todo[:2] = units(2, {i: {"do": "meet", "folder": sys.argv[3], "count": 2} for i in range(2)})
out = run_batch(todo, {"offset": 0}, init, work, failure,
                BatchConfig(workers=2, backend="ray", ray_address=sys.argv[1]), on_record=kill_after_the_first_record)
print(json.dumps({"records": out.records, "events": out.events, "fault": out.fault}))
"""


def drive(cluster: Cluster, victims: list[int], meet: Path | None = None) -> dict:
    """Run six 1.5 s units on two actors (with ``meet``, a folder, the first two instead run at the same time:
    both actors take part) in a driver process that SIGKILLs ``victims`` after the first record; its stdout
    must be its JSON line alone. The limit is twice Ray's own 60 s wait for a lost head."""
    proc = subprocess.run([sys.executable, "-c", DRIVER, cluster.address, ",".join(map(str, victims)), str(meet or "")],
                          env=cluster.env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout)


def test_a_lost_worker_node_changes_no_record_and_ray_keeps_off_stdout(cluster, tmp_path):
    data = drive(cluster, cluster.pids(1, "raylet"), tmp_path)
    assert data["fault"] is None
    assert data["records"] == run_batch(units(6), {"offset": 0}, init, work, failure).records
    assert [e["unit_action"] for e in data["events"] if e["event"] == "worker_lost"] == ["retried"]


def test_a_lost_head_ends_the_batch_with_a_one_line_fault(cluster):
    data = drive(cluster, cluster.pids(0, "gcs_server", "raylet"))
    assert data["fault"].startswith("lost the Ray head at ") and "\n" not in data["fault"]
    assert len(data["records"]) < 6 and data["events"][-1]["event"] == "batch_stopped"
