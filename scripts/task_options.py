"""The task options shared by `pih demos`, `pih evaluate`, `pih sweep` and `pih run`, spelled the same everywhere.

    --preset NAME  --peg-mount grasped|welded  --clearance-mm C  --chamfer-mm C  --grasp-force-n F
    --hole-error-mm R  --hole-error-deg A  --grasp-offset-mm G  --force-limit-n F

Every option defaults to None ("not given"), so a command can tell an explicit choice from the preset's value.
"""

from __future__ import annotations

import argparse
from typing import Any

from envs.task import DEFAULT_PRESET, PRESETS, TaskConfig, preset, with_overrides
from scripts.options import number

SCENE_OPTIONS: tuple[str, ...] = ("peg_mount", "clearance_mm", "chamfer_mm", "grasp_force_n")
EPISODE_OPTIONS: tuple[str, ...] = ("hole_error_mm", "hole_error_deg", "grasp_offset_mm", "force_limit_n")


def add_task_arguments(parser: argparse.ArgumentParser, episode: bool = True) -> Any:
    """Add the task options (``episode``: also the per-episode perturbations and the force limit) in a group
    "task", returned so a command can add its own task options to it. The defaults shown are the default
    preset's; a command uses the given values over --preset's."""
    default = PRESETS[DEFAULT_PRESET]
    group = parser.add_argument_group("task (default: the values of --preset)")
    group.add_argument("--preset", choices=tuple(PRESETS),
                       help=f"task preset (default {DEFAULT_PRESET}: grasped peg, "
                            f"{default.clearance_m * 1e3:g} mm clearance, {default.chamfer_m * 1e3:g} mm chamfer, "
                            f"hole error {default.perturbations.hole_error_m * 1e3:g} mm / "
                            f"{default.perturbations.hole_error_deg:g} deg; paper: 1 mm, no chamfer, exact hole)")
    group.add_argument("--peg-mount", choices=("grasped", "welded"),
                       help="grasped: a free peg held by the fingers with the grasp force; welded: rigid "
                            f"(default {default.peg_mode})")
    group.add_argument("--clearance-mm", type=number(),
                       help=f"hole-minus-peg clearance, mm, 0.1-5 (default {default.clearance_m * 1e3:g})")
    group.add_argument("--chamfer-mm", type=number(),
                       help=f"45 deg chamfer at every hole mouth, mm, 0-3, 0 = none (default {default.chamfer_m * 1e3:g})")
    group.add_argument("--grasp-force-n", type=number(),
                       help=f"grasp force per finger, N (default {default.grasp_force_n:g}, the Franka hand's)")
    if episode:
        ranges = default.perturbations
        group.add_argument("--hole-error-mm", type=number(),
                           help="the real hole is moved by up to this much horizontally, mm (seeded, per episode; "
                                f"default {ranges.hole_error_m * 1e3:g})")
        group.add_argument("--hole-error-deg", type=number(),
                           help="and turned about its axis and tilted by up to this much, deg (seeded, per episode; "
                                f"default {ranges.hole_error_deg:g})")
        group.add_argument("--grasp-offset-mm", type=number(),
                           help="the peg sits in the grasp shifted along its axis by up to this much, mm (per "
                                f"episode; default {ranges.grasp_offset_m * 1e3:g})")
        group.add_argument("--force-limit-n", type=number(infinite=True),
                           help="an episode whose wrist force stays above this many N for 5 ms fails, inf = none "
                                f"(default {default.force_limit_n:g})")
    return group


def _mm(value: float | None) -> float | None:
    return None if value is None else value * 1e-3


def task_from_args(args: argparse.Namespace, base: TaskConfig | None = None) -> TaskConfig:
    """The TaskConfig of --preset (or ``base``, or the default preset) with the explicit options applied.

    Raises:
        EnvError: an unknown preset or an invalid value (negative, NaN, out of range), naming the option.
    """
    task = preset(args.preset) if getattr(args, "preset", None) else (base or PRESETS[DEFAULT_PRESET])
    return with_overrides(
        task,
        peg_mode=getattr(args, "peg_mount", None),
        clearance_m=_mm(getattr(args, "clearance_mm", None)),
        chamfer_m=_mm(getattr(args, "chamfer_mm", None)),
        grasp_force_n=getattr(args, "grasp_force_n", None),
        hole_error_m=_mm(getattr(args, "hole_error_mm", None)),
        hole_error_deg=getattr(args, "hole_error_deg", None),
        grasp_offset_m=_mm(getattr(args, "grasp_offset_mm", None)),
        force_limit_n=getattr(args, "force_limit_n", None),
    )


def scene_given(args: argparse.Namespace) -> dict[str, Any]:
    """The scene options given explicitly (or all of the preset's when --preset was given), as SceneConfig fields."""
    task = task_from_args(args)
    if getattr(args, "preset", None):
        return task.scene_fields()
    names = {"peg_mount": "peg_mode", "clearance_mm": "clearance_m", "chamfer_mm": "chamfer_m",
             "grasp_force_n": "grasp_force_n"}  # hole depth: only through --preset
    fields = task.scene_fields()
    return {names[o]: fields[names[o]] for o in SCENE_OPTIONS if getattr(args, o, None) is not None}
