"""The settings of skill execution, apart from the code that runs it, so that a command line can be built
(and checked) without loading torch or MuJoCo: the policy modes and lookahead, the commanded stiffness, and
`EvaluationConfig` (what `evaluate` runs; see envs/execution/evaluate.py for the starts and statistics).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from batch.errors import BatchError
from batch.config import BatchConfig
from envs.errors import EnvError
from envs.perturbation import PerturbationRanges
from envs.sorter import check_chamfer, check_clearance
from envs.task import DEFAULT_PRESET, PRESETS

if TYPE_CHECKING:
    from rflow.skill_io import PoseSkill

MODES: tuple[str, ...] = ("closed-loop", "open-loop")
DEFAULT_LOOKAHEAD_S: float = 0.05
"""Closed-loop lookahead along the learned flow (tuned on the default scene, see envs/execution/evaluate.py)."""


AROUND: tuple[str, ...] = ("mean", "demo")


STIFFNESS_KINDS: tuple[str, ...] = ("learned", "constant")


@dataclass(frozen=True)
class StiffnessSetting:
    """Which translational stiffness a policy commands: "learned" (the skill's) or "constant" (K I, N/m)."""

    kind: str
    constant_n_m: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in STIFFNESS_KINDS:
            raise EnvError(f"stiffness kind {self.kind!r} must be one of {', '.join(STIFFNESS_KINDS)}")
        if self.kind == "constant" and not (np.isfinite(self.constant_n_m) and self.constant_n_m > 0.0):
            raise EnvError(f"constant stiffness {self.constant_n_m!r} N/m must be a positive finite number")

    @classmethod
    def parse(cls, text: str) -> "StiffnessSetting":
        """"learned" or "constant:K" (K in N/m, > 0). Raises EnvError naming the text."""
        if text == "learned":
            return cls("learned")
        kind, _, value = str(text).partition(":")
        if kind != "constant" or not value:
            raise EnvError(f"stiffness {text!r} must be 'learned' or 'constant:K' with K in N/m")
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


@dataclass(frozen=True)
class EvaluationConfig:
    """What `evaluate` runs.

    Attributes:
        episodes: number of perturbed starts K.
        seed: seed of the start poses.
        mode: "closed-loop" (query the flow at the measured pose every step) or "open-loop" (generate
            the trajectory once, track it in time).
        pos_range_m: half-width of the position box around a demo start.
        rot_range_deg: radius of the orientation ball around a demo start.
        around: the centre of the perturbations, "mean" (mean demo start) or "demo" (a random demo start).
        lookahead_s: closed loop: flow time between the measured and the commanded pose.
        feedforward_gain: scale of the impedance velocity feed-forward (envs.execution.policy); 0 turns it off.
        speed: time scaling of the learned flow (the same path, speed times as fast), both modes.
        time_limit_s: an episode without success ends (fails) after this much simulated time.
        clearance_m: hole clearance of the scene (None: the demos').
        chamfer_m, peg_mode, grasp_force_n: the scene's chamfer, peg mount and grasp force (None: the demos').
        perturbations: per-episode hole-pose error and grasp offset ranges (envs.perturbation), drawn from a
            generator seeded with (seed, 1), apart from the start poses, so the starts do not depend on them.
        force_limit_n: wrist force limit of an episode (N; inf: none).
        shape: the scene's peg/hole shape (None: the demos'); must equal the demos' shape.
        hole_at_goal: place the target hole at the skill's goal pose (demos from another setup).
        workers: processes (1: in this process) or Ray actors.
        unit_timeout_s: wall-clock seconds one episode may take before its worker is killed and the episode
            recorded "wall_timeout" (None: no limit).
        backend: "process" (local processes) or "ray".
        ray_address: HOST:PORT of a Ray cluster (None: a local Ray instance on all cores).
        stiffness: the translational stiffness commanded ("learned": the skill's, "constant:K": K I in N/m;
            None: the controller's default), see envs.execution.policy.StiffnessSetting.
        contact_adaptation: closed loop: adapt to the contact near the hole (axial push, frame shift, rotational
            compliance; envs.execution.adaptation); False runs the bare learned flow (the ablation).
    """

    episodes: int = 100
    seed: int = 0
    mode: str = "closed-loop"
    pos_range_m: float = 0.05
    rot_range_deg: float = 15.0
    around: str = "mean"
    lookahead_s: float = DEFAULT_LOOKAHEAD_S
    feedforward_gain: float = 1.0
    speed: float = 1.0
    time_limit_s: float = 20.0
    clearance_m: float | None = None
    chamfer_m: float | None = None
    peg_mode: str | None = None
    grasp_force_n: float | None = None
    perturbations: PerturbationRanges = field(default_factory=lambda: PRESETS[DEFAULT_PRESET].perturbations)
    force_limit_n: float = PRESETS[DEFAULT_PRESET].force_limit_n
    shape: str | None = None
    hole_at_goal: bool = False
    workers: int = 1
    unit_timeout_s: float | None = 300.0
    backend: str = "process"
    ray_address: str | None = None
    stiffness: str | None = None
    contact_adaptation: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.episodes, int) or self.episodes < 1:
            raise EnvError(f"episodes={self.episodes!r} must be an integer >= 1")
        if self.stiffness is not None:
            StiffnessSetting.parse(self.stiffness)
        if self.mode not in MODES:
            raise EnvError(f"mode={self.mode!r} must be one of {', '.join(MODES)}")
        for name in ("pos_range_m", "rot_range_deg"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0.0):
                raise EnvError(f"{name}={value!r} must be a finite number >= 0")
        if self.around not in AROUND:
            raise EnvError(f"around={self.around!r} must be one of {', '.join(AROUND)}")
        if not self.rot_range_deg < 180.0:
            raise EnvError(f"rot_range_deg={self.rot_range_deg} must be < 180")
        for name in ("lookahead_s", "time_limit_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise EnvError(f"{name}={value!r} must be a positive number")
        if not (np.isfinite(self.speed) and self.speed > 0.0):
            raise EnvError(f"speed={self.speed!r} must be > 0")
        if not (np.isfinite(self.feedforward_gain) and self.feedforward_gain >= 0.0):
            raise EnvError(f"feedforward_gain={self.feedforward_gain!r} must be >= 0")
        if self.clearance_m is not None:
            check_clearance(self.clearance_m)
        if self.chamfer_m is not None:
            check_chamfer(self.chamfer_m)
        if not isinstance(self.perturbations, PerturbationRanges):
            raise EnvError(f"perturbations={self.perturbations!r} must be a PerturbationRanges")
        if not (isinstance(self.force_limit_n, (int, float)) and not math.isnan(self.force_limit_n)
                and self.force_limit_n > 0.0):
            raise EnvError(f"force_limit_n={self.force_limit_n!r} must be > 0 (inf: no limit)")
        if not isinstance(self.workers, int) or self.workers < 1:
            raise EnvError(f"workers={self.workers!r} must be an integer >= 1")
        try:
            self.batch_config()
        except BatchError as err:
            raise EnvError(str(err)) from None

    def batch_config(self) -> BatchConfig:
        """How the episodes run as a batch (workers, wall-time limit, backend)."""
        return BatchConfig(workers=self.workers, unit_timeout_s=self.unit_timeout_s, backend=self.backend,
                           ray_address=self.ray_address)


