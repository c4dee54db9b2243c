"""The demonstration file: N peg_tip pose trajectories of M samples sharing a goal (``.npz``).

Schema (all arrays, float64 unless noted):
    pos          (N, M, 3)  peg_tip positions, metres, world frame
    quat         (N, M, 4)  peg_tip orientations, unit quaternions (w, x, y, z), continuous in m
    dt           ()         sampling time, seconds (duration / (M - 1))
    goal_pos     (3,)       shared goal position; pos[n, -1] == goal_pos for every n
    goal_quat    (4,)       shared goal orientation; quat[n, -1] == goal_quat for every n
    shape        () str     hole/peg shape name
    clearance_m  ()         radial peg-hole clearance, metres
    config_json  () str     JSON with the configuration that produced the file (free-form)
Optional:
    residual_pos_m   (N,)   |measured settled position - goal| before snapping to the goal, metres
    residual_rot_deg (N,)   angle between measured settled orientation and goal, degrees
    stiffness    (N, M, 3, 3) translational stiffness the demonstration used, N/m, world frame: symmetric
                            (to 1e-9 relative), positive definite and finite at every sample, and
                            stiffness[n, -1] == goal_stiffness for every n (to 1e-9 relative)
    goal_stiffness (3, 3)   the shared goal stiffness; present exactly when ``stiffness`` is
    control_*               what the robot did at the control rate while each demo was recorded (`ControlSignals`;
                            K samples, k control_dt apart from the demo's start, K = duration / control_dt + 1):
      control_dt            ()             the control period, s (0.01)
      control_joint_pos     (N, K, 7)      arm joint positions, rad
      control_joint_vel     (N, K, 7)      arm joint velocities, rad/s
      control_wrist_wrench  (N, K, 6)      the wrist F/T sensor's reading [N; N m], sensor frame, tool load removed
      control_action_pos    (N, K, 3)      the tcp position commanded after sample k (the last repeats), m
      control_action_quat   (N, K, 4)      the tcp orientation commanded after sample k (w, x, y, z)
      control_action_stiffness (N, K, 3, 3) the translational stiffness commanded after sample k, N/m
      control_action_rot_stiffness (N, K) the rotational stiffness commanded after sample k, N m/rad
                            (all together or none: a file of before them, or of demos imported or made noisy,
                            has none)
    ends_apart   () bool    the demos end apart, as recorded (real demonstrations rarely end in one pose): then
                            goal_pos / goal_quat are the mean of the last samples (position mean, quaternion mean),
                            each demo's end lies within END_SPREAD_M / END_SPREAD_DEG of it, and ``residual_pos_m``
                            / ``residual_rot_deg`` hold each end's distance from it. `pih train` learns such demos
                            each relative to its own end (`anchored_at_goal`). Absent: False.

Files are written by envs.io.owned_output.save_npz (atomically, with pih's marker array "pih") and read with
``allow_pickle=False``.
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.io.npz import open_npz
from envs.io.owned_output import save_npz, strict_json
from envs.poses import quat_angle_rad
from pihutil.bounds import SAMPLE_PERIOD_S

FloatArray = npt.NDArray[np.float64]

REQUIRED_KEYS: tuple[str, ...] = ("pos", "quat", "dt", "goal_pos", "goal_quat", "shape", "clearance_m",
                                  "config_json")
OPTIONAL_KEYS: tuple[str, ...] = ("residual_pos_m", "residual_rot_deg", "stiffness", "goal_stiffness")
CONTROL_PREFIX = "control_"

#: A demo "ends at the goal" when its last sample is this close to the stored goal.
GOAL_TOL_M: float = 1e-6
GOAL_TOL_RAD: float = 1e-6
#: Largest |norm - 1| of a stored quaternion.
UNIT_TOL: float = 1e-6
#: Largest |K - K^T| and |K_end - K_goal| of a stored stiffness, relative to max |K|.
STIFFNESS_REL_TOL: float = 1e-9
#: Demos that end apart (``ends_apart``) must end this close to their mean goal (a larger spread is a mistake,
#: e.g. demos of two different holes).
END_SPREAD_M: float = 0.02
END_SPREAD_DEG: float = 20.0
#: ... and the stored goal must be their mean end to this tolerance.
MEAN_GOAL_TOL_M: float = 1e-9
MEAN_GOAL_TOL_RAD: float = 1e-9


@dataclass(frozen=True)
class ControlSignals:
    """What the robot did at the control rate while the demos were recorded (the module docstring's control_*).

    Attributes:
        dt: the control period, s.
        joint_pos, joint_vel: (N, K, 7) arm joint positions (rad) and velocities (rad/s).
        wrist_wrench: (N, K, 6) the wrist sensor's reading [N; N m] (sensor frame, tool load removed).
        action_pos, action_quat: (N, K, 3), (N, K, 4) the tcp pose commanded after each sample (the last repeats).
        action_stiffness: (N, K, 3, 3) the translational stiffness commanded after each sample, N/m.
        action_rot_stiffness: (N, K) the rotational stiffness commanded after each sample, N m/rad.
    """

    dt: float
    joint_pos: FloatArray
    joint_vel: FloatArray
    wrist_wrench: FloatArray
    action_pos: FloatArray
    action_quat: FloatArray
    action_stiffness: FloatArray
    action_rot_stiffness: FloatArray

    ARRAYS: ClassVar[tuple[tuple[str, tuple[int, ...]], ...]] = (
        ("joint_pos", (7,)), ("joint_vel", (7,)), ("wrist_wrench", (6,)), ("action_pos", (3,)),
        ("action_quat", (4,)), ("action_stiffness", (3, 3)), ("action_rot_stiffness", ()))

    @property
    def num_samples(self) -> int:
        """K, the control samples per demo."""
        return int(np.shape(self.joint_pos)[1])

    def validate(self, num_demos: int, source: str) -> None:
        """Check the shapes (N, K, ...) and finiteness.

        Raises:
            EnvError: one line naming ``source`` and the array.
        """
        if not (np.isfinite(self.dt) and self.dt > 0.0):
            raise EnvError(f"{source}: 'control_dt' must be a finite positive number of seconds, got {self.dt}")
        count = np.shape(self.joint_pos)[1] if np.ndim(self.joint_pos) >= 2 else 0
        for name, tail in self.ARRAYS:
            arr = np.asarray(getattr(self, name))
            if arr.shape != (num_demos, count, *tail) or count < 2:
                raise EnvError(f"{source}: '{CONTROL_PREFIX}{name}' must have shape {(num_demos, count, *tail)} "
                               f"(N demos, K >= 2 control samples), got {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise EnvError(f"{source}: '{CONTROL_PREFIX}{name}' contains NaN or inf")


@dataclass(frozen=True)
class DemoSet:
    """Demonstrations in memory; see the module docstring for the meaning of each field."""

    pos: FloatArray
    quat: FloatArray
    dt: float
    goal_pos: FloatArray
    goal_quat: FloatArray
    shape: str
    clearance_m: float
    config: dict[str, Any] = field(default_factory=dict)
    residual_pos_m: FloatArray | None = None
    residual_rot_deg: FloatArray | None = None
    stiffness: FloatArray | None = None
    goal_stiffness: FloatArray | None = None
    ends_apart: bool = False
    control: ControlSignals | None = None

    @property
    def num_demos(self) -> int:
        """N, the number of demonstrations."""
        return int(self.pos.shape[0])

    @property
    def num_samples(self) -> int:
        """M, the number of samples per demonstration."""
        return int(self.pos.shape[1])

    @property
    def duration_s(self) -> float:
        """Duration of every demonstration, (M - 1) dt."""
        return float(self.dt * (self.num_samples - 1))


def validate_demos(demos: DemoSet, source: str = "demos") -> None:
    """Check shapes, finiteness, unit quaternions and the shared goal of a DemoSet.

    Raises:
        EnvError: one line naming ``source`` and the first problem found.
    """
    pos, quat = np.asarray(demos.pos), np.asarray(demos.quat)
    if pos.ndim != 3 or pos.shape[2] != 3:
        raise EnvError(f"{source}: 'pos' must have shape (N, M, 3), got {pos.shape}")
    if quat.shape != pos.shape[:2] + (4,):
        raise EnvError(f"{source}: 'quat' must have shape {pos.shape[:2] + (4,)} to match 'pos', got {quat.shape}")
    if pos.shape[0] < 1 or pos.shape[1] < 2:
        raise EnvError(f"{source}: need at least 1 demo of at least 2 samples, got {pos.shape[:2]}")
    goal_pos, goal_quat = np.asarray(demos.goal_pos), np.asarray(demos.goal_quat)
    if goal_pos.shape != (3,):
        raise EnvError(f"{source}: 'goal_pos' must have shape (3,), got {goal_pos.shape}")
    if goal_quat.shape != (4,):
        raise EnvError(f"{source}: 'goal_quat' must have shape (4,), got {goal_quat.shape}")
    for name, arr in (("pos", pos), ("quat", quat), ("goal_pos", goal_pos), ("goal_quat", goal_quat)):
        if not np.all(np.isfinite(arr)):
            bad = np.argwhere(~np.isfinite(arr))[0].tolist()
            raise EnvError(f"{source}: '{name}' contains NaN or inf (first at index {bad})")
    if not SAMPLE_PERIOD_S.contains(float(demos.dt)):
        raise EnvError(f"{source}: 'dt' must be a number of seconds {SAMPLE_PERIOD_S.text()}, got {demos.dt}")
    if not (np.isfinite(demos.clearance_m) and demos.clearance_m >= 0.0):
        raise EnvError(f"{source}: 'clearance_m' must be finite and >= 0, got {demos.clearance_m}")
    if not demos.shape:
        raise EnvError(f"{source}: 'shape' is empty")
    norms = np.linalg.norm(quat, axis=-1)
    worst = np.unravel_index(np.argmax(np.abs(norms - 1.0)), norms.shape)
    if abs(norms[worst] - 1.0) > UNIT_TOL:
        raise EnvError(f"{source}: 'quat' is not unit at demo {worst[0]}, sample {worst[1]} "
                       f"(norm {norms[worst]:.6g})")
    if abs(float(np.linalg.norm(goal_quat, axis=-1)) - 1.0) > UNIT_TOL:
        raise EnvError(f"{source}: 'goal_quat' {goal_quat.tolist()} is not unit")
    pos_err = np.linalg.norm(pos[:, -1] - goal_pos, axis=-1)
    rot_err = quat_angle_rad(quat[:, -1], goal_quat)
    if demos.ends_apart:
        _check_ends_apart(demos, pos_err, rot_err, source)
    else:
        for n in range(pos.shape[0]):
            if pos_err[n] > GOAL_TOL_M or rot_err[n] > GOAL_TOL_RAD:
                raise EnvError(f"{source}: demo {n} does not end at the goal (final sample off by "
                               f"{pos_err[n] * 1e3:.3g} mm, {np.rad2deg(rot_err[n]):.3g} deg; demos that end "
                               f"apart are marked ends_apart)")
    for name, arr in (("residual_pos_m", demos.residual_pos_m), ("residual_rot_deg", demos.residual_rot_deg)):
        if arr is not None and np.asarray(arr).shape != (pos.shape[0],):
            raise EnvError(f"{source}: '{name}' must have shape ({pos.shape[0]},), got {np.asarray(arr).shape}")
    validate_stiffness(demos, source)
    if demos.control is not None:
        demos.control.validate(pos.shape[0], source)


def _check_ends_apart(demos: DemoSet, pos_err: FloatArray, rot_err: FloatArray, source: str) -> None:
    """Demos that end apart: the goal is their mean end and no end lies farther than END_SPREAD_M / _DEG from it."""
    from envs.poses import mean_quat

    pos, quat = np.asarray(demos.pos), np.asarray(demos.quat)
    mean_pos = np.mean(pos[:, -1], axis=0)
    if float(np.linalg.norm(mean_pos - np.asarray(demos.goal_pos), axis=-1)) > MEAN_GOAL_TOL_M or \
            float(quat_angle_rad(mean_quat(quat[:, -1]), demos.goal_quat)) > MEAN_GOAL_TOL_RAD:
        raise EnvError(f"{source}: the demos end apart but the goal is not the mean of their ends")
    worst = int(np.argmax(pos_err / END_SPREAD_M + np.rad2deg(rot_err) / END_SPREAD_DEG))
    if pos_err[worst] > END_SPREAD_M or np.rad2deg(rot_err[worst]) > END_SPREAD_DEG:
        raise EnvError(f"{source}: demo {worst} ends {pos_err[worst] * 1e3:.3g} mm, {np.rad2deg(rot_err[worst]):.3g} "
                       f"deg from the demos' mean goal (at most {END_SPREAD_M * 1e3:g} mm, {END_SPREAD_DEG:g} deg: "
                       f"demos of one skill)")
    if demos.stiffness is not None:
        raise EnvError(f"{source}: demos that end apart carry no stiffness")


def anchored_at_goal(demos: DemoSet) -> tuple[FloatArray, FloatArray]:
    """Each demo moved rigidly so that it ends at the goal: the rigid motion T_n = (R_n, t_n) that takes the demo's
    end pose (p_N, q_N) to the goal (g_p, g_q), applied to every sample,

        R_n = R(g_q conj(q_N)),    p' = g_p + R_n (p - p_N),    q' = g_q conj(q_N) q,

    so each demo is what it was relative to its own end (its own target: where the part sat, how the peg sat in the
    hand), now relative to the goal, as a demonstration recorded at the goal would be. The shape of each demo is kept
    (unlike `envs.demos.importing.snap_to_goal`, which bends its last part onto the goal). Demos that end at the goal
    are returned as they are.
    """
    from numerics.quaternion import quat_conj, quat_mul, rotate

    pos, quat = np.asarray(demos.pos, dtype=np.float64), np.asarray(demos.quat, dtype=np.float64)
    if not demos.ends_apart:
        return pos, quat
    goal_pos, goal_quat = np.asarray(demos.goal_pos, dtype=np.float64), np.asarray(demos.goal_quat, dtype=np.float64)
    new_pos, new_quat = np.empty_like(pos), np.empty_like(quat)
    for n in range(pos.shape[0]):
        turn = quat_mul(goal_quat, quat_conj(quat[n, -1]))  # g_q conj(q_N)
        new_pos[n] = goal_pos + rotate(np.broadcast_to(turn, (pos.shape[1], 4)), pos[n] - pos[n, -1])
        new_quat[n] = quat_mul(turn[None], quat[n])
    new_quat /= np.linalg.norm(new_quat, axis=-1, keepdims=True)
    new_pos[:, -1] = goal_pos
    new_quat[:, -1] = goal_quat
    return new_pos, new_quat


def validate_stiffness(demos: DemoSet, source: str = "demos") -> None:
    """Check the optional stiffness of a DemoSet (module docstring); nothing to check when absent.

    Raises:
        EnvError: one line naming ``source`` and the first problem found: only one of the two arrays,
            wrong shapes, NaN, an asymmetric or not positive definite matrix, a demo not ending at the goal.
    """
    if demos.stiffness is None and demos.goal_stiffness is None:
        return
    if demos.stiffness is None or demos.goal_stiffness is None:
        missing = "stiffness" if demos.stiffness is None else "goal_stiffness"
        raise EnvError(f"{source}: has {'goal_stiffness' if missing == 'stiffness' else 'stiffness'} but no "
                       f"'{missing}' (they come together)")
    k, goal = np.asarray(demos.stiffness), np.asarray(demos.goal_stiffness)
    want = np.asarray(demos.pos).shape[:2] + (3, 3)
    if k.shape != want:
        raise EnvError(f"{source}: 'stiffness' must have shape {want} to match 'pos', got {k.shape}")
    if goal.shape != (3, 3):
        raise EnvError(f"{source}: 'goal_stiffness' must have shape (3, 3), got {goal.shape}")
    for name, arr in (("stiffness", k), ("goal_stiffness", goal)):
        if not np.all(np.isfinite(arr)):
            bad = np.argwhere(~np.isfinite(arr))[0].tolist()
            raise EnvError(f"{source}: '{name}' contains NaN or inf (first at index {bad})")
        scale = np.maximum(np.abs(arr).max(axis=(-2, -1)), 1e-300)
        asym = np.abs(arr - np.swapaxes(arr, -1, -2)).max(axis=(-2, -1)) / scale
        if np.any(asym > STIFFNESS_REL_TOL):
            where = np.unravel_index(np.argmax(asym), asym.shape)
            at = f" at demo {where[0]}, sample {where[1]}" if asym.ndim else ""
            raise EnvError(f"{source}: '{name}' is not symmetric{at} (max |K - K^T| / max |K| = {asym.max():.3g})")
        low = np.linalg.eigvalsh(0.5 * (arr + np.swapaxes(arr, -1, -2)))[..., 0]  # blas-ok: a validity check, no record
        if np.any(low <= 0.0):
            where = np.unravel_index(np.argmin(low), low.shape)
            at = f" at demo {where[0]}, sample {where[1]}" if low.ndim else ""
            raise EnvError(f"{source}: '{name}' is not positive definite{at} (smallest eigenvalue "
                           f"{low.min():.3g} N/m)")
    end_err = np.abs(k[:, -1] - goal).max(axis=(-2, -1)) / np.abs(goal).max()
    worst = int(np.argmax(end_err))
    if end_err[worst] > STIFFNESS_REL_TOL:
        raise EnvError(f"{source}: demo {worst} does not end at the goal stiffness (final sample off by "
                       f"{end_err[worst]:.3g} relative to max |K_goal|)")


def save_demos(path: str | os.PathLike[str], demos: DemoSet) -> Path:
    """Validate and write ``demos`` to ``path`` (envs.io.owned_output.save_npz: atomic, marked).

    Returns:
        the written path.

    Raises:
        EnvError: invalid demos, or the folder cannot be written.
    """
    out = Path(path)
    validate_demos(demos, source=str(out))
    arrays: dict[str, Any] = {
        "pos": np.asarray(demos.pos, dtype=np.float64),
        "quat": np.asarray(demos.quat, dtype=np.float64),
        "dt": np.float64(demos.dt),
        "goal_pos": np.asarray(demos.goal_pos, dtype=np.float64),
        "goal_quat": np.asarray(demos.goal_quat, dtype=np.float64),
        "shape": np.str_(demos.shape),
        "clearance_m": np.float64(demos.clearance_m),
        "config_json": np.str_(json.dumps(strict_json(demos.config), sort_keys=True, allow_nan=False)),
    }
    if demos.residual_pos_m is not None:
        arrays["residual_pos_m"] = np.asarray(demos.residual_pos_m, dtype=np.float64)
    if demos.residual_rot_deg is not None:
        arrays["residual_rot_deg"] = np.asarray(demos.residual_rot_deg, dtype=np.float64)
    if demos.stiffness is not None:
        arrays["stiffness"] = np.asarray(demos.stiffness, dtype=np.float64)
        arrays["goal_stiffness"] = np.asarray(demos.goal_stiffness, dtype=np.float64)
    if demos.ends_apart:
        arrays["ends_apart"] = np.bool_(True)
    if demos.control is not None:
        arrays[f"{CONTROL_PREFIX}dt"] = np.float64(demos.control.dt)
        for name, _ in ControlSignals.ARRAYS:
            arrays[CONTROL_PREFIX + name] = np.asarray(getattr(demos.control, name), dtype=np.float64)
    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir():
        raise EnvError(f"cannot write demos to {out}: folder {folder} does not exist")
    return save_npz(out, arrays)


def _scalar(archive: Any, key: str, source: str, kind: type) -> Any:
    value = archive[key]
    if value.shape != ():
        raise EnvError(f"{source}: '{key}' must be a scalar, got shape {value.shape}")
    try:
        return kind(value.item())
    except (TypeError, ValueError):
        raise EnvError(f"{source}: '{key}' is not a {kind.__name__} (dtype {value.dtype})") from None


def _flag(archive: Any, key: str, source: str) -> bool:
    value = archive[key]
    if value.shape != () or value.dtype != np.bool_:
        raise EnvError(f"{source}: '{key}' must be a boolean scalar, got dtype {value.dtype} shape {value.shape}")
    return bool(value.item())


def load_demos(path: str | os.PathLike[str]) -> DemoSet:
    """Read and validate a demonstration file written by :func:`save_demos`.

    Raises:
        EnvError: missing file, not a readable .npz, missing keys, wrong shapes or types, NaN,
            non-unit quaternions, or demos that do not end at the stored goal.
    """
    src = str(path)
    if Path(path).is_dir():
        raise EnvError(f"demo file {src} is a folder, not a .npz file")
    if not Path(path).is_file():
        raise EnvError(f"demo file {src} not found")
    try:
        with open_npz(path) as archive:
            missing = [k for k in REQUIRED_KEYS if k not in archive.files]
            if missing:
                raise EnvError(f"{src}: missing keys {missing} (a demo file needs {list(REQUIRED_KEYS)})")
            arrays = {k: archive[k] for k in ("pos", "quat", "goal_pos", "goal_quat")}
            for key, arr in arrays.items():
                if not np.issubdtype(arr.dtype, np.number):
                    raise EnvError(f"{src}: '{key}' must be numeric, got dtype {arr.dtype}")
            dt = _scalar(archive, "dt", src, float)
            clearance_m = _scalar(archive, "clearance_m", src, float)
            shape = _scalar(archive, "shape", src, str)
            config_text = _scalar(archive, "config_json", src, str)
            optional = {k: np.asarray(archive[k], dtype=float) for k in OPTIONAL_KEYS if k in archive.files}
            ends_apart = "ends_apart" in archive.files and _flag(archive, "ends_apart", src)
            control = _control(archive, src)
    except EnvError:
        raise
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as err:
        raise EnvError(f"{src}: not a readable .npz demo file ({type(err).__name__}: {err})") from None
    try:
        config = json.loads(config_text)
    except json.JSONDecodeError as err:
        raise EnvError(f"{src}: 'config_json' is not valid JSON ({err})") from None
    if not isinstance(config, dict):
        raise EnvError(f"{src}: 'config_json' must hold a JSON object, got {type(config).__name__}")
    demos = DemoSet(
        pos=np.asarray(arrays["pos"], dtype=float),
        quat=np.asarray(arrays["quat"], dtype=float),
        dt=dt,
        goal_pos=np.asarray(arrays["goal_pos"], dtype=float),
        goal_quat=np.asarray(arrays["goal_quat"], dtype=float),
        shape=shape,
        clearance_m=clearance_m,
        config=config,
        residual_pos_m=optional.get("residual_pos_m"),
        residual_rot_deg=optional.get("residual_rot_deg"),
        stiffness=optional.get("stiffness"),
        goal_stiffness=optional.get("goal_stiffness"),
        ends_apart=bool(ends_apart),
        control=control,
    )
    validate_demos(demos, source=src)
    return demos


def _control(archive: Any, source: str) -> ControlSignals | None:
    """The control signals of an open demo file: all of them, or None when it has none.

    Raises:
        EnvError: some of them only, or one that is not numeric.
    """
    names = [f"{CONTROL_PREFIX}dt"] + [CONTROL_PREFIX + name for name, _ in ControlSignals.ARRAYS]
    present = [n for n in names if n in archive.files]
    if not present:
        return None
    if len(present) != len(names):
        raise EnvError(f"{source}: has {present[0]!r} but not {sorted(set(names) - set(present))} (the control "
                       "signals come together)")
    values = {}
    for name, _ in ControlSignals.ARRAYS:
        arr = archive[CONTROL_PREFIX + name]
        if not np.issubdtype(arr.dtype, np.number):
            raise EnvError(f"{source}: '{CONTROL_PREFIX}{name}' must be numeric, got dtype {arr.dtype}")
        values[name] = np.asarray(arr, dtype=float)
    return ControlSignals(dt=_scalar(archive, f"{CONTROL_PREFIX}dt", source, float), **values)
