"""batch.runner: a killed worker (mid-unit or while starting) changes no record, its unit runs again and the
loss is listed; a unit lost on every try is an infrastructure error, outside the records and the journal; an
overrunning unit and an escaped exception each become one failed record and the batch goes on; records do
not depend on the number of workers; a journal resumes a run. The worker-process tests run with spawned and with
forked workers (``BatchConfig.start_method``)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from batch import BatchConfig, BatchError, Journal, run_batch
from batch.config import START_METHODS
from tests.helpers import REPO
from tests.helpers.batch_units import failure, init, units, work

SETUP = {"offset": 7}
EACH_START = pytest.mark.parametrize("start", START_METHODS)


def run(todo, config=BatchConfig(), **kwargs):
    return run_batch(todo, SETUP, init, work, failure, config, **kwargs)


@EACH_START
def test_records_follow_the_unit_order_and_the_context(start):
    outcome = run(units(5), BatchConfig(workers=2, start_method=start))
    assert list(outcome.records) == [f"u{i:03d}" for i in range(5)]
    assert [r["value"] for r in outcome.records.values()] == [i * i + 7 for i in range(5)]
    assert outcome.complete and not outcome.interrupted


def test_records_do_not_depend_on_the_number_of_workers():
    assert run(units(6)).records == run(units(6), BatchConfig(workers=3)).records


def kill_first(counter, times=1):
    return {"do": "kill_first", "counter": str(counter), "times": times}


@EACH_START
def test_a_worker_killed_mid_unit_changes_no_record_and_the_loss_is_listed(tmp_path, start):
    outcome = run(units(6, {2: kill_first(tmp_path / "c")}), BatchConfig(workers=2, start_method=start))
    assert outcome.complete and outcome.records == run(units(6)).records
    (event,) = outcome.events
    assert (event["event"], event["unit"], event["unit_action"], event["tries"]) == ("worker_lost", "u002", "retried", 1)
    assert event["where"]["exit_code"] == -9 and event["where"]["pid"] > 0


def test_two_workers_killed_at_once_change_no_record(tmp_path):
    outcome = run(units(5, {0: kill_first(tmp_path / "a"), 1: kill_first(tmp_path / "b")}), BatchConfig(workers=2))
    assert outcome.records == run(units(5)).records
    assert sorted(e["unit"] for e in outcome.events) == ["u000", "u001"]


@pytest.mark.parametrize("action, exit_code", [("kill", -9), ("exit", 3)])
def test_a_unit_lost_on_every_try_is_an_infrastructure_error(action, exit_code):
    outcome = run(units(4, {2: {"do": action}}), BatchConfig(workers=2, max_retries=1))
    assert not outcome.complete and "u002" not in outcome.records
    assert outcome.infrastructure_errors["u002"]["reason"] == "infrastructure: worker_died after 2 tries"
    assert [(e["unit_action"], e["where"]["exit_code"]) for e in outcome.events] == [("retried", exit_code),
                                                                                    ("given_up", exit_code)]
    assert [r["value"] for r in outcome.records.values()] == [7, 8, 16]


def test_resume_runs_an_infrastructure_error_again(tmp_path):
    path, todo = tmp_path / "j.jsonl", units(4, {1: kill_first(tmp_path / "c", times=2)})
    with Journal.open(path, {"run": 1}) as journal:
        first = run(todo, BatchConfig(workers=2, max_retries=1), journal=journal)
    assert list(first.infrastructure_errors) == ["u001"] and "u001" not in journal.done()
    with Journal.open(path, {"run": 1}, resume=True) as journal:
        second = run(todo, BatchConfig(workers=2, max_retries=1), journal=journal)
    assert second.complete and second.records == run(units(4)).records
    assert second.events == first.events  # the journal keeps the earlier segment's events


@EACH_START
def test_workers_killed_while_starting_are_replaced(tmp_path, start):
    """The first two inits are killed; the first two units must run at the same time, so no worker finishes the
    batch alone before both losses are seen (a forked replacement may start before the other first worker)."""
    setup = {**SETUP, "kill_starts": 2, "counter": str(tmp_path / "c")}
    meet = {"do": "meet", "folder": str(tmp_path / "m"), "count": 2}
    (tmp_path / "m").mkdir()
    outcome = run_batch(units(4, {0: meet, 1: meet}), setup, init, work, failure,
                        BatchConfig(workers=2, start_method=start))
    assert outcome.complete and outcome.records == run(units(4)).records
    assert [(e["event"], e["replaced"], e["where"]["exit_code"]) for e in outcome.events] == [
        ("worker_lost_at_start", True, -9)] * 2


def test_workers_that_hang_while_starting_are_killed_and_replaced(tmp_path):
    """Both first workers hang in init (as a forked child would on a lock held at the fork): each is killed at
    the start limit and replaced; the batch ends with the usual records instead of waiting forever. The first two
    units must run at the same time, so on a loaded machine the first replacement cannot finish the batch alone
    before the second hung worker's limit is seen."""
    setup = {**SETUP, "hang_starts": 2, "counter": str(tmp_path / "c")}
    meet = {"do": "meet", "folder": str(tmp_path / "m"), "count": 2}
    (tmp_path / "m").mkdir()
    outcome = run_batch(units(4, {0: meet, 1: meet}), setup, init, work, failure,
                        BatchConfig(workers=2, start_method="fork", start_timeout_s=2.0))
    assert outcome.complete and outcome.records == run(units(4)).records
    assert [(e["event"], e["replaced"], e["where"]["exit_code"], e["detail"]) for e in outcome.events] == [
        ("worker_lost_at_start", True, -9, "not ready 2 s after it was started")] * 2


def test_workers_that_never_start_stop_the_batch_with_a_fault(tmp_path):
    setup = {**SETUP, "kill_starts": 100, "counter": str(tmp_path / "c")}
    outcome = run_batch(units(3), setup, init, work, failure, BatchConfig(workers=2, max_retries=1))
    assert outcome.fault is not None and "starting" in outcome.fault
    assert outcome.records == {} and not outcome.complete and not outcome.interrupted
    assert [e["event"] for e in outcome.events] == ["worker_lost_at_start"] * 4 + ["batch_stopped"]


def test_the_outcome_counts_the_workers_that_ran(tmp_path):
    """Two units that must run at the same time, on workers=3."""
    meet = {"do": "meet", "folder": str(tmp_path), "count": 2}
    assert run(units(2, {0: meet, 1: meet}), BatchConfig(workers=3)).workers == 2


def test_a_worker_with_nothing_left_to_do_ends_while_the_others_run(tmp_path):
    """Once the queue is empty an idle worker is asked to return at once (its ~1 s interpreter shutdown overlaps
    the units still running) instead of waiting for the end of the batch."""
    files = {"pidfile": str(tmp_path / "pid"), "started": str(tmp_path / "started")}
    todo = [("u000", {"n": 0, "do": "note_pid", **files}), ("u001", {"n": 1, "do": "await_pid", **files})]
    outcome = run(todo, BatchConfig(workers=2))
    assert outcome.records["u000"]["value"] == 7
    assert outcome.records["u001"]["value"] is True  # u000's worker ended while u001 was running


@pytest.mark.slow
@EACH_START
def test_a_unit_over_the_wall_time_limit_is_killed_and_recorded(start):
    outcome = run(units(4, {1: {"do": "sleep", "seconds": 600.0}}),
                  BatchConfig(workers=2, unit_timeout_s=5.0, start_method=start))
    assert outcome.complete
    assert [r["reason"] for r in outcome.records.values()] == ["ok", "wall_timeout", "ok", "ok"]


def test_the_wall_time_limit_holds_in_this_process_too():
    outcome = run(units(3, {1: {"do": "sleep", "seconds": 600.0}}), BatchConfig(workers=1, unit_timeout_s=1.0))
    assert [r["reason"] for r in outcome.records.values()] == ["ok", "wall_timeout", "ok"]


@pytest.mark.parametrize("workers", [1, 2])
def test_an_escaped_exception_is_recorded_as_an_error(workers):
    outcome = run(units(3, {1: {"do": "raise"}}), BatchConfig(workers=workers))
    assert outcome.records["u001"]["reason"] == "error: ZeroDivisionError: unit asked to raise"
    assert outcome.records["u002"]["value"] == 11


def test_a_failing_init_in_a_worker_is_a_batch_error():
    with pytest.raises(BatchError, match="init was told to fail"):
        run_batch(units(3), {"fail_init": True}, init, work, failure, BatchConfig(workers=2))


def test_duplicate_keys_are_refused():
    with pytest.raises(BatchError, match="unique"):
        run([("a", {"n": 1}), ("a", {"n": 2})])


@pytest.mark.parametrize("workers", [1, 2])
def test_interrupted_run_resumes_to_the_same_records(tmp_path, workers):
    path = tmp_path / "j.jsonl"
    seen: list[str] = []

    def stop_after_three(key, record):
        seen.append(key)
        if len(seen) == 3:
            raise KeyboardInterrupt

    with Journal.open(path, {"run": 1}) as journal:
        first = run(units(8), BatchConfig(workers=workers), journal=journal, on_record=stop_after_three)
    assert first.interrupted and not first.complete and len(first.records) == 3
    rerun: list[str] = []
    with Journal.open(path, {"run": 1}, resume=True) as journal:
        second = run(units(8), BatchConfig(workers=workers), journal=journal, on_record=lambda k, r: rerun.append(k))
    assert second.complete and not second.interrupted
    assert sorted(rerun) == sorted(set(second.records) - set(first.records))  # finished units are not rerun
    assert second.records == run(units(8)).records


def test_every_record_is_in_the_journal_as_it_finishes(tmp_path):
    path = tmp_path / "j.jsonl"
    counts: list[int] = []
    with Journal.open(path, {"run": 1}) as journal:
        run(units(4), BatchConfig(workers=2), journal=journal,
            on_record=lambda k, r: counts.append(len(path.read_text().splitlines()) - 1))
    assert counts == [1, 2, 3, 4]


@EACH_START
def test_ctrl_c_stops_workers_keeps_the_journal_and_prints_no_traceback(tmp_path, start):
    """A real SIGINT to the whole process group, as a terminal's Ctrl-C sends it."""
    journal = tmp_path / "j.jsonl"
    script = textwrap.dedent(f"""
        from batch import BatchConfig, Journal, run_batch
        from tests.helpers.batch_units import failure, init, units, work
        todo = units(6, {{i: {{"do": "sleep", "seconds": 600.0}} for i in range(2, 6)}})
        with Journal.open({str(journal)!r}, {{"run": 1}}) as j:
            out = run_batch(todo, {{"offset": 0}}, init, work, failure, BatchConfig(workers=2, start_method={start!r}),
                            journal=j,
                            on_record=lambda k, r: print("finished", k, flush=True))
        print("interrupted" if out.interrupted else "not interrupted", len(out.records), flush=True)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, cwd=REPO)
    try:
        lines = [proc.stdout.readline() for _ in range(2)]
        assert sorted(lines) == ["finished u000\n", "finished u001\n"]
        time.sleep(1.0)  # both workers are now in their 600 s units
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert out.strip() == "interrupted 2"
    assert "Traceback" not in err
    assert len(journal.read_text().splitlines()) == 3  # header + the two finished units


def test_config_is_validated():
    for bad in ({"workers": 0}, {"unit_timeout_s": -1.0}, {"backend": "dask"},
                {"backend": "ray", "ray_address": "nohost"}, {"ray_address": "127.0.0.1:6379"}, {"max_retries": -1},
                {"start_method": "forkserver"}, {"start_timeout_s": 0.0}, {"start_timeout_s": float("inf")},
                {"worker_environment": "MKL_CBWR"}, {"worker_environment": ("A=1",)}, {"worker_environment": ("",)}):
        with pytest.raises(BatchError):
            BatchConfig(**bad)


def test_an_evaluation_sends_the_cpu_dispatch_to_a_clusters_workers():
    """The settings rflow pins are read when a process starts: a cluster's actors get the driver's
    (`batch.BatchConfig.worker_environment`), or their records would depend on how their node was started."""
    from envs.evaluation.config import EvaluationConfig
    from numerics.cpu_dispatch import DISPATCH_VARIABLES, PINNED_ENVIRONMENT

    assert set(PINNED_ENVIRONMENT) < set(EvaluationConfig().batch_config().worker_environment) == set(DISPATCH_VARIABLES)


def test_a_resumed_run_tells_its_own_infrastructure_events_from_the_earlier_parts(tmp_path):
    """The journal keeps the events of the earlier parts (the JSON lists them all), and the outcome says how many
    came first, so a resumed run does not report an earlier worker loss as news."""
    todo = units(4, {1: {"do": "kill_first", "counter": str(tmp_path / "c")}})
    path = tmp_path / "j.jsonl"
    with Journal.open(path, {"run": 1}) as journal:
        first = run(todo[:2], BatchConfig(workers=2), journal=journal)
    assert [e["event"] for e in first.events] == ["worker_lost"] and first.events_before == 0
    with Journal.open(path, {"run": 1}, resume=True) as journal:
        resumed = run(todo, BatchConfig(workers=2), journal=journal)
    assert resumed.complete and resumed.events == first.events and resumed.events_before == 1
