"""Episodes recorded as they run: the per-step trace of every episode of an evaluation, written by the worker that ran
it (`pih evaluate --record-episodes DIR`), and played back without running any policy again.

Why. An evaluation JSON holds one record per episode, no per-step data. The RiemannianFlow skill's episodes can be
replayed from its checkpoint (physics is deterministic, envs.evaluation.replay), but a user's policy may not be
deterministic, nor importable later: what it did is kept as it happens. Each episode's `EpisodeTrace` -- the measured
tcp and the peg's own pose, the joints, the true and the sensed wrench, the commanded pose and stiffness, the
simulator's success flag and its whole position state ``sim_qpos`` -- goes into DIR/episode-NNNNNN.npz, written
atomically when the episode ends, with the record it ended with (index, success, reason, steps). The folder's marker,
DIR/pih_recording.json, and the evaluation JSON's "recorded_episodes" name each other's run.

Playback. `play` puts the scene in the episode's start (its hole-pose error and grasp offset set in the model, as the
episode's reset did) and then each row's position state, the kinematics only (no physics runs), so a camera draws
exactly what ran: `pih evaluate --policy ... --video/--figure` render the chosen episodes from their recordings, and
`pih export --episodes` exports a recorded evaluation from them (envs.evaluation.replay.replay_evaluation).
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Callable

import numpy as np

from envs.errors import EnvError
from envs.rollout.episode import EpisodeTrace, StartPose

MARKER = "pih_recording.json"
"""The marker file of a recording folder."""
FORMAT = 1
"""The format version of a recording (its marker's "pih_recording")."""
_EPISODE = re.compile(r"^episode-(\d{6,})\.npz$")
RECORD_KEYS: tuple[str, ...] = ("index", "success", "reason", "steps")
"""What an episode's file keeps of its record, checked against the evaluation JSON's record on playback."""
TRACE_ARRAYS: tuple[str, ...] = tuple(f.name for f in fields(EpisodeTrace))
EPISODE_BYTES = 2 * 1024 * 1024
"""Generous size of one recorded episode (20 s at 100 Hz, ~60 float64 per row, compressed)."""


def episode_file(folder: str | os.PathLike[str], index: int) -> Path:
    """The file of episode ``index`` in a recording folder."""
    return Path(folder) / f"episode-{int(index):06d}.npz"


def prepare_recording(folder: Path, overwrite: bool, resume: bool, run: dict[str, Any]) -> None:
    """Make ``folder`` ready to record into: a new or empty folder gets the marker; a recording of an earlier run is
    continued (``resume``: its episodes are kept) or emptied (``overwrite``); anything else is refused.

    Args:
        run: what identifies the run (its journal's run record): kept in the marker.

    Raises:
        EnvError: naming --record-episodes and the problem.
    """
    from envs.io.owned_output import write_json

    check_recording(folder, overwrite, resume)
    if folder.is_dir() and overwrite and not resume:
        for path in folder.iterdir():
            path.unlink()
    folder.mkdir(parents=True, exist_ok=True)
    write_json(folder / MARKER, {"pih_recording": FORMAT, "run": run})


def check_recording(folder: Path, overwrite: bool, resume: bool) -> None:
    """The checks of `prepare_recording`, before any work (nothing written).

    Raises:
        EnvError: naming --record-episodes and the problem.
    """
    where = f"--record-episodes {folder}"
    if folder.exists() and not folder.is_dir():
        raise EnvError(f"{where} is a file, not a folder")
    if folder.is_dir() and any(folder.iterdir()):
        if not is_recording(folder):
            raise EnvError(f"{where} holds files that are not a pih recording: not writing into it; choose another "
                           "folder")
        if not (overwrite or resume):
            raise EnvError(f"{where} holds an earlier recording (use --resume to continue that run, --overwrite to "
                           "replace it)")


def is_recording(folder: Path) -> bool:
    """Whether ``folder`` holds a recording and nothing else (its marker and episode files)."""
    from envs.io.owned_output import MARKER_KEY

    try:
        marker = json.loads((folder / MARKER).read_text())
    except (OSError, ValueError):
        return False
    if not (isinstance(marker, dict) and marker.get("pih_recording") == FORMAT and MARKER_KEY in marker):
        return False
    return all(p.name == MARKER or (_EPISODE.match(p.name) and p.is_file() and not p.is_symlink())
               for p in folder.iterdir())


def save_episode(folder: str | os.PathLike[str], record: dict[str, Any], trace: EpisodeTrace) -> Path:
    """Write one episode's trace and record into the recording (atomically, compressed)."""
    from envs.io.owned_output import write_file

    arrays = {name: np.asarray(getattr(trace, name)) for name in TRACE_ARRAYS if getattr(trace, name) is not None}
    arrays["record"] = np.str_(json.dumps({k: record.get(k) for k in RECORD_KEYS}))
    return write_file(episode_file(folder, record["index"]), lambda handle: np.savez_compressed(handle, **arrays),
                      binary=True)


def load_episode(path: Path) -> tuple[dict[str, Any], EpisodeTrace]:
    """(the record it kept, the trace) of one recorded episode.

    Raises:
        EnvError: missing, unreadable or malformed.
    """
    import zipfile

    from envs.io.npz import open_npz

    try:
        with open_npz(path) as data:
            record = json.loads(str(data["record"]))
            arrays = {name: np.array(data[name]) for name in TRACE_ARRAYS if name in data.files}
    except FileNotFoundError:
        raise EnvError(f"{path}: the recorded episode is missing") from None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as err:
        raise EnvError(f"{path}: not a recorded episode ({type(err).__name__}: {err})") from None
    required = [f.name for f in fields(EpisodeTrace) if f.default is not None and f.name not in arrays]
    rows = len(arrays.get("times_s", ()))
    if required or not isinstance(record, dict) or rows < 1 or any(len(a) != rows for a in arrays.values()):
        raise EnvError(f"{path}: not a whole recorded episode (arrays missing or of unequal length)")
    return record, EpisodeTrace(**arrays)


def check_episode(kept: dict[str, Any], record: dict[str, Any], trace: EpisodeTrace, source: str) -> None:
    """A recorded episode belongs to the JSON's record: the same index, outcome, reason and steps, and one row per
    step after the start.

    Raises:
        EnvError: naming the episode and the first field that differs.
    """
    for key in RECORD_KEYS:
        if kept.get(key) != record.get(key):
            raise EnvError(f"{source}: the recorded episode {record.get('index')} differs from its record ({key}: "
                           f"{record.get(key)!r} in the JSON, {kept.get(key)!r} recorded): another run's recording")
    if len(trace.times_s) != int(record.get("steps") or 0) + 1:
        raise EnvError(f"{source}: the recorded episode {record.get('index')} has {len(trace.times_s)} rows for "
                       f"{record.get('steps')} steps")


def recording_folder(data: dict[str, Any], source: Path) -> Path | None:
    """The recording an evaluation JSON names ("recorded_episodes"): its folder as written, else the folder of that
    name beside the JSON; None when it names none.

    Raises:
        EnvError: it names one that is not there.
    """
    named = data.get("recorded_episodes")
    if named is None:
        return None
    if not isinstance(named, dict) or not isinstance(named.get("folder"), str):
        raise EnvError(f"{source}: 'recorded_episodes' must be an object with the recording's 'folder'")
    for candidate in (Path(named["folder"]), source.parent / Path(named["folder"]).name):
        if candidate.is_dir() and (candidate / MARKER).is_file():
            return candidate
    raise EnvError(f"{source}: its recorded episodes ({named['folder']}) are not there (moved? keep the folder "
                   "beside the JSON)")


class PlaybackView:
    """What the callbacks of a replay see of an episode played back (`play`): the environment's ``model``, ``data``
    (the row's position state), ``goal``, ``shape``, ``scene`` and ``control_period_s``, and an ``observation`` with
    the row's ``time_s``, true ``wrist_wrench`` and ``contact_force_n``."""

    def __init__(self, env: Any):
        self._env = env
        self.observation: Any = None

    def __getattr__(self, name: str) -> Any:
        return getattr(self._env, name)


@dataclass
class _Row:
    time_s: float
    wrist_wrench: np.ndarray
    contact_force_n: float


def play(env: Any, start: StartPose, trace: EpisodeTrace, on_step: Callable[[Any], None] | None) -> None:
    """Draw a recorded episode again (module docstring): reset ``env`` at its start, then for every row set the
    simulator's position state and its kinematics and call ``on_step`` with a `PlaybackView`.

    Raises:
        EnvError: the trace has no position state, or one of another scene's size.
    """
    import mujoco

    if on_step is None:
        return
    if trace.sim_qpos is None or np.shape(trace.sim_qpos)[1:] != (env.model.nq,):
        raise EnvError("the recorded episode holds no position state of this scene (it cannot be drawn)")
    env.reset(start_pose=start.pose, perturbation=start.perturbation)
    view = PlaybackView(env)
    data = env.data
    for k in range(len(trace.times_s)):
        data.qpos[:] = trace.sim_qpos[k]
        data.qvel[:] = 0.0
        mujoco.mj_forward(env.model, data)
        view.observation = _Row(float(trace.times_s[k]), np.asarray(trace.wrist_wrench[k]), float(trace.force_n[k]))
        on_step(view)
