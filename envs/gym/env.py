"""Gymnasium environment ``pih/PegInHole-v1``: the simulator (envs.sim.env.PegInHoleEnv) behind Gymnasium's API, its
episodes run by the episode loop every policy runs through (envs.rollout.episode.EpisodeRun), so a Gym episode is
scored and recorded exactly as `pih evaluate` records it.

    import envs.gym_env   # registers pih/PegInHole-v1 (or gymnasium.make("envs.gym_env:pih/PegInHole-v1", ...))
    env = gymnasium.make("pih/PegInHole-v1", shape="square", clearance_mm=0.2)

Options (keyword arguments of ``gymnasium.make``): ``task`` (an envs.task.task.Task, e.g. ``preset("factory")`` or
``Task.from_toml("my_task.toml")``: its scene, perturbations, force and time limits and success tolerances; its start
range, which is around demos' starts, applies to ``episode`` resets only); ``demos`` (a demo file: the scene and the
starts of `pih evaluate --policy ... --demos FILE`, see Randomness) with ``evaluation_seed`` (its ``--seed``, 0); then
any field of SceneConfig, EpisodeConfig or ImpedanceConfig, or of a config nested in them (EpisodeConfig.perturbations,
.start_region, .success, ...), by its name; a field ending in ``_m`` may also be given in millimetres as ``..._mm``
(``clearance_mm=0.2`` sets ``clearance_m=0.0002``, ``hole_error_mm=1`` the perturbations' ``hole_error_m``). Besides:
``stiffness_action`` (bool: the action holds the stiffness), ``privileged`` (bool, default False), ``reward`` (a
RewardConfig), ``render_mode`` ("rgb_array" or None), ``camera``, ``width``, ``height`` (of the frames). An unknown
option is an EnvError naming it.

Spaces: the observation is the policy's `Observation`, the action an `Action` (envs.gym.schema: the one schema).
``step`` also takes an `Action` itself (a `Policy`'s, with its feed-forward: envs.gym.agent.run_policy). A malformed
action (not real numbers, a wrong shape, NaN or inf, an Action the controller refuses) is an EnvError naming it, in one
line; so is ``step`` before ``reset`` or after the episode ended.

Info: after every reset and step the simulator's truth under named keys (envs.gym.schema.TRUTH_KEYS), ``time_s``;
after a step ``reason`` (the simulator's end reason, None while running), ``is_success``, ``commanded_tcp_pos`` and
``commanded_tcp_quat`` (the pose the controller was sent); at the episode's end ``episode_record``: the episode's record
as `pih evaluate --json` writes it (envs.rollout.episode.EpisodeRecord.to_dict).

Reward, dense: r_t = -(|p - g_p| + ROT_WEIGHT_M_PER_RAD angle(q, g_q)) (metres; 0.1 m per rad makes 10 deg
cost like 17 mm) for the peg's own peg_tip (p, q) and the true goal g inside the (possibly displaced) hole,
plus ``success_bonus`` on the step at which the simulator declares success. ``terminated`` on success or on
any other end reason but the time limit (instability, force limit); ``truncated`` at the time limit.

Randomness: ``reset(seed=s)`` seeds ``np_random``; the simulator draws the episode's perturbation (hole-pose error,
grasp offset) and start pose from a seed taken from ``np_random``, so the same seed gives the same episode.
``options={"start_pose": (pos, quat)}`` starts at a given tcp pose (the perturbation drawn, or
``"perturbation": Perturbation``); with ``demos``, ``options={"episode": k}`` runs episode k of `pih evaluate --policy
... --demos FILE --seed evaluation_seed` with the same task options: its start and perturbation, its record.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium
import mujoco
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from controllers.impedance import ImpedanceConfig
from envs.cell.scene_config import SceneConfig
from envs.errors import EnvError
from envs.gym.schema import (ENV_ID, PRIVILEGED_PREFIX, ActionSchema, observation_dict, observation_sizes,
                             truth_info)
from envs.media.rendering import MAX_FRAME_PX
from envs.policies.interface import Action
from envs.poses import Pose, quat_angle_rad
from envs.rollout.episode import EpisodeRecord, EpisodeRun, StartPose
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.sim.observation import REASON_TIME_LIMIT, SimulatorState
from envs.task.perturbation import Perturbation
from envs.task.task import Task
from numerics.small_linalg import norm

FloatArray = npt.NDArray[np.float64]

JOINT_RANGE_MARGIN: float = 0.1
"""rad for hinge, m/10 for slide joints: MuJoCo's joint limits are soft, so qpos can pass a limit slightly."""
ROT_WEIGHT_M_PER_RAD: float = 0.1
WORKSPACE_HALF_WIDTH_M: float = 2.0
"""Positions are bounded by +-2 m per axis around the robot base (the arm reaches ~1.2 m with the peg)."""
MAX_GRIPPER_WIDTH_M: float = 0.1
"""Bound of the finger opening (the Franka hand opens 80 mm)."""
RENDER_OPTIONS: tuple[str, ...] = ("render_mode", "camera", "width", "height")
RESET_OPTIONS: tuple[str, ...] = ("start_pose", "perturbation", "episode")


@dataclass(frozen=True)
class RewardConfig:
    """Dense reward (module docstring): distance weight per metre, rotation weight in m/rad, success bonus."""

    distance_weight: float = 1.0
    rot_weight_m_per_rad: float = ROT_WEIGHT_M_PER_RAD
    success_bonus: float = 100.0

    def __post_init__(self) -> None:
        for name in ("distance_weight", "rot_weight_m_per_rad", "success_bonus"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0.0):
                raise EnvError(f"RewardConfig.{name}={value!r} must be finite and >= 0")


def configs_from_kwargs(options: dict[str, Any], task: Task | None = None,
                        base: tuple[SceneConfig, ImpedanceConfig, EpisodeConfig] | None = None,
                        ) -> tuple[SceneConfig, ImpedanceConfig, EpisodeConfig]:
    """Map ``gymnasium.make`` keyword arguments onto the three simulator configs (module docstring), starting from
    ``base`` when given, else ``task``'s scene and episode settings (else the configs' defaults).

    A name is a field of SceneConfig, ImpedanceConfig or EpisodeConfig, or a field of a config nested in one
    of them (e.g. ``hole_error_m`` of EpisodeConfig.perturbations, ``max_angle_deg`` of its start_region);
    a field ending in ``_m`` may be given in millimetres as ``_mm``.

    Raises:
        EnvError: an option that names no field, one that names fields of two configs, or an invalid value
            (the config's own check).
    """
    if task is not None and not isinstance(task, Task):
        raise EnvError(f"{ENV_ID}: task={task!r} must be an envs.task.task.Task")
    if base is None:
        base = (SceneConfig() if task is None else task.scene_config(), ImpedanceConfig(),
                EpisodeConfig() if task is None else EpisodeConfig.from_task(task))
    configs: dict[str, Any] = dict(zip(("scene", "controller", "episode"), base))
    owners: dict[str, list[tuple[str, str | None]]] = {}
    for key, cfg in configs.items():
        for top in dataclasses.fields(cfg):
            owners.setdefault(top.name, []).append((key, None))
            nested = getattr(cfg, top.name)
            if dataclasses.is_dataclass(nested) and not isinstance(nested, type):
                for inner in dataclasses.fields(nested):
                    owners.setdefault(inner.name, []).append((key, top.name))
    chosen: dict[tuple[str, str | None], dict[str, Any]] = {}
    for name, value in options.items():
        field_name = name
        if name not in owners and name.endswith("_mm") and name[:-3] + "_m" in owners:
            field_name = name[:-3] + "_m"
            try:
                value = float(value) * 1e-3
            except (TypeError, ValueError):
                raise EnvError(f"{ENV_ID}: option {name}={value!r} must be a number (millimetres)") from None
        if field_name not in owners:
            raise EnvError(f"{ENV_ID}: unknown option {name!r}; options are task, demos, evaluation_seed, "
                           "stiffness_action, privileged, reward, "
                           f"{', '.join(RENDER_OPTIONS)}, and the config fields {', '.join(sorted(owners))} "
                           f"(any *_m also as *_mm)")
        if len(owners[field_name]) > 1:
            where = " and ".join(f"{key}{'.' + nested if nested else ''}" for key, nested in owners[field_name])
            raise EnvError(f"{ENV_ID}: option {name!r} is ambiguous (a field of {where})")
        chosen.setdefault(owners[field_name][0], {})[field_name] = value
    try:
        for (key, nested), values in sorted(chosen.items(), key=lambda item: item[0][1] is not None):
            if nested is None:
                configs[key] = dataclasses.replace(configs[key], **values)
            else:
                inner = dataclasses.replace(getattr(configs[key], nested), **values)
                configs[key] = dataclasses.replace(configs[key], **{nested: inner})
    except TypeError as err:
        raise EnvError(f"{ENV_ID}: bad option ({err})") from None
    return configs["scene"], configs["controller"], configs["episode"]


def joint_position_bounds(model: mujoco.MjModel, size: int) -> tuple[FloatArray, FloatArray]:
    """Bounds of the first ``size`` qpos entries: limited hinge/slide joints by their range (+- margin),
    quaternion entries of free/ball joints by [-1, 1], everything else unbounded."""
    low, high = np.full(model.nq, -np.inf), np.full(model.nq, np.inf)
    widths = {mujoco.mjtJoint.mjJNT_FREE: 7, mujoco.mjtJoint.mjJNT_BALL: 4}
    for j in range(model.njnt):
        kind, adr = mujoco.mjtJoint(model.jnt_type[j]), int(model.jnt_qposadr[j])
        if kind in widths:
            quat = slice(adr + widths[kind] - 4, adr + widths[kind])
            low[quat], high[quat] = -1.0, 1.0
        elif model.jnt_limited[j]:
            margin = JOINT_RANGE_MARGIN if kind == mujoco.mjtJoint.mjJNT_HINGE else 0.1 * JOINT_RANGE_MARGIN
            low[adr], high[adr] = model.jnt_range[j, 0] - margin, model.jnt_range[j, 1] + margin
    if size > model.nq:
        return np.full(size, -np.inf), np.full(size, np.inf)
    return low[:size], high[:size]


def _box(low: npt.ArrayLike, high: npt.ArrayLike, dtype: Any = np.float64) -> spaces.Box:
    return spaces.Box(low=np.asarray(low, dtype=dtype), high=np.asarray(high, dtype=dtype), dtype=dtype)


class StartError(EnvError):
    """An episode that could not start (an unreachable or colliding start); ``record`` is its record."""

    def __init__(self, message: str, record: EpisodeRecord):
        super().__init__(message)
        self.record = record


class _Commanded:
    """The episode loop's policy in a Gym episode: the actions come from ``step``, so it only takes the reset."""

    def reset(self, observation: Any, period_s: float) -> None:
        pass

    def act(self, observation: Any) -> Action:
        raise EnvError(f"{ENV_ID}: the actions of a Gym episode come from step()")


class PegInHoleGymEnv(gymnasium.Env[dict[str, Any], np.ndarray]):
    """``pih/PegInHole-v1``: the Gymnasium face of PegInHoleEnv (spaces, reward and ends in the module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, render_mode: str | None = None, stiffness_action: bool = False, privileged: bool = False,
                 reward: RewardConfig = RewardConfig(), camera: str = "front", width: int = 640, height: int = 480,
                 task: Task | None = None, demos: str | Path | None = None, evaluation_seed: int = 0,
                 **options: Any):
        """Args: see the module docstring. Raises: EnvError on an unknown or invalid option."""
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise EnvError(f"{ENV_ID}: render_mode={render_mode!r} must be None or 'rgb_array'")
        if not isinstance(reward, RewardConfig):
            raise EnvError(f"{ENV_ID}: reward={reward!r} must be a RewardConfig")
        for name, flag in (("stiffness_action", stiffness_action), ("privileged", privileged)):
            if not isinstance(flag, (bool, np.bool_)):  # "no" would count as true
                raise EnvError(f"{ENV_ID}: {name}={flag!r} must be True or False")
        if isinstance(evaluation_seed, bool) or not isinstance(evaluation_seed, (int, np.integer)) or \
                evaluation_seed < 0:
            raise EnvError(f"{ENV_ID}: evaluation_seed={evaluation_seed!r} must be an integer >= 0")
        self._evaluation: tuple[dict[str, Any], Task] | None = None
        base = None
        if demos is not None:
            base, self._evaluation = self._demos_setup(demos, task)
        scene_config, controller_config, episode_config = configs_from_kwargs(options, task, base)
        self.render_mode = render_mode
        self.reward_config = reward
        self.privileged = bool(privileged)
        self.evaluation_seed = int(evaluation_seed)
        if not isinstance(camera, str):  # MuJoCo's name lookup takes a string only (None crashes it)
            raise EnvError(f"{ENV_ID}: camera={camera!r} must be the name of a camera of the scene")
        for name, value in (("width", width), ("height", height)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 16 <= value <= MAX_FRAME_PX:
                raise EnvError(f"{ENV_ID}: {name}={value!r} must be an integer number of pixels in [16, "
                               f"{MAX_FRAME_PX}]")
        self._camera, self._size = camera, (int(width), int(height))
        self._renderer: Any = None
        self.sim = PegInHoleEnv(scene_config, controller_config, episode_config)
        if mujoco.mj_name2id(self.sim.model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            raise EnvError(f"{ENV_ID}: camera={camera!r} is not a camera of the scene")
        self.nominal_goal: Pose = self.sim.nominal_goal
        self.action_schema = ActionSchema.for_cell(self.sim.nominal_hole, self.sim.nominal_goal,
                                                   self.sim.config.start_region, bool(stiffness_action))
        self.action_space = _box(-np.ones(self.action_schema.size), np.ones(self.action_schema.size), np.float32)
        self._run: EpisodeRun | None = None
        self._resets = 0
        self._starts: list[StartPose] = []
        self.episode_record: EpisodeRecord | None = None
        """The record of the last episode that ended (also an unreachable start's), as `pih evaluate` records it."""
        self.sim.reset(start_pose=self.sim.nominal_start())  # for the observation space's sizes
        self.observation_space = self._observation_space()

    @staticmethod
    def _demos_setup(demos: str | Path, task: Task | None) -> tuple[tuple[SceneConfig, ImpedanceConfig, EpisodeConfig],
                                                                    tuple[dict[str, Any], Task]]:
        """The configs `pih evaluate --policy ... --demos FILE` runs (the demos' scene, the task's episodes: with a
        ``task`` its scene fields replace the demos', as --task does) and what its starts are drawn from."""
        from envs.evaluation.config import SCENE_FROM_TASK, EvaluationConfig
        from envs.evaluation.evaluate import scene_config_for
        from envs.evaluation.evaluate_policy import demo_metadata

        if task is not None and not isinstance(task, Task):
            raise EnvError(f"{ENV_ID}: task={task!r} must be an envs.task.task.Task")
        metadata = demo_metadata(demos)
        config = EvaluationConfig(task=task or Task(), scene_from_task=SCENE_FROM_TASK if task is not None else ())
        goal = Pose(pos=np.asarray(metadata["goal_pos"]), quat=np.asarray(metadata["goal_quat"]))
        scene = scene_config_for(metadata, config, goal)
        return (scene, ImpedanceConfig(), EpisodeConfig.from_task(config.task)), (metadata, config.task)

    # ------------------------------------------------------------------------------------------- spaces

    @property
    def stiffness_action(self) -> bool:
        """The action holds the stiffness."""
        return self.action_schema.stiffness

    @property
    def physical_low(self) -> FloatArray:
        """The lower end of the action's physical range (envs.gym.schema)."""
        return np.asarray(self.action_schema.low)

    @property
    def physical_high(self) -> FloatArray:
        """The upper end of the action's physical range (envs.gym.schema)."""
        return np.asarray(self.action_schema.high)

    @property
    def control_period_s(self) -> float:
        """Seconds per step."""
        return self.sim.control_period_s

    def to_physical(self, action: npt.ArrayLike) -> FloatArray:
        """The physical command u = c + a h of a normalised action (envs.gym.schema.ActionSchema.to_physical)."""
        return self.action_schema.to_physical(action)

    def to_action(self, physical: npt.ArrayLike) -> np.ndarray:
        """The normalised action of a physical command (envs.gym.schema.ActionSchema.to_action)."""
        return self.action_schema.to_action(physical)

    def policy_action(self, action: npt.ArrayLike | Action) -> Action:
        """The `Action` a step commands: an Action as it is, a normalised action through the schema.

        Raises:
            EnvError: a malformed normalised action (not real numbers, a wrong shape, NaN or inf).
        """
        return action if isinstance(action, Action) else self.action_schema.to_policy_action(action)

    def _observation_space(self) -> spaces.Dict:
        first = observation_dict(self._observe(), self.privileged)
        sizes = {k: v.size for k, v in first.items()}
        assert set(sizes) == set(observation_sizes(self.privileged)), "the observation is the schema's"
        q_low, q_high = joint_position_bounds(self.sim.model, sizes["qpos"])
        workspace = (-WORKSPACE_HALF_WIDTH_M, WORKSPACE_HALF_WIDTH_M)
        unbounded = (-np.inf, np.inf)
        bounds: dict[str, tuple[Any, Any]] = {
            "time_s": (0.0, self.sim.config.time_limit_s + self.sim.control_period_s), "qpos": (q_low, q_high),
            "qvel": unbounded, "gripper_width_m": (0.0, MAX_GRIPPER_WIDTH_M), "wrist_wrench": unbounded,
        }
        out: dict[str, spaces.Space] = {}
        for key, size in sizes.items():
            if key.endswith("_quat") or key == f"{PRIVILEGED_PREFIX}hole_axis":
                low, high = -1.0, 1.0
            elif key.endswith("_pos"):
                low, high = workspace
            else:
                low, high = bounds[key]
            out[key] = _box(np.broadcast_to(low, (size,)), np.broadcast_to(high, (size,)))
        return spaces.Dict(out)

    def _observe(self) -> Any:
        from envs.policies.interface import observe

        return observe(self.sim, self.privileged)

    # ------------------------------------------------------------------------------------------- episode

    def reward(self, obs: SimulatorState) -> float:
        """-(w_d |p - g_p| + w_r angle(q, g_q)) + bonus on success, g the true goal (module docstring)."""
        cfg = self.reward_config
        goal = self.sim.goal
        distance = norm(obs.peg_tip.pos - goal.pos)
        angle = float(quat_angle_rad(obs.peg_tip.quat, goal.quat))
        return -cfg.distance_weight * (distance + cfg.rot_weight_m_per_rad * angle) + (
            cfg.success_bonus if obs.success else 0.0)

    def evaluation_start(self, episode: int) -> StartPose:
        """Episode ``episode``'s start and perturbation in `pih evaluate --policy ... --demos FILE --seed
        evaluation_seed` (envs.evaluation.starts; the starts come from one stream, so episode k's does not depend on
        how many are drawn).

        Raises:
            EnvError: an environment made without ``demos``, or a negative index.
        """
        if self._evaluation is None:
            raise EnvError(f"{ENV_ID}: reset option 'episode' needs an environment made with demos=FILE (the demo "
                           "file whose starts `pih evaluate --policy --demos` draws)")
        if isinstance(episode, bool) or not isinstance(episode, (int, np.integer)) or episode < 0:
            raise EnvError(f"{ENV_ID}: reset option episode={episode!r} must be an integer >= 0")
        if episode >= len(self._starts):
            from envs.evaluation.starts import metadata_starts, sample_starts

            metadata, task = self._evaluation
            demo_starts = metadata_starts(metadata, "the demo file")
            start = task.start
            self._starts = sample_starts(demo_starts["pos"], demo_starts["quat"], max(int(episode) + 1,
                                                                                          2 * len(self._starts)),
                                         self.evaluation_seed, start.pos_range_m, start.rot_range_deg, start.around,
                                         self.sim.config.perturbations)
        return self._starts[int(episode)]

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
        """Start an episode (module docstring: Randomness). ``info`` holds the start, the perturbation, the episode's
        index and the simulator's truth.

        Raises:
            EnvError: an unknown option. StartError (an EnvError): an unreachable or colliding start; its
                ``record`` (and ``episode_record``) is the episode's record, as `pih evaluate` records it.
        """
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - set(RESET_OPTIONS)
        if unknown:
            raise EnvError(f"{ENV_ID}: unknown reset option(s) {sorted(unknown)}; they are {', '.join(RESET_OPTIONS)}")
        if "episode" in options:
            if set(options) != {"episode"}:
                raise EnvError(f"{ENV_ID}: reset option 'episode' sets the start and perturbation; give it alone")
            start = self.evaluation_start(options["episode"])
        else:
            perturbation = options.get("perturbation")
            if perturbation is not None and not isinstance(perturbation, Perturbation):
                raise EnvError(f"{ENV_ID}: reset option perturbation={perturbation!r} must be an "
                               "envs.task.perturbation.Perturbation")
            sim_seed = int(self.np_random.integers(2**63 - 1))
            self._run = None
            self.sim.reset(seed=sim_seed, start_pose=options.get("start_pose"), perturbation=perturbation)
            start = StartPose(self._resets, -1, self.sim.start, self.sim.perturbation)
        self._resets += 1
        self._run = EpisodeRun(self.sim, _Commanded(), start, privileged=self.privileged)
        if not self._run.begin():
            record, _ = self._run.finish()
            self.episode_record, self._run = record, None
            raise StartError(f"{ENV_ID}: episode {start.index} did not start: {record.reason}", record)
        info = {"episode": start.index, "start_pos": self.sim.start.pos.copy(),
                "start_quat": self.sim.start.quat.copy(), "perturbation": self.sim.perturbation,
                "time_s": self.sim.observation.time_s, **truth_info(self.sim.observation)}
        return observation_dict(self._run.observation(), self.privileged), info

    def step(self, action: npt.ArrayLike | Action) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        """One control period of ``action`` (a normalised action, or a policy's `Action`); returns (obs, reward,
        terminated, truncated, info) (module docstring).

        Raises:
            EnvError: before the first ``reset()``, after the episode ended (or its reset failed), or a bad action
                (not real numbers, a wrong shape, NaN or inf, an Action the controller refuses).
        """
        run = self._run
        if run is None:
            raise EnvError(f"{ENV_ID}: step() before reset(): call reset() first")
        if not run.running:
            ended = self.sim.reason if self.sim.reason is not None else "an error"
            raise EnvError(f"{ENV_ID}: no episode to step: it ended ({ended}); call reset() first")
        period = run.command(self.policy_action(action))
        if period is None:  # the Action was refused (the episode loop ended the episode with the reason)
            self.episode_record = run.finish()[0]
            raise EnvError(f"{ENV_ID}: {self.episode_record.reason}")
        run.physics(period)
        run.complete(period)
        state = self.sim.observation
        done = not run.running
        info: dict[str, Any] = {"reason": self.sim.reason, "is_success": bool(state.success), "time_s": state.time_s,
                                "commanded_tcp_pos": np.array(period.pose.pos),
                                "commanded_tcp_quat": np.array(period.pose.quat), **truth_info(state)}
        if done:
            self.episode_record = run.finish()[0]
            info["episode_record"] = self.episode_record.to_dict()
            if info["reason"] is None:  # an error inside the episode loop ended it
                info["reason"] = self.episode_record.reason
        truncated = done and info["reason"] == REASON_TIME_LIMIT
        return (observation_dict(run.observation(), self.privileged), self.reward(state), done and not truncated,
                truncated, info)

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        """An RGB frame (height, width, 3) from ``camera`` with render_mode "rgb_array"; None otherwise."""
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            from envs.media.video import OffscreenRenderer

            self._renderer = OffscreenRenderer(self.sim.model, *self._size)
            self._renderer.set_camera(self._camera)
        self._renderer.update_scene(self.sim.data)
        return self._renderer.render().copy()

    def close(self) -> None:
        """Free the renderer, if any."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
