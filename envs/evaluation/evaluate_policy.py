"""Score any `Policy` as the RiemannianFlow skill is scored: `pih evaluate --policy package.module:factory`.

The factory. ``package.module:factory`` names a callable that the evaluation imports (the current folder first on
``sys.path``, as ``python -m`` does) and calls once per worker process, before the worker's first episode, as

    factory(task: PolicyTask, **options: str) -> Policy

with the nominal task (envs.policies.interface.PolicyTask: shape, clearance, control period, time and force
limits, nominal hole and goal, the controller's default stiffness) and the ``--policy-option KEY=VALUE`` pairs as
string keyword arguments. It returns an object with ``reset(observation, period_s)`` and ``act(observation) ->
Action`` (envs.policies.interface). The policy must not rely on state from the parent process.

Supervised. A user's module, its factory and its policy run only in supervised worker processes (even with one
worker), never in pih's own: this process finds the module's file without importing it (`policy_files`), and each
worker imports it and calls the factory while it starts, under the batch's start limit
(``EvaluationConfig.start_timeout_s``), then runs the episodes under the wall-time limit. A factory that takes its
process down (``os._exit``, a segfault) or hangs loses that worker's start, an infrastructure event with its reason,
and after the retries the run ends with one line (`batch.supervision.Fault`); one that raises is one line and exit
status 2. A resumed run checks the policy's source files against the journal's digest (`policy_digest`).

The same episodes. The scene is the demos' (shape, clearance, chamfer, peg mount, hole depth, from the demo file's
recorded scene, as `pih train` keeps it for the skill) with the task options given; the starts are drawn around the
demo file's start poses with the same seed and ranges (envs.evaluation.starts.evaluation_starts), each with its
hole-pose error and grasp offset; success is the same physics check. So a policy evaluated on the demos a skill was
trained on meets exactly the skill's starts and perturbations (`pih compare` pairs the two JSONs episode by episode).

Errors in the policy. What the policy itself does wrong -- an exception out of its ``reset`` or ``act``, an action
that is not an `Action` or one the controller cannot command -- ends that episode as failure "policy_error" with the
policy's traceback (envs.rollout.episode). By default the first one stops the evaluation: its workers are stopped,
the journal keeps the episodes that finished, and `envs.errors.PolicyFailure` carries the traceback out (`pih
evaluate` prints it and exits 4, writing no success rate). With ``keep_going`` the evaluation runs on: such episodes
are not failed insertions, so they are not scored -- listed apart in ``EvaluationResult.policy_errors``, out of the
success rate's denominator -- and `pih evaluate --keep-going` still exits 4 after writing its JSON.

Recorded episodes. With ``record_dir`` each worker writes every episode's trace into the recording as the episode
ends (envs.evaluation.recording): what a video, a figure or a dataset of a policy's episodes is drawn from, since a
user's policy is not replayed.

Privileged. A teacher that needs the true hole (the scripted expert, envs.policies.expert) is evaluated with
``privileged=True`` (`--privileged`), which fills ``Observation.privileged``; the JSON records it.
"""

from __future__ import annotations

import importlib
import os
import re
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

from batch import Journal, WorkerInitError
from envs.errors import EnvError, PolicyFailure
from envs.evaluation.config import EvaluationConfig
from envs.evaluation.evaluate import SlotPool, build_env, run_episodes, run_settings
from envs.evaluation.result import EvaluationResult
from envs.evaluation.starts import evaluation_starts, metadata_starts
from envs.io.jsonable import to_jsonable
from envs.policies.interface import Policy, PolicyTask, is_policy, policy_task
from envs.poses import Pose
from envs.rollout.episode import StartPose
from envs.rollout.episode import record_from_dict
from numerics.small_linalg import norm

FACTORY_SIGNATURE = "factory(task: PolicyTask, **options: str) -> Policy"
_DOTTED = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")
_KEY = re.compile(r"^[A-Za-z_]\w*$")


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return f"{type(err).__name__}: {text.splitlines()[0]}" if text else type(err).__name__


@dataclass(frozen=True)
class PolicySpec:
    """A user policy to evaluate (picklable: workers import and build it themselves).

    Attributes:
        spec: "package.module:factory" (the factory may be a dotted attribute path, "module:Class.make").
        options: (key, value) string pairs passed to the factory as keyword arguments.
        privileged: observations carry the true hole (a teacher only).
        search_path: a folder put first on ``sys.path`` before the import (`pih evaluate`: the current folder).

    Raises:
        EnvError: a spec that is not "module:attribute" with dotted Python names, or a bad option key.
    """

    spec: str
    options: tuple[tuple[str, str], ...] = ()
    privileged: bool = False
    search_path: str | None = None

    def __post_init__(self) -> None:
        module, colon, attribute = str(self.spec).partition(":")
        if not colon:
            raise EnvError(f"--policy {self.spec!r} must be package.module:factory (no ':' in it)")
        if not (_DOTTED.match(module) and _DOTTED.match(attribute)):
            raise EnvError(f"--policy {self.spec!r} must be package.module:factory with Python names on both sides "
                           "of the ':'")
        for key, value in self.options:
            if not (_KEY.match(key) and isinstance(value, str)):
                raise EnvError(f"--policy-option {key}={value!r}: the key must be a Python name")

    @property
    def module(self) -> str:
        """The module part of the spec."""
        return self.spec.partition(":")[0]

    @property
    def attribute(self) -> str:
        """The factory's (dotted) name in the module."""
        return self.spec.partition(":")[2]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: spec, options and privilege (not the search path, which is where it ran)."""
        return {"spec": self.spec, "options": dict(self.options), "privileged": self.privileged}


def parse_policy_options(values: Sequence[str]) -> tuple[tuple[str, str], ...]:
    """``--policy-option KEY=VALUE`` strings as (key, value) pairs.

    Raises:
        EnvError: a value without '=' or a repeated key.
    """
    pairs: list[tuple[str, str]] = []
    for text in values:
        key, eq, value = text.partition("=")
        if not eq or not _KEY.match(key):
            raise EnvError(f"--policy-option {text!r} must be KEY=VALUE with a Python name as the key")
        if key in dict(pairs):
            raise EnvError(f"--policy-option {key} is given twice")
        pairs.append((key, value))
    return tuple(pairs)


def load_factory(spec: PolicySpec) -> Callable[..., Any]:
    """Import ``spec.module`` and return its callable ``spec.attribute``.

    Raises:
        EnvError: one line naming the spec: the module cannot be imported (or fails while importing), has no such
            attribute, or the attribute is not callable.
    """
    if spec.search_path and spec.search_path not in sys.path:
        sys.path.insert(0, spec.search_path)
    try:
        target: Any = importlib.import_module(spec.module)
    except ImportError as err:
        raise EnvError(f"--policy {spec.spec}: cannot import module {spec.module!r} ({_first_line(err)})") from None
    except Exception as err:  # the user's module failed while importing
        raise EnvError(f"--policy {spec.spec}: importing {spec.module!r} failed ({_first_line(err)})") from None
    for part in spec.attribute.split("."):
        if not hasattr(target, part):
            raise EnvError(f"--policy {spec.spec}: module {spec.module!r} has no attribute {spec.attribute!r}")
        target = getattr(target, part)
    if not callable(target):
        raise EnvError(f"--policy {spec.spec}: {spec.attribute!r} is a {type(target).__name__}, not a callable "
                       f"factory ({FACTORY_SIGNATURE})")
    return target


MAX_POLICY_FILES = 2_000
"""At most this many source files enter a policy's digest (a package larger than that is cut, in sorted order)."""


def policy_files(spec: PolicySpec) -> list[Path]:
    """The source files of the spec's module, found on its search path (``spec.search_path`` first, then
    ``sys.path``) without importing or running any of it: the module's file and, when it sits in a package, every
    .py file of that package's folder and below (what it most likely imports); a package named as the module: its
    folder's.

    Raises:
        EnvError: the module is not found (one line naming the spec).
    """
    import importlib.machinery
    import importlib.util

    parts = spec.module.split(".")
    path = ([spec.search_path] if spec.search_path else []) + [p for p in sys.path if p != spec.search_path]
    found = None
    for depth in range(len(parts)):
        name = ".".join(parts[:depth + 1])
        try:
            found = importlib.machinery.PathFinder.find_spec(name, path)
            if found is None and depth == 0 and name not in sys.builtin_module_names:
                found = importlib.util.find_spec(name)  # an installed package's own finder (a top level name
                #                                          is found without importing anything)
        except (ImportError, ValueError):
            found = None
        if found is None or (depth < len(parts) - 1 and found.submodule_search_locations is None):
            raise EnvError(f"--policy {spec.spec}: cannot import module {spec.module!r} (no module named {name!r} "
                           f"on the path, the current folder first)")
        path = list(found.submodule_search_locations or [])
    assert found is not None
    if found.origin is None or not Path(found.origin).is_file():
        folders = [Path(p) for p in found.submodule_search_locations or []]  # a namespace package
        return sorted(f for folder in folders for f in folder.rglob("*.py"))[:MAX_POLICY_FILES]
    origin = Path(found.origin)
    package = origin.parent if origin.name == "__init__.py" or len(parts) > 1 else None
    if package is None:
        return [origin]
    files = sorted(f for f in package.rglob("*.py") if "__pycache__" not in f.parts)[:MAX_POLICY_FILES]
    return files if origin in files else [origin, *files]


def policy_digest(spec: PolicySpec) -> str:
    """SHA-256 of the policy's source files (`policy_files`: their paths relative to the first one's folder and
    their bytes): what a resumed run compares with the journal's, so that an edited policy is not mixed into a run
    begun with another version.

    Raises:
        EnvError: the module is not found, or a file cannot be read.
    """
    import hashlib

    files = policy_files(spec)
    root = files[0].parent if files else Path(".")
    digest = hashlib.sha256(spec.module.encode())
    for path in files:
        try:
            data = path.read_bytes()
        except OSError as err:
            raise EnvError(f"--policy {spec.spec}: cannot read {path} ({err.strerror or err})") from None
        name = os.path.relpath(path, root)
        digest.update(f"{name}\0{len(data)}\0".encode())
        digest.update(data)
    return digest.hexdigest()


def make_user_policy(spec: PolicySpec, task: PolicyTask) -> Policy:
    """Call the spec's factory with the task and options and check that it returned a `Policy`.

    Raises:
        EnvError: see `load_factory`; the factory raised; or it returned something without reset/act methods.
    """
    factory = load_factory(spec)
    try:
        policy = factory(task, **dict(spec.options))
    except Exception as err:
        raise EnvError(f"--policy {spec.spec}: the factory raised {_first_line(err)} (it is called as "
                       f"{FACTORY_SIGNATURE})") from None
    if not is_policy(policy):
        raise EnvError(f"--policy {spec.spec}: the factory returned a {type(policy).__name__}, not a Policy (an "
                       "object with reset(observation, period_s) and act(observation) methods)")
    return policy


def demo_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """What an evaluation needs from a demo file (as a checkpoint keeps it): shape, clearance, recorded scene, goal,
    start poses, and the file's path and SHA-256.

    Raises:
        EnvError: a missing or invalid demo file (envs.demos.file.load_demos).
    """
    from envs.demos.file import load_demos
    from rflow.skill_io import file_sha256

    demos = load_demos(path)
    scene = demos.config.get("scene") if isinstance(demos.config.get("scene"), dict) else None
    return {"shape": demos.shape, "clearance_m": demos.clearance_m, "scene": scene,
            "goal_pos": demos.goal_pos.tolist(), "goal_quat": demos.goal_quat.tolist(),
            "demo_starts": {"pos": demos.pos[:, 0].tolist(), "quat": demos.quat[:, 0].tolist()},
            "demo_file": str(Path(path).resolve()), "demo_sha256": file_sha256(path)}


def build_policy_setup(spec: PolicySpec, metadata: dict[str, Any], config: EvaluationConfig) -> tuple[Any, Policy]:
    """The evaluation's environment (`build_env` of the demos' metadata) and the user's policy for it (with
    ``follow_observed_hole``, run in the observed hole's frame from the task's nominal goal, envs.policies.goal_frame).

    Raises:
        EnvError: an invalid scene, or see `make_user_policy`.
    """
    goal = Pose(pos=metadata["goal_pos"], quat=metadata["goal_quat"])
    env = build_env(metadata, goal, config)
    task = policy_task(env)
    policy = make_user_policy(spec, task)
    if config.follow_observed_hole:
        from envs.policies.goal_frame import GoalFramePolicy

        return env, GoalFramePolicy(policy, task.nominal_goal)
    return env, policy


@dataclass(frozen=True)
class _PolicySetup:
    """What a worker needs to rebuild the environment and the policy (plain data, picklable)."""

    spec: PolicySpec
    metadata: dict[str, Any]
    config: EvaluationConfig
    record_dir: str | None = None
    record_only: frozenset[int] | None = None


def _init_policy_worker(setup: _PolicySetup) -> dict[str, Any]:
    """Worker context: the environment and the user's policy (torch, if the policy uses it, on one thread)."""
    import torch

    torch.set_num_threads(1)
    env, policy = build_policy_setup(setup.spec, setup.metadata, setup.config)
    return {"env": env, "policy": policy, "gain": setup.config.feedforward_gain, "privileged": setup.spec.privileged,
            "slots": SlotPool(env, policy, _PolicySlotMaker(setup)), "user_policy": True,
            "record_dir": setup.record_dir, "record_only": setup.record_only}


class _PolicySlotMaker:
    """Another lockstep slot of a policy evaluation: an environment of its own and a policy from the factory."""

    def __init__(self, setup: _PolicySetup):
        self.setup = setup

    def __call__(self) -> tuple[Any, Policy]:
        return build_policy_setup(self.setup.spec, self.setup.metadata, self.setup.config)


def policy_journal_run(spec: PolicySpec, metadata: dict[str, Any], config: EvaluationConfig) -> dict[str, Any]:
    """What identifies a policy evaluation for its journal: the spec and options, the digest of the policy's source
    files (`policy_digest`), the demo file's checksum and every config field that changes a record.

    Raises:
        EnvError: the policy's module is not found.
    """
    return {"task": "pih evaluate --policy", "policy": spec.to_dict(), "policy_sha256": policy_digest(spec),
            "demo_sha256": metadata.get("demo_sha256"), **run_settings(config)}


POLICY_ERROR = "policy_error"
"""The failure kind of an episode in which the user's policy failed (module docstring)."""


def policy_failure(record: dict[str, Any]) -> PolicyFailure | None:
    """The `PolicyFailure` of a record whose policy failed (failure "policy_error"), else None."""
    if record.get("failure") != POLICY_ERROR:
        return None
    reason = str(record.get("reason", POLICY_ERROR))
    return PolicyFailure(int(record.get("index", -1)), reason, str(record.get("traceback") or reason))


def _stop_at_policy_error(record: dict[str, Any]) -> None:
    failure = policy_failure(record)
    if failure is not None:
        raise failure


def evaluate_policy(spec: PolicySpec, metadata: dict[str, Any], config: EvaluationConfig = EvaluationConfig(),
                    progress: bool = True, starts: Sequence[StartPose] | None = None,
                    journal: Journal | None = None, keep_going: bool = False,
                    record_dir: str | os.PathLike[str] | None = None,
                    record_only: Sequence[int] | None = None) -> EvaluationResult:
    """Run ``config.episodes`` episodes of the user's policy (module docstring) and collect the records.

    Args:
        spec: the policy.
        metadata: the demos' (`demo_metadata`): scene, goal and the start poses the starts are drawn around.
        config: the evaluation (its skill fields -- mode, lookahead, speed, stiffness, adaptation -- are unused;
            ``follow_observed_hole`` runs the policy in the observed hole's frame).
        progress: tqdm bar.
        starts: explicit starts (default: `evaluation_starts` around the demos' starts).
        journal: as for envs.evaluation.evaluate.evaluate (open it with `policy_journal_run`).
        keep_going: run on after the policy fails in an episode (module docstring); False: stop at the first.
        record_dir: record the episodes' traces into this folder as they end (envs.evaluation.recording, prepared
            with `prepare_recording`); the result names it.
        record_only: record only these episode indices (None: all).

    Returns:
        EvaluationResult with ``policy`` set (``model_dir`` empty), the episodes in which the policy failed in
        ``policy_errors`` (only with ``keep_going``).

    Raises:
        PolicyFailure: without ``keep_going``, the policy failed in an episode (one the journal holds, or the first
            of this run), with its traceback; the journal keeps what finished.
        EnvError: a bad spec, a factory that fails or returns no Policy (in the worker that calls it), an invalid
            scene, no demo starts.
        BatchError: workers that cannot build the environment.
    """
    wall = time.perf_counter()
    goal = Pose(pos=metadata["goal_pos"], quat=metadata["goal_quat"])
    env = build_env(metadata, goal, config)  # every check of ours in this process first; the user's code: none
    goal_mismatch_mm = norm(env.goal.pos - metadata["goal_pos"]) * 1e3
    scene_config = env.scene.config
    scene = to_jsonable(asdict(scene_config))
    if starts is None:
        starts = evaluation_starts(metadata_starts(metadata, f"--demos {metadata.get('demo_file')}"), config)
    del env  # the workers build their own, with the policy
    check = None if keep_going else _stop_at_policy_error
    if check is not None and journal is not None:  # a resumed run stops where the earlier one did
        wanted = {str(s.index) for s in starts}
        for key, record in sorted(journal.done().items(), key=lambda kv: int(kv[0]) if kv[0].isdigit() else -1):
            if key in wanted:
                check(record)
    folder = None if record_dir is None else str(Path(record_dir).resolve())
    setup = _PolicySetup(spec, metadata, config, folder, None if record_only is None else frozenset(record_only))
    try:
        outcome, records, earlier_s = run_episodes(starts, setup, _init_policy_worker, {}, config, progress, journal,
                                                   f"evaluate ({spec.spec})", isolate=True,  # a user's code may take
                                                   check=check)                              # its process down
    except WorkerInitError as err:
        if err.kind == "EnvError":  # the factory (or its module) failed in the worker: the user's input
            raise EnvError(err.detail) from None
        raise
    scored = [r for r in records if r.failure != POLICY_ERROR]
    return EvaluationResult(config, scored, earlier_s + time.perf_counter() - wall, "", metadata, scene,
                            goal_mismatch_mm, outcome.complete, outcome.interrupted,
                            [record_from_dict(r) for r in outcome.infrastructure_errors.values()], outcome.events,
                            outcome.workers, outcome.fault, policy=spec.to_dict(),
                            task=config.task.with_scene(scene_config), events_before=outcome.events_before,
                            policy_errors=[r for r in records if r.failure == POLICY_ERROR],
                            recorded_episodes=folder)
