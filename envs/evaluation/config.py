"""The settings of an evaluation, apart from the code that runs it, so that a command line can be built (and checked)
without loading torch or MuJoCo: `EvaluationConfig` (what `evaluate` runs; see envs/evaluation/starts.py and result.py
for the starts and statistics), on the skill's own settings (envs.policies.skill_settings: modes, lookahead, the
commanded stiffness).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

from batch.config import BatchConfig
from batch.errors import BatchError
from envs.errors import EnvError
from envs.policies.skill_settings import DEFAULT_LOOKAHEAD_S, MODES, StiffnessSetting
from envs.task.task import Task
from numerics.cpu_dispatch import DISPATCH_VARIABLES
from numerics.errors import shown
from pihutil.bounds import EPISODES, FEEDFORWARD_GAIN, LOOKAHEAD_S, SEED, SPEED

DEFAULT_LOCKSTEP = 8
"""Episodes a worker runs in lockstep by default (`EvaluationConfig.lockstep`)."""
MAX_LOCKSTEP = 256
"""At most this many (each slot holds an environment of its own, a few MB)."""


SCENE_FROM_TASK: tuple[str, ...] = ("peg_mode", "clearance_m", "chamfer_m", "grasp_force_n")
"""The scene fields an evaluation may take from its task instead of the demos' (`EvaluationConfig.scene_from_task`);
the hole depth and the goal are always the demos': a skill is evaluated at the depth it was taught."""


MAX_SPEED = SPEED.high
"""The largest time scaling of the learned flow an evaluation runs (10x the demonstrated speed; pihutil.bounds)."""


@dataclass(frozen=True)
class EvaluationConfig:
    """What `evaluate` runs: the task (envs.task.task.Task), how the skill executes it and how the episodes run.

    The scene is the demos' (the checkpoint's or demo file's recorded scene; envs.evaluation.evaluate.scene_config_for)
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
        feedforward_gain: scale of the impedance velocity feed-forward (envs.policies.flow_skill); 0 turns it off.
        speed: time scaling of the learned flow (the same path, speed times as fast), both modes.
        task: the task (envs.task.task.Task; default: the "contact" preset).
        scene_from_task: the task's scene fields (of SCENE_FROM_TASK) that replace the demos' (a task file or preset
            given: all of them; single options: those given).
        hole_at_goal: place the target hole at the skill's goal pose (demos from another setup).
        workers: processes (1: in this process) or Ray actors.
        unit_timeout_s: wall-clock seconds one episode may take before its worker is killed and the episode
            recorded "wall_timeout" (None: no limit).
        start_timeout_s: wall-clock seconds a worker process may take to start (import the libraries, build the
            scene; with a user's policy: import it and call its factory) before it is killed and counts as lost at
            start (`batch.BatchConfig.start_timeout_s`).
        backend: "process" (local processes) or "ray".
        ray_address: HOST:PORT of a Ray cluster (None: a local Ray instance on all cores).
        stiffness: the translational stiffness commanded ("learned": the skill's, "constant:K": K I in N/m,
            "schedule[:FREE/LATERAL/AXIAL]": the expert's schedule from the nominal hole;
            None: the controller's default), see envs.policies.skill_settings.StiffnessSetting.
        contact_adaptation: closed loop: adapt to the contact near the hole (axial push, frame shift, rotational
            compliance; envs.policies.adaptation); False runs the bare learned flow (the ablation).
        adaptation_off: parts of the adaptation turned off (envs.policies.adaptation.ADAPTATION_PARTS: "push",
            "frame", "compliance", "search", "seat"), the ablation of each.
        lockstep: episodes a worker runs side by side, one control period at a time for all
            (envs.rollout.lockstep); the records do not depend on it, only the wall time does.
        follow_observed_hole: run the skill in the frame of the hole the cell observes (the policy's nominal goal;
            with the task's ``hole_observation = "measured"`` a sensor's measurement of the true hole) instead of
            where the demonstrations' hole was (envs.policies.goal_frame).
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
    start_timeout_s: float = 600.0
    backend: str = "process"
    ray_address: str | None = None
    stiffness: str | None = None
    contact_adaptation: bool = True
    adaptation_off: tuple[str, ...] = ()
    lockstep: int = DEFAULT_LOCKSTEP
    follow_observed_hole: bool = False

    def __post_init__(self) -> None:
        if not EPISODES.contains(self.episodes):
            raise EnvError(f"episodes={shown(self.episodes)} must be an integer {EPISODES.text()}")
        if not SEED.contains(self.seed):
            raise EnvError(f"seed={shown(self.seed)} must be an integer {SEED.text()}")
        for name in ("hole_at_goal", "contact_adaptation"):
            if not isinstance(getattr(self, name), bool):
                raise EnvError(f"{name}={getattr(self, name)!r} must be True or False")
        if self.stiffness is not None:
            StiffnessSetting.parse(self.stiffness)
        if self.mode not in MODES:
            raise EnvError(f"mode={self.mode!r} must be one of {', '.join(MODES)}")
        for name, bound in (("lookahead_s", LOOKAHEAD_S), ("speed", SPEED), ("feedforward_gain", FEEDFORWARD_GAIN)):
            if not bound.contains(getattr(self, name)):
                raise EnvError(f"{name}={getattr(self, name)!r} must be a number {bound.text()}")
        if not isinstance(self.task, Task):
            raise EnvError(f"task={self.task!r} must be an envs.task.task.Task")
        if not isinstance(self.scene_from_task, (tuple, list)) or not all(isinstance(n, str) for n in self.scene_from_task):
            raise EnvError(f"scene_from_task={self.scene_from_task!r} must be a list of scene field names")
        object.__setattr__(self, "scene_from_task", tuple(self.scene_from_task))
        unknown = [name for name in self.scene_from_task if name not in SCENE_FROM_TASK]
        if unknown:
            raise EnvError(f"scene_from_task names {unknown}: only {', '.join(SCENE_FROM_TASK)} may replace the "
                           "demos' scene")
        if not isinstance(self.adaptation_off, (tuple, list)):
            raise EnvError(f"adaptation_off={self.adaptation_off!r} must be a list of parts")
        object.__setattr__(self, "adaptation_off", tuple(self.adaptation_off))
        if self.adaptation_off:
            from envs.policies.adaptation import adaptation_parts  # numba through envs.poses: only when asked for

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
        return BatchConfig(workers=self.workers, unit_timeout_s=self.unit_timeout_s,
                           start_timeout_s=self.start_timeout_s, backend=self.backend,
                           ray_address=self.ray_address, start_method="fork", worker_environment=DISPATCH_VARIABLES)

    def settings(self) -> dict[str, Any]:
        """Every field but the task, JSON-ready: a result's "config" (the task is recorded beside it)."""
        return {f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v
                for f in fields(self) if f.name != "task"}
