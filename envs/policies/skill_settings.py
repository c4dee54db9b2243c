"""The settings of the RiemannianFlow skill's execution, apart from the code that runs it, so that a command line can be
built (and checked) without loading torch or MuJoCo: the policy modes and lookahead, and the commanded stiffness
(`StiffnessSetting`). `EvaluationConfig` (envs.evaluation.config) holds them for an evaluation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from envs.errors import EnvError
from pihutil.bounds import STIFFNESS

if TYPE_CHECKING:
    from envs.policies.stiffness_schedule import StiffnessSchedule
    from rflow.skill_io import PoseSkill

MODES: tuple[str, ...] = ("closed-loop", "open-loop")
DEFAULT_LOOKAHEAD_S: float = 0.05
"""Closed-loop lookahead along the learned flow (tuned on the default scene, see envs/evaluation/evaluate.py)."""


STIFFNESS_KINDS: tuple[str, ...] = ("learned", "constant", "schedule")


@dataclass(frozen=True)
class StiffnessSetting:
    """Which translational stiffness a policy commands: "learned" (the skill's), "constant" (K I, N/m) or
    "schedule" (the scripted expert's schedule K(h), `envs.policies.stiffness_schedule`, at the measured pose's height h
    above the nominal hole's mouth: what the cell believes, never the true hole; the teacher a learned
    stiffness can at best reproduce)."""

    kind: str
    constant_n_m: float = 0.0
    schedule: StiffnessSchedule | None = None

    def __post_init__(self) -> None:
        if self.kind not in STIFFNESS_KINDS:
            raise EnvError(f"stiffness kind {self.kind!r} must be one of {', '.join(STIFFNESS_KINDS)}")
        if self.kind == "constant" and not STIFFNESS.contains(self.constant_n_m):
            raise EnvError(f"constant stiffness {self.constant_n_m!r} N/m must be {STIFFNESS.text()} (what the "
                           "controller commands)")
        if self.kind == "schedule" or self.schedule is not None:
            from envs.policies.stiffness_schedule import StiffnessSchedule  # imports MuJoCo: only when asked for

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
            from envs.policies.stiffness_schedule import StiffnessSchedule

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
        if not STIFFNESS.contains(k):
            raise EnvError(f"stiffness {text!r}: K must be {STIFFNESS.text()} (what the controller commands)")
        return cls("constant", k)

    def check_skill(self, skill: PoseSkill) -> None:
        """Raise EnvError when "learned" is asked of a skill without a stiffness model."""
        if self.kind == "learned" and not skill.has_stiffness:
            raise EnvError("stiffness 'learned' needs a skill trained with `pih train --stiffness ...`")
