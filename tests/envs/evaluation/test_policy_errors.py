"""A user's policy's errors surface (`pih evaluate --policy`): an exception out of its ``act`` or ``reset``, or an
action that is not an `Action`, stops the run with the policy's traceback on stderr, exit status 4 and no success
rate written (a journal stays for --resume); with --keep-going such episodes are recorded as "policy_error", kept out
of the success rate, the rest run, and the exit status is still 4. The built-in skill's own errors stay "error"."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from envs.errors import ActionError, EnvError
from envs.policies.interface import Action
from envs.rollout.episode import StartPose, run_episode
from scripts.cli import main
from tests.helpers.skill_fixtures import write_demo_file

POLICIES = "tests.helpers.policies_for_tests"
SHORT = ["--pos-range-mm", "10", "--time-limit-s", "0.3", "--quiet"]
EXIT_POLICY_ERROR = 4


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> Path:
    return write_demo_file(tmp_path_factory.mktemp("demos"))


def _evaluate(demos: Path, out: Path, policy: str, *extra: str) -> int:
    return main(["evaluate", "--policy", f"{POLICIES}:{policy}", "--demos", str(demos), *SHORT, "--json", str(out),
                 *extra])


def test_a_policy_that_raises_in_act_stops_the_run_with_its_traceback_and_no_rate(demos, tmp_path, capsys) -> None:
    out = tmp_path / "e.json"
    assert _evaluate(demos, out, "typo", "--episodes", "4") == EXIT_POLICY_ERROR
    err = capsys.readouterr().err
    assert "AttributeError: 'Typo' object has no attribute 'gaol'" in err  # the traceback's last line
    assert "Traceback (most recent call last):" in err and "policies_for_tests.py" in err and "in act" in err
    assert "episode.py" not in err  # the policy's frames, not the episode loop's
    assert err.rstrip().splitlines()[-1].startswith("pih evaluate: error: the policy failed in episode ")
    assert not out.exists()  # no success rate written
    journal = tmp_path / "e.json.journal.jsonl"  # what finished, for --resume
    assert journal.is_file() and '"policy_error"' in journal.read_text()


def test_an_action_that_is_not_an_action_stops_the_run(demos, tmp_path, capsys) -> None:
    out = tmp_path / "e.json"
    assert _evaluate(demos, out, "returns_array", "--episodes", "2") == EXIT_POLICY_ERROR
    err = capsys.readouterr().err
    assert "ReturnsArray.act returned a ndarray, not an Action" in err and "policies_for_tests.py" in err
    assert not out.exists()


def test_keep_going_records_policy_errors_apart_from_the_rate_and_exits_non_zero(demos, tmp_path, capsys) -> None:
    """One worker, no lockstep: episodes 1 and 3 meet the broken act, 0 and 2 run to their time limit."""
    out = tmp_path / "e.json"
    status = _evaluate(demos, out, "typo_every_other", "--episodes", "4", "--workers", "1", "--lockstep", "1",
                       "--keep-going")
    assert status == EXIT_POLICY_ERROR
    err = capsys.readouterr().err
    assert "AttributeError: 'TypoEveryOther' object has no attribute 'gaol'" in err
    data = json.loads(out.read_text())
    errors = data["policy_errors"]
    assert [r["index"] for r in errors] == [1, 3]
    for r in errors:
        assert r["failure"] == "policy_error" and not r["success"]
        assert r["reason"].startswith("policy_error: AttributeError: 'TypoEveryOther' object has no attribute")
        assert "Traceback" in r["traceback"]
    scored = data["per_episode"]
    assert [r["index"] for r in scored] == [0, 2] and all(r["failure"] != "policy_error" for r in scored)
    assert data["episodes"] == 2 and data["success_rate"] == 0.0  # the denominator: scored episodes only
    assert "policy_error" not in data["statistics"]["failures_by_kind"]
    assert not (tmp_path / "e.json.journal.jsonl").exists()  # a complete run: the JSON holds every record


def test_a_resumed_run_stops_at_the_error_its_journal_holds(demos, tmp_path, capsys) -> None:
    out = tmp_path / "e.json"
    assert _evaluate(demos, out, "typo", "--episodes", "2") == EXIT_POLICY_ERROR
    capsys.readouterr()
    assert _evaluate(demos, out, "typo", "--episodes", "2", "--resume") == EXIT_POLICY_ERROR
    assert "no attribute 'gaol'" in capsys.readouterr().err and not out.exists()
    assert _evaluate(demos, out, "typo", "--episodes", "2", "--resume", "--keep-going") == EXIT_POLICY_ERROR
    assert len(json.loads(out.read_text())["policy_errors"]) == 2


class _RaisesInAct:
    def reset(self, observation, period_s):
        self.start = observation.tcp

    def act(self, observation):
        raise ValueError("broken")


class _Uncommandable(_RaisesInAct):
    def act(self, observation):
        return Action(self.start, stiffness=-np.eye(3))


@pytest.mark.parametrize("policy,reason", [(_RaisesInAct(), "ValueError: broken"),
                                           (_Uncommandable(), "ActionError: bad stiffness")])
def test_the_episode_loop_tells_a_user_policys_errors_apart_and_the_skills_stay_errors(policy, reason) -> None:
    from envs.poses import Pose
    from envs.sim.env import PegInHoleEnv

    env = PegInHoleEnv()
    start = StartPose(0, -1, Pose(pos=env.goal.pos + np.array([0.0, 0.0, 0.05]), quat=env.goal.quat))
    mine, _ = run_episode(env, policy, start, user_policy=True, max_steps=5)
    builtin, _ = run_episode(env, policy, start, max_steps=5)
    assert mine.failure == "policy_error" and mine.reason.startswith(f"policy_error: {reason}"), mine.reason
    assert mine.to_dict()["traceback"] == mine.traceback and reason.split(":")[0] in mine.traceback
    assert builtin.failure == "error" and builtin.reason.startswith("error: ") and "traceback" not in builtin.to_dict()
    assert issubclass(ActionError, EnvError)
