"""`pih evaluate --policy package.module:factory`: a user's policy (tests/helpers/policies_for_tests.py) scored by
physics on the skill's starts and perturbations, and every bad spec refused with one line and exit 2 before any
episode."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rflow.skill_io import save_skill
from scripts.cli import main
from tests.helpers import REPO
from tests.helpers.skill_fixtures import tiny_skill, write_demo_file

POLICIES = "tests.helpers.policies_for_tests"
"""The module of the tests' policies, as `--policy` names it (POLICIES:FACTORY)."""
RUN = ["--episodes", "4", "--pos-range-mm", "10", "--quiet"]
"""Starts within 10 mm of the synthetic demos' mean start (all reachable), the contact preset's 1 mm / 1 deg hole
errors."""


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> Path:
    """The synthetic demos tiny_skill() is trained on (same seed), so the two meet the same starts."""
    return write_demo_file(tmp_path_factory.mktemp("demos"))


def _evaluate(tmp_path: Path, name: str, *args: str) -> dict:
    out = tmp_path / f"{name}.json"
    assert main(["evaluate", *args, *RUN, "--json", str(out)]) == 0
    return json.loads(out.read_text())


@pytest.fixture(scope="module")
def goal_run(demos, tmp_path_factory) -> dict:
    return _evaluate(tmp_path_factory.mktemp("goal"), "goal", "--policy", f"{POLICIES}:goal", "--demos",
                     str(demos), "--time-limit-s", "6", "--policy-option", "duration_s=2.5")


def test_a_policy_that_holds_its_start_fails_every_episode_at_the_time_limit(demos, tmp_path) -> None:
    data = _evaluate(tmp_path, "hold", "--policy", f"{POLICIES}:hold", "--demos", str(demos),
                     "--time-limit-s", "1")
    records = data["per_episode"]
    assert data["policy"] == {"spec": f"{POLICIES}:hold", "options": {}, "privileged": False}
    assert len(records) == 4 and data["successes"] == 0
    for r in records:
        assert r["reason"].startswith("time_limit") and r["steps"] == 100
        assert np.linalg.norm(np.subtract(r["final_pos"], r["start_pos"])) < 2e-3  # the peg stayed where it began


def test_a_policy_that_commands_the_nominal_goal_is_scored_by_the_true_hole(goal_run) -> None:
    """It never sees the hole-pose error, so the physics check sorts its episodes by it: the peg seats (30 mm deep)
    where the hole moved least and jams on the chamfer (force limit) where it moved most."""
    records = goal_run["per_episode"]
    seated = [r for r in records if r["success"]]
    failed = [r for r in records if not r["success"]]
    assert goal_run["policy"]["options"] == {"duration_s": "2.5"}
    assert seated and failed
    assert all(r["insertion_depth_mm"] > 28.0 and r["reason"] == "success" for r in seated)
    assert all(r["touched"] and r["insertion_depth_mm"] < 5.0 and r["reason"].startswith("force_limit") for r in failed)
    offset = lambda r: r["perturbation"]["hole_offset_mm"]  # noqa: E731
    assert max(map(offset, seated)) < min(map(offset, failed))


def test_the_same_policy_in_the_frame_of_the_measured_hole_seats_every_episode(demos, goal_run, tmp_path) -> None:
    """Run in the frame of the hole a sensor measures (no sensor error), the policy that commands the nominal goal
    commands the true one: it seats where it jammed before, on the same starts and hole errors."""
    data = _evaluate(tmp_path, "follow", "--policy", f"{POLICIES}:goal", "--demos", str(demos),
                     "--time-limit-s", "6", "--policy-option", "duration_s=2.5", "--hole-observation", "measured",
                     "--follow-observed-hole")
    assert data["config"]["follow_observed_hole"] is True and data["task"]["perturbations"]["hole_observation"] == \
        "measured"
    assert [r["perturbation"] for r in data["per_episode"]] == [r["perturbation"] for r in goal_run["per_episode"]]
    assert goal_run["successes"] < 4 and data["successes"] == 4, [r["reason"] for r in data["per_episode"]]


def test_a_policy_meets_the_starts_and_perturbations_of_the_skill_trained_on_the_same_demos(goal_run, tmp_path) -> None:
    model = save_skill(tmp_path / "model", tiny_skill())
    skill_run = _evaluate(tmp_path, "skill", "--model", str(model), "--time-limit-s", "0.05")
    assert "policy" not in skill_run
    for mine, skill in zip(goal_run["per_episode"], skill_run["per_episode"], strict=True):
        assert (mine["index"], mine["start_pos"], mine["start_quat"], mine["perturbation"]) == (
            skill["index"], skill["start_pos"], skill["start_quat"], skill["perturbation"])
    assert goal_run["scene"] == skill_run["scene"]


def test_a_policy_evaluation_without_recorded_episodes_is_refused_by_the_episode_export(goal_run, tmp_path,
                                                                                        capsys) -> None:
    path = tmp_path / "goal.json"
    path.write_text(json.dumps(goal_run))
    assert main(["export", "--episodes", str(path), "--format", "lerobot", "--out", str(tmp_path / "ds")]) == 2
    err = capsys.readouterr().err.strip()
    assert "--policy tests.helpers.policies_for_tests:goal cannot be replayed" in err and "\n" not in err
    assert "--record-episodes" in err


@pytest.mark.parametrize("spec,words", [
    (f"{POLICIES}.goal", "no ':'"),
    (f"{POLICIES}:", "Python names"),
    ("no_such_module_here:make", "cannot import module 'no_such_module_here'"),
    (f"{POLICIES}:missing", "has no attribute 'missing'"),
    (f"{POLICIES}:NOT_CALLABLE", "is a int, not a callable factory"),
    (f"{POLICIES}:not_a_policy", "returned a dict, not a Policy"),
    (f"{POLICIES}:raises", "the factory raised ValueError: no weights found"),
])
def test_a_bad_policy_spec_is_one_line_and_exit_2_with_nothing_written(demos, tmp_path, capsys, spec, words) -> None:
    out = tmp_path / "eval.json"
    status = main(["evaluate", "--policy", spec, "--demos", str(demos), *RUN, "--json", str(out)])
    err = capsys.readouterr().err.strip()
    assert status == 2 and err.startswith("pih evaluate: error: --policy") and words in err and "\n" not in err
    assert not out.exists() and not list(tmp_path.iterdir())  # nor a journal


@pytest.mark.parametrize("args,words", [
    (["--policy", f"{POLICIES}:hold"], "--policy needs --demos"),
    (["--policy", f"{POLICIES}:hold", "--demos", "DEMOS", "--mode", "open-loop"], "--mode: not with --policy"),
    (["--policy", f"{POLICIES}:hold", "--demos", "DEMOS", "--speed", "2"], "--speed: not with --policy"),
    (["--model", "DEMOS", "--keep-going"], "--keep-going: only with --policy"),
    (["--policy", f"{POLICIES}:hold", "--demos", "DEMOS", "--policy-option", "x"], "must be KEY=VALUE"),
    (["--demos", "DEMOS"], "give --model DIR"),
])
def test_policy_options_are_checked_before_any_episode(demos, tmp_path, capsys, args, words) -> None:
    args = [str(demos) if a == "DEMOS" else a for a in args]
    assert main(["evaluate", *args, *RUN, "--json", str(tmp_path / "e.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pih evaluate: error:") and words in err and "\n" not in err


def test_a_policy_that_takes_its_process_down_loses_its_episodes_not_the_run(demos, tmp_path, capsys) -> None:
    """Even with one worker a user's policy runs in a supervised process: each try of an episode dies with it, the
    episodes end as infrastructure errors after their retries, and the JSON is written."""
    out = tmp_path / "exits.json"
    code = main(["evaluate", "--policy", f"{POLICIES}:exits", "--demos", str(demos), "--episodes", "2",
                 "--pos-range-mm", "10", "--workers", "1", "--lockstep", "1", "--quiet", "--json", str(out)])
    assert code != 0 and out.is_file()
    data = json.loads(out.read_text())
    assert len(data["infrastructure_errors"]) == 2 and data["successes"] == 0


# ---- user code runs supervised: a factory that exits or hangs is one line and exit 1, never pih's death or hang ----

def _pih(*argv: str, cwd: Path, timeout_s: float = 240.0) -> subprocess.CompletedProcess:
    """`pih` in a process of its own (a factory that takes its process down must not take the test's)."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-m", "scripts.cli", *argv], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout_s)


@pytest.mark.slow
@pytest.mark.parametrize("factory,limit,words", [("exits_at_start", [], "with exit code 9"),
                                                 ("hangs_at_start", ["--start-timeout-s", "1"],
                                                  "not ready 1 s after it was started")])
def test_a_factory_that_exits_or_hangs_is_one_line_and_exit_1(demos, tmp_path, factory, limit, words) -> None:
    """pih survives it, says why in one line, and leaves nothing (no journal blocks a plain rerun)."""
    done = _pih("evaluate", "--policy", f"{POLICIES}:{factory}", "--demos", str(demos), "--episodes", "2", "--quiet",
                "--json", str(tmp_path / "e.json"), *limit, cwd=REPO)
    assert done.returncode == 1, done.stderr
    assert done.stderr.count("\n") == 1 and done.stderr.startswith(f"pih evaluate: error: --policy {POLICIES}")
    assert words in done.stderr and done.stdout == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == []


POLICY_SOURCE = '''
from tests.helpers.policies_for_tests import HoldStart


def make(task, **options):
    return HoldStart()  # VERSION
'''


def test_a_resume_refuses_a_policy_whose_source_changed(demos, tmp_path, monkeypatch, capsys) -> None:
    (tmp_path / "pih_resumed_policy.py").write_text(POLICY_SOURCE.replace("VERSION", "first"))
    monkeypatch.chdir(tmp_path)  # the policy's module is found in the current folder first
    argv = ["evaluate", "--policy", "pih_resumed_policy:make", "--demos", str(demos), "--episodes", "2",
            "--time-limit-s", "0.05", "--quiet", "--json", str(tmp_path / "e.json"), "--journal",
            str(tmp_path / "e.jsonl")]  # a journal named with --journal is kept once the run completes
    assert main(argv) == 0 and main([*argv, "--resume"]) == 0  # the same source: the run continues (all done)
    (tmp_path / "pih_resumed_policy.py").write_text(POLICY_SOURCE.replace("VERSION", "second"))
    capsys.readouterr()
    assert main([*argv, "--resume"]) == 2
    err = capsys.readouterr().err
    assert "policy_sha256" in err and err.count("\n") == 1, err
