"""Gymnasium environment ``pih/PegInHole-v0``: a thin wrapper around :class:`envs.sim.env.PegInHoleEnv`.

    import gymnasium
    env = gymnasium.make("envs.gym_env:pih/PegInHole-v0", shape="square", clearance_mm=0.2)
    # or: import envs.gym_env; gymnasium.make("pih/PegInHole-v0", ...)

Gymnasium 1.x has no plugin entry points (they were removed in 1.0); ``gymnasium.make`` registers a
third-party environment by importing the module named before the ':' of the id, as above.

Options (keyword arguments of ``gymnasium.make``): ``task`` (an envs.task.task.Task, e.g. ``preset("factory")`` or
``Task.from_toml("my_task.toml")``: its scene, perturbations, force and time limits and success tolerances; its
start range, which is around demos' starts, does not apply: starts come from EpisodeConfig.start_region), then any
field of SceneConfig, EpisodeConfig or
ImpedanceConfig, or of a config nested in them (EpisodeConfig.perturbations, .start_region, .success, ...),
by its name; a field ending in ``_m`` may also be given in millimetres as ``..._mm`` (``clearance_mm=0.2``
sets ``clearance_m=0.0002``, ``hole_error_mm=1`` the perturbations' ``hole_error_m``). Besides: ``stiffness_action``
(bool), ``privileged`` (bool, default False: see Observation), ``reward`` (a RewardConfig), ``render_mode``
("rgb_array" or None), ``camera``, ``width``, ``height`` (of the frames). An unknown option is an EnvError naming it.

Action (Box [-1, 1]^n, float32; stable-baselines3's convention): a normalised action a is mapped affinely onto the
physical command u = c + a h, with c and h the centre and half-width of the physical range below (``physical_low``,
``physical_high``; ``to_physical`` and ``to_action`` convert), after clipping a to [-1, 1]. The physical command is
the tcp pose under the nominal grasp (the simulator's ``tcp``, which the robot controls; the peg's own pose differs
by the grasp offset and any slip), held for one control period (10 ms by default):
    u[0:3]  position p_cmd, metres, world (robot base) frame, within the box spanned by the start region and the
            nominal goal widened by ACTION_POS_MARGIN_M (c: the box's centre, h: its half-widths, 0.15-0.175 m by
            default);
    u[3:6]  rotation vector r (radians, world frame) of the commanded orientation relative to the nominal goal
            orientation, q_cmd = exp(r) q_goal, each component within +-(max start angle + ACTION_ANGLE_MARGIN_DEG)
            (c = 0, h = 45 deg = 0.785 rad by default); relative, so the task's z-down orientation is r = 0 (a = 0), far
            from the pi wrap-around of an absolute rotation vector;
    u[6:9]  (only with ``stiffness_action=True``) the translational stiffness diagonal k_x, k_y, k_z in N/m within
            STIFFNESS_RANGE_N_M (c = 1550, h = 1450); the commanded 6x6 world-frame stiffness is
            K = diag(k_x, k_y, k_z, k_r, k_r, k_r) with k_r the controller's rotational stiffness.
An action that is not real numbers, has n entries in another shape than (n,) (axes of length 1 aside) or holds NaN
or inf is an EnvError naming it, in one line; so is ``step`` before ``reset`` or after the episode ended.

Observation (Dict; every value float32): what a real cell measures, as the Policy protocol's observation
(envs.policies.interface):
    tcp_pos (3,) m, tcp_quat (4,) (w, x, y, z): the nominal peg_tip from the arm's kinematics, positions within
        +-WORKSPACE_HALF_WIDTH_M;
    qpos, qvel (7,): arm joint positions (bounded by the joint ranges widened by JOINT_RANGE_MARGIN) and velocities;
    wrist_wrench (6,) [N; N m] from the wrist F/T sensor, sensor frame, tool load removed;
    gripper_width_m (1,) opening between the finger pads, m;
    nominal_hole_pos (3,), nominal_hole_quat (4,): where the cell believes the target hole is (not the true one);
    time_s (1,) seconds since the reset.
The simulator's truth -- the peg's own pose (peg_tip_pos, peg_tip_quat), the contact force on it (contact_force_n),
its state against the TRUE, perturbed hole (insertion: depth m, lateral m, tilt deg, yaw error deg; in_hole,
inserted: 0 or 1) -- is in ``info`` after every reset and step, never in the observation, unless the env is made
with ``privileged=True`` (a teacher or an ablation), which adds those keys to the observation (in_hole and
inserted as Discrete(2)). Bounds are infinite only where nothing physical bounds a value (velocities, wrenches).

Reward, dense: r_t = -(|p - g_p| + ROT_WEIGHT_M_PER_RAD angle(q, g_q)) (metres; 0.1 m per rad makes 10 deg
cost like 17 mm) for the peg's own peg_tip (p, q) and the true goal g inside the (possibly displaced) hole,
plus ``success_bonus`` on the step at which the simulator declares success. ``terminated`` on success or on
any other end reason but the time limit (instability, force limit); ``truncated`` at the time limit.
``info["reason"]`` is the simulator's end reason (None while running); ``info["is_success"]`` its success flag.
Randomness: ``reset(seed=s)`` seeds ``np_random``; the simulator draws the episode's perturbation (hole-pose
error, grasp offset) and start pose from a seed taken from ``np_random``, so the same seed gives the same
episode. ``options={"start_pose": (pos, quat)}``
starts at a given peg_tip pose instead.
"""

from __future__ import annotations

import dataclasses
import numbers
from dataclasses import dataclass
from typing import Any

import gymnasium
import mujoco
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from controllers.impedance import ImpedanceConfig
from envs.cell.scene_config import SceneConfig
from envs.errors import EnvError
from envs.media.rendering import MAX_FRAME_PX
from envs.poses import Pose, quat_angle_rad, quat_from_rotvec, quat_mul
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.sim.observation import REASON_TIME_LIMIT, SimulatorState
from envs.task.task import Task
from numerics.errors import shown
from numerics.small_linalg import norm

FloatArray = npt.NDArray[np.float64]

ENV_ID = "pih/PegInHole-v0"
ACTION_POS_MARGIN_M: float = 0.05
ACTION_ANGLE_MARGIN_DEG: float = 25.0
STIFFNESS_RANGE_N_M: tuple[float, float] = (100.0, 3000.0)
JOINT_RANGE_MARGIN: float = 0.1
"""rad for hinge, m/10 for slide joints: MuJoCo's joint limits are soft, so qpos can pass a limit slightly."""
ROT_WEIGHT_M_PER_RAD: float = 0.1
WORKSPACE_HALF_WIDTH_M: float = 2.0
"""peg_tip positions are bounded by +-2 m per axis around the robot base (the arm reaches ~1.2 m with the peg)."""
INSERTION_LOW = np.array([-2.0 * WORKSPACE_HALF_WIDTH_M, 0.0, 0.0, -180.0])
INSERTION_HIGH = np.array([2.0 * WORKSPACE_HALF_WIDTH_M, 2.0 * WORKSPACE_HALF_WIDTH_M, 180.0, 180.0])
MAX_GRIPPER_WIDTH_M: float = 0.1
"""Bound of the finger opening (the Franka hand opens 80 mm)."""
RENDER_OPTIONS: tuple[str, ...] = ("render_mode", "camera", "width", "height")
PRIVILEGED_KEYS: tuple[str, ...] = ("peg_tip_pos", "peg_tip_quat", "contact_force_n", "insertion", "in_hole", "inserted")
"""The simulator's truth: in ``info`` always, in the observation only with ``privileged=True`` (module docstring)."""


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


def configs_from_kwargs(options: dict[str, Any],
                        task: Task | None = None) -> tuple[SceneConfig, ImpedanceConfig, EpisodeConfig]:
    """Map ``gymnasium.make`` keyword arguments onto the three simulator configs (module docstring), starting from
    ``task``'s scene and episode settings when given (else the configs' defaults).

    A name is a field of SceneConfig, ImpedanceConfig or EpisodeConfig, or a field of a config nested in one
    of them (e.g. ``hole_error_m`` of EpisodeConfig.perturbations, ``max_angle_deg`` of its start_region);
    a field ending in ``_m`` may be given in millimetres as ``_mm``.

    Raises:
        EnvError: an option that names no field, one that names fields of two configs, or an invalid value
            (the config's own check).
    """
    if task is not None and not isinstance(task, Task):
        raise EnvError(f"{ENV_ID}: task={task!r} must be an envs.task.task.Task")
    configs: dict[str, Any] = {"scene": SceneConfig() if task is None else task.scene_config(),
                               "controller": ImpedanceConfig(),
                               "episode": EpisodeConfig() if task is None else EpisodeConfig.from_task(task)}
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
            raise EnvError(f"{ENV_ID}: unknown option {name!r}; options are task, stiffness_action, privileged, "
                           "reward, "
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


def _as_command_vector(value: Any, what: str, size: int) -> FloatArray:
    """``value`` as a float64 vector (size,): real numbers (bool, integer or float dtype) in an array of ``size``
    entries whose other axes have length 1 (a policy's (1, size) output is taken; (2, 3) for 6 entries is not).

    Raises:
        EnvError: in one line naming ``what``: not numbers (strings, None, complex), or another shape.
    """
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
    return np.asarray(value, dtype=np.float64).reshape(-1)  # the conversion actions always had


def _box(low: npt.ArrayLike, high: npt.ArrayLike) -> spaces.Box:
    return spaces.Box(low=np.asarray(low, dtype=np.float32), high=np.asarray(high, dtype=np.float32),
                      dtype=np.float32)


class PegInHoleGymEnv(gymnasium.Env[dict[str, Any], np.ndarray]):
    """``pih/PegInHole-v0``: the Gymnasium face of PegInHoleEnv (spaces, reward and ends in the module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, render_mode: str | None = None, stiffness_action: bool = False, privileged: bool = False,
                 reward: RewardConfig = RewardConfig(), camera: str = "front", width: int = 640, height: int = 480,
                 task: Task | None = None, **options: Any):
        """Args: see the module docstring. Raises: EnvError on an unknown or invalid option."""
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise EnvError(f"{ENV_ID}: render_mode={render_mode!r} must be None or 'rgb_array'")
        if not isinstance(reward, RewardConfig):
            raise EnvError(f"{ENV_ID}: reward={reward!r} must be a RewardConfig")
        for name, flag in (("stiffness_action", stiffness_action), ("privileged", privileged)):
            if not isinstance(flag, (bool, np.bool_)):  # "no" would count as true
                raise EnvError(f"{ENV_ID}: {name}={flag!r} must be True or False")
        scene_config, controller_config, episode_config = configs_from_kwargs(options, task)
        self.render_mode = render_mode
        self.reward_config = reward
        self.stiffness_action = bool(stiffness_action)
        self.privileged = bool(privileged)
        if not isinstance(camera, str):  # MuJoCo's name lookup takes a string only (None crashes it)
            raise EnvError(f"{ENV_ID}: camera={camera!r} must be the name of a camera of the scene")
        for name, value in (("width", width), ("height", height)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 16 <= value <= MAX_FRAME_PX:
                raise EnvError(f"{ENV_ID}: {name}={value!r} must be an integer number of pixels in [16, "
                               f"{MAX_FRAME_PX}]")
        self._camera, self._size = camera, (int(width), int(height))
        self._renderer: Any = None
        self.sim = PegInHoleEnv(scene_config, controller_config, episode_config)
        self._reset_called = False  # the simulator is reset below (for the observation space), the env is not
        if mujoco.mj_name2id(self.sim.model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            raise EnvError(f"{ENV_ID}: camera={camera!r} is not a camera of the scene")
        self._rot_stiffness = controller_config.rotational_stiffness
        self.nominal_goal: Pose = self.sim.nominal_goal
        self.physical_low, self.physical_high = self._physical_bounds()
        self.action_space = _box(-np.ones(self.physical_low.size), np.ones(self.physical_low.size))
        first = self.sim.reset(start_pose=self.sim.nominal_start())
        self.observation_space = self._observation_space(first)

    # ------------------------------------------------------------------------------------------- spaces

    def _physical_bounds(self) -> tuple[FloatArray, FloatArray]:
        """The physical command's range (module docstring): position box, rotation vector, stiffness diagonal."""
        region = self.sim.config.start_region
        nominal = self.sim.nominal_start()
        half = np.asarray(region.pos_half_width_m)
        low = np.minimum(nominal.pos - half, self.nominal_goal.pos) - ACTION_POS_MARGIN_M
        high = np.maximum(nominal.pos + half, self.nominal_goal.pos) + ACTION_POS_MARGIN_M
        angle = np.deg2rad(region.max_angle_deg + ACTION_ANGLE_MARGIN_DEG)
        low, high = np.concatenate([low, -angle * np.ones(3)]), np.concatenate([high, angle * np.ones(3)])
        if self.stiffness_action:
            low = np.concatenate([low, np.full(3, STIFFNESS_RANGE_N_M[0])])
            high = np.concatenate([high, np.full(3, STIFFNESS_RANGE_N_M[1])])
        return low, high

    def to_physical(self, action: npt.ArrayLike) -> FloatArray:
        """The physical command u = c + a h of a normalised action a, clipped to [-1, 1] first (module docstring).

        Raises:
            EnvError: not real numbers, a wrong shape, NaN or inf (`_as_command_vector`).
        """
        a = _as_command_vector(action, "action", self.physical_low.size)
        if not np.all(np.isfinite(a)):
            raise EnvError(f"{ENV_ID}: action {a.tolist()} contains NaN or inf")
        centre, half = 0.5 * (self.physical_high + self.physical_low), 0.5 * (self.physical_high - self.physical_low)
        return centre + np.clip(a, -1.0, 1.0) * half

    def to_action(self, physical: npt.ArrayLike) -> np.ndarray:
        """The normalised action (float32) of a physical command u (module docstring): a = (u - c) / h, not clipped.

        Raises:
            EnvError: not real numbers, a wrong shape, NaN or inf (`_as_command_vector`).
        """
        u = _as_command_vector(physical, "physical command", self.physical_low.size)
        if not np.all(np.isfinite(u)):
            raise EnvError(f"{ENV_ID}: physical command {u.tolist()} contains NaN or inf")
        centre, half = 0.5 * (self.physical_high + self.physical_low), 0.5 * (self.physical_high - self.physical_low)
        return ((u - centre) / half).astype(np.float32)

    def _observation_space(self, first: SimulatorState) -> spaces.Dict:
        nq, nv = np.asarray(first.qpos).size, np.asarray(first.qvel).size
        q_low, q_high = joint_position_bounds(self.sim.model, nq)
        workspace = (np.full(3, -WORKSPACE_HALF_WIDTH_M), np.full(3, WORKSPACE_HALF_WIDTH_M))
        measured: dict[str, spaces.Space] = {
            "tcp_pos": _box(*workspace),
            "tcp_quat": _box(-np.ones(4), np.ones(4)),
            "qpos": _box(q_low, q_high),
            "qvel": _box(np.full(nv, -np.inf), np.full(nv, np.inf)),
            "wrist_wrench": _box(np.full(6, -np.inf), np.full(6, np.inf)),
            "gripper_width_m": _box([0.0], [MAX_GRIPPER_WIDTH_M]),
            "nominal_hole_pos": _box(*workspace),
            "nominal_hole_quat": _box(-np.ones(4), np.ones(4)),
            "time_s": _box([0.0], [self.sim.config.time_limit_s + self.sim.control_period_s]),
        }
        if self.privileged:
            measured.update({
                "peg_tip_pos": _box(*workspace),
                "peg_tip_quat": _box(-np.ones(4), np.ones(4)),
                "contact_force_n": _box([0.0], [np.inf]),
                "insertion": _box(INSERTION_LOW, INSERTION_HIGH),
                "in_hole": spaces.Discrete(2),
                "inserted": spaces.Discrete(2),
            })
        return spaces.Dict(measured)

    def _observe(self, obs: SimulatorState) -> dict[str, Any]:
        """The observation dict: the measured keys, and the truth's with ``privileged``."""
        hole = self.sim.believed_hole  # where the cell believes the hole is (with the task's observation error)
        values: dict[str, Any] = {
            "tcp_pos": obs.tcp.pos,
            "tcp_quat": obs.tcp.quat,
            "qpos": obs.qpos,
            "qvel": obs.qvel,
            "wrist_wrench": obs.wrist_wrench,
            "gripper_width_m": [obs.gripper_width_m],
            "nominal_hole_pos": hole.pos,
            "nominal_hole_quat": hole.quat,
            "time_s": [obs.time_s],
        }
        out: dict[str, Any] = {key: np.asarray(value, dtype=np.float32) for key, value in values.items()}
        if self.privileged:
            out.update(self._truth(obs))
        return out

    @staticmethod
    def _truth(obs: SimulatorState) -> dict[str, Any]:
        """The simulator's truth (PRIVILEGED_KEYS): float32 arrays, in_hole and inserted as int."""
        ins = obs.insertion
        return {
            "peg_tip_pos": np.asarray(obs.peg_tip.pos, dtype=np.float32),
            "peg_tip_quat": np.asarray(obs.peg_tip.quat, dtype=np.float32),
            "contact_force_n": np.asarray([obs.contact_force_n], dtype=np.float32),
            "insertion": np.asarray([ins.depth_m, ins.lateral_m, ins.tilt_deg, ins.yaw_error_deg], dtype=np.float32),
            "in_hole": int(ins.in_hole),
            "inserted": int(obs.inserted),
        }

    # ------------------------------------------------------------------------------------------- episode

    def command(self, action: npt.ArrayLike) -> tuple[Pose, np.ndarray | None]:
        """The peg_tip pose (and 6x6 stiffness, or None) a normalised action commands (`to_physical`: clipped to
        [-1, 1], then scaled).

        Raises:
            EnvError: a wrong shape, NaN or inf.
        """
        a = self.to_physical(action)
        quat = quat_mul(quat_from_rotvec(a[3:6]), self.nominal_goal.quat)
        pose = Pose(pos=a[:3], quat=quat / norm(quat))
        if not self.stiffness_action:
            return pose, None
        return pose, np.diag(np.concatenate([a[6:9], np.full(3, self._rot_stiffness)]))

    def reward(self, obs: SimulatorState) -> float:
        """-(w_d |p - g_p| + w_r angle(q, g_q)) + bonus on success, g the true goal (module docstring)."""
        cfg = self.reward_config
        goal = self.sim.goal
        distance = norm(obs.peg_tip.pos - goal.pos)
        angle = float(quat_angle_rad(obs.peg_tip.quat, goal.quat))
        return -cfg.distance_weight * (distance + cfg.rot_weight_m_per_rad * angle) + (
            cfg.success_bonus if obs.success else 0.0)

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
        """Start an episode: perturbation and start drawn by the simulator from a seed taken from ``np_random``;
        ``options={"start_pose": (pos, quat)}`` fixes the start (the perturbation is still drawn). ``info`` holds the
        start, the perturbation and the simulator's truth (PRIVILEGED_KEYS)."""
        super().reset(seed=seed)
        unknown = set(options or {}) - {"start_pose"}
        if unknown:
            raise EnvError(f"{ENV_ID}: unknown reset option(s) {sorted(unknown)}; the only one is 'start_pose'")
        obs = self.sim.reset(seed=int(self.np_random.integers(2**63 - 1)), start_pose=(options or {}).get("start_pose"))
        self._reset_called = True
        return self._observe(obs), {"start_pos": self.sim.start.pos.copy(), "start_quat": self.sim.start.quat.copy(),
                                    "perturbation": self.sim.perturbation, **self._truth(obs)}

    def step(self, action: npt.ArrayLike) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        """One control period at the pose a normalised action commands; returns (obs, reward, terminated, truncated,
        info), ``info`` with the end reason, success, the commanded pose and the simulator's truth (PRIVILEGED_KEYS).

        Raises:
            EnvError: before the first ``reset()``, after the episode ended (or its reset failed), or a bad action
                (not real numbers, a wrong shape, NaN or inf).
        """
        if not self._reset_called:
            raise EnvError(f"{ENV_ID}: step() before reset(): call reset() first")
        if self.sim.done:
            raise EnvError(f"{ENV_ID}: no episode to step: it ended ({self.sim.reason}); call reset() first")
        pose, stiffness = self.command(action)
        result = self.sim.step(pose, stiffness)
        truncated = result.done and result.reason == REASON_TIME_LIMIT
        terminated = result.done and not truncated
        info = {"reason": result.reason, "is_success": bool(result.obs.success), "time_s": result.obs.time_s,
                "target_pos": pose.pos, "target_quat": pose.quat, **self._truth(result.obs)}
        return self._observe(result.obs), self.reward(result.obs), terminated, truncated, info

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


gymnasium.register(id=ENV_ID, entry_point="envs.gym_env:PegInHoleGymEnv")
