"""The settings of skill execution, apart from the code that runs it, so that a command line can be built
(and checked) without loading torch or MuJoCo: the policy modes and lookahead, the commanded stiffness, and
`EvaluationConfig` (what `evaluate` runs; see envs/execution/starts.py and result.py for the starts and statistics).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

import numpy as np

from batch.errors import BatchError
from batch.config import BatchConfig
from envs.errors import EnvError
from envs.task import Task, check_number
from numerics.cpu_dispatch import DISPATCH_VARIABLES

if TYPE_CHECKING:
    from envs.stiffness_schedule import StiffnessSchedule
    from rflow.skill_io import PoseSkill

MODES: tuple[str, ...] = ("closed-loop", "open-loop")
DEFAULT_LOOKAHEAD_S: float = 0.05
"""Closed-loop lookahead along the learned flow (tuned on the default scene, see envs/execution/evaluate.py)."""


STIFFNESS_KINDS: tuple[str, ...] = ("learned", "constant", "schedule")


@dataclass(frozen=True)
class StiffnessSetting:
    """Which translational stiffness a policy commands: "learned" (the skill's), "constant" (K I, N/m) or
    "schedule" (the scripted expert's schedule K(h), `envs.stiffness_schedule`, at the measured pose's height h
    above the nominal hole's mouth: what the cell believes, never the true hole; the teacher a learned
    stiffness can at best reproduce)."""

    kind: str
    constant_n_m: float = 0.0
    schedule: StiffnessSchedule | None = None

    def __post_init__(self) -> None:
        if self.kind not in STIFFNESS_KINDS:
            raise EnvError(f"stiffness kind {self.kind!r} must be one of {', '.join(STIFFNESS_KINDS)}")
        if self.kind == "constant" and not (np.isfinite(self.constant_n_m) and self.constant_n_m > 0.0):
            raise EnvError(f"constant stiffness {self.constant_n_m!r} N/m must be a positive finite number")
        if self.kind == "schedule" or self.schedule is not None:
            from envs.stiffness_schedule import StiffnessSchedule  # imports MuJoCo: only when asked for

            if self.kind != "schedule" or not isinstance(self.schedule, StiffnessSchedule):
                raise EnvError("a 'schedule' stiffness needs a StiffnessSchedule, and only it takes one")

    @classmethod
    def parse(cls, text: str) -> "StiffnessSetting":
        """"learned", "constant:K" (K in N/m, > 0), "schedule" (the expert's) or "schedule:FREE/LATERAL/AXIAL"
        (its three stiffnesses in N/m). Raises EnvError naming the text."""
        if text == "learned":
            return cls("learned")
        kind, _, value = str(text).partition(":")
        if kind == "schedule":
            from envs.stiffness_schedule import StiffnessSchedule

            if not value:
                return cls("schedule", schedule=StiffnessSchedule())
            try:
                return cls("schedule", schedule=StiffnessSchedule.parse(value))
            except EnvError as err:
                raise EnvError(f"stiffness {text!r}: {err}") from None
        if kind != "constant" or not value:
            raise EnvError(f"stiffness {text!r} must be 'learned', 'constant:K' with K in N/m, or 'schedule[:FREE/"
                           "LATERAL/AXIAL]'")
        try:
            k = float(value)
        except ValueError:
            raise EnvError(f"stiffness {text!r}: K={value!r} is not a number of N/m") from None
        if not (np.isfinite(k) and k > 0.0):
            raise EnvError(f"stiffness {text!r}: K must be a positive finite number of N/m")
        return cls("constant", k)

    def check_skill(self, skill: PoseSkill) -> None:
        """Raise EnvError when "learned" is asked of a skill without a stiffness model."""
        if self.kind == "learned" and not skill.has_stiffness:
            raise EnvError("stiffness 'learned' needs a skill trained with `pih train --stiffness ...`")


DEFAULT_LOCKSTEP = 8
"""Episodes a worker runs in lockstep by default (`EvaluationConfig.lockstep`)."""
MAX_LOCKSTEP = 256
"""At most this many (each slot holds an environment of its own, a few MB)."""


SCENE_FROM_TASK: tuple[str, ...] = ("peg_mode", "clearance_m", "chamfer_m", "grasp_force_n")
"""The scene fields an evaluation may take from its task instead of the demos' (`EvaluationConfig.scene_from_task`);
the hole depth and the goal are always the demos': a skill is evaluated at the depth it was taught."""


MAX_SPEED = 10.0
"""The largest time scaling of the learned flow an evaluation runs (10x the demonstrated speed)."""


@dataclass(frozen=True)
class EvaluationConfig:
    """What `evaluate` runs: the task (envs.task.Task), how the skill executes it and how the episodes run.

    The scene is the demos' (the checkpoint's or demo file's recorded scene; envs.execution.evaluate.scene_config_for)
    but for the task's shape, when set, and the task's fields named in ``scene_from_task``; the finger pads, the
    perturbations, force and time limits, success tolerances and start range are the task's. The task the episodes
    ran, resolved against the demos' scene, is in the result (`EvaluationResult.task`).

    Attributes:
        episodes: number of perturbed starts K.
        seed: seed of the start poses; each episode's perturbation (``task.perturbations``) is drawn from a
            generator seeded with (seed, 1), apart from the start poses, so the starts do not depend on them.
        mode: "closed-loop" (query the flow at the measured pose every step) or "open-loop" (generate
            the trajectory once, track it in time).
        lookahead_s: closed loop: flow time between the measured and the commanded pose.
        feedforward_gain: scale of the impedance velocity feed-forward (envs.execution.policy); 0 turns it off.
        speed: time scaling of the learned flow (the same path, speed times as fast), both modes.
        task: the task (envs.task.Task; default: the "contact" preset).
        scene_from_task: the task's scene fields (of SCENE_FROM_TASK) that replace the demos' (a task file or preset
            given: all of them; single options: those given).
        hole_at_goal: place the target hole at the skill's goal pose (demos from another setup).
        workers: processes (1: in this process) or Ray actors.
        unit_timeout_s: wall-clock seconds one episode may take before its worker is killed and the episode
            recorded "wall_timeout" (None: no limit).
        backend: "process" (local processes) or "ray".
        ray_address: HOST:PORT of a Ray cluster (None: a local Ray instance on all cores).
        stiffness: the translational stiffness commanded ("learned": the skill's, "constant:K": K I in N/m,
            "schedule[:FREE/LATERAL/AXIAL]": the expert's schedule from the nominal hole;
            None: the controller's default), see envs.execution.policy.StiffnessSetting.
        contact_adaptation: closed loop: adapt to the contact near the hole (axial push, frame shift, rotational
            compliance; envs.execution.adaptation); False runs the bare learned flow (the ablation).
        adaptation_off: parts of the adaptation turned off (envs.execution.adaptation.ADAPTATION_PARTS: "push",
            "frame", "compliance", "search", "seat"), the ablation of each.
        lockstep: episodes a worker runs side by side, one control period at a time for all
            (envs.execution.lockstep); the records do not depend on it, only the wall time does.
        follow_observed_hole: run the skill in the frame of the hole the cell observes (the policy's nominal goal;
            with the task's ``hole_observation = "measured"`` a sensor's measurement of the true hole) instead of
            where the demonstrations' hole was (envs.execution.goal_frame).
    """

    episodes: int = 100
    seed: int = 0
    mode: str = "closed-loop"
    lookahead_s: float = DEFAULT_LOOKAHEAD_S
    feedforward_gain: float = 1.0
    speed: float = 1.0
    task: Task = field(default_factory=Task)
    scene_from_task: tuple[str, ...] = ()
    hole_at_goal: bool = False
    workers: int = 1
    unit_timeout_s: float | None = 300.0
    backend: str = "process"
    ray_address: str | None = None
    stiffness: str | None = None
    contact_adaptation: bool = True
    adaptation_off: tuple[str, ...] = ()
    lockstep: int = DEFAULT_LOCKSTEP
    follow_observed_hole: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.episodes, int) or self.episodes < 1:
            raise EnvError(f"episodes={self.episodes!r} must be an integer >= 1")
        if self.stiffness is not None:
            StiffnessSetting.parse(self.stiffness)
        if self.mode not in MODES:
            raise EnvError(f"mode={self.mode!r} must be one of {', '.join(MODES)}")
        check_number("lookahead_s", self.lookahead_s, strict=True)
        if not check_number("speed", self.speed, strict=True) <= MAX_SPEED:
            raise EnvError(f"speed={self.speed!r} must be <= {MAX_SPEED} (a time scaling of the learned flow)")
        check_number("feedforward_gain", self.feedforward_gain)
        if not isinstance(self.task, Task):
            raise EnvError(f"task={self.task!r} must be an envs.task.Task")
        object.__setattr__(self, "scene_from_task", tuple(self.scene_from_task))
        unknown = [name for name in self.scene_from_task if name not in SCENE_FROM_TASK]
        if unknown:
            raise EnvError(f"scene_from_task names {unknown}: only {', '.join(SCENE_FROM_TASK)} may replace the "
                           "demos' scene")
        object.__setattr__(self, "adaptation_off", tuple(self.adaptation_off))
        if self.adaptation_off:
            from envs.execution.adaptation import adaptation_parts  # numba through envs.poses: only when asked for

            try:
                adaptation_parts(self.adaptation_off)
            except EnvError as err:
                raise EnvError(f"adaptation_off: {err}") from None
        if self.mode != "closed-loop" and (self.adaptation_off or not self.contact_adaptation):
            raise EnvError(f"adaptation_off / contact_adaptation: the contact adaptation is part of the closed loop; "
                           f"mode {self.mode!r} has none to turn off")
        if not isinstance(self.workers, int) or self.workers < 1:
            raise EnvError(f"workers={self.workers!r} must be an integer >= 1")
        if not isinstance(self.follow_observed_hole, bool):
            raise EnvError(f"follow_observed_hole={self.follow_observed_hole!r} must be True or False")
        lockstep = self.lockstep
        if isinstance(lockstep, bool) or not isinstance(lockstep, int) or not 1 <= lockstep <= MAX_LOCKSTEP:
            raise EnvError(f"lockstep={self.lockstep!r} must be an integer from 1 to {MAX_LOCKSTEP}")
        try:
            self.batch_config()
        except BatchError as err:
            raise EnvError(str(err)) from None

    def batch_config(self) -> BatchConfig:
        """How the episodes run as a batch (workers, wall-time limit, backend); worker processes are forked, as
        every episode worker runs torch on one thread (`batch.BatchConfig.start_method`)."""
        return BatchConfig(workers=self.workers, unit_timeout_s=self.unit_timeout_s, backend=self.backend,
                           ray_address=self.ray_address, start_method="fork", worker_environment=DISPATCH_VARIABLES)

    def settings(self) -> dict[str, Any]:
        """Every field but the task, JSON-ready: a result's "config" (the task is recorded beside it)."""
        return {f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v
                for f in fields(self) if f.name != "task"}
