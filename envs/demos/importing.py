"""Demonstrations recorded elsewhere (e.g. on a real Panda with the Franka hand), converted to peg_tip demos.

Input file (``.npz``, read with ``allow_pickle=False``), in one of two layouts:
    stacked   pos (N, M, 3), quat (N, M, 4)                     N demos of M samples each
    ragged    pos_0 (M_0, 3), quat_0 (M_0, 4), pos_1, quat_1 ...  demos of different lengths (indices 0..N-1)
  optional    dt () seconds between samples; shape () str; clearance_m () metres
Poses are those of a TOOL frame in the robot base frame (= the world frame of the testbed), positions in
metres, unit quaternions (w, x, y, z); a norm off 1 by at most QUAT_NORM_TOL is normalised.

Conversion. With T_F^T the tool frame in the flange frame (the "tool offset"; e.g. the Franka hand's TCP,
FRANKA_TCP: 103.4 mm along the flange z, rotated -45 deg about it) and T_F^P the testbed's nominal grasp
(the peg_tip frame in the flange frame, envs.cell.scene.nominal_flange_to_peg_tip):
    T_W^F = T_W^T (T_F^T)^-1,   T_W^P = T_W^F T_F^P,   i.e.   T_W^P = T_W^T T_T^P,  T_T^P = (T_F^T)^-1 T_F^P.

Common length. Every demo is first extended to the longest duration T = max_n (M_n - 1) dt by holding its
last pose (recorded speeds are kept; nothing is time-scaled), then resampled to M samples on [0, T]
(positions linearly, orientations by slerp; envs.poses.resample_trajectory), so dt' = T / (M - 1).

Common goal. g = (mean of the last positions, envs.poses.mean_quat of the last orientations). Demo n
jumps by |p_n(T) - g_p| and angle(q_n(T), g_q) from its last sample to the goal. A demo file needs every
jump within GOAL_TOL_M / GOAL_TOL_RAD (envs.demos.file); larger jumps are an error unless snapping is asked
for. Snapping blends each demo onto the goal over the last ``snap_fraction`` of its duration: with w(t) the
minimum-jerk ramp from 0 at t = (1 - snap_fraction) T to 1 at T,
    p'(t) = p(t) + w(t) (g_p - p(T)),   q'(t) = exp(w(t) Log(g_q conj(q(T)))) q(t),
so each demo ends exactly at the goal and moves by at most its jump.

Stiffness (optional, demos exported by `pih export`, envs.datasets). A translational stiffness K (N/m, world
frame) per sample is held and resampled with the poses, entrywise linearly (a convex combination of two
symmetric positive definite matrices is one). Its goal is the mean last stiffness K_g; demo n jumps by
max|K_n(T) - K_g| / max|K_g|, which counts as off the goal above STIFFNESS_REL_TOL, and snapping blends it
with the poses' ramp: K'(t) = K(t) + w(t) (K_g - K(T)).
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from envs.demos.file import GOAL_TOL_M, GOAL_TOL_RAD, STIFFNESS_REL_TOL, DemoSet
from envs.errors import EnvError
from envs.io.npz import open_npz
from envs.poses import QUAT_NORM_TOL, Pose, make_continuous, mean_quat, minimum_jerk, resample_trajectory
from numerics.quaternion import quat_angle_rad, quat_conj, quat_from_rotvec, quat_mul, quat_to_rotvec, rotate
from numerics.small_linalg import norm
from pihutil.bounds import SAMPLE_PERIOD_S, TOOL_OFFSET_M

FloatArray = npt.NDArray[np.float64]

#: The Franka hand's TCP in the flange frame (Franka's default F_T_EE): 103.4 mm along z, -45 deg about z.
FRANKA_TCP: Pose = Pose(pos=np.array([0.0, 0.0, 0.1034]),
                        quat=np.array([np.cos(-np.pi / 8.0), 0.0, 0.0, np.sin(-np.pi / 8.0)]))
#: Named tool offsets accepted by :func:`parse_tool_offset`.
TOOL_OFFSETS: dict[str, Pose] = {"franka-tcp": FRANKA_TCP, "flange": Pose(np.zeros(3), np.array([1.0, 0, 0, 0]))}
#: Largest | |q| - 1 | of a tool-offset quaternion (9 significant digits, e.g. 0.923879533,0,0,-0.382683432).
TOOL_QUAT_UNIT_TOL: float = 1e-6


@dataclass(frozen=True)
class RecordedDemos:
    """Tool-frame demos as read from an import file (see the module docstring).

    Attributes:
        pos: one (M_n, 3) array per demo, metres.
        quat: one (M_n, 4) array per demo, unit quaternions (w, x, y, z), normalised.
        dt: sampling time in seconds, None when the file has none.
        shape: the file's ``shape``, or None.
        clearance_m: the file's ``clearance_m``, or None.
        layout: "stacked" or "ragged" (.npz), "lerobot" or "robomimic" (envs.datasets).
        stiffness: one (M_n, 3, 3) translational stiffness (N/m, world frame) per demo, or None.
        tool_frame: the frame the file names for its poses ("tcp": this testbed's, so no tool offset is
            needed), or None.
        source_config: the configuration the file carries from the testbed that wrote it (e.g. "scene"), or None.
    """

    pos: tuple[FloatArray, ...]
    quat: tuple[FloatArray, ...]
    dt: float | None
    shape: str | None
    clearance_m: float | None
    layout: str
    stiffness: tuple[FloatArray, ...] | None = None
    tool_frame: str | None = None
    source_config: dict[str, Any] | None = None

    @property
    def lengths(self) -> list[int]:
        """M_n, the number of samples of each demo."""
        return [int(p.shape[0]) for p in self.pos]


@dataclass(frozen=True)
class ImportConfig:
    """How recorded demos become a demo file.

    Attributes:
        num_samples: M, samples per demo after resampling (4000, as the paper).
        snap_goal: blend demos that end off the common goal onto it (else such demos are an error).
        snap_fraction: the blend covers this last fraction of every demo's duration.
        ends_apart: keep demos that end off the common goal as they are, the goal their mean end (the file's
            ``ends_apart``; `pih train` learns each relative to its own end). Not with ``snap_goal``.
    """

    num_samples: int = 4000
    snap_goal: bool = False
    snap_fraction: float = 0.2
    ends_apart: bool = False

    def __post_init__(self) -> None:
        if int(self.num_samples) != self.num_samples or self.num_samples < 2:
            raise EnvError(f"ImportConfig.num_samples={self.num_samples} must be an integer >= 2")
        if self.snap_goal and self.ends_apart:
            raise EnvError("--snap-goal and --ends-apart exclude each other: blend the demos onto the goal, or keep "
                           "their ends")
        if not (np.isfinite(self.snap_fraction) and 0.0 < self.snap_fraction <= 1.0):
            raise EnvError(f"ImportConfig.snap_fraction={self.snap_fraction} must lie in (0, 1]")


@dataclass(frozen=True)
class ImportResult:
    """The converted demos and, per demo, the jump from its last sample to the common goal (before snapping)."""

    demos: DemoSet
    jump_m: FloatArray
    jump_rad: FloatArray
    snapped: bool
    snap_duration_s: float


# ----------------------------------------------------------------------------------------------- rigid poses


def compose(a: Pose, b: Pose) -> Pose:
    """T_a T_b: p = p_a + R_a p_b, q = q_a q_b (either may carry leading axes; they broadcast)."""
    return Pose(pos=a.pos + rotate(a.quat, b.pos), quat=quat_mul(a.quat, b.quat))


def invert(a: Pose) -> Pose:
    """T_a^-1: p = -R_a^T p_a, q = conj(q_a)."""
    q = quat_conj(a.quat)
    return Pose(pos=-rotate(q, a.pos), quat=q)


def tool_to_peg_tip(tool: Pose, tool_offset: Pose, grasp: Pose) -> Pose:
    """peg_tip poses from tool poses: T_W^P = T_W^T (T_F^T)^-1 T_F^P (module docstring).

    Args:
        tool: T_W^T, arrays (..., 3) and (..., 4).
        tool_offset: T_F^T, the tool frame in the flange frame.
        grasp: T_F^P, the peg_tip frame in the flange frame.

    Returns:
        T_W^P with the shapes of ``tool``, quaternions normalised.
    """
    tip = compose(tool, compose(invert(tool_offset), grasp))
    return Pose(pos=tip.pos, quat=tip.quat / np.linalg.norm(tip.quat, axis=-1, keepdims=True))


# ----------------------------------------------------------------------------------------------- user input


def parse_tool_offset(text: str) -> Pose:
    """A tool offset from 'X,Y,Z,QW,QX,QY,QZ' (metres, unit quaternion w, x, y, z) or a name in TOOL_OFFSETS.

    Raises:
        EnvError: not 7 finite numbers, or a quaternion whose norm is off 1 by more than TOOL_QUAT_UNIT_TOL
            (a typo, not rounding, so it is refused rather than normalised without a word).
    """
    name = text.strip().lower()
    if name in TOOL_OFFSETS:
        offset = TOOL_OFFSETS[name]
        return Pose(pos=offset.pos.copy(), quat=offset.quat.copy())
    parts = [p for p in text.replace(" ", "").split(",")]
    try:
        values = np.array([float(p) for p in parts])
    except ValueError:
        values = np.zeros(0)
    if values.shape != (7,) or not np.all(np.isfinite(values)):
        raise EnvError(f"--tool-offset {text!r} must be 7 finite numbers X,Y,Z,QW,QX,QY,QZ (metres, quaternion "
                       f"w, x, y, z) or one of {', '.join(TOOL_OFFSETS)}")
    if not TOOL_OFFSET_M.contains(norm(values[:3])):
        raise EnvError(f"--tool-offset {text!r}: the offset's length {norm(values[:3]):.3g} m must be "
                       f"{TOOL_OFFSET_M.text()} (a tool longer than the arm's reach is none the Panda carries)")
    length = norm(values[3:])
    if abs(length - 1.0) > TOOL_QUAT_UNIT_TOL:
        raise EnvError(f"--tool-offset {text!r}: the quaternion {values[3:].tolist()} has norm {length:.9g}, not 1 "
                       f"(within {TOOL_QUAT_UNIT_TOL:g}); give a unit quaternion w, x, y, z")
    return Pose(pos=values[:3], quat=values[3:] / length)


def resolve_dt(file_dt: float | None, flag_dt: float | None, source: str) -> float:
    """The sampling time: the file's ``dt``, the ``--dt-s`` flag, or both when they agree (relative 1e-9).

    Raises:
        EnvError: neither given, they differ, or the value is not a positive finite number.
    """
    for what, value in (("--dt-s", flag_dt), (f"{source}: 'dt'", file_dt)):
        if value is not None and not (np.isfinite(value) and value > 0.0):
            raise EnvError(f"{what} = {value} must be a positive finite number of seconds")
    if file_dt is None and flag_dt is None:
        raise EnvError(f"{source} has no 'dt': give the sampling time with --dt-s SECONDS")
    if file_dt is not None and flag_dt is not None and abs(file_dt - flag_dt) > 1e-9 * max(file_dt, flag_dt):
        raise EnvError(f"--dt-s {flag_dt} differs from the file's dt {file_dt} ({source}); give one of them")
    dt = float(flag_dt if flag_dt is not None else file_dt)  # type: ignore[arg-type]
    if not SAMPLE_PERIOD_S.contains(dt):
        raise EnvError(f"{source}: the sampling time {dt:g} s must be {SAMPLE_PERIOD_S.text()}")
    return dt


def check_trajectory(pos: Any, quat: Any, label: str, source: str) -> tuple[FloatArray, FloatArray]:
    """Shapes (M >= 2), finite values and unit quaternions (|norm - 1| <= QUAT_NORM_TOL, then normalised)."""
    for key, arr, width in (("pos", pos, 3), ("quat", quat, 4)):
        if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
            raise EnvError(f"{source}: {key} of {label} must be real numbers, got dtype {arr.dtype}")
        if arr.ndim != 2 or arr.shape[1] != width:
            raise EnvError(f"{source}: {key} of {label} must have shape (M, {width}), got {arr.shape}")
    p, q = np.asarray(pos, dtype=float), np.asarray(quat, dtype=float)
    if q.shape[0] != p.shape[0]:
        raise EnvError(f"{source}: {label} has {p.shape[0]} positions but {q.shape[0]} quaternions")
    if p.shape[0] < 2:
        raise EnvError(f"{source}: {label} has {p.shape[0]} sample(s); need at least 2")
    for key, arr in (("pos", p), ("quat", q)):
        if not np.all(np.isfinite(arr)):
            bad = int(np.argwhere(~np.isfinite(arr))[0][0])
            raise EnvError(f"{source}: {key} of {label} contains NaN or inf (first at sample {bad})")
    norms = np.linalg.norm(q, axis=-1)
    worst = int(np.argmax(np.abs(norms - 1.0)))
    if abs(norms[worst] - 1.0) > QUAT_NORM_TOL:
        raise EnvError(f"{source}: quat of {label} is not unit at sample {worst} (norm {norms[worst]:.6g}, "
                       f"tolerance {QUAT_NORM_TOL:g})")
    return p, q / norms[:, None]


def _optional_scalar(archive: Any, key: str, source: str, kind: type) -> Any:
    if key not in archive.files:
        return None
    value = archive[key]
    if value.shape != ():
        raise EnvError(f"{source}: '{key}' must be a scalar, got shape {value.shape}")
    if kind is float and not (np.issubdtype(value.dtype, np.number) and not np.iscomplexobj(value)):
        raise EnvError(f"{source}: '{key}' must be a number, got dtype {value.dtype}")
    if kind is str and value.dtype.kind not in "US":
        raise EnvError(f"{source}: '{key}' must be a string, got dtype {value.dtype}")
    return kind(value.item())


def _ragged_indices(files: list[str], source: str) -> int:
    """N for the ragged layout: pos_i and quat_i for exactly i = 0..N-1."""
    indices: dict[str, set[int]] = {"pos": set(), "quat": set()}
    for name in files:
        head, _, tail = name.partition("_")
        if head in indices and tail.isdigit():
            indices[head].add(int(tail))
    if indices["pos"] != indices["quat"]:
        odd = sorted(indices["pos"] ^ indices["quat"])
        raise EnvError(f"{source}: ragged layout needs pos_i and quat_i in pairs; unmatched index(es) {odd}")
    num = len(indices["pos"])
    if indices["pos"] != set(range(num)):
        raise EnvError(f"{source}: ragged layout needs pos_0 .. pos_{num - 1} without gaps, got indices "
                       f"{sorted(indices['pos'])}")
    return num


def load_recorded_demos(path: str | os.PathLike[str]) -> RecordedDemos:
    """Read and check an import file (layouts in the module docstring).

    Raises:
        EnvError: missing file, not an .npz (or pickled content), no or both layouts, wrong shapes or
            dtypes, fewer than 2 samples, NaN/inf, quaternions off unit by more than QUAT_NORM_TOL, or a
            non-scalar dt/shape/clearance_m.
    """
    source = str(path)
    if not Path(path).is_file():
        raise EnvError(f"import file {source} not found")
    try:
        with open_npz(path) as archive:
            if not isinstance(archive, np.lib.npyio.NpzFile):
                raise EnvError(f"{source} is a single .npy array, not an .npz archive with pos and quat")
            files = list(archive.files)
            stacked = "pos" in files or "quat" in files
            num_ragged = _ragged_indices(files, source)
            if stacked and num_ragged:
                raise EnvError(f"{source} holds both the stacked (pos, quat) and the ragged (pos_0, quat_0, ...) "
                               f"layout; keep one")
            if stacked:
                if "pos" not in files or "quat" not in files:
                    raise EnvError(f"{source}: the stacked layout needs both 'pos' and 'quat'")
                pos, quat = archive["pos"], archive["quat"]
                if pos.ndim != 3 or quat.ndim != 3 or pos.shape[:2] != quat.shape[:2]:
                    raise EnvError(f"{source}: stacked layout needs pos (N, M, 3) and quat (N, M, 4), got "
                                   f"{pos.shape} and {quat.shape}")
                pairs = [(pos[n], quat[n]) for n in range(pos.shape[0])]
            elif num_ragged:
                pairs = [(archive[f"pos_{n}"], archive[f"quat_{n}"]) for n in range(num_ragged)]
            else:
                raise EnvError(f"{source}: no demos; expected 'pos' (N, M, 3) and 'quat' (N, M, 4), or pos_0, "
                               f"quat_0, pos_1, ...; found keys {files}")
            if not pairs:
                raise EnvError(f"{source}: holds 0 demos")
            layout = "stacked" if stacked else "ragged"
            checked = [check_trajectory(p, q, f"demo {n}", source) for n, (p, q) in enumerate(pairs)]
            dt = _optional_scalar(archive, "dt", source, float)
            shape = _optional_scalar(archive, "shape", source, str)
            clearance_m = _optional_scalar(archive, "clearance_m", source, float)
    except EnvError:
        raise
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as err:
        raise EnvError(f"{source}: not a readable .npz of arrays ({type(err).__name__}: {err})") from None
    if clearance_m is not None and not (np.isfinite(clearance_m) and clearance_m >= 0.0):
        raise EnvError(f"{source}: 'clearance_m' = {clearance_m} must be finite and >= 0")
    return RecordedDemos(pos=tuple(p for p, _ in checked), quat=tuple(q for _, q in checked), dt=dt,
                         shape=shape, clearance_m=clearance_m, layout=layout)


# ----------------------------------------------------------------------------------------------- conversion


def _held_times(length: int, dt: float, duration: float) -> tuple[FloatArray, bool]:
    """Sample times of a demo of ``length`` samples on [0, duration]: (times, True) with ``duration`` appended
    when the demo ends earlier (its last sample is held), else (times with the end pinned to ``duration``, False)."""
    times = dt * np.arange(length)
    if times[-1] < duration * (1.0 - 1e-12):
        return np.append(times, duration), True
    times[-1] = duration  # the longest demo: pin its end to the grid's end exactly
    return times, False


def common_length(pos: list[FloatArray], quat: list[FloatArray], dt: float,
                  num_samples: int) -> tuple[FloatArray, FloatArray, float]:
    """Hold every demo's last pose until the longest ends, then resample all to ``num_samples`` on [0, T].

    Returns:
        (pos (N, M, 3), quat (N, M, 4) continuous in m, dt' = T / (M - 1)).
    """
    duration = dt * (max(p.shape[0] for p in pos) - 1)
    grid = np.linspace(0.0, duration, num_samples)
    out_pos, out_quat = [], []
    for p, q in zip(pos, quat):
        times, held = _held_times(p.shape[0], dt, duration)
        if held:
            p, q = np.vstack([p, p[-1]]), np.vstack([q, q[-1]])
        new_pos, new_quat = resample_trajectory(times, p, q, grid)
        out_pos.append(new_pos)
        out_quat.append(new_quat)
    return np.stack(out_pos), np.stack(out_quat), duration / (num_samples - 1)


def common_length_stiffness(stiffness: tuple[FloatArray, ...], dt: float, num_samples: int) -> FloatArray:
    """`common_length` of the stiffness: held, then resampled entrywise linearly on the same grid.

    Returns:
        (N, M, 3, 3).
    """
    duration = dt * (max(k.shape[0] for k in stiffness) - 1)
    grid = np.linspace(0.0, duration, num_samples)
    out = []
    for k in stiffness:
        times, held = _held_times(k.shape[0], dt, duration)
        flat = k.reshape(k.shape[0], 9)
        if held:
            flat = np.vstack([flat, flat[-1]])
        out.append(np.stack([np.interp(grid, times, flat[:, i]) for i in range(9)], axis=-1).reshape(-1, 3, 3))
    return np.stack(out)


def common_goal_stiffness(stiffness: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The goal stiffness (mean last stiffness) and each demo's relative jump to it (module docstring).

    Returns:
        (goal (3, 3), jump (N,)).
    """
    goal = np.mean(stiffness[:, -1], axis=0)
    goal = 0.5 * (goal + goal.T)
    jump = np.abs(stiffness[:, -1] - goal).max(axis=(-2, -1)) / max(float(np.abs(goal).max()), 1e-300)
    return goal, jump


def snap_weight(num_samples: int, fraction: float) -> FloatArray:
    """w over the samples of a demo: the minimum-jerk ramp from 0 at (1 - fraction) T to 1 at T, (M,)."""
    s = np.linspace(0.0, 1.0, num_samples)
    return minimum_jerk((s - (1.0 - fraction)) / fraction)


def common_goal(pos: FloatArray, quat: FloatArray) -> tuple[Pose, FloatArray, FloatArray]:
    """The goal (mean last position, mean last orientation) and each demo's jump to it.

    Returns:
        (goal, jump_m (N,), jump_rad (N,)).
    """
    goal = Pose(pos=np.mean(pos[:, -1], axis=0), quat=mean_quat(quat[:, -1]))
    jump_m = np.linalg.norm(pos[:, -1] - goal.pos, axis=-1)
    jump_rad = quat_angle_rad(quat[:, -1], goal.quat)
    return goal, jump_m, jump_rad


def snap_to_goal(pos: FloatArray, quat: FloatArray, goal: Pose, fraction: float) -> tuple[FloatArray, FloatArray]:
    """Blend every demo onto the goal over its last ``fraction`` of samples (module docstring).

    Returns:
        (pos, quat) ending exactly at the goal, quaternions continuous and ending at +goal.quat.
    """
    weight = snap_weight(pos.shape[1], fraction)[None, :, None]  # (1, M, 1)
    new_pos = pos + weight * (goal.pos - pos[:, -1])[:, None, :]
    correction = quat_to_rotvec(quat_mul(goal.quat, quat_conj(quat[:, -1])))  # (N, 3)
    new_quat = quat_mul(quat_from_rotvec(weight * correction[:, None, :]), quat)
    new_pos[:, -1] = goal.pos
    new_quat[:, -1] = goal.quat
    new_quat /= np.linalg.norm(new_quat, axis=-1, keepdims=True)
    return new_pos, make_continuous(new_quat, reference=goal.quat)


def import_demos(recorded: RecordedDemos, tool_offset: Pose, grasp: Pose, dt: float, shape: str,
                 clearance_m: float, config: ImportConfig = ImportConfig(),
                 provenance: dict[str, Any] | None = None) -> ImportResult:
    """Convert recorded tool-frame demos into a peg_tip DemoSet ending at their common goal.

    Args:
        recorded: the checked file content (load_recorded_demos).
        tool_offset: T_F^T, the recorded tool frame in the flange frame.
        grasp: T_F^P, the nominal peg_tip frame in the flange frame (envs.cell.scene.nominal_flange_to_peg_tip).
        dt: the recording's sampling time, seconds (resolve_dt).
        shape, clearance_m: stored in the demo file (the scene the demos are for).
        config: resampling and snapping.
        provenance: extra entries for the file's config_json (e.g. the source file).

    Returns:
        ImportResult; ``demos.residual_pos_m`` / ``residual_rot_deg`` hold the jumps before snapping.

    Raises:
        EnvError: a demo ends off the common goal by more than GOAL_TOL_M / GOAL_TOL_RAD and
            ``config.snap_goal`` is False (the message lists every such demo with its jump).
    """
    tips = [tool_to_peg_tip(Pose(p, q), tool_offset, grasp) for p, q in zip(recorded.pos, recorded.quat)]
    pos, quat, new_dt = common_length([t.pos for t in tips], [t.quat for t in tips], dt, config.num_samples)
    goal, jump_m, jump_rad = common_goal(pos, quat)
    quat = make_continuous(quat, reference=goal.quat)
    stiffness = goal_k = None
    jump_k = np.zeros(len(jump_m))
    if recorded.stiffness is not None:
        stiffness = common_length_stiffness(recorded.stiffness, dt, config.num_samples)
        goal_k, jump_k = common_goal_stiffness(stiffness)
    off = np.flatnonzero((jump_m > GOAL_TOL_M) | (jump_rad > GOAL_TOL_RAD) | (jump_k > STIFFNESS_REL_TOL))
    ends_apart = bool(off.size) and config.ends_apart
    if ends_apart and stiffness is not None:
        raise EnvError("--ends-apart: demos with a recorded stiffness must end at one goal stiffness and pose; "
                       "use --snap-goal")
    if off.size and not config.snap_goal and not ends_apart:
        listing = ", ".join(f"demo {n}: {jump_m[n] * 1e3:.3f} mm / {np.rad2deg(jump_rad[n]):.3f} deg"
                            + (f" / stiffness {jump_k[n]:.2g} relative" if stiffness is not None else "") for n in off)
        raise EnvError(f"{off.size} of {len(jump_m)} demos do not end at the common goal ({listing}; tolerance "
                       f"{GOAL_TOL_M * 1e3:g} mm / {np.rad2deg(GOAL_TOL_RAD):.2g} deg); pass --ends-apart to keep "
                       f"their ends (the skill learns each demo relative to its own end) or --snap-goal to blend "
                       f"them onto it over the last {100 * config.snap_fraction:g} % of each demo")
    snapped = bool(off.size) and config.snap_goal
    if snapped:
        pos, quat = snap_to_goal(pos, quat, goal, config.snap_fraction)
        if stiffness is not None:
            weight = snap_weight(config.num_samples, config.snap_fraction)[None, :, None, None]
            stiffness = stiffness + weight * (goal_k - stiffness[:, -1])[:, None]
            stiffness[:, -1] = goal_k
    snap_duration_s = config.snap_fraction * new_dt * (config.num_samples - 1)
    record = {
        "source": "import",
        "layout": recorded.layout,
        "input_lengths": recorded.lengths,
        "input_dt_s": dt,
        "tool_offset": [*tool_offset.pos.tolist(), *tool_offset.quat.tolist()],
        "nominal_grasp": [*grasp.pos.tolist(), *grasp.quat.tolist()],
        "num_samples": config.num_samples,
        "snap_goal": config.snap_goal,
        "snapped": snapped,
        "ends_apart": ends_apart,
        "snap_fraction": config.snap_fraction,
        "snap_duration_s": snap_duration_s,
        "goal_jump_mm": (jump_m * 1e3).tolist(),
        "goal_jump_deg": np.rad2deg(jump_rad).tolist(),
        **({"goal_jump_stiffness_rel": jump_k.tolist()} if stiffness is not None else {}),
        **(provenance or {}),
    }
    demos = DemoSet(pos=pos, quat=quat, dt=new_dt, goal_pos=goal.pos, goal_quat=goal.quat, shape=shape,
                    clearance_m=clearance_m, config=record, residual_pos_m=jump_m,
                    residual_rot_deg=np.rad2deg(jump_rad), stiffness=stiffness, goal_stiffness=goal_k,
                    ends_apart=ends_apart)
    return ImportResult(demos=demos, jump_m=jump_m, jump_rad=jump_rad, snapped=snapped,
                        snap_duration_s=snap_duration_s)
