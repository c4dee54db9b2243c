"""The task options shared by `pih demos`, `evaluate`, `sweep`, `run`, `benchmark`, `compare --sequential` and
`task`, spelled the same everywhere:

    --task NAME|FILE.toml (--preset NAME: the same)  --peg-mount grasped|welded  --clearance-mm C  --chamfer-mm C
    --grasp-force-n F  --hole-error-mm R  --hole-error-deg A  --grasp-offset-mm G  --force-limit-n F
    and, where episodes run, --time-limit-s T  --pos-range-mm P  --rot-range-deg A  --around mean|demo

The task is --task's (a preset of envs/task/presets/ or a TOML file; default: the contact preset) with each single
option given replacing its field (envs.task.task.Task.override validates them, one line naming the field). Every option
defaults to None ("not given"), so a command can tell an explicit choice from the task's value.

Help: the single options are documented once, by `pih task --help` (``expanded``); every other command accepts them
all but shows --task and one line pointing there (COLLAPSED_HELP), so its --help stays short.
"""

from __future__ import annotations

import argparse
from typing import Any

from envs.errors import EnvError
from envs.task.perturbation import HOLE_OBSERVATIONS
from envs.task.task import AROUND, DEFAULT_PRESET, PRESET_NAMES, Task, load_task
from pihutil.bounds import TIME_LIMIT_S
from scripts.options import number

OPTION_FIELDS: dict[str, tuple[str, float | None]] = {
    "shape": ("shape", None),
    "peg_mount": ("peg_mode", None),
    "clearance_mm": ("clearance_m", 1e-3),
    "chamfer_mm": ("chamfer_m", 1e-3),
    "grasp_force_n": ("grasp_force_n", 1.0),
    "hole_error_mm": ("hole_error_m", 1e-3),
    "hole_error_deg": ("hole_error_deg", 1.0),
    "grasp_offset_mm": ("grasp_offset_m", 1e-3),
    "hole_observation": ("hole_observation", None),
    "hole_observation_error_mm": ("hole_observation_error_m", 1e-3),
    "hole_observation_error_deg": ("hole_observation_error_deg", 1.0),
    "hole_observation_tilt_deg": ("hole_observation_tilt_deg", 1.0),
    "force_limit_n": ("force_limit_n", 1.0),
    "time_limit_s": ("time_limit_s", 1.0),
    "pos_range_mm": ("pos_range_m", 1e-3),
    "rot_range_deg": ("rot_range_deg", 1.0),
    "around": ("around", None),
}
"""Option (argparse dest) -> the task field it sets (envs.task.task.Task.override) and the scale to the field's unit."""


COLLAPSED_HELP = ("single options (--clearance-mm, --time-limit-s, ...) replace fields of --task: `pih task --help` "
                  "lists them")
"""What a command's --help says of the single task options it accepts without listing them."""


def add_task_file_arguments(group: Any, expanded: bool = True) -> None:
    """--task and its alias --preset, into ``group`` (--preset listed only when ``expanded``)."""
    group.add_argument("--task", metavar="NAME|FILE.toml",
                       help=f"a preset ({', '.join(PRESET_NAMES)}) or a task file (default {DEFAULT_PRESET})")
    group.add_argument("--preset", choices=PRESET_NAMES,
                       help="the same as --task NAME" if expanded else argparse.SUPPRESS)


def _shown(text: str, expanded: bool) -> str:
    return text if expanded else argparse.SUPPRESS


def add_task_arguments(parser: argparse.ArgumentParser, episode: bool = True, expanded: bool = False) -> Any:
    """Add --task, --preset and the single task options (``episode``: also the per-episode perturbations and the
    force limit) in a group "task", returned so a command can add its own task options to it. The defaults shown are
    the default task's. Unless ``expanded`` (`pih task --help`), the single options are accepted but left out of the
    help, which says so in one line (COLLAPSED_HELP)."""
    default = Task()
    group = parser.add_argument_group("task", None if expanded else COLLAPSED_HELP)
    add_task_file_arguments(group, expanded)
    group.add_argument("--peg-mount", choices=("grasped", "welded"),
                       help=_shown("grasped: a free peg held by the fingers with the grasp force; welded: rigid "
                                   f"(default {default.peg_mode})", expanded))
    group.add_argument("--clearance-mm", type=number(), metavar="MM",
                       help=_shown(f"hole-minus-peg clearance, mm, 0.1-5 (default {default.clearance_m * 1e3:g})",
                                   expanded))
    group.add_argument("--chamfer-mm", type=number(), metavar="MM",
                       help=_shown("45 deg chamfer at every hole mouth, mm, 0-3, 0 = none (default "
                                   f"{default.chamfer_m * 1e3:g})", expanded))
    group.add_argument("--grasp-force-n", type=number(), metavar="N",
                       help=_shown(f"grasp force per finger, N (default {default.grasp_force_n:g}, the Franka hand's)",
                                   expanded))
    if episode:
        ranges = default.perturbations
        group.add_argument("--hole-error-mm", type=number(), metavar="MM",
                           help=_shown("the real hole is moved by up to this much horizontally, mm (seeded, per "
                                       f"episode; default {ranges.hole_error_m * 1e3:g})", expanded))
        group.add_argument("--hole-error-deg", type=number(), metavar="DEG",
                           help=_shown("and turned about its axis and tilted by up to this much, deg (seeded, per "
                                       f"episode; default {ranges.hole_error_deg:g})", expanded))
        group.add_argument("--grasp-offset-mm", type=number(), metavar="MM",
                           help=_shown("the peg sits in the grasp shifted along its axis by up to this much, mm (per "
                                       f"episode; default {ranges.grasp_offset_m * 1e3:g})", expanded))
        group.add_argument("--hole-observation", choices=HOLE_OBSERVATIONS,
                           help=_shown("where the cell believes the hole is (the policy's nominal hole): the nominal "
                                       "hole (nominal) or the true one measured by a sensor that sees the part "
                                       "(measured), each moved by the observation error below (default "
                                       f"{ranges.hole_observation})", expanded))
        group.add_argument("--hole-observation-error-mm", type=number(), metavar="MM",
                           help=_shown("that belief is off by up to this much horizontally, mm (seeded, per episode; "
                                       f"default {ranges.hole_observation_error_m * 1e3:g})", expanded))
        group.add_argument("--hole-observation-error-deg", type=number(), metavar="DEG",
                           help=_shown("and turned about the hole's axis by up to this much, deg (seeded, per "
                                       f"episode; default {ranges.hole_observation_error_deg:g})", expanded))
        group.add_argument("--hole-observation-tilt-deg", type=number(), metavar="DEG",
                           help=_shown("and tilted by up to this much, deg (seeded, per episode; default "
                                       f"{ranges.hole_observation_tilt_deg:g})", expanded))
        group.add_argument("--force-limit-n", type=number(infinite=True), metavar="N",
                           help=_shown("an episode whose wrist force stays above this many N for 5 ms fails, inf = "
                                       f"none (default {default.force_limit_n:g})", expanded))
    return group


def add_start_arguments(group: Any, expanded: bool = False) -> None:
    """The task's start range and time limit (--pos-range-mm, --rot-range-deg, --around, --time-limit-s), into
    ``group`` (a command's "starts and run"); listed in the help only when ``expanded`` (`add_task_arguments`)."""
    start, limit = Task().start, Task().time_limit_s
    group.add_argument("--pos-range-mm", type=number(minimum=0.0), metavar="MM",
                       help=_shown(f"the task's start position half-width, mm (default {start.pos_range_m * 1e3})",
                                   expanded))
    group.add_argument("--rot-range-deg", type=number(minimum=0.0, maximum=179.0), metavar="DEG",
                       help=_shown(f"the task's start orientation radius, deg (default {start.rot_range_deg})",
                                   expanded))
    group.add_argument("--around", choices=AROUND,
                       help=_shown("the task's centre of the start perturbations: the mean demo start or a random "
                                   f"demo's start (default {start.around})", expanded))
    group.add_argument("--time-limit-s", type=number(bound=TIME_LIMIT_S), metavar="S",
                       help=_shown(f"the task's time limit: simulated seconds per episode (default {limit})", expanded))


def task_from_args(args: argparse.Namespace, base: Task | None = None) -> Task:
    """The Task of --task (or --preset, or ``base``, or the default task) with the single options given applied.

    Raises:
        EnvError: --task and --preset both given, a missing or invalid task file, an invalid value (negative, out of
            range), one line naming the file or the field.
    """
    given, alias = getattr(args, "task", None), getattr(args, "preset", None)
    if given is not None and alias is not None:
        raise EnvError(f"--task {given} and --preset {alias}: give one (--preset NAME is --task NAME)")
    spec = given if given is not None else alias
    task = load_task(spec) if spec is not None else (base or Task())
    values, given = {}, {}
    for option, (name, scale) in OPTION_FIELDS.items():
        value = getattr(args, option, None)
        values[name] = value if value is None or scale is None else value * scale
        if value is not None:
            given[option] = (value, name)
    try:
        return task.override(**values)
    except EnvError:  # name the option and its value as given, when one alone is at fault
        for option, (value, name) in given.items():
            check_option_value(task, f"--{option.replace('_', '-')}", value, name, values[name])
        raise


def check_option_value(task: Task, option: str, given: Any, name: str, value: Any) -> None:
    """``task`` with its field ``name`` set to ``value`` (the option's ``given`` value in the field's unit) must be
    valid; the error names the option and the value as given, the field's own message after it.

    Raises:
        EnvError: "OPTION GIVEN: out of range (the field's message)".
    """
    try:
        task.override(**{name: value})
    except EnvError as err:
        raise EnvError(f"{option} {given:g}: out of range ({err})" if isinstance(given, float) else
                       f"{option} {given}: {err}") from None


def scene_from_task(args: argparse.Namespace) -> tuple[str, ...]:
    """The scene fields (envs.evaluation.config.SCENE_FROM_TASK) an evaluation takes from the task instead of the
    demos: all of them when --task or --preset names the task, else those whose option was given."""
    from envs.evaluation.config import SCENE_FROM_TASK

    if getattr(args, "task", None) is not None or getattr(args, "preset", None) is not None:
        return SCENE_FROM_TASK
    given = {name for option, (name, _) in OPTION_FIELDS.items() if getattr(args, option, None) is not None}
    return tuple(name for name in SCENE_FROM_TASK if name in given)
