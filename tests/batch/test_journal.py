"""batch.journal: header, append, resume, torn last line, header mismatch, never replacing a foreign file."""

from __future__ import annotations

import json
import stat

import pytest

from batch import BatchError, Journal

RUN = {"model": "m", "episodes": 4, "range": (0.05, 15.0)}


def test_records_survive_a_reopen(tmp_path):
    path = tmp_path / "j.jsonl"
    with Journal.open(path, RUN) as journal:
        journal.append("a", {"x": 1})
        journal.append("b", {"x": (2, 3)})
    with Journal.open(path, RUN, resume=True) as journal:
        assert journal.done() == {"a": {"x": 1}, "b": {"x": [2, 3]}}


def test_first_line_is_the_header(tmp_path):
    path = tmp_path / "j.jsonl"
    Journal.open(path, RUN).close()
    assert json.loads(path.read_text().splitlines()[0]) == {"kind": "header", "run": {**RUN, "range": [0.05, 15.0]}}


def test_existing_journal_is_not_reused_without_resume(tmp_path):
    path = tmp_path / "j.jsonl"
    Journal.open(path, RUN).close()
    with pytest.raises(BatchError, match="--resume"):
        Journal.open(path, RUN)


def test_resume_needs_an_existing_journal(tmp_path):
    with pytest.raises(BatchError, match="does not exist"):
        Journal.open(tmp_path / "missing.jsonl", RUN, resume=True)


def test_resume_of_a_different_run_names_the_key(tmp_path):
    path = tmp_path / "j.jsonl"
    Journal.open(path, RUN).close()
    with pytest.raises(BatchError, match="'episodes'"):
        Journal.open(path, {**RUN, "episodes": 5}, resume=True)


def test_torn_last_line_is_ignored_and_cut_before_appending(tmp_path):
    path = tmp_path / "j.jsonl"
    with Journal.open(path, RUN) as journal:
        journal.append("a", {"x": 1})
    with open(path, "a") as handle:
        handle.write('{"kind": "unit", "key": "b", "rec')  # crash mid-write
    with Journal.open(path, RUN, resume=True) as journal:
        assert journal.done() == {"a": {"x": 1}}
        journal.append("c", {"x": 3})
    with Journal.open(path, RUN, resume=True) as journal:
        assert journal.done() == {"a": {"x": 1}, "c": {"x": 3}}


def test_corrupt_line_in_the_middle_is_an_error(tmp_path):
    path = tmp_path / "j.jsonl"
    with Journal.open(path, RUN) as journal:
        journal.append("a", {"x": 1})
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0], "garbage", lines[1]]) + "\n")
    with pytest.raises(BatchError, match="line 2"):
        Journal.open(path, RUN, resume=True)


def test_overwrite_never_replaces_a_file_that_is_not_a_journal(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("someone's notes\n")
    with pytest.raises(BatchError, match="not a batch journal"):
        Journal.open(path, RUN, overwrite=True)
    assert path.read_text() == "someone's notes\n"


def test_overwrite_replaces_an_old_journal(tmp_path):
    path = tmp_path / "j.jsonl"
    with Journal.open(path, RUN) as journal:
        journal.append("a", {"x": 1})
    with Journal.open(path, RUN, overwrite=True) as journal:
        assert journal.done() == {}


def test_missing_folder_is_an_error(tmp_path):
    with pytest.raises(BatchError, match="does not exist"):
        Journal.open(tmp_path / "nope" / "j.jsonl", RUN)


def test_file_mode_follows_the_umask(tmp_path):
    path = tmp_path / "j.jsonl"
    Journal.open(path, RUN).close()
    import os

    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask


def test_append_after_close_is_an_error(tmp_path):
    journal = Journal.open(tmp_path / "j.jsonl", RUN)
    journal.close()
    with pytest.raises(BatchError, match="closed"):
        journal.append("a", {})


def test_events_survive_a_reopen_and_do_not_count_as_units(tmp_path):
    path = tmp_path / "j.jsonl"
    with Journal.open(path, RUN) as journal:
        journal.note({"event": "worker_lost", "unit": "a"})
        journal.append("b", {"x": 1})
    with Journal.open(path, RUN, resume=True) as journal:
        assert journal.events() == [{"event": "worker_lost", "unit": "a"}]
        assert journal.done() == {"b": {"x": 1}}


def test_earlier_wall_time_adds_each_segment_up_to_its_last_line(tmp_path):
    path = tmp_path / "j.jsonl"
    Journal.open(path, RUN).close()
    header = path.read_text()
    lines = [{"kind": "unit", "key": "a", "record": {}, "segment": 0, "elapsed_s": 2.0},
             {"kind": "event", "event": {}, "segment": 0, "elapsed_s": 5.0},
             {"kind": "unit", "key": "b", "record": {}, "segment": 1, "elapsed_s": 1.5}]
    path.write_text(header + "".join(json.dumps(line) + "\n" for line in lines))
    with Journal.open(path, RUN, resume=True) as journal:
        assert journal.earlier_wall_s == 6.5
        journal.append("c", {})
    assert json.loads(path.read_text().splitlines()[-1])["segment"] == 2
    with Journal.open(tmp_path / "new.jsonl", RUN) as journal:
        assert journal.earlier_wall_s == 0.0


def test_a_resume_of_another_run_names_the_first_value_that_differs(tmp_path) -> None:
    path = tmp_path / "j.jsonl"
    run = {"cells": [{"settings": {"clearance_m": 0.0002}}, {"settings": {"clearance_m": 0.0003}}], "seed": 0}
    with Journal.open(path, run):
        pass
    other = {"cells": [{"settings": {"clearance_m": 0.0002}}, {"settings": {"clearance_m": 0.0004}}], "seed": 0}
    with pytest.raises(BatchError, match=r"'cells\[1\]\.settings\.clearance_m' was 0\.0003, now 0\.0004"):
        Journal.open(path, other, resume=True)


HOLDER = """
import sys, time
from batch import Journal
journal = Journal.open(sys.argv[1], {"run": 1})
journal.append("u0", {"n": 0})
print("holding", flush=True)
time.sleep(60)
"""


def test_a_journal_a_run_owns_is_refused_to_a_second_run(tmp_path):
    """A --resume (or an --overwrite) started while the first run still goes would duplicate its work and tear
    its file: refused in one line while the first run holds the journal, and free once it ended."""
    import subprocess
    import sys

    from tests.helpers import REPO

    path = tmp_path / "j.jsonl"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(path)], cwd=REPO, stdout=subprocess.PIPE)
    try:
        assert holder.stdout.readline() == b"holding\n"
        for how in ({"resume": True}, {"overwrite": True}):
            with pytest.raises(BatchError, match="is in use by another run") as info:
                Journal.open(path, {"run": 1}, **how)
            assert "\n" not in str(info.value)
        assert path.read_text().count("\n") == 2  # the first run's header and unit, untouched
    finally:
        holder.kill()
        holder.wait()
    with Journal.open(path, {"run": 1}, resume=True) as journal:  # its owner is gone: the lock went with it
        assert journal.done() == {"u0": {"n": 0}}
