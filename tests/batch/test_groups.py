"""batch.runner with unit groups (``group_size``, ``work_group``; episodes in lockstep): every unit keeps its own
record, journal entry and order whatever the group size; the groups shrink toward the end; a group over its
wall-time limit is split so that only the unit that hangs is recorded "wall_timeout"; a group whose worker is lost
runs again whole and changes no record; after its last try each member is an infrastructure error."""

from __future__ import annotations

import pytest

from batch import BatchConfig, BatchError, Journal, run_batch
from batch.runner import unit_groups
from tests.helpers.batch_units import failure, init, units, work, work_group

SETUP = {"offset": 7}


def run(todo, config=BatchConfig(), group_size=4, **kwargs):
    return run_batch(todo, SETUP, init, work, failure, config, group_size=group_size, work_group=work_group, **kwargs)


def values(outcome):
    return {k: (r["n"], r["value"], r["reason"]) for k, r in outcome.records.items()}


@pytest.mark.parametrize("workers", [1, 2])
def test_grouped_records_equal_the_unit_by_unit_ones(workers):
    grouped = run(units(11), BatchConfig(workers=workers))
    single = run_batch(units(11), SETUP, init, work, failure, BatchConfig(workers=workers))
    assert list(grouped.records) == list(single.records) and values(grouped) == values(single)
    assert max(r["group"] for r in grouped.records.values()) > 1  # groups did run


def test_groups_are_consecutive_and_shrink_toward_the_end():
    todo = [(f"u{i}", i) for i in range(30)]
    groups = unit_groups(todo, 8, workers=2)
    assert [m for g in groups for m in g.members] == todo
    sizes = [len(g.members) for g in groups]
    assert max(sizes) == 8 and sizes == sorted(sizes, reverse=True) and sizes[-1] == 1
    assert [len(g.members) for g in unit_groups(todo, 1, workers=2)] == [1] * 30


def test_each_unit_of_a_group_is_journalled_as_it_finishes_and_a_resume_skips_it(tmp_path):
    path = tmp_path / "j.jsonl"
    seen: list[str] = []

    def stop_after_five(key, record):
        seen.append(key)
        if len(seen) == 5:  # inside the second group
            raise KeyboardInterrupt

    with Journal.open(path, {"run": 1}) as journal:
        first = run(units(10), BatchConfig(workers=1), journal=journal, on_record=stop_after_five)
    assert first.interrupted and len(first.records) == 5
    assert len(path.read_text().splitlines()) - 1 == 5  # one entry per unit, not per group
    rerun: list[str] = []
    with Journal.open(path, {"run": 1}, resume=True) as journal:
        second = run(units(10), BatchConfig(workers=2), journal=journal, on_record=lambda k, r: rerun.append(k))
    assert second.complete and sorted(rerun) == sorted(set(second.records) - set(first.records))
    assert values(second) == values(run(units(10)))


@pytest.mark.slow
@pytest.mark.parametrize("workers", [1, 2])
def test_a_group_over_its_limit_is_split_and_only_the_hanging_unit_times_out(workers):
    outcome = run(units(12, {2: {"do": "sleep", "seconds": 600.0}}), BatchConfig(workers=workers, unit_timeout_s=2.0),
                  group_size=3)  # the first group is u000..u002
    assert outcome.complete
    assert [r["reason"] for r in outcome.records.values()] == ["ok", "ok", "wall_timeout"] + ["ok"] * 9
    assert [r["value"] for k, r in outcome.records.items() if k != "u002"] == [i * i + 7 for i in range(12) if i != 2]
    assert [e["event"] for e in outcome.events] == ["group_split"]


def test_a_group_whose_worker_is_killed_runs_again_and_changes_no_record(tmp_path):
    outcome = run(units(8, {5: {"do": "kill_first", "counter": str(tmp_path / "c")}}), BatchConfig(workers=2))
    assert outcome.complete and values(outcome) == values(run(units(8)))
    (event,) = outcome.events
    assert event["event"] == "worker_lost" and event["unit_action"] == "retried"


def test_a_group_lost_on_every_try_makes_each_member_an_infrastructure_error():
    outcome = run(units(8, {1: {"do": "kill"}}), BatchConfig(workers=2, max_retries=1), group_size=4)
    lost = set(outcome.infrastructure_errors)
    assert "u001" in lost and not outcome.complete
    assert lost.isdisjoint(outcome.records) and lost | set(outcome.records) == {f"u{i:03d}" for i in range(8)}
    assert all(r["reason"].startswith("infrastructure") for r in outcome.infrastructure_errors.values())


def test_an_exception_in_the_group_work_fails_each_member():
    outcome = run(units(8, {1: {"do": "raise"}}), BatchConfig(workers=1), group_size=4)  # groups u000..u003, ...
    reasons = [r["reason"] for r in outcome.records.values()]
    assert reasons == ["error: ZeroDivisionError: unit asked to raise"] * 4 + ["ok"] * 4


def test_group_size_is_validated():
    with pytest.raises(BatchError, match="group_size"):
        run(units(2), group_size=0)
