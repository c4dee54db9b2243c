"""Evaluation as a batch (tiny skill, short episodes): a killed worker's episode runs again, so the run
completes with the JSON of an undisturbed run and lists the loss; Ctrl-C keeps the finished episodes and
--resume gives the JSON of an uninterrupted run; every option is checked before any episode runs, and
nothing is left behind on bad input."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from batch import Journal
from envs.evaluation.evaluate import EvaluationConfig, evaluate, journal_run
from envs.task.task import Task, preset
from rflow.skill_io import save_skill
from scripts.cli import main as pih
from tests.helpers.procfs import worker_processes
from tests.helpers.skill_fixtures import tiny_skill

PIH = str(Path(sys.executable).with_name("pih"))
FAST = ["--episodes", "4", "--time-limit-s", "0.05", "--quiet"]


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    return save_skill(tmp_path_factory.mktemp("ck") / "model", tiny_skill())


def without_wall_times(data: dict) -> dict:
    """The JSON of an evaluation without what depends on the machine: wall times and the workers that ran."""
    data = {k: v for k, v in data.items() if k not in ("wall_s", "workers")}
    data["statistics"] = {k: v for k, v in data["statistics"].items() if "wall" not in k}
    data["per_episode"] = [{k: v for k, v in r.items() if k != "wall_s"} for r in data["per_episode"]]
    return data


@pytest.mark.slow
def test_resumed_evaluation_equals_an_uninterrupted_one(model, tmp_path):
    config = EvaluationConfig(episodes=4, task=Task(time_limit_s=0.05))
    path = tmp_path / "j.jsonl"
    with Journal.open(path, journal_run(model, config)) as journal:
        whole = evaluate(model, config, progress=False, journal=journal)
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:3]) + lines[3][:40])  # a run stopped after 2 episodes, mid-write of the 3rd
    with Journal.open(path, journal_run(model, config), resume=True) as journal:
        assert len(journal.done()) == 2
        resumed = evaluate(model, EvaluationConfig(episodes=4, task=Task(time_limit_s=0.05), workers=2),
                           progress=False, journal=journal)
    assert resumed.complete and len(path.read_text().splitlines()) == 5
    a, b = without_wall_times(whole.to_dict()), without_wall_times(resumed.to_dict())
    assert (a["config"].pop("workers"), b["config"].pop("workers")) == (1, 2)
    assert a == b


def test_journal_of_another_model_is_refused(model, tmp_path):
    config = EvaluationConfig(episodes=4)
    other = save_skill(tmp_path / "other", tiny_skill(layout="joint"))
    Journal.open(tmp_path / "j.jsonl", journal_run(model, config)).close()
    with pytest.raises(Exception, match="different run"):
        Journal.open(tmp_path / "j.jsonl", journal_run(other, config), resume=True)


@pytest.mark.parametrize("option, value, message", [
    ("--camera", "ceiling", "not a camera of the scene"),
    ("--video-episodes", "0,9", "must lie in 0..3"),
    ("--video", "OUT/out.avi", "must end in .mp4"),
    ("--figure", "OUT/missing/fig.png", "does not exist"),
])
def test_bad_video_options_fail_before_any_episode(model, tmp_path, capsys, option, value, message):
    extra = [option, value.replace("OUT", str(tmp_path))]
    if option != "--video":
        extra += ["--video", str(tmp_path / "v.mp4")]
    code = pih(["evaluate", "--model", str(model), *FAST, "--json", str(tmp_path / "e.json"), *extra])
    assert code == 2 and message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # no JSON, no journal, no video


def test_someone_elses_json_is_never_replaced(model, tmp_path, capsys):
    out = tmp_path / "e.json"
    out.write_text("someone's results")
    assert pih(["evaluate", "--model", str(model), *FAST, "--json", str(out), "--overwrite"]) == 2
    assert "not written by pih" in capsys.readouterr().err and out.read_text() == "someone's results"


def test_a_complete_run_removes_its_own_journal_and_keeps_a_named_one(model, tmp_path):
    assert pih(["evaluate", "--model", str(model), *FAST, "--json", str(tmp_path / "e.json")]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.json"]  # no e.json.journal.jsonl beside it
    named = tmp_path / "named.jsonl"
    assert pih(["evaluate", "--model", str(model), *FAST, "--json", str(tmp_path / "f.json"), "--journal",
                str(named)]) == 0
    assert len(named.read_text().splitlines()) == 1 + 4  # the header and every episode


def test_existing_journal_needs_resume_or_overwrite(model, tmp_path, capsys):
    args = ["evaluate", "--model", str(model), *FAST, "--json", str(tmp_path / "e.json"), "--journal",
            str(tmp_path / "j.jsonl")]  # a journal named with --journal is kept after the run
    assert pih(args) == 0
    assert pih(args + ["--overwrite"]) == 0
    os.remove(tmp_path / "e.json")
    assert pih(args) == 2 and "--resume" in capsys.readouterr().err
    assert pih(args + ["--resume"]) == 0  # everything is in the journal: nothing runs, the JSON is rewritten
    assert json.loads((tmp_path / "e.json").read_text())["complete"] is True


def test_resume_without_a_journal_is_an_error(model, tmp_path, capsys):
    assert pih(["evaluate", "--model", str(model), *FAST, "--resume"]) == 2
    assert "--resume" in capsys.readouterr().err


def test_failed_model_check_leaves_no_journal(tmp_path, capsys):
    (tmp_path / "model").mkdir()
    assert pih(["evaluate", "--model", str(tmp_path / "model"), *FAST, "--json", str(tmp_path / "e.json")]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model"]


def _run(args: list[str], **kwargs) -> subprocess.Popen:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.Popen([PIH, "evaluate", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env, start_new_session=True, **kwargs)


def _wait_for_records(journal: Path, count: int, proc: subprocess.Popen, limit_s: float = 240.0) -> None:
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline and proc.poll() is None:
        if journal.is_file() and len(journal.read_text().splitlines()) >= 1 + count:
            return
        time.sleep(0.02)
    raise AssertionError(f"no {count} records in {journal} (exit {proc.poll()})")


def _cpu_ticks(pid: int) -> int:
    """utime + stime of process ``pid`` (clock ticks; 0 when it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0
    return int(fields[11]) + int(fields[12])


@pytest.mark.slow
def test_sigkill_of_a_worker_changes_no_episode_and_is_listed(model, tmp_path):
    out, journal = tmp_path / "e.json", tmp_path / "e.json.journal.jsonl"
    proc = _run(["--model", str(model), "--episodes", "8", "--time-limit-s", "1.0", "--workers", "2", "--quiet",
                 "--json", str(out)])
    try:
        _wait_for_records(journal, 1, proc)
        # the busiest worker: it has run an episode, so it is past its start (a worker still importing its libraries
        # on a loaded machine is lost "at start", another path: tests/batch/test_runner.py)
        victims = sorted(worker_processes(proc.pid), key=_cpu_ticks, reverse=True)
        assert victims, "no worker process found"
        os.kill(victims[0], signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 0, stderr
    data = without_wall_times(json.loads(out.read_text()))
    assert data.pop("pih")["command"] == "evaluate"  # the file's marker (envs/io/owned_output.py), not in to_dict
    undisturbed = without_wall_times(evaluate(model, EvaluationConfig(episodes=8, task=Task(time_limit_s=1.0),
                                                                      workers=2), progress=False).to_dict())
    (event,) = data.pop("infrastructure_events")
    assert event["event"] == "worker_lost" and event["where"]["pid"] == victims[0] and "infrastructure:" in stderr
    assert undisturbed.pop("infrastructure_events") == []
    assert data == undisturbed and data["complete"]


@pytest.mark.slow
def test_ctrl_c_then_resume_gives_the_uninterrupted_json(model, tmp_path):
    args = ["--model", str(model), "--episodes", "8", "--time-limit-s", "1.0", "--quiet"]
    whole = _run(args + ["--json", str(tmp_path / "whole.json"), "--workers", "1"])
    assert whole.wait(300) == 0, whole.stderr.read()
    out, journal = tmp_path / "e.json", tmp_path / "e.json.journal.jsonl"
    proc = _run(args + ["--json", str(out), "--workers", "2"])
    try:
        _wait_for_records(journal, 1, proc)
        os.killpg(proc.pid, signal.SIGINT)  # a terminal's Ctrl-C reaches the whole process group
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, stderr
    assert "--resume" in stderr and "Traceback" not in stderr
    partial = json.loads(out.read_text())
    assert partial["complete"] is False and 1 <= partial["episodes"] < 8
    assert journal.is_file()  # kept while the run is incomplete
    resumed = _run(args + ["--json", str(out), "--workers", "2", "--resume"])
    assert resumed.wait(300) == 0, resumed.stderr.read()
    assert not journal.exists()  # complete: out of the user's way
    a = without_wall_times(json.loads((tmp_path / "whole.json").read_text()))
    b = without_wall_times(json.loads(out.read_text()))
    assert b["config"].pop("workers") == 2 and a["config"].pop("workers") == 1
    assert a == b


def test_one_replay_renders_the_video_of_all_and_the_figure_of_the_chosen(model, tmp_path, monkeypatch):
    import scripts.evaluate as evaluate_cli

    config = EvaluationConfig(episodes=3, task=Task(time_limit_s=0.05))
    result = evaluate(model, config, progress=False)
    plotted: list[list[int]] = []
    monkeypatch.setattr(evaluate_cli, "plot_episodes",
                        lambda model_dir, skill, replays, starts, path, config: plotted.append([s.index for s in starts]) or path)
    out = evaluate_cli.render_and_plot(model, config, result, [0, 1, 2], tmp_path / "v.mp4", tmp_path / "f.png",
                                       figure_episodes=[0, 2])
    assert plotted == [[0, 2]]
    assert out["replayed"] == [0, 1, 2] and Path(out["video"]).stat().st_size > 0


def test_a_resumed_evaluation_counts_the_wall_time_of_the_earlier_part(model, tmp_path):
    config = EvaluationConfig(episodes=2, task=Task(time_limit_s=0.05))
    path = tmp_path / "j.jsonl"
    with Journal.open(path, journal_run(model, config)) as journal:
        evaluate(model, config, progress=False, journal=journal)
    header, *units = [json.loads(line) for line in path.read_text().splitlines()]
    path.write_text("".join(json.dumps(line) + "\n" for line in [header, *units[:1], {**units[1], "elapsed_s": 1e4}]))
    with Journal.open(path, journal_run(model, config), resume=True) as journal:
        assert evaluate(model, config, progress=False, journal=journal).wall_s >= 1e4


def test_a_fault_is_one_error_line_with_the_resume_command_and_exit_1(model, tmp_path, capsys, monkeypatch):
    """A batch stopped by a fault (the Ray head lost) ends `pih evaluate` with exit 1 and one line on stderr: the
    fault and how to resume; no success table of the run that did not happen."""
    import envs.evaluation.evaluate as evaluate_module
    from envs.evaluation.result import EvaluationResult

    def lost_head(model_dir, config, progress=True, journal=None, record_dir=None):
        journal.append("0", {"index": 0})  # one episode finished before the head was lost
        return EvaluationResult(config, [], 1.0, str(model_dir), complete=False, workers=2,
                                fault="lost the Ray head at 10.0.0.1:6379: its GCS has not answered for 3 s")

    monkeypatch.setattr(evaluate_module, "evaluate", lost_head)  # scripts.evaluate imports it when it runs
    assert pih(["evaluate", "--model", str(model), *FAST, "--json", str(tmp_path / "e.json")]) == 1
    out, err = capsys.readouterr()
    assert err.startswith("pih evaluate: error: lost the Ray head at 10.0.0.1:6379") and err.count("\n") == 1
    assert "continue with:" in err and "--resume" in err and "success rate" not in out, (out, err)


@pytest.mark.parametrize("workers", [1, 2])
def test_lockstep_evaluation_equals_one_episode_at_a_time_in_the_imperfect_cell(model, workers):
    """Episodes in lockstep (each slot on a copy of the worker's model as built) give the records of one episode at a
    time also where every episode writes its perturbation into its model (the realistic preset: friction, payload,
    joint friction, pads, torque noise)."""
    task = dataclasses.replace(preset("realistic"), time_limit_s=0.4)
    alone = evaluate(model, EvaluationConfig(episodes=7, task=task, workers=workers, lockstep=1), progress=False)
    batched = evaluate(model, EvaluationConfig(episodes=7, task=task, workers=workers, lockstep=3), progress=False)
    a, b = without_wall_times(alone.to_dict()), without_wall_times(batched.to_dict())
    assert (a["config"].pop("lockstep"), b["config"].pop("lockstep")) == (1, 3)
    assert a == b and len(a["per_episode"]) == 7
    assert len({json.dumps(r["perturbation"], sort_keys=True) for r in a["per_episode"]}) == 7  # all perturbed apart


@pytest.mark.parametrize("value, message", [("schedule:1500/300", "FREE/LATERAL/AXIAL"),
                                            ("schedule:1500/-1/300", "lateral_hole_n_m"),
                                            ("stiff", "must be 'learned'")])
def test_a_bad_stiffness_is_one_line_and_exit_2_with_nothing_written(model, tmp_path, capsys, value, message):
    code = pih(["evaluate", "--model", str(model), *FAST, "--json", str(tmp_path / "e.json"), "--stiffness", value])
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_adaptation_parts_turn_off_one_at_a_time_and_all_of_them_are_the_bare_flow(model, tmp_path, capsys):
    """`--adaptation-off` turns off the named parts (ContactAdaptation.without); all of them are --no-contact-adaptation
    to the last bit of every record; an unknown part is a one-line error, exit 2, nothing written."""
    from envs.errors import EnvError
    from envs.evaluation.evaluate import _policy_for
    from envs.policies.adaptation import ADAPTATION_PARTS, ContactAdaptation
    from rflow.skill_io import load_skill

    full = ContactAdaptation()
    assert full.without(["compliance"]) == dataclasses.replace(full, rotational_stiffness=None)
    assert full.without(["push", "seat"]) == dataclasses.replace(full, push_limit_m=0.0, seat_speed_m_s=0.0)
    assert full.without(list(ADAPTATION_PARTS)) == ContactAdaptation.off()
    with pytest.raises(EnvError, match="wiggle"):
        full.without(["wiggle"])
    for bad in (("wiggle",), ("push", "push")):
        with pytest.raises(EnvError, match="adaptation_off"):
            EvaluationConfig(adaptation_off=bad)
    skill = load_skill(model)  # the evaluation's policy gets the config's parts off
    assert _policy_for(skill, EvaluationConfig(adaptation_off=("compliance",))).inner.adapter.config == \
        full.without(["compliance"])  # (the insertion wraps the closed loop)
    assert _policy_for(skill, EvaluationConfig(adaptation_off=tuple(ADAPTATION_PARTS))).adapter.config == \
        ContactAdaptation.off()
    common = ["evaluate", "--model", str(model), "--episodes", "2", "--time-limit-s", "0.3", "--quiet"]
    assert pih([*common, "--no-contact-adaptation", "--json", str(tmp_path / "bare.json")]) == 0
    assert pih([*common, "--adaptation-off", ",".join(ADAPTATION_PARTS), "--json", str(tmp_path / "all.json")]) == 0
    bare, parts = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("bare", "all"))
    assert parts["config"]["adaptation_off"] == list(ADAPTATION_PARTS)
    for a, b in zip(bare["per_episode"], parts["per_episode"]):
        a.pop("wall_s"), b.pop("wall_s")
        assert a == b
    capsys.readouterr()
    out = tmp_path / "bad"
    out.mkdir()
    assert pih([*common, "--adaptation-off", "push,wiggle", "--json", str(out / "e.json")]) == 2
    err = capsys.readouterr().err
    assert "--adaptation-off" in err and len(err.strip().splitlines()) == 1 and list(out.iterdir()) == []
    # all parts off and some parts off at once is an ambiguous ablation: refused before anything runs
    assert pih([*common, "--adaptation-off", "push", "--no-contact-adaptation", "--json", str(out / "e.json")]) == 2
    err = capsys.readouterr().err
    assert "not allowed with" in err and len(err.strip().splitlines()) == 1 and list(out.iterdir()) == []


def test_forked_workers_run_on_the_context_built_before_the_fork(model, monkeypatch):
    """Forked evaluation workers take their copy of the environment and policy the evaluation built in this process
    (they do not build the scene and load the skill again), and their records are those of one process."""
    from envs.evaluation import evaluate as evaluate_module

    task = dataclasses.replace(preset("realistic"), time_limit_s=0.2)
    here = evaluate(model, EvaluationConfig(episodes=4, task=task, workers=1), progress=False)

    def no_second_build(setup):
        raise AssertionError("a forked worker built its own environment")

    monkeypatch.setattr(evaluate_module, "_init_worker", no_second_build)
    forked = evaluate(model, EvaluationConfig(episodes=4, task=task, workers=2), progress=False)
    assert forked.complete and forked.workers == 2
    a, b = without_wall_times(here.to_dict()), without_wall_times(forked.to_dict())
    assert (a["config"].pop("workers"), b["config"].pop("workers")) == (1, 2)
    assert a == b and len(a["per_episode"]) == 4


def test_a_run_with_no_completed_episode_says_so_instead_of_a_rate_of_0_of_0():
    from envs.evaluation.result import EvaluationResult
    from envs.rollout.episode import EpisodeRecord

    lost = [EpisodeRecord(i, -1, [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], reason="infrastructure: worker_died after 3 "
                          "tries") for i in range(2)]
    table = EvaluationResult(EvaluationConfig(episodes=2), [], 1.0, "m", complete=False,
                             infrastructure_errors=lost).summary_table()
    assert "(0/0)" not in table and "none: no episode completed (2 lost to infrastructure)" in table
