"""A recorded evaluation replayed: its configuration and starts read back from the JSON of `pih evaluate`, and
its episodes re-run with traces (envs.rollout.episode.EpisodeTrace) -- or, when the evaluation recorded its episodes
as they ran (`pih evaluate --record-episodes`, envs.evaluation.recording: any policy's, a user's among them), played
back from that recording, each checked against its record, without running any policy again.

An evaluation JSON holds no per-step traces, but an episode is deterministic in its start and perturbation:
the starts are drawn again from the checkpoint's demo starts with the recorded seed and ranges
(`evaluation_starts`), checked against the recorded start poses, and each replayed episode is checked
against its record (success, end reason, steps), so a replay made with other code or another checkpoint is
an error instead of a silently different trajectory.

A JSON is input like an option (`check_recorded`, for `pih export` and `pih compare`): its config's types and ranges,
its episode indexes against its own counts (each below the episodes it ran, none twice: an index of 2^40 would ask
for that many starts), and every record's start pose and perturbation against those its seed draws again, so a
hand-edited perturbation never reaches a dataset's table or a comparison while the episode replays the real one.
"""

from __future__ import annotations

import dataclasses
import math
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from envs.errors import EnvError
from envs.evaluation.config import SCENE_FROM_TASK
from envs.evaluation.evaluate import EvaluationConfig, iter_replays
from envs.evaluation.starts import evaluation_starts, metadata_starts, seeded_perturbations
from envs.rollout.episode import EpisodeRecord, EpisodeTrace, StartPose
from envs.task.task import Task
from numerics.errors import shown
from pihutil.bounds import EPISODES

#: Largest difference between a recorded and a redrawn start position (m) or quaternion component.
START_TOL: float = 1e-12


@dataclass(frozen=True)
class RecordedEvaluation:
    """What an evaluation JSON says about its episodes.

    Attributes:
        path: the JSON file.
        model_dir: the checkpoint it evaluated (None for a recorded evaluation, which needs none).
        config: its EvaluationConfig with the task the episodes ran (run in one process for the replay).
        scene: the scene it ran in (asdict of SceneConfig).
        skill: the checkpoint's metadata (demo starts, shape, clearance, ...).
        records: the per-episode records (dicts, as in the file).
        recording: the folder of its recorded episodes (envs.evaluation.recording), or None.
        policy: a user policy's spec, options and privilege (`pih evaluate --policy`), or None.
    """

    path: Path
    model_dir: Path | None
    config: EvaluationConfig
    scene: dict[str, Any]
    skill: dict[str, Any]
    records: list[dict[str, Any]]
    recording: Path | None = None
    policy: dict[str, Any] | None = None


LEGACY_TASK_KEYS: tuple[str, ...] = ("pos_range_m", "rot_range_deg", "around", "time_limit_s", "clearance_m",
                                      "chamfer_m", "peg_mode", "grasp_force_n", "perturbations", "force_limit_n",
                                      "shape")
"""Task fields an evaluation JSON's "config" held before task files (None in a scene field: the demos')."""


def evaluation_config_from_dict(values: dict[str, Any], source: str, task: Any = None) -> EvaluationConfig:
    """The EvaluationConfig of an evaluation JSON: its "config" (`EvaluationConfig.settings`) and its "task" (the
    task the episodes ran, envs.task.task.Task.to_dict); a JSON of before task files has no "task" and the task's fields
    in "config" (LEGACY_TASK_KEYS). Unknown keys, from other versions, are an error because they may change an
    episode. Workers and backend become one local process.

    Raises:
        EnvError: not an object, unknown keys, or values the config or the task rejects.
    """
    if not isinstance(values, dict):
        raise EnvError(f"{source}: 'config' must be a JSON object, got {type(values).__name__}")
    known = {f.name for f in dataclasses.fields(EvaluationConfig)} - {"task"}
    legacy = set(LEGACY_TASK_KEYS) if task is None else set()
    unknown = sorted(set(values) - known - legacy)
    if unknown:
        raise EnvError(f"{source}: 'config' has keys this version does not know: {unknown}")
    fields = {k: v for k, v in values.items() if k in known}
    if task is not None:
        fields["task"] = Task.from_dict(task, f"{source}: task")
    else:
        fields.update(_legacy_task(values, source))
    fields.update(workers=1, backend="process", ray_address=None)
    try:
        return EvaluationConfig(**fields)
    except TypeError as err:
        raise EnvError(f"{source}: 'config' is malformed ({err})") from None


def _legacy_task(values: dict[str, Any], source: str) -> dict[str, Any]:
    """The task and scene_from_task of a "config" of before task files (None in a scene field: the demos')."""
    leaves = {k: values[k] for k in LEGACY_TASK_KEYS if k in values and k != "perturbations"}
    ranges = values.get("perturbations")
    if ranges is not None and not isinstance(ranges, dict):
        raise EnvError(f"{source}: 'config.perturbations' is malformed ({ranges!r})")
    leaves.update(ranges or {})
    if "force_limit_n" in leaves and leaves["force_limit_n"] is None:
        leaves["force_limit_n"] = math.inf  # strict JSON writes "no limit" (inf) as null (envs.io.owned_output)
    try:
        task = Task().override(**leaves)
    except TypeError as err:
        raise EnvError(f"{source}: 'config' is malformed ({err})") from None
    return {"task": task, "scene_from_task": tuple(k for k in SCENE_FROM_TASK if values.get(k) is not None)}


PERTURBATION_TOL: float = 1e-9
"""Largest difference between a recorded and a redrawn perturbation value (mm, deg, ...)."""


def check_recorded(data: dict[str, Any], source: str) -> EvaluationConfig | None:
    """An evaluation JSON's episodes checked field by field (module docstring): the config (for a JSON of this format,
    with its "task"), the number of episodes it says it ran and holds, each episode's index (an integer below that
    number, none twice) and, where the JSON carries what draws them (its task and the demos' start poses in
    "skill"), each record's start pose and perturbation against the ones its seed draws again.

    Returns:
        The JSON's EvaluationConfig (None for a JSON of before task files, checked against its counts only).

    Raises:
        EnvError: one line naming ``source``, the episode and the field.
    """
    records = data.get("per_episode")
    if not isinstance(records, list) or not all(isinstance(r, dict) for r in records):
        raise EnvError(f"{source}: 'per_episode' must be a list of episode records")
    current = isinstance(data.get("task"), dict)
    values = data.get("config")
    config = evaluation_config_from_dict(values, source, data["task"]) if current else None
    declared = config.episodes if config is not None else (values or {}).get("episodes", data.get("episodes",
                                                                                                  len(records)))
    if not EPISODES.contains(declared):
        raise EnvError(f"{source}: its number of episodes {declared!r} must be an integer {EPISODES.text()}")
    count = data.get("episodes", len(records))
    if count != len(records) or len(records) > declared:
        raise EnvError(f"{source}: it holds {len(records)} episode records but says {count!r} of {declared} ran")
    seen: set[int] = set()
    for position, record in enumerate(records):
        index = record.get("index")
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < declared:
            raise EnvError(f"{source}: record {position} has index {shown(index)}, not an episode of 0..{declared - 1}")
        if index in seen:
            raise EnvError(f"{source}: episode {index} is recorded twice")
        seen.add(index)
    if config is None or not records:
        return config
    skill = data.get("skill") if isinstance(data.get("skill"), dict) else {}
    if skill.get("demo_starts") is not None:  # what the start poses are drawn around (a JSON of `pih evaluate`)
        drawn = evaluation_starts(metadata_starts(skill, f"{source}: 'skill'"),
                                  dataclasses.replace(config, episodes=max(seen) + 1))
        for record in records:
            pose = drawn[record["index"]].pose
            recorded = _numbers(record.get("start_pos"), 3) + _numbers(record.get("start_quat"), 4)
            redrawn = [*pose.pos.tolist(), *pose.quat.tolist()]
            if len(recorded) != 7 or max(abs(a - b) for a, b in zip(recorded, redrawn)) > START_TOL:
                raise EnvError(f"{source}: episode {record['index']}'s start pose differs from the one its seed draws "
                               f"(seed {config.seed}): edited, or run with explicit starts")
    perturbations = seeded_perturbations(config.task.perturbations, config.seed, max(seen) + 1)
    for record in records:
        what = _perturbation_difference(record.get("perturbation"), perturbations[record["index"]].to_dict())
        if what is not None:
            raise EnvError(f"{source}: episode {record['index']}'s perturbation {what} from the one its seed draws "
                           f"(seed {config.seed}): edited, or not this evaluation's")
    return config


def _numbers(value: Any, length: int) -> list[float]:
    """``value`` as ``length`` finite floats, or [] when it is not that."""
    if not isinstance(value, list) or len(value) != length:
        return []
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value):
        return []
    return [float(v) for v in value]


def _perturbation_difference(recorded: Any, drawn: dict[str, float]) -> str | None:
    """What differs between a recorded perturbation and the drawn one (None: equal)."""
    if not isinstance(recorded, dict):
        return f"is {shown(recorded)}, not an object, and differs"
    if not recorded:  # an episode that never ran (no trajectory) may carry none
        return None
    for key in sorted(set(recorded) | set(drawn)):
        was, now = recorded.get(key), drawn.get(key)
        if key not in drawn or key not in recorded:
            return f"{'has' if key in recorded else 'lacks'} {key!r}, which differs"
        if isinstance(was, bool) or not isinstance(was, (int, float)) or abs(was - now) > PERTURBATION_TOL:
            return f"{key} = {shown(was)} differs"
    return None


def load_evaluation(path: str | os.PathLike[str], model_dir: str | os.PathLike[str] | None = None) -> RecordedEvaluation:
    """Read an evaluation JSON written by `pih evaluate --json`.

    Args:
        path: the JSON file.
        model_dir: the checkpoint (default: the file's "model", taken relative to the current folder, else
            to the JSON's folder); none for an evaluation whose episodes were recorded.

    Raises:
        EnvError: missing or unreadable file, missing keys, an incomplete evaluation, no checkpoint folder, an
            evaluation of a user policy (`pih evaluate --policy`) that recorded no episodes, a recording that is not
            there.
    """
    src = Path(path)
    if not src.is_file():
        raise EnvError(f"evaluation file {src} not found")
    try:
        data = json.loads(src.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise EnvError(f"{src}: not a readable evaluation JSON ({type(err).__name__}: {err})") from None
    if not isinstance(data, dict):
        raise EnvError(f"{src}: not an evaluation JSON (a JSON object from `pih evaluate --json`)")
    from envs.evaluation.recording import recording_folder

    policy = data.get("policy") if isinstance(data.get("policy"), dict) else None
    recording = recording_folder(data, src)
    if policy is not None and recording is None:
        raise EnvError(f"{src}: an evaluation of --policy {policy.get('spec')} cannot be replayed (a policy is not run "
                       "again): evaluate it with --record-episodes DIR to export its episodes")
    if recording is not None and model_dir is not None:
        raise EnvError(f"--model {model_dir}: {src} recorded its episodes ({recording}); they are exported from there")
    missing = [k for k in ("model", "config", "per_episode", "skill") if k not in data]
    if missing:
        raise EnvError(f"{src}: missing keys {missing} (not written by `pih evaluate --json`?)")
    records = data["per_episode"]
    if not isinstance(records, list) or not records or not all(isinstance(r, dict) for r in records):
        raise EnvError(f"{src}: 'per_episode' must be a non-empty list of episode records")
    check_recorded(data, str(src))
    if recording is not None:
        pass
    elif model_dir is None:
        candidates = [Path(str(data["model"])), src.parent / str(data["model"])]
        found = next((c for c in candidates if c.is_dir()), None)
        if found is None:
            raise EnvError(f"{src}: its checkpoint {data['model']!r} is not a folder here; give it with --model")
        model_dir = found
    elif not Path(model_dir).is_dir():
        raise EnvError(f"--model {model_dir}: checkpoint folder not found")
    skill = data["skill"] if isinstance(data["skill"], dict) else {}
    config = evaluation_config_from_dict(data["config"], str(src), data.get("task"))
    return RecordedEvaluation(src, None if model_dir is None else Path(model_dir), config, data.get("scene") or {},
                              skill, records, recording, policy)


def recorded_starts(evaluation: RecordedEvaluation, indices: Sequence[int] | None = None) -> list[StartPose]:
    """The starts of the chosen episodes (default: all recorded), drawn again and checked against the records.

    Raises:
        EnvError: an index with no record, no demo starts in the skill metadata, or a redrawn start that differs
            from the recorded one.
    """
    by_index = {int(r.get("index", -1)): r for r in evaluation.records}
    chosen = sorted(by_index) if indices is None else list(indices)
    absent = [i for i in chosen if i not in by_index]
    if absent:
        raise EnvError(f"{evaluation.path}: no episode record with index {absent} (it holds {len(by_index)})")
    meta = metadata_starts(evaluation.skill, f"{evaluation.path}: 'skill'")
    drawn = evaluation_starts(meta, dataclasses.replace(evaluation.config,
                                                        episodes=max(evaluation.config.episodes, max(chosen) + 1)))
    starts = []
    for i in chosen:
        start, record = drawn[i], by_index[i]
        recorded = np.concatenate([np.asarray(record.get("start_pos"), float), np.asarray(record.get("start_quat"), float)])
        redrawn = np.concatenate([start.pose.pos, start.pose.quat])
        if recorded.shape != (7,) or not np.all(np.abs(recorded - redrawn) <= START_TOL):
            raise EnvError(f"{evaluation.path}: episode {i}'s recorded start differs from the start drawn from its "
                           "seed (the evaluation used explicit starts or another checkpoint)")
        starts.append(start)
    return starts


def check_replay(record: dict[str, Any], replayed: EpisodeRecord, source: str) -> None:
    """The replayed episode must end as recorded (success, end reason, steps).

    Raises:
        EnvError: naming the episode and the first field that differs.
    """
    for key in ("success", "reason", "steps"):
        was, now = record.get(key), getattr(replayed, key)
        if was != now:
            raise EnvError(f"{source}: the replay of episode {replayed.index} differs from its record ({key}: "
                           f"{was!r} recorded, {now!r} replayed); evaluate again with this code and checkpoint")


#: Records whose reason starts with one of these have no trajectory to replay (no episode ran, or its worker
#: was lost).
NO_TRAJECTORY: tuple[str, ...] = ("unreachable start", "worker_died", "wall_timeout")


def replay_evaluation(evaluation: RecordedEvaluation, indices: Sequence[int] | None = None,
                      on_step: Callable[[Any], None] | None = None,
                      on_episode: Callable[[StartPose, Any], None] | None = None,
                      on_trace: Callable[[dict[str, Any], EpisodeRecord, EpisodeTrace], None] | None = None
                      ) -> tuple[list[int], dict[int, str]]:
    """Replay the chosen episodes (default: all) one at a time with traces, each checked against its record;
    episodes without a trajectory (NO_TRAJECTORY) are skipped.

    Args:
        evaluation: from `load_evaluation`.
        indices: the episodes to replay.
        on_step, on_episode: as for `iter_replays` (e.g. video capture).
        on_trace: called after each episode with (recorded dict, replayed record, trace), so that a caller can
            write the episode out and let go of it before the next one.

    Returns:
        (the replayed episode indices, {skipped index: its recorded reason}).

    Raises:
        EnvError: see `recorded_starts` and `check_replay`.
        RFlowError: a missing or corrupt checkpoint.
    """
    by_index = {int(r.get("index", -1)): r for r in evaluation.records}
    chosen = sorted(by_index) if indices is None else list(indices)
    skipped = {i: str(by_index[i].get("reason")) for i in chosen
               if i in by_index and str(by_index[i].get("reason", "")).startswith(NO_TRAJECTORY)}
    starts = recorded_starts(evaluation, [i for i in chosen if i not in skipped])
    if evaluation.recording is not None:
        return _play_recorded(evaluation, starts, by_index, on_step, on_episode, on_trace), skipped
    replays = iter_replays(evaluation.model_dir, evaluation.config, starts, on_step=on_step, on_episode=on_episode)
    for start, (replayed, trace) in zip(starts, replays):
        check_replay(by_index[start.index], replayed, str(evaluation.path))
        if on_trace is not None and trace is not None:
            on_trace(by_index[start.index], replayed, trace)
    return [s.index for s in starts], skipped


def _play_recorded(evaluation: RecordedEvaluation, starts: Sequence[StartPose], by_index: dict[int, dict[str, Any]],
                   on_step: Callable[[Any], None] | None, on_episode: Callable[[StartPose, Any], None] | None,
                   on_trace: Callable[[dict[str, Any], EpisodeRecord, EpisodeTrace], None] | None) -> list[int]:
    """`replay_evaluation` of a recorded evaluation: each chosen episode's recording read and checked against its
    record, played back for ``on_step`` (envs.evaluation.recording.play) and handed to ``on_trace``."""
    from envs.evaluation.evaluate import build_env
    from envs.evaluation.recording import check_episode, episode_file, load_episode, play
    from envs.poses import Pose
    from envs.rollout.episode import record_from_dict

    assert evaluation.recording is not None
    source = f"{evaluation.path} (recording {evaluation.recording})"
    recorded = []
    for start in starts:  # every file checked before any is exported
        record = by_index[start.index]
        kept, trace = load_episode(episode_file(evaluation.recording, start.index))
        check_episode(kept, record, trace, source)
        recorded.append((start, record))
    skill = evaluation.skill
    env = build_env(skill, Pose(pos=skill["goal_pos"], quat=skill["goal_quat"]), evaluation.config)
    for start, record in recorded:
        _, trace = load_episode(episode_file(evaluation.recording, start.index))
        if on_episode is not None:
            on_episode(start, env)
        play(env, start, trace, on_step)
        if on_trace is not None:
            on_trace(record, record_from_dict(record), trace)
    return [s.index for s in starts]
