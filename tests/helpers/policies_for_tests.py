"""Small policies written for the tests of `pih evaluate --policy` (tests/envs/evaluation/test_evaluate_policy.py):
factories called as ``factory(task, **options)`` (envs.evaluation.evaluate_policy), and factories that break each rule
once."""

from __future__ import annotations

from typing import Any

import numpy as np

from envs.geometry import quat_to_mat
from envs.policies.interface import Action, Observation, PolicyTask
from envs.poses import Pose, slerp

NOT_CALLABLE = 3


class HoldStart:
    """Commands the measured start pose for the whole episode: it never inserts, so every episode hits the time
    limit where it started."""

    def reset(self, observation: Observation, period_s: float) -> None:
        self.start = Pose(pos=np.array(observation.tcp.pos), quat=np.array(observation.tcp.quat))

    def act(self, observation: Observation) -> Action:
        return Action(self.start)


class GoToNominalGoal:
    """Moves in ``duration_s`` from the start to 20 mm above the NOMINAL hole's opening, then in as long again
    straight down its axis to the NOMINAL goal (the demos' goal) and holds it: the peg meets the (displaced) hole and
    the physics decides what becomes of it."""

    def __init__(self, duration_s: float) -> None:
        self.duration_s = duration_s

    def reset(self, observation: Observation, period_s: float) -> None:
        self.start, self.period_s, self.step = observation.tcp, period_s, 0

    def act(self, observation: Observation) -> Action:
        self.step += 1
        hole, goal = observation.nominal_hole, observation.nominal_goal
        axis = quat_to_mat(hole.quat)[:, 2]
        above = np.asarray(hole.pos) + 0.02 * axis
        t = self.step * self.period_s / self.duration_s
        s = min(1.0, t) ** 2 * (3.0 - 2.0 * min(1.0, t))
        if t <= 1.0:
            pos = (1.0 - s) * np.asarray(self.start.pos) + s * above
            return Action(Pose(pos=pos, quat=slerp(self.start.quat, goal.quat, s)))
        d = min(1.0, t - 1.0)
        return Action(Pose(pos=(1.0 - d) * above + d * np.asarray(goal.pos), quat=np.asarray(goal.quat)))


def hold(task: PolicyTask) -> HoldStart:
    """The `HoldStart` policy."""
    return HoldStart()


def goal(task: PolicyTask, duration_s: str = "2.5") -> GoToNominalGoal:
    """The `GoToNominalGoal` policy; ``duration_s`` comes from ``--policy-option duration_s=...``."""
    return GoToNominalGoal(float(duration_s))


def not_a_policy(task: PolicyTask) -> Any:
    """Returns something without reset/act."""
    return {"reset": None}


def raises(task: PolicyTask) -> Any:
    """Fails while building the policy."""
    raise ValueError("no weights found")


class ExitsInAct(HoldStart):
    """Takes its process down at its first action, as a crashing extension (a segfault) would."""

    def act(self, observation: Observation) -> Action:
        import os

        os._exit(3)


def exits(task: PolicyTask) -> ExitsInAct:
    """A policy whose act() ends the process."""
    return ExitsInAct()


def exits_at_start(task: PolicyTask) -> Any:
    """A factory that takes its process down (as a crashing extension would while loading its weights)."""
    import os

    os._exit(9)


def hangs_at_start(task: PolicyTask) -> Any:
    """A factory that never returns (a lock never released, a download that never ends)."""
    import time

    time.sleep(3600.0)


class Typo(HoldStart):
    """Its act has a typo (``self.gaol``): AttributeError at its first action, as a new user's policy would."""

    def act(self, observation: Observation) -> Action:
        return Action(self.gaol)  # type: ignore[attr-defined]  # noqa: the error under test


def typo(task: PolicyTask) -> Typo:
    """A policy whose act raises AttributeError."""
    return Typo()


class ReturnsArray(HoldStart):
    """Returns the measured position as an ndarray instead of an Action."""

    def act(self, observation: Observation) -> Any:
        return np.asarray(observation.tcp.pos)


def returns_array(task: PolicyTask) -> ReturnsArray:
    """A policy whose act returns no Action."""
    return ReturnsArray()


_RESETS = [0]
"""Resets of `TypoEveryOther` in this process."""


class TypoEveryOther(HoldStart):
    """Holds its start, but in every second episode this process runs (the 2nd, the 4th, ...) its act has the typo of
    `Typo`: with one worker and --lockstep 1, episodes 1, 3, ... fail and 0, 2, ... run to their time limit."""

    def reset(self, observation: Observation, period_s: float) -> None:
        super().reset(observation, period_s)
        _RESETS[0] += 1
        self.broken = _RESETS[0] % 2 == 0

    def act(self, observation: Observation) -> Action:
        if self.broken:
            return Action(self.gaol)  # type: ignore[attr-defined]  # noqa: the error under test
        return super().act(observation)


def typo_every_other(task: PolicyTask) -> TypoEveryOther:
    """A policy that fails in every second episode."""
    return TypoEveryOther()


def seeded(task: PolicyTask, demo_seed: str, demo_file: str, **options: str) -> HoldStart:
    """A learner's factory as `pih benchmark --policy` calls it: it reads the replicate's demos (where a learner would
    train on them, seeded with ``demo_seed``) and holds its start."""
    from envs.demos.file import load_demos

    load_demos(demo_file)
    int(demo_seed)
    return HoldStart()
