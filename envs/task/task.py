"""The insertion task: one frozen `Task`, saved and loaded as a TOML file; the presets are such files.

A task is everything that says what is asked of a skill or policy, apart from the skill or policy itself:
  - the scene: the peg and hole shape (None: the demos'), the peg mount and grasp force, the clearance, the chamfer
    and the hole depth;
  - the per-episode perturbations (hole-pose error, grasp offset; envs.task.perturbation);
  - the wrist force limit and the time limit of an episode;
  - the success tolerances (`SuccessConfig`: seated within 1 mm, inside the walls, at rest, held; envs.task.success);
  - where an evaluation's episodes start (`StartRange`: around the demos' starts).
Every field is checked here, once (``__post_init__`` of `Task` and of its nested configs); every command, the
Gymnasium environment (envs.gym_env), `evaluate`, `sweep`, the demos and the protocol take a Task, and every
checkpoint and result JSON records the one it ran (`Task.to_dict`, versioned).

Task file (TOML, `Task.to_toml` / `Task.from_toml`): ``version = 1``, the scalar fields as top-level keys and the
nested configs as tables ``[perturbations]``, ``[success]``, ``[start]``, ``[sensing]``; units are in the names (_m
metres, _deg degrees, _n newtons, _s seconds, _m_s metres per second; ``force_limit_n = inf`` is no limit). A key left out
keeps the default task's value (the "contact" preset); an unknown key, a value of the wrong type or out of range,
a missing file or malformed TOML is an EnvError of one line naming the file and the key.

Presets (package data, envs/task/presets/NAME.toml, `preset(name)`):
  - "contact" (default, equal to ``Task()``): the peg grasped with 70 N, a 0.2 mm clearance, 1 mm chamfers, holes
    exactly as deep as the insertion (seated = on the hole's floor, as in Factory), the real hole off by up to 1 mm
    horizontally and 1 deg (yaw and tilt), a 40 N wrist force limit. The peg meets the walls in most episodes, so
    the impedance controller's compliance is part of the task. (NVIDIA Factory's peg task: 0.11 mm clearance, 1 mm
    hole-position noise, success within 1 mm of seated.)
  - "paper": the paper's toy setting: 1 mm clearance, no chamfer, 40 mm deep holes (the goal 30 mm down), the hole
    exactly where the demos ended.
  - "factory": Factory's tolerances on our 30 mm square peg: 0.1 mm clearance (the smallest we build), 1 mm hole
    error, a 3 mm grasp offset along the peg axis, 0.5 mm chamfers.
  - "realistic": the contact task in an imperfect cell: every imperfection of envs.evaluation.sensitivity at once
    (friction per episode, in-hand pose and grasp offset, payload and joint-friction errors the controller does
    not know, a noisy, biased, filtered wrist sensor).
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

from envs.cell.pads import check_pad_stiffness
from envs.cell.peg import FRANKA_GRASP_FORCE_N, PEG_MODES, check_grasp_force
from envs.cell.shapes import check_shape
from envs.cell.sorter import check_chamfer, check_clearance, check_hole_depth
from envs.errors import EnvError
from envs.task.perturbation import PerturbationRanges
from envs.task.sensor_config import WristSensorConfig
from pihutil.bounds import (FLOOR_FORCE_N, PENETRATION_TOLERANCE_M, REST_SPEED_M_S, SEAT_TOLERANCE_M,
                            TIME_LIMIT_S)

if TYPE_CHECKING:
    from envs.cell.scene_config import SceneConfig

TASK_VERSION: int = 2
"""Version 2 replaced version 1's uniform joint friction (``joint_friction_min_nm``, ``joint_friction_max_nm``,
``joint_damping_nm_s``) by the Panda's identified friction, scaled (``joint_friction_scale_min``, ``_max``,
``joint_friction_model``); a version-1 record without joint friction reads as version 2."""
_VERSION_1_JOINT_FRICTION: tuple[str, ...] = ("joint_friction_min_nm", "joint_friction_max_nm", "joint_damping_nm_s")
"""Version of the task record (files, checkpoints, result JSON); a reader refuses another."""
TASK_PEG_MODES: tuple[str, ...] = tuple(m for m in PEG_MODES if m != "free")
AROUND: tuple[str, ...] = ("mean", "demo")
"""Centres of an evaluation's start perturbations: the mean demo start, or a random demo's start."""
PRESET_NAMES: tuple[str, ...] = ("contact", "paper", "factory", "realistic", "harsh")
DEFAULT_PRESET: str = "contact"


def check_number(name: str, value: Any, minimum: float = 0.0, *, strict: bool = False,
                 infinite: bool = False) -> float:
    """``value`` as a float if it is a number (not a bool), not NaN, finite unless ``infinite``, and >= ``minimum``
    (> with ``strict``).

    Raises:
        EnvError: otherwise, one line naming ``name``.
    """
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and not math.isnan(value)
    ok = ok and (math.isfinite(value) or (infinite and value == math.inf))
    if not (ok and (value > minimum if strict else value >= minimum)):
        bound = f"{'>' if strict else '>='} {minimum:g}"
        raise EnvError(f"{name}={value!r} must be a {'' if infinite else 'finite '}number {bound}"
                       + (" (inf: no limit)" if infinite else ""))
    return float(value)


def check_force_limit(value: Any, name: str = "force_limit_n") -> float:
    """A wrist force limit in N: > 0, inf for none. Raises EnvError naming ``name`` (the force limit)."""
    try:
        return check_number(name, value, strict=True, infinite=True)
    except EnvError as err:
        raise EnvError(f"force limit: {err}") from None


@dataclass(frozen=True)
class SuccessConfig:
    """Criteria of a seated insertion (defaults after NVIDIA Factory: within 1 mm of fully inserted; envs.task.success
    applies them to the peg's measured pose).

    Attributes:
        seat_tolerance_m: |depth - target depth| must be at most this.
        penetration_tolerance_m: largest wall penetration (envs.task.success) still counted as inside.
        max_speed_m_s: the peg must move slower than this (at rest).
        hold_s: how long (physics time) the criteria must hold without interruption.
        floor_force_n: > 0: the peg must also press on the hole's floor with at least this normal force (N), so a
            peg held a hair above the floor by the walls is not seated; 0: not required (the depth decides).

    The penetration tolerance is set from the contact model (tests/envs/task/test_success_tolerances.py): a peg pressed
    sideways into a wall with the force limit's 40 N penetrates it ~20 um (13 um at 27 N), so the tolerance is 1.5x
    that, 30 um: a peg the walls hold at any force an episode may hold counts as inside, and one off by more than
    the clearance (100 um a side at 0.2 mm) does not. (A 20 um tolerance is reached at ~42 N: near the limit the
    verdict would hang on the solver's softness.)
    """

    seat_tolerance_m: float = 0.001
    penetration_tolerance_m: float = 3e-5
    max_speed_m_s: float = 0.005
    hold_s: float = 0.2
    floor_force_n: float = 0.0

    def __post_init__(self) -> None:
        for name, bound in (("seat_tolerance_m", SEAT_TOLERANCE_M), ("penetration_tolerance_m", PENETRATION_TOLERANCE_M),
                            ("max_speed_m_s", REST_SPEED_M_S), ("hold_s", TIME_LIMIT_S), ("floor_force_n", FLOOR_FORCE_N)):
            check_number(name, getattr(self, name))
            if not bound.contains(getattr(self, name)) and not (name == "hold_s" and getattr(self, name) == 0):
                raise EnvError(f"success.{name}={getattr(self, name)!r} must be a number {bound.text()}")


MAX_POS_RANGE_M = 0.5
"""The largest start-position range (half-width of the box, m): beyond it no start is within the Panda's reach."""


@dataclass(frozen=True)
class StartRange:
    """Where an evaluation's episodes start (envs.evaluation.starts.sample_starts): a centre pose, the mean demo
    start ("mean") or a random demo's start ("demo"), its position moved uniformly in the box
    [-pos_range_m, pos_range_m]^3 and turned by a rotation vector drawn uniformly from the ball of radius
    rot_range_deg.

    Raises:
        EnvError: a negative or non-finite range, rot_range_deg >= 180, an unknown centre.
    """

    pos_range_m: float = 0.05
    rot_range_deg: float = 15.0
    around: str = "mean"

    def __post_init__(self) -> None:
        if not check_number("pos_range_m", self.pos_range_m) <= MAX_POS_RANGE_M:
            raise EnvError(f"pos_range_m={self.pos_range_m!r} must be <= {MAX_POS_RANGE_M} (the arm's reach)")
        if not check_number("rot_range_deg", self.rot_range_deg) < 180.0:
            raise EnvError(f"rot_range_deg={self.rot_range_deg!r} must be < 180")
        if self.around not in AROUND:
            raise EnvError(f"around={self.around!r} must be one of {', '.join(AROUND)}")


@dataclass(frozen=True)
class Task:
    """The insertion task (module docstring); the defaults are the "contact" preset.

    Attributes:
        shape: the peg and hole shape (envs.cell.shapes); None: the demos' (new demos: "square").
        peg_mode: "grasped" (a free peg held by friction) or "welded" (rigidly in the hand).
        clearance_m: hole-minus-peg clearance, in [0.1 mm, 5 mm].
        chamfer_m: 45 deg chamfer at the hole mouths, in [0, 3 mm].
        grasp_force_n: force closing each finger (grasped peg), in (0, 140] N.
        pad_stiffness_nm_rad: torsional stiffness of each rubber finger pad about the closing axis (envs.cell.pads),
            N m/rad; 0: rigid pads.
        hole_depth_m: depth of the blind holes (the goal is 30 mm below the opening; equal: seated on the floor).
        perturbations: per-episode hole-pose error and grasp offset ranges.
        force_limit_n: an episode whose wrist force stays above this for 5 ms fails "force_limit" (inf: none).
        time_limit_s: an episode without success ends, failed, after this much simulated time.
        success: the success tolerances.
        start: where an evaluation's episodes start, around the demos' starts.
        sensing: how the cell senses the wrench (envs.task.sensor_config: ideal, a wrist sensor or the joint torques).

    Raises:
        EnvError: an invalid field (one line naming it).
    """

    shape: str | None = None
    peg_mode: str = "grasped"
    clearance_m: float = 0.0002
    chamfer_m: float = 0.001
    grasp_force_n: float = FRANKA_GRASP_FORCE_N
    pad_stiffness_nm_rad: float = 0.0
    hole_depth_m: float = 0.03
    perturbations: PerturbationRanges = field(
        default_factory=lambda: PerturbationRanges(hole_error_m=0.001, hole_error_deg=1.0))
    force_limit_n: float = 40.0
    time_limit_s: float = 20.0
    success: SuccessConfig = field(default_factory=SuccessConfig)
    start: StartRange = field(default_factory=StartRange)
    sensing: WristSensorConfig = field(default_factory=WristSensorConfig)

    def __post_init__(self) -> None:
        if self.shape is not None:
            check_shape(self.shape)
        if self.peg_mode not in TASK_PEG_MODES:
            raise EnvError(f"peg_mode={self.peg_mode!r} must be one of {', '.join(TASK_PEG_MODES)}")
        check_clearance(self.clearance_m)
        check_chamfer(self.chamfer_m)
        check_grasp_force(self.grasp_force_n)
        check_pad_stiffness(self.pad_stiffness_nm_rad)
        check_hole_depth(self.hole_depth_m)
        check_force_limit(self.force_limit_n)
        if not TIME_LIMIT_S.contains(self.time_limit_s):
            raise EnvError(f"time_limit_s={self.time_limit_s!r} must be a number of simulated seconds "
                           f"{TIME_LIMIT_S.text()}")
        for name, kind in _NESTED.items():
            if not isinstance(getattr(self, name), kind):
                raise EnvError(f"{name}={getattr(self, name)!r} must be a {kind.__name__}")
        # a floor force no episode can press would fail every episode for a reason the task file caused
        if self.success.floor_force_n >= self.force_limit_n:
            raise EnvError(f"success.floor_force_n={self.success.floor_force_n!r} must be below force_limit_n="
                           f"{self.force_limit_n!r}: pressing the floor that hard ends the episode first")

    # ------------------------------------------------------------------------------------------- derived

    def scene_fields(self) -> dict[str, Any]:
        """The SceneConfig fields this task sets (the shape only when it is set)."""
        values = {name: getattr(self, name) for name in SCENE_FIELDS}
        return values if self.shape is None else {"shape": self.shape, **values}

    def scene_config(self, **overrides: Any) -> SceneConfig:
        """The scene of this task (its shape, when set, and its scene fields, `scene_fields`), plus ``overrides``.
        Built here, not in envs.cell, so that the cell knows nothing of tasks."""
        from envs.cell.scene_config import SceneConfig  # numba (small_linalg): not for a command's --help

        return SceneConfig(**{**self.scene_fields(), **overrides})

    def override(self, **values: Any) -> Task:
        """This task with single fields replaced, each named by its own name wherever it sits (``clearance_m``,
        ``hole_error_m`` of the perturbations, ``pos_range_m`` of the start range, ...); None leaves a field as it is
        (an option not given).

        Raises:
            EnvError: a name that is no field of the task, or an invalid value (one line naming it).
        """
        top: dict[str, Any] = {}
        nested: dict[str, dict[str, Any]] = {}
        for name, value in values.items():
            if value is None:
                continue
            if name not in _LEAVES:
                raise EnvError(f"{name!r} is not a task field (fields: {', '.join(sorted(_LEAVES))})")
            owner = _LEAVES[name]
            if owner is None:
                top[name] = value
            else:
                nested.setdefault(owner, {})[name] = value
        for owner, inner in nested.items():
            top[owner] = replace(getattr(self, owner), **inner)
        return replace(self, **top)

    def with_scene(self, scene: Any) -> Task:
        """This task with the shape and scene fields of ``scene`` (a SceneConfig): the task a scene built from the
        demos and this task actually ran."""
        return replace(self, shape=scene.shape, **{name: getattr(scene, name) for name in SCENE_FIELDS})

    # ------------------------------------------------------------------------------------------- records

    def to_dict(self) -> dict[str, Any]:
        """The versioned record: {"version": 1, scalar fields..., "perturbations": {...}, "success": {...},
        "start": {...}} (shape left out when None); what checkpoints and result JSON hold and a TOML file says."""
        values: dict[str, Any] = {"version": TASK_VERSION}
        for f in fields(self):
            value = getattr(self, f.name)
            if is_dataclass(value):
                values[f.name] = asdict(value)
            elif value is not None:
                values[f.name] = value
        return values

    @classmethod
    def from_dict(cls, values: Any, source: str = "task") -> Task:
        """The Task of a record (`to_dict`, a TOML file's table or JSON read back); a key left out keeps the default
        task's value. JSON's null for force_limit_n is inf (strict JSON has no infinity).

        Raises:
            EnvError: one line naming ``source`` and the key: not a table, no or another version, an unknown key, a
                value of the wrong type, an invalid value.
        """
        if not isinstance(values, Mapping):
            raise EnvError(f"{source}: a task must be a table of fields, got {type(values).__name__}")
        version = values.get("version")
        if version is None:
            raise EnvError(f"{source}: missing key 'version' (write version = {TASK_VERSION})")
        if isinstance(version, bool) or version not in (1, TASK_VERSION):
            raise EnvError(f"{source}: version = {version!r} is not one this pih reads ({TASK_VERSION})")
        if version == 1:
            values = _from_version_1(values, source)
        default = cls()
        changes: dict[str, Any] = {}
        for key, value in values.items():
            if key == "version":
                continue
            if key not in _TYPES:
                raise EnvError(f"{source}: unknown key {key!r} (keys: version, {', '.join(_TYPES)})")
            if key in _NESTED:
                if not isinstance(value, Mapping):
                    raise EnvError(f"{source}: {key} must be a table [{key}], got {value!r}")
                known = {f.name: f.type for f in fields(_NESTED[key])}
                unknown = sorted(set(value) - set(known))
                if unknown:
                    raise EnvError(f"{source}: unknown key '{key}.{unknown[0]}' (keys of [{key}]: {', '.join(known)})")
                changes[key] = {k: _typed(f"{key}.{k}", v, known[k], source) for k, v in value.items()}
            else:
                changes[key] = _typed(key, value, _TYPES[key], source)
        try:
            nested = {key: replace(getattr(default, key), **changes.pop(key)) for key in _NESTED if key in changes}
            return replace(default, **changes, **nested)
        except EnvError as err:
            raise EnvError(f"{source}: {err}") from None

    def to_toml(self) -> str:
        """The task as a TOML file (module docstring), readable by `from_toml`."""
        lines = ["# pih task file (envs/task/task.py): lengths in m, angles in deg, forces in N, times in s", ""]
        tables = []
        for key, value in self.to_dict().items():
            if isinstance(value, dict):
                tables += ["", f"[{key}]", *(f"{k} = {_toml_value(v)}" for k, v in value.items())]
            else:
                lines.append(f"{key} = {_toml_value(value)}")
        if self.shape is None:
            lines.insert(3, '# shape = "square"   (left out: the demos\' shape; new demos: square)')
        return "\n".join(lines + tables) + "\n"

    @classmethod
    def from_toml(cls, path: str | Path) -> Task:
        """The task of a TOML file (module docstring).

        Raises:
            EnvError: one line naming the file (and the key): missing or unreadable, not TOML, see `from_dict`.
        """
        source = f"task file {path}"
        try:
            text = Path(path).read_text(encoding="utf-8")
        except FileNotFoundError:
            raise EnvError(f"{source} not found") from None
        except (OSError, UnicodeDecodeError) as err:
            raise EnvError(f"{source}: cannot read it ({type(err).__name__})") from None
        return parse_toml(text, source)


_NESTED: dict[str, type] = {"perturbations": PerturbationRanges, "success": SuccessConfig, "start": StartRange,
                            "sensing": WristSensorConfig}
_TYPES: dict[str, Any] = {f.name: f.type for f in fields(Task)}
"""Each Task field's annotation (strings: the module uses postponed annotations)."""
_LEAVES: dict[str, str | None] = {
    **{name: None for name in _TYPES if name not in _NESTED},
    **{f.name: owner for owner, kind in _NESTED.items() for f in fields(kind)},
}
"""Every leaf field of a Task by its name -> the nested config holding it (None: the Task itself); the names are
unique, so a single field can be named without its table (`Task.override`, the CLI options)."""
SCENE_FIELDS: tuple[str, ...] = ("peg_mode", "clearance_m", "chamfer_m", "grasp_force_n", "pad_stiffness_nm_rad",
                                 "hole_depth_m")
"""The scene fields a task sets besides the shape (SceneConfig fields of the same names)."""


def _typed(key: str, value: Any, annotation: str, source: str) -> Any:
    """``value`` of a file or record checked against the field's type: "float" takes an int or a float (not a bool),
    "str" a string, "str | None" a string or null."""
    if annotation == "float":
        if value is None and key == "force_limit_n":
            return math.inf
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise EnvError(f"{source}: {key} = {value!r} must be a number")
    if isinstance(value, str) or (value is None and annotation == "str | None"):
        return value
    raise EnvError(f"{source}: {key} = {value!r} must be a string")


def _toml_value(value: Any) -> str:
    """A TOML literal of a number, string or bool (json's string escapes are TOML's)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, float):
        return repr(value)  # "inf" and exponents like 2e-05 are TOML floats
    return str(value)


def _from_version_1(values: Mapping[str, Any], source: str) -> dict[str, Any]:
    """A version-1 record as version 2: its joint friction fields dropped when they are all 0.

    Raises:
        EnvError: a version-1 joint friction that is set (version 2 has no uniform joint friction).
    """
    values = dict(values)
    perturbations = values.get("perturbations")
    if isinstance(perturbations, Mapping):
        perturbations = dict(perturbations)
        for key in _VERSION_1_JOINT_FRICTION:
            value = perturbations.pop(key, 0.0)
            if value != 0.0:
                raise EnvError(f"{source}: perturbations.{key} = {value!r} is version 1's uniform joint friction; "
                               f"version {TASK_VERSION} scales the Panda's identified friction instead "
                               f"(joint_friction_scale_min, joint_friction_scale_max, joint_friction_model)")
        values["perturbations"] = perturbations
    return values


def parse_toml(text: str, source: str) -> Task:
    """The task of a TOML text (module docstring).

    Raises:
        EnvError: one line naming ``source``: not TOML (with the line), see `Task.from_dict`.
    """
    try:
        values = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise EnvError(f"{source}: not valid TOML ({err})") from None
    return Task.from_dict(values, source)


@lru_cache(maxsize=None)
def preset(name: str) -> Task:
    """The named preset: the package's task file envs/task/presets/NAME.toml.

    Raises:
        EnvError: for an unknown name.
    """
    if name not in PRESET_NAMES:
        raise EnvError(f"preset {name!r} is unknown; choose one of {', '.join(PRESET_NAMES)}")
    text = resources.files("envs.task").joinpath("presets", f"{name}.toml").read_text(encoding="utf-8")
    return parse_toml(text, f"preset {name} (envs/task/presets/{name}.toml)")


def load_task(spec: str | Path) -> Task:
    """A preset by name (`PRESET_NAMES`) or a task file by path.

    Raises:
        EnvError: a missing or invalid file (one line naming it).
    """
    return preset(str(spec)) if str(spec) in PRESET_NAMES else Task.from_toml(spec)
