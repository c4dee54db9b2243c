"""One schema for the Gymnasium environment and the `Policy` interface: the Gym observation IS the policy's
`Observation` (envs.policies.interface), flattened for Gymnasium's Dict space, and the Gym action IS an `Action`,
normalised for RL libraries.

Observation. Every field of `Observation` is a key of the Gym observation under its own name; a `Pose` field ``f``
becomes the two keys ``f_pos`` (3,) m and ``f_quat`` (4,) (w, x, y, z), a scalar a (1,) array:

    time_s (1,) s, qpos (7,) rad, qvel (7,) rad/s, gripper_width_m (1,), tcp_pos, tcp_quat,
    wrist_wrench (6,) [N; N m], nominal_hole_pos, nominal_hole_quat, nominal_goal_pos, nominal_goal_quat

and ``privileged`` (`PrivilegedState`, only in an environment made with ``privileged=True``): privileged_hole_pos,
privileged_hole_quat, privileged_hole_axis (3,), privileged_goal_pos, privileged_goal_quat. Values are float64, the
policy's numbers exactly: `observation_dict` and `observation_from_dict` are inverse to the last bit, so a `Policy`
stepped through the Gym environment sees what `run_episode` hands it. (A flat Dict, not a nested one:
stable-baselines3's MultiInputPolicy takes no nested Dict.)

Action. A Box [-1, 1]^n (float32, stable-baselines3's convention) whose physical value u = c + a h (a clipped to
[-1, 1]; c, h the centre and half-width of ``low``..``high``) holds the `Action`'s fields, named in ACTION_FIELDS:

    pos_m (3,)                     Action.pose.pos: the commanded tcp position, m, world frame, within the box
                                   spanned by the start region and the nominal goal widened by ACTION_POS_MARGIN_M
    rotvec_rad (3,)                Action.pose.quat = exp(r) q_goal: a rotation vector relative to the NOMINAL goal's
                                   orientation (r = 0: the task's z-down orientation, far from the pi wrap-around),
                                   each component within +-(max start angle + ACTION_ANGLE_MARGIN_DEG)
    stiffness_n_m (3,)             Action.stiffness = diag(k_x, k_y, k_z), N/m, in STIFFNESS_RANGE_N_M   } with
    rotational_stiffness_nm_rad (1,) Action.rotational_stiffness k_r, N m/rad, in ROT_STIFFNESS_RANGE_NM_RAD } stiffness

Without stiffness the action commands none (the controller's default, `PolicyTask`'s stiffness). The range depends
on the nominal cell only (`ActionSchema.for_cell`: the nominal hole and goal a `PolicyTask` holds, the start region),
so a Gym-trained agent's actions mean the same to `pih evaluate --policy` (envs.gym.agent).

Info. The simulator's truth under named keys with their units (TRUTH_KEYS): peg_tip_pos, peg_tip_quat,
contact_force_n, insertion_depth_m, lateral_error_m, tilt_deg, yaw_error_deg, in_hole, inserted.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Mapping

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.policies.interface import Action, Observation, PrivilegedState
from envs.poses import Pose, StartRegion, nominal_start, quat_from_rotvec, quat_mul, rotate
from numerics.errors import shown
from numerics.small_linalg import norm

FloatArray = npt.NDArray[np.float64]

ENV_ID = "pih/PegInHole-v1"
"""The Gymnasium id (v0 had its own observation keys and no rotational stiffness in the action)."""
ACTION_POS_MARGIN_M: float = 0.05
ACTION_ANGLE_MARGIN_DEG: float = 25.0
STIFFNESS_RANGE_N_M: tuple[float, float] = (100.0, 3000.0)
ROT_STIFFNESS_RANGE_NM_RAD: tuple[float, float] = (2.0, 150.0)

POSE_PARTS: tuple[tuple[str, int], ...] = (("pos", 3), ("quat", 4))
"""A Pose field f of the observation is the keys f_pos (3,) and f_quat (4,)."""
OBSERVATION_SIZES: dict[str, int] = {"time_s": 1, "qpos": 7, "qvel": 7, "gripper_width_m": 1, "wrist_wrench": 6}
"""The sizes of the observation's fields that are not poses (qpos and qvel: the arm's 7 joints)."""
PRIVILEGED_SIZES: dict[str, int] = {"hole_axis": 3}
PRIVILEGED_PREFIX = "privileged_"

TRUTH_KEYS: tuple[str, ...] = ("peg_tip_pos", "peg_tip_quat", "contact_force_n", "insertion_depth_m",
                               "lateral_error_m", "tilt_deg", "yaw_error_deg", "in_hole", "inserted")
"""The simulator's truth in every ``info``: the peg's own pose, the contact force on it (N), its state against the TRUE
hole (depth below the opening m, distance from the axis m, tilt deg, yaw error deg; in_hole, inserted: bool)."""


def _is_pose(cls: type, name: str) -> bool:
    return {f.name: f.type for f in fields(cls)}[name] in ("Pose", Pose)


def _flat_keys(cls: type, prefix: str, sizes: dict[str, int]) -> dict[str, int]:
    out: dict[str, int] = {}
    for f in fields(cls):
        if f.name == "privileged":
            continue
        if _is_pose(cls, f.name):
            out.update({f"{prefix}{f.name}_{part}": n for part, n in POSE_PARTS})
        else:
            out[prefix + f.name] = sizes[f.name]
    return out


def observation_sizes(privileged: bool = False) -> dict[str, int]:
    """Key -> size of the Gym observation (module docstring): `Observation`'s fields, its poses split in two, and
    with ``privileged`` the `PrivilegedState`'s fields prefixed ``privileged_``."""
    out = _flat_keys(Observation, "", OBSERVATION_SIZES)
    if privileged:
        out.update(_flat_keys(PrivilegedState, PRIVILEGED_PREFIX, PRIVILEGED_SIZES))
    return out


def _values(obj: Any, cls: type, prefix: str) -> dict[str, FloatArray]:
    out: dict[str, FloatArray] = {}
    for f in fields(cls):
        if f.name == "privileged":
            continue
        value = getattr(obj, f.name)
        if _is_pose(cls, f.name):
            out[f"{prefix}{f.name}_pos"] = np.array(value.pos, dtype=np.float64)
            out[f"{prefix}{f.name}_quat"] = np.array(value.quat, dtype=np.float64)
        else:
            out[prefix + f.name] = np.array(value, dtype=np.float64).reshape(-1)
    return out


def observation_dict(observation: Observation, privileged: bool = False) -> dict[str, FloatArray]:
    """The Gym observation of a policy's `Observation` (module docstring): float64 copies of its numbers.

    Raises:
        EnvError: ``privileged`` asked for but the observation carries no privileged state.
    """
    out = _values(observation, Observation, "")
    if privileged:
        if observation.privileged is None:
            raise EnvError("a privileged observation was asked for, but the episode does not run privileged "
                           "(pih evaluate --privileged)")
        out.update(_values(observation.privileged, PrivilegedState, PRIVILEGED_PREFIX))
    return out


def _rebuild(cls: type, values: Mapping[str, Any], prefix: str, **extra: Any) -> Any:
    kwargs: dict[str, Any] = {}
    for f in fields(cls):
        if f.name == "privileged":
            continue
        if _is_pose(cls, f.name):
            kwargs[f.name] = Pose(pos=np.array(values[f"{prefix}{f.name}_pos"], dtype=np.float64),
                                  quat=np.array(values[f"{prefix}{f.name}_quat"], dtype=np.float64))
        elif f.type in ("float", float):
            kwargs[f.name] = float(np.asarray(values[prefix + f.name], dtype=np.float64).reshape(-1)[0])
        else:
            kwargs[f.name] = np.array(values[prefix + f.name], dtype=np.float64).reshape(-1)
    return cls(**kwargs, **extra)


def observation_from_dict(values: Mapping[str, Any]) -> Observation:
    """The policy's `Observation` of a Gym observation (the inverse of `observation_dict`; privileged state when its
    keys are there).

    Raises:
        EnvError: a key of the schema is missing.
    """
    missing = [k for k in observation_sizes() if k not in values]
    if missing:
        raise EnvError(f"not a {ENV_ID} observation: keys {missing} are missing")
    privileged = None
    if any(k.startswith(PRIVILEGED_PREFIX) for k in values):
        privileged = _rebuild(PrivilegedState, values, PRIVILEGED_PREFIX)
    return _rebuild(Observation, values, "", privileged=privileged)


def _as_command_vector(value: Any, what: str, size: int) -> FloatArray:
    """``value`` as a float64 vector (size,): real numbers (bool, integer or float dtype) in an array of ``size``
    entries whose other axes have length 1 (a policy's (1, size) output is taken; (2, 3) for 6 entries is not).

    Raises:
        EnvError: in one line naming ``what``: not numbers (strings, None, complex), another shape, NaN or inf.
    """
    import numbers

    try:
        raw = np.asarray(value)
    except (TypeError, ValueError) as err:  # e.g. a ragged sequence
        raise EnvError(f"{ENV_ID}: {what} is not an array of numbers ({err})") from None
    objects = raw.dtype.kind == "O"  # numbers numpy does not type (e.g. Decimal), or None, a dict, ...
    if objects and all(isinstance(v, numbers.Number) and not isinstance(v, complex) for v in raw.flat):
        raw = raw.astype(np.float64)
    if raw.dtype.kind not in "biuf":  # strings, complex numbers, None, other objects
        raise EnvError(f"{ENV_ID}: {what} must be an array of {size} real numbers, got {shown(value)}"
                       f"{'' if objects else f' (dtype {raw.dtype})'}")
    if raw.size != size or raw.ndim == 0 or max(raw.shape) != size:
        raise EnvError(f"{ENV_ID}: {what} has shape {raw.shape}, expected ({size},)")
    vector = np.asarray(value, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(vector)):
        raise EnvError(f"{ENV_ID}: {what} {vector.tolist()} contains NaN or inf")
    return vector


@dataclass(frozen=True)
class ActionSchema:
    """The Gym action's physical range and its meaning as an `Action` (module docstring).

    Attributes:
        low, high: the physical range of each entry (ACTION_FIELDS' layout).
        goal_quat: the nominal goal orientation (w, x, y, z) the rotation vector is relative to.
        stiffness: the action holds the stiffness (stiffness_n_m, rotational_stiffness_nm_rad).
    """

    low: tuple[float, ...]
    high: tuple[float, ...]
    goal_quat: tuple[float, ...]
    stiffness: bool = False

    @classmethod
    def for_cell(cls, nominal_hole: Pose, nominal_goal: Pose, start_region: StartRegion = StartRegion(),
                 stiffness: bool = False) -> ActionSchema:
        """The schema of a cell: the position box spans the start region around its nominal start (above the nominal
        hole, envs.poses.nominal_start) and the nominal goal, widened by ACTION_POS_MARGIN_M; the angles reach the
        region's largest start angle plus ACTION_ANGLE_MARGIN_DEG."""
        axis = rotate(np.asarray(nominal_hole.quat, dtype=np.float64), [0.0, 0.0, 1.0])
        centre = nominal_start(nominal_hole.pos, axis, nominal_goal.quat, start_region)
        half = np.asarray(start_region.pos_half_width_m, dtype=np.float64)
        goal = np.asarray(nominal_goal.pos, dtype=np.float64)
        low = np.minimum(centre.pos - half, goal) - ACTION_POS_MARGIN_M
        high = np.maximum(centre.pos + half, goal) + ACTION_POS_MARGIN_M
        angle = np.deg2rad(start_region.max_angle_deg + ACTION_ANGLE_MARGIN_DEG)
        low, high = np.concatenate([low, np.full(3, -angle)]), np.concatenate([high, np.full(3, angle)])
        if stiffness:
            low = np.concatenate([low, np.full(3, STIFFNESS_RANGE_N_M[0]), [ROT_STIFFNESS_RANGE_NM_RAD[0]]])
            high = np.concatenate([high, np.full(3, STIFFNESS_RANGE_N_M[1]), [ROT_STIFFNESS_RANGE_NM_RAD[1]]])
        return cls(tuple(low.tolist()), tuple(high.tolist()), tuple(float(v) for v in nominal_goal.quat),
                   bool(stiffness))

    @classmethod
    def for_task(cls, task: Any, stiffness: bool = False, start_region: StartRegion = StartRegion()) -> ActionSchema:
        """`for_cell` of a `PolicyTask` (what `pih evaluate --policy` hands a factory): its nominal hole and goal."""
        return cls.for_cell(task.nominal_hole, task.nominal_goal, start_region, stiffness)

    @property
    def parts(self) -> tuple[tuple[str, int], ...]:
        """(name, size) of the action's parts, in order."""
        parts = (("pos_m", 3), ("rotvec_rad", 3))
        return parts + ((("stiffness_n_m", 3), ("rotational_stiffness_nm_rad", 1)) if self.stiffness else ())

    @property
    def size(self) -> int:
        """n, the action's length."""
        return len(self.low)

    def _centre_half(self) -> tuple[FloatArray, FloatArray]:
        low, high = np.asarray(self.low), np.asarray(self.high)
        return 0.5 * (high + low), 0.5 * (high - low)

    def to_physical(self, action: npt.ArrayLike) -> FloatArray:
        """The physical command u = c + a h of a normalised action a, clipped to [-1, 1] first.

        Raises:
            EnvError: not real numbers, a wrong shape, NaN or inf.
        """
        a = _as_command_vector(action, "action", self.size)
        centre, half = self._centre_half()
        return centre + np.clip(a, -1.0, 1.0) * half

    def to_action(self, physical: npt.ArrayLike) -> np.ndarray:
        """The normalised action (float32) of a physical command u: a = (u - c) / h, not clipped.

        Raises:
            EnvError: not real numbers, a wrong shape, NaN or inf.
        """
        u = _as_command_vector(physical, "physical command", self.size)
        centre, half = self._centre_half()
        return ((u - centre) / half).astype(np.float32)

    def to_policy_action(self, action: npt.ArrayLike) -> Action:
        """The `Action` a normalised action commands (`to_physical`, then the fields of ACTION_FIELDS).

        Raises:
            EnvError: not real numbers, a wrong shape, NaN or inf.
        """
        u = self.to_physical(action)
        quat = quat_mul(quat_from_rotvec(u[3:6]), np.asarray(self.goal_quat))
        pose = Pose(pos=u[:3], quat=quat / norm(quat))
        if not self.stiffness:
            return Action(pose=pose)
        return Action(pose=pose, stiffness=np.diag(u[6:9]), rotational_stiffness=float(u[9]))


ACTION_FIELDS: tuple[tuple[str, int], ...] = ActionSchema((), (), (1.0, 0.0, 0.0, 0.0), True).parts
"""The names and sizes of the action's parts, the stiffness's last (module docstring)."""


def truth_info(state: Any) -> dict[str, Any]:
    """The simulator's truth of a `SimulatorState` under TRUTH_KEYS (module docstring)."""
    ins = state.insertion
    return {"peg_tip_pos": np.array(state.peg_tip.pos, dtype=np.float64),
            "peg_tip_quat": np.array(state.peg_tip.quat, dtype=np.float64),
            "contact_force_n": float(state.contact_force_n), "insertion_depth_m": float(ins.depth_m),
            "lateral_error_m": float(ins.lateral_m), "tilt_deg": float(ins.tilt_deg),
            "yaw_error_deg": float(ins.yaw_error_deg), "in_hole": bool(ins.in_hole), "inserted": bool(state.inserted)}
