"""batch.runner: a killed worker, an overrunning unit and an escaped exception each become one failed
record and the batch goes on; records do not depend on the number of workers; a journal resumes a run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from batch import BatchConfig, BatchError, Journal, run_batch
from batch_units import failure, init, units, work

SETUP = {"offset": 7}


def run(todo, config=BatchConfig(), **kwargs):
    return run_batch(todo, SETUP, init, work, failure, config, **kwargs)


def test_records_follow_the_unit_order_and_the_context():
    outcome = run(units(5), BatchConfig(workers=2))
    assert list(outcome.records) == [f"u{i:03d}" for i in range(5)]
    assert [r["value"] for r in outcome.records.values()] == [i * i + 7 for i in range(5)]
    assert outcome.complete and not outcome.interrupted


def test_records_do_not_depend_on_the_number_of_workers():
    assert run(units(6)).records == run(units(6), BatchConfig(workers=3)).records


@pytest.mark.parametrize("action", ["kill", "exit"])
def test_a_dead_worker_is_one_failed_unit_and_the_batch_goes_on(action):
    outcome = run(units(6, {2: {"do": action}}), BatchConfig(workers=2))
    assert outcome.complete
    assert outcome.records["u002"]["reason"] == "worker_died"
    assert [r["value"] for k, r in outcome.records.items() if k != "u002"] == [i * i + 7 for i in (0, 1, 3, 4, 5)]


def test_a_worker_with_nothing_left_to_do_ends_while_the_others_run(tmp_path):
    """Once the queue is empty an idle worker is asked to return at once (its ~1 s interpreter shutdown overlaps
    the units still running) instead of waiting for the end of the batch."""
    files = {"pidfile": str(tmp_path / "pid"), "started": str(tmp_path / "started")}
    todo = [("u000", {"n": 0, "do": "note_pid", **files}), ("u001", {"n": 1, "do": "await_pid", **files})]
    outcome = run(todo, BatchConfig(workers=2))
    assert outcome.records["u000"]["value"] == 7
    assert outcome.records["u001"]["value"] is True  # u000's worker ended while u001 was running


def test_two_dead_workers_in_a_row_are_both_recorded():
    outcome = run(units(5, {0: {"do": "kill"}, 1: {"do": "kill"}}), BatchConfig(workers=2))
    assert [r["reason"] for r in outcome.records.values()] == ["worker_died"] * 2 + ["ok"] * 3


def test_a_unit_over_the_wall_time_limit_is_killed_and_recorded():
    outcome = run(units(4, {1: {"do": "sleep", "seconds": 600.0}}), BatchConfig(workers=2, unit_timeout_s=5.0))
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


def test_ctrl_c_stops_workers_keeps_the_journal_and_prints_no_traceback(tmp_path):
    """A real SIGINT to the whole process group, as a terminal's Ctrl-C sends it."""
    journal = tmp_path / "j.jsonl"
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from batch import BatchConfig, Journal, run_batch
        from batch_units import failure, init, units, work
        todo = units(6, {{i: {{"do": "sleep", "seconds": 600.0}} for i in range(2, 6)}})
        with Journal.open({str(journal)!r}, {{"run": 1}}) as j:
            out = run_batch(todo, {{"offset": 0}}, init, work, failure, BatchConfig(workers=2), journal=j,
                            on_record=lambda k, r: print("finished", k, flush=True))
        print("interrupted" if out.interrupted else "not interrupted", len(out.records), flush=True)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
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
                {"backend": "ray", "ray_address": "nohost"}, {"ray_address": "127.0.0.1:6379"}):
        with pytest.raises(BatchError):
            BatchConfig(**bad)
