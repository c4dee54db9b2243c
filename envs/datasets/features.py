"""What an exported episode holds, shared by the LeRobot and the robomimic layouts (envs.datasets).

One table, FEATURES, names every per-step quantity once with its meaning and unit, and its key in each layout.
Poses are [x, y, z, qw, qx, qy, qz] (metres, unit quaternion w, x, y, z) in the world (robot base) frame, stored
as float64, so a pose survives an export and an import bit for bit.

Frames. An export has an integer frame rate ``fps`` (default: the control rate, 100): every signal is resampled onto
the frames t_j = j / fps (envs.datasets.resample: measurements interpolated, commands held), so a dataset of demos,
recorded at 4000 samples over 7 s, has the frame rate of a dataset of episodes.

Actions. ``action`` is the whole command of a control period, what a trainer regresses: the commanded tcp pose (7),
the commanded translational stiffness (9, 3x3 row-major, N/m) and rotational stiffness (1, N m/rad), ACTION_NAMES;
``action_stiffness`` is the translational stiffness alone (what `pih demos --import` reads back). The action at a
control step is what was commanded after observing it (the command of the step from t to t + dt); the last step,
after which nothing was commanded, repeats the last command:
    action[t] = [cmd_pose[t + 1], K[t + 1], k_r[t + 1]]   (t < T),   row T repeats row T - 1's.

Episodes (`episode_from_trace`, from a replayed evaluation) hold every feature. Demonstrations (`episodes_from_demos`,
from a demo file) hold ``tcp_pose`` (the demo's poses) and ``done``; a demo file recorded with its control signals
(envs.demos.file.ControlSignals) also the joints, the wrench and the action as the robot ran them. Absent, and listed
under "absent" in the export's metadata: ``peg_tip_pose`` (the peg's own pose, simulator truth a demo does not keep),
``success`` per step (a kept demo ends inserted, which is its per-episode ``success``), and for a demo file without
control signals (of before them, imported or made noisy) the joints, the wrench and the action
(ABSENT_WITHOUT_CONTROL).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import numpy.typing as npt

from envs.demos.file import DemoSet
from envs.demos.importing import RecordedDemos, check_trajectory
from envs.errors import EnvError
from envs.io.owned_output import EXPORT_MARKER_FILE

FloatArray = npt.NDArray[np.float64]

POSE_NAMES: tuple[str, ...] = ("x", "y", "z", "qw", "qx", "qy", "qz")
JOINT_NAMES: tuple[str, ...] = tuple(f"panda_joint{i}" for i in range(1, 8))
WRENCH_NAMES: tuple[str, ...] = ("fx", "fy", "fz", "tx", "ty", "tz")
STIFFNESS_NAMES: tuple[str, ...] = tuple(f"k_{r}{c}" for r in "xyz" for c in "xyz")
ACTION_NAMES: tuple[str, ...] = POSE_NAMES + STIFFNESS_NAMES + ("k_rot",)
#: The frame rate of an export unless the user picks one: the control rate (one frame per control step).
DEFAULT_FPS: int = 100

#: The format version of the metadata this package writes (``ExportMeta.to_json``).
EXPORT_VERSION: int = 1
#: The marker file of an export folder: our metadata; its presence lets `--overwrite` replace the folder.
MARKER_FILE: str = EXPORT_MARKER_FILE


@dataclass(frozen=True)
class Feature:
    """One per-step quantity.

    Attributes:
        key: its name here.
        lerobot: its column in LeRobot's data tables.
        robomimic: its dataset under ``data/demo_N`` in robomimic's HDF5 layout.
        names: the names of its components.
        dtype: "float64" or "bool".
        description: what it is, with units.
    """

    key: str
    lerobot: str
    robomimic: str
    names: tuple[str, ...]
    dtype: str
    description: str


FEATURES: tuple[Feature, ...] = (
    Feature("tcp_pose", "observation.state", "obs/tcp_pose", POSE_NAMES, "float64",
            "measured tcp pose (the nominal peg_tip through the arm's kinematics; the skill's frame), m and (w, x, y, z)"),
    Feature("peg_tip_pose", "observation.peg_tip_pose", "obs/peg_tip_pose", POSE_NAMES, "float64",
            "the peg's own peg_tip pose (simulator truth: tcp pose + grasp offset, slip and tilt)"),
    Feature("joint_pos", "observation.joint_pos", "obs/joint_pos", JOINT_NAMES, "float64", "arm joint positions, rad"),
    Feature("joint_vel", "observation.joint_vel", "obs/joint_vel", JOINT_NAMES, "float64",
            "arm joint velocities, rad/s"),
    Feature("wrist_wrench", "observation.wrist_wrench", "obs/wrist_wrench", WRENCH_NAMES, "float64",
            "wrist F/T reading [N; N m] as the cell's sensor reads it (what a policy sees), sensor frame, tool load "
            "removed"),
    Feature("action", "action", "actions", ACTION_NAMES, "float64",
            "the command after this frame: the tcp pose sent to the impedance controller (m, w x y z), the "
            "translational stiffness (3x3 row-major, N/m, world frame) and the rotational stiffness (N m/rad)"),
    Feature("action_stiffness", "action.stiffness", "action_stiffness", STIFFNESS_NAMES, "float64",
            "commanded translational stiffness after this frame, 3x3 row-major, N/m, world frame"),
    Feature("success", "next.success", "rewards", ("success",), "bool",
            "the simulator's success flag (seated and at rest for the hold time); robomimic: 0/1 reward"),
    Feature("done", "next.done", "dones", ("done",), "bool", "last frame of the episode"),
)
FEATURE_BY_KEY: dict[str, Feature] = {f.key: f for f in FEATURES}

ABSENT_IN_DEMOS: dict[str, str] = {
    "peg_tip_pose": "a demo file records the tcp pose, not the peg's own (simulator truth)",
    "success": "a demo file records no per-step success (every kept demo ends inserted)",
}
ABSENT_WITHOUT_CONTROL: dict[str, str] = {
    "joint_pos": "this demo file has no control signals (recorded before them, imported or made noisy)",
    "joint_vel": "this demo file has no control signals",
    "wrist_wrench": "this demo file has no control signals",
    "action": "this demo file has no control signals (the command of each step)",
}


@dataclass
class ExportEpisode:
    """One episode to export.

    Attributes:
        index: its index in the source (demo n, or the evaluation's episode index).
        data: feature key -> (T, n) array (bool (T,) for ``success`` and ``done``), T frames.
        success: the episode's outcome.
        end_reason: why it ended ("success", "time_limit (...)", ...; "demonstration" for a demo).
        extra: per-episode metadata (numbers, strings, bools): the perturbation, the demo it started near, ...
        frames: (T, H, W, 3) uint8 camera frames for a layout that stores images in the table (robomimic), or None.
    """

    index: int
    data: dict[str, np.ndarray]
    success: bool
    end_reason: str
    extra: dict[str, Any] = field(default_factory=dict)
    frames: npt.NDArray[np.uint8] | None = None

    @property
    def num_frames(self) -> int:
        """T, the number of frames."""
        return int(next(iter(self.data.values())).shape[0])


@dataclass(frozen=True)
class ExportMeta:
    """What an export is, stored beside the data (LeRobot: ``pih_export.json``; robomimic: also the ``data``
    group's ``pih_export`` attribute) and read back on import.

    Attributes:
        kind: "demos" or "episodes".
        source: the file it was made from.
        dt_s: seconds between frames, 1 / fps (LeRobot's ``fps``, an integer, is 1 / dt_s).
        task: the task in words (LeRobot's task table).
        shape, clearance_m: the peg/hole shape and clearance (m).
        features: the feature keys present.
        absent: feature key -> why it is absent.
        config: the source's configuration (demo file: its config_json; evaluation: config, scene and skill).
        frame: the frame of ``tcp_pose`` ("tcp").
        camera: the camera of the video frames, or None.
    """

    kind: str
    source: str
    dt_s: float
    task: str
    shape: str
    clearance_m: float
    features: tuple[str, ...]
    absent: dict[str, str]
    config: dict[str, Any]
    frame: str = "tcp"
    camera: str | None = None

    def to_json(self, layout: str) -> dict[str, Any]:
        """The JSON object of the metadata (and the marker of an export folder of ``layout``)."""
        return {"pih_export": EXPORT_VERSION, "layout": layout, "kind": self.kind, "source": self.source,
                "dt_s": self.dt_s, "task": self.task, "shape": self.shape, "clearance_m": self.clearance_m,
                "frame": self.frame, "camera": self.camera, "features": list(self.features), "absent": self.absent,
                "feature_descriptions": {k: FEATURE_BY_KEY[k].description for k in self.features},
                "config": self.config}


def task_text(shape: str, clearance_m: float) -> str:
    """The task in words, as LeRobot's task table holds it."""
    return f"insert the {shape} peg into the {shape} hole ({clearance_m * 1e3:g} mm clearance)"


def _done(num_frames: int) -> npt.NDArray[np.bool_]:
    done = np.zeros(num_frames, dtype=bool)
    done[-1] = True
    return done


def _action(pos: np.ndarray, quat: np.ndarray, stiffness: np.ndarray, rot_stiffness: np.ndarray) -> np.ndarray:
    """The (T, 17) ``action`` rows: pose, translational stiffness (row-major), rotational stiffness."""
    return np.concatenate([pos, quat, np.asarray(stiffness).reshape(len(pos), 9),
                           np.asarray(rot_stiffness).reshape(len(pos), 1)], axis=-1)


def episodes_from_demos(demos: DemoSet, source: str, fps: int | None = DEFAULT_FPS) -> tuple[ExportMeta,
                                                                                           list[ExportEpisode]]:
    """A demo file's demos as episodes at ``fps`` frames per second (None: the demo file's own samples, dt apart),
    what a demo file holds (module docstring)."""
    from envs.datasets.resample import frame_times, held, interpolated, interpolated_pose

    control = demos.control
    features = ["tcp_pose", "done"] + (["action_stiffness"] if demos.stiffness is not None else [])
    absent = dict(ABSENT_IN_DEMOS)
    if control is not None:
        features += ["joint_pos", "joint_vel", "wrist_wrench", "action"]
    else:
        absent.update(ABSENT_WITHOUT_CONTROL)
    if demos.stiffness is None:
        absent["action_stiffness"] = "this demo file has no stiffness"
    times = frame_times(demos.duration_s, fps) if fps is not None else None
    dt = demos.dt if fps is None else 1.0 / fps
    episodes = []
    for n in range(demos.num_demos):
        pose = np.concatenate([demos.pos[n], demos.quat[n]], axis=-1)
        data: dict[str, np.ndarray] = {"tcp_pose": pose if times is None else interpolated_pose(pose, demos.dt, times)}
        rows = len(data["tcp_pose"])
        data["done"] = _done(rows)
        if demos.stiffness is not None:
            k = np.asarray(demos.stiffness[n]).reshape(demos.num_samples, 9)
            data["action_stiffness"] = k if times is None else held(k, demos.dt, times)
        if control is not None:
            at = times if times is not None else np.arange(rows) * demos.dt
            for name in ("joint_pos", "joint_vel", "wrist_wrench"):
                data[name] = interpolated(getattr(control, name)[n], control.dt, at)
            command = _action(control.action_pos[n], control.action_quat[n], control.action_stiffness[n],
                              control.action_rot_stiffness[n])
            data["action"] = held(command, control.dt, at)
            if "action_stiffness" in data:  # the command's stiffness, as in the action: one dataset, one command
                data["action_stiffness"] = data["action"][:, 7:16].copy()
        extra = {}
        if demos.residual_pos_m is not None and demos.residual_rot_deg is not None:
            extra = {"residual_pos_mm": float(demos.residual_pos_m[n]) * 1e3,
                     "residual_rot_deg": float(demos.residual_rot_deg[n])}
        episodes.append(ExportEpisode(n, data, True, "demonstration", extra))
    meta = ExportMeta("demos", source, dt, task_text(demos.shape, demos.clearance_m), demos.shape,
                      demos.clearance_m, tuple(f.key for f in FEATURES if f.key in features), absent,
                      dict(demos.config))
    return meta, episodes


def _shifted(values: np.ndarray) -> np.ndarray:
    """values[t + 1] at row t, the last row repeated (module docstring)."""
    return np.concatenate([values[1:], values[-1:]], axis=0)


def episode_from_trace(record: dict[str, Any], trace: Any, fps: int | None = DEFAULT_FPS) -> ExportEpisode:
    """An evaluation episode from its record (a dict of the evaluation JSON) and its replayed trace, at ``fps``
    frames per second (None: one frame per control step).

    Args:
        record: the episode's record (index, demo_index, success, reason, perturbation).
        trace: an envs.rollout.episode.EpisodeTrace (times_s, tcp_pos, tcp_quat, pos, quat, qpos, qvel,
            sensed_wrench, cmd_pos, cmd_quat, stiffness, rot_stiffness, success), a row per control step.
        fps: the frame rate.
    """
    from envs.datasets.resample import frame_times, held, interpolated, interpolated_pose

    num = len(trace.times_s)
    dt = float(trace.times_s[1] - trace.times_s[0]) if num > 1 else 1.0
    times = frame_times(float(trace.times_s[-1]), fps) if fps is not None else np.asarray(trace.times_s, dtype=float)
    command = _shifted(_action(trace.cmd_pos, trace.cmd_quat, trace.stiffness, trace.rot_stiffness))
    data = {
        "tcp_pose": interpolated_pose(np.concatenate([trace.tcp_pos, trace.tcp_quat], axis=-1), dt, times),
        "peg_tip_pose": interpolated_pose(np.concatenate([trace.pos, trace.quat], axis=-1), dt, times),
        "joint_pos": interpolated(trace.qpos, dt, times),
        "joint_vel": interpolated(trace.qvel, dt, times),
        "wrist_wrench": interpolated(trace.sensed_wrench, dt, times),
        "action": held(command, dt, times),
        "action_stiffness": held(command[:, 7:16], dt, times),
        "success": held(np.asarray(trace.success, dtype=bool), dt, times),
        "done": _done(len(times)),
    }
    extra: dict[str, Any] = {"demo_index": int(record.get("demo_index", -1))}
    perturbation = record.get("perturbation") or {}
    extra.update({f"perturbation.{k}": float(v) for k, v in perturbation.items() if isinstance(v, (int, float))})
    return ExportEpisode(int(record["index"]), data, bool(record["success"]), str(record["reason"]), extra)


def evaluation_meta(source: str, dt_s: float, shape: str, clearance_m: float, config: dict[str, Any],
                    camera: str | None) -> ExportMeta:
    """The metadata of exported evaluation episodes (every feature present)."""
    return ExportMeta("episodes", source, dt_s, task_text(shape, clearance_m), shape, clearance_m,
                      tuple(f.key for f in FEATURES), {}, config, camera=camera)


def fps_of(dt_s: float) -> int | float:
    """Frames per second 1 / dt: an integer when it is one (to 1e-9 relative), else the exact float."""
    fps = 1.0 / dt_s
    return int(round(fps)) if abs(fps - round(fps)) <= 1e-9 * fps else fps


def read_meta(values: Any, source: str) -> dict[str, Any]:
    """Our metadata (``ExportMeta.to_json``) from a JSON text or object, checked for what an import reads.

    Raises:
        EnvError: not JSON, not an object, no "pih_export" version, or a malformed dt_s/shape/clearance_m.
    """
    if isinstance(values, (str, bytes)):
        try:
            values = json.loads(values)
        except json.JSONDecodeError as err:
            raise EnvError(f"{source}: the pih export metadata is not valid JSON ({err})") from None
    if not isinstance(values, dict) or values.get("pih_export") != EXPORT_VERSION:
        raise EnvError(f"{source}: not pih export metadata of version {EXPORT_VERSION}")
    dt = values.get("dt_s")
    if not isinstance(dt, (int, float)) or not (math.isfinite(dt) and dt > 0.0):
        raise EnvError(f"{source}: the pih export metadata's dt_s={dt!r} must be a positive number of seconds")
    if not isinstance(values.get("shape"), str) or not isinstance(values.get("clearance_m"), (int, float)):
        raise EnvError(f"{source}: the pih export metadata needs a string 'shape' and a number 'clearance_m'")
    return values


def recorded_from_poses(poses: Sequence[np.ndarray], stiffness: Sequence[np.ndarray] | None, dt: float | None,
                        meta: dict[str, Any] | None, layout: str, source: str) -> RecordedDemos:
    """Demos to import (envs.demos.importing.import_demos) from per-episode tcp poses and stiffness.

    Args:
        poses: one (T_n, 7) array per episode, [x, y, z, qw, qx, qy, qz].
        stiffness: one (T_n, 9) array per episode (3x3 row-major), or None.
        dt: seconds between frames (None: not known; give --dt-s).
        meta: our metadata when the file was exported here (`read_meta`), else None.
        layout: "lerobot" or "robomimic".
        source: the file, for messages.

    Raises:
        EnvError: no episodes, wrong shapes, fewer than 2 frames, NaN or inf, quaternions off unit, a stiffness
            with NaN or another length than its poses.
    """
    if not poses:
        raise EnvError(f"{source}: holds no episodes")
    pos, quat, ks = [], [], []
    for n, pose in enumerate(poses):
        pose = np.asarray(pose)
        if pose.ndim != 2 or pose.shape[1] != 7:
            raise EnvError(f"{source}: the tcp poses of episode {n} must have shape (T, 7), got {pose.shape}")
        p, q = check_trajectory(pose[:, :3], pose[:, 3:], f"episode {n}", source)
        pos.append(p)
        quat.append(q)
        if stiffness is not None:
            k = np.asarray(stiffness[n], dtype=float)
            if k.shape != (pose.shape[0], 9):
                raise EnvError(f"{source}: the stiffness of episode {n} must have shape ({pose.shape[0]}, 9), "
                               f"got {k.shape}")
            if not np.all(np.isfinite(k)):
                raise EnvError(f"{source}: the stiffness of episode {n} contains NaN or inf")
            ks.append(k.reshape(-1, 3, 3))
    meta = meta or {}
    return RecordedDemos(pos=tuple(pos), quat=tuple(quat), dt=dt, shape=meta.get("shape"),
                         clearance_m=None if meta.get("clearance_m") is None else float(meta["clearance_m"]),
                         layout=layout, stiffness=tuple(ks) if stiffness is not None else None,
                         tool_frame=meta.get("frame"),
                         source_config=meta.get("config") if isinstance(meta.get("config"), dict) else None)
