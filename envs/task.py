"""The insertion task's parameters in one config, and the named presets.

A task is the scene's contact geometry (peg mount, clearance, chamfer, grasp force), the per-episode
perturbations (hole-pose error, grasp offset) and the force limit. The success criteria live in
envs.success.SuccessConfig (seated within 1 mm, inside the walls, at rest).

Presets:
  - "contact" (default): the peg grasped with 70 N, a 0.2 mm clearance, 1 mm chamfers, holes exactly as deep
    as the insertion (seated = on the hole's floor, as in Factory), the real hole off by up to 1 mm
    horizontally and 1 deg (yaw and tilt), a 40 N wrist force limit. The peg meets the walls in most
    episodes, so the impedance controller's compliance is part of the task. (NVIDIA Factory's peg task: 0.11 mm
    clearance, 1 mm hole-position noise, success within 1 mm of seated.)
  - "paper": the paper's toy setting: 1 mm clearance, no chamfer, 40 mm deep holes (the goal 30 mm down), the
    hole exactly where the demos ended.
  - "factory": Factory's tolerances on our 30 mm square peg: 0.1 mm clearance (the smallest we build), 1 mm
    hole error, a 3 mm grasp offset along the peg axis, 0.5 mm chamfers.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from envs.errors import EnvError
from envs.perturbation import PerturbationRanges
from envs.peg import FRANKA_GRASP_FORCE_N, PEG_MODES
from envs.sorter import check_chamfer, check_clearance, check_hole_depth

if TYPE_CHECKING:
    from envs.scene import SceneConfig

TASK_PEG_MODES: tuple[str, ...] = tuple(m for m in PEG_MODES if m != "free")


@dataclass(frozen=True)
class TaskConfig:
    """Parameters of the insertion task (defaults: the "contact" preset).

    Attributes:
        peg_mode: "grasped" (a free peg held by friction) or "welded" (rigidly in the hand).
        clearance_m: hole-minus-peg clearance, in [0.1 mm, 5 mm].
        chamfer_m: 45 deg chamfer at the hole mouths, in [0, 3 mm].
        grasp_force_n: force closing each finger (grasped peg).
        hole_depth_m: depth of the blind holes (the goal is 30 mm below the opening; equal: seated on the floor).
        perturbations: per-episode hole-pose error and grasp offset ranges.
        force_limit_n: an episode whose wrist force stays above this for 5 ms fails "force_limit" (inf: none).

    Raises:
        EnvError: an invalid field (one line naming it).
    """

    peg_mode: str = "grasped"
    clearance_m: float = 0.0002
    chamfer_m: float = 0.001
    grasp_force_n: float = FRANKA_GRASP_FORCE_N
    hole_depth_m: float = 0.03
    perturbations: PerturbationRanges = field(
        default_factory=lambda: PerturbationRanges(hole_error_m=0.001, hole_error_deg=1.0))
    force_limit_n: float = 40.0

    def __post_init__(self) -> None:
        if self.peg_mode not in TASK_PEG_MODES:
            raise EnvError(f"peg mount {self.peg_mode!r} must be one of {', '.join(TASK_PEG_MODES)}")
        check_clearance(self.clearance_m)
        check_chamfer(self.chamfer_m)
        check_hole_depth(self.hole_depth_m)
        if not (isinstance(self.force_limit_n, (int, float)) and not np.isnan(self.force_limit_n)
                and self.force_limit_n > 0.0):
            raise EnvError(f"force limit {self.force_limit_n!r} N must be > 0 (inf: no limit)")
        if not isinstance(self.perturbations, PerturbationRanges):
            raise EnvError(f"perturbations={self.perturbations!r} must be a PerturbationRanges")

    def scene_fields(self) -> dict[str, Any]:
        """The SceneConfig fields this task sets."""
        return {"peg_mode": self.peg_mode, "clearance_m": self.clearance_m, "chamfer_m": self.chamfer_m,
                "grasp_force_n": self.grasp_force_n, "hole_depth_m": self.hole_depth_m}

    def scene_config(self, **overrides: Any) -> SceneConfig:
        """A SceneConfig with this task's fields (plus ``overrides``, e.g. shape or goal)."""
        from envs.scene import SceneConfig  # loads MuJoCo; the task's values and checks do not need it

        return SceneConfig(**{**self.scene_fields(), **overrides})


PRESETS: Mapping[str, TaskConfig] = MappingProxyType({
    "contact": TaskConfig(),
    "paper": TaskConfig(clearance_m=0.001, chamfer_m=0.0, hole_depth_m=0.04, perturbations=PerturbationRanges()),
    "factory": TaskConfig(clearance_m=0.0001, chamfer_m=0.0005,
                          perturbations=PerturbationRanges(hole_error_m=0.001, hole_error_deg=0.0,
                                                           grasp_offset_m=0.003)),
})
DEFAULT_PRESET: str = "contact"


def preset(name: str) -> TaskConfig:
    """The named preset.

    Raises:
        EnvError: for an unknown name.
    """
    if name not in PRESETS:
        raise EnvError(f"preset {name!r} is unknown; choose one of {', '.join(PRESETS)}")
    return PRESETS[name]


def with_overrides(task: TaskConfig, *, peg_mode: str | None = None, clearance_m: float | None = None,
                   chamfer_m: float | None = None, grasp_force_n: float | None = None,
                   hole_error_m: float | None = None, hole_error_deg: float | None = None,
                   grasp_offset_m: float | None = None, force_limit_n: float | None = None) -> TaskConfig:
    """``task`` with the given (non-None) fields replaced, validated.

    Raises:
        EnvError: an invalid value (one line naming it).
    """
    ranges = task.perturbations
    ranges = PerturbationRanges(
        hole_error_m=ranges.hole_error_m if hole_error_m is None else hole_error_m,
        hole_error_deg=ranges.hole_error_deg if hole_error_deg is None else hole_error_deg,
        grasp_offset_m=ranges.grasp_offset_m if grasp_offset_m is None else grasp_offset_m,
    )
    scene = {k: v for k, v in (("peg_mode", peg_mode), ("clearance_m", clearance_m), ("chamfer_m", chamfer_m),
                               ("grasp_force_n", grasp_force_n), ("force_limit_n", force_limit_n)) if v is not None}
    return replace(task, perturbations=ranges, **scene)
