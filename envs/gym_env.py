"""Gymnasium environment ``pih/PegInHole-v0``: a thin wrapper around :class:`envs.env.PegInHoleEnv`.

    import gymnasium
    env = gymnasium.make("envs.gym_env:pih/PegInHole-v0", shape="square", clearance_mm=0.2)
    # or: import envs.gym_env; gymnasium.make("pih/PegInHole-v0", ...)

Gymnasium 1.x has no plugin entry points (they were removed in 1.0); ``gymnasium.make`` registers a
third-party environment by importing the module named before the ':' of the id, as above.

Options (keyword arguments of ``gymnasium.make``): any field of SceneConfig, EpisodeConfig or
ImpedanceConfig, or of a config nested in them (EpisodeConfig.perturbations, .start_region, .success, ...),
by its name; a field ending in ``_m`` may also be given in millimetres as ``..._mm`` (``clearance_mm=0.2``
sets ``clearance_m=0.0002``, ``hole_error_mm=1`` the perturbations' ``hole_error_m``). Besides: ``stiffness_action`` (bool), ``reward``
(a RewardConfig), ``render_mode`` ("rgb_array" or None), ``camera``, ``width``, ``height`` (of the frames).
An unknown option is an EnvError naming it.

Action (Box, float32), the commanded peg_tip pose under the nominal grasp (the simulator's ``tcp``, which
the robot controls; the peg's own pose differs by the grasp offset and any slip), held for one control
period (10 ms by default):
    a[0:3]  position p_cmd, metres, world (robot base) frame, within the box spanned by the start region
            and the nominal goal widened by ACTION_POS_MARGIN_M;
    a[3:6]  rotation vector r (radians, world frame) of the commanded orientation relative to the nominal
            goal orientation: q_cmd = exp(r) q_goal, each component within +-(max start angle +
            ACTION_ANGLE_MARGIN_DEG); relative, so the task's z-down orientation is r = 0, far from the pi
            wrap-around of an absolute rotation vector;
    a[6:9]  (only with ``stiffness_action=True``) the translational stiffness diagonal k_x, k_y, k_z in N/m
            within STIFFNESS_RANGE_N_M; the commanded 6x6 world-frame stiffness is
            K = diag(k_x, k_y, k_z, k_r, k_r, k_r) with k_r the controller's rotational stiffness.
Actions are clipped to the Box before use.

Observation (Dict; every value float32 unless noted), read from the simulator's Observation:
    tcp_pos (3,) m, tcp_quat (4,) (w, x, y, z): the nominal peg_tip from the arm's kinematics (what the
        robot knows), positions within +-WORKSPACE_HALF_WIDTH_M;
    peg_tip_pos (3,), peg_tip_quat (4,): the peg's own peg_tip (simulator truth; a real robot would not
        measure it; drop it with gymnasium.wrappers.FilterObservation for a robot-side policy);
    qpos, qvel: the simulator's joint vectors, sizes read from a first observation at construction; qpos
        bounded by the joint ranges widened by JOINT_RANGE_MARGIN where a joint is limited;
    wrist_wrench (6,) [N; N m] from the wrist F/T sensor, sensor frame, tool load removed;
    contact_force_n (1,) sum of contact normal-force magnitudes on the peg, N;
    gripper_width_m (1,) opening between the finger pads, m;
    insertion (4,) depth m, lateral m, tilt deg, yaw error deg of the peg relative to the (true) target hole;
    in_hole, inserted: Discrete(2); time_s (1,) seconds since the reset.
    Bounds are infinite only where nothing physical bounds a value (velocities, wrenches); the action keeps
    physical units, so normalising it is left to the user (gymnasium.wrappers.RescaleAction).

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
from dataclasses import dataclass
from typing import Any

import gymnasium
import mujoco
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from controllers.impedance import ImpedanceConfig
from envs.env import REASON_TIME_LIMIT, EpisodeConfig, Observation, PegInHoleEnv
from envs.errors import EnvError
from envs.poses import Pose, quat_angle_rad, quat_from_rotvec, quat_mul
from envs.scene import SceneConfig
from rflow.small_linalg import norm

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


def configs_from_kwargs(options: dict[str, Any]) -> tuple[SceneConfig, ImpedanceConfig, EpisodeConfig]:
    """Map ``gymnasium.make`` keyword arguments onto the three simulator configs (module docstring).

    A name is a field of SceneConfig, ImpedanceConfig or EpisodeConfig, or a field of a config nested in one
    of them (e.g. ``hole_error_m`` of EpisodeConfig.perturbations, ``max_angle_deg`` of its start_region);
    a field ending in ``_m`` may be given in millimetres as ``_mm``.

    Raises:
        EnvError: an option that names no field, one that names fields of two configs, or an invalid value
            (the config's own check).
    """
    configs: dict[str, Any] = {"scene": SceneConfig(), "controller": ImpedanceConfig(), "episode": EpisodeConfig()}
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
            raise EnvError(f"{ENV_ID}: unknown option {name!r}; options are stiffness_action, reward, "
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


def _box(low: npt.ArrayLike, high: npt.ArrayLike) -> spaces.Box:
    return spaces.Box(low=np.asarray(low, dtype=np.float32), high=np.asarray(high, dtype=np.float32),
                      dtype=np.float32)


class PegInHoleGymEnv(gymnasium.Env[dict[str, Any], np.ndarray]):
    """``pih/PegInHole-v0``: the Gymnasium face of PegInHoleEnv (spaces, reward and ends in the module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, render_mode: str | None = None, stiffness_action: bool = False,
                 reward: RewardConfig = RewardConfig(), camera: str = "front", width: int = 640, height: int = 480,
                 **options: Any):
        """Args: see the module docstring. Raises: EnvError on an unknown or invalid option."""
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise EnvError(f"{ENV_ID}: render_mode={render_mode!r} must be None or 'rgb_array'")
        if not isinstance(reward, RewardConfig):
            raise EnvError(f"{ENV_ID}: reward={reward!r} must be a RewardConfig")
        scene_config, controller_config, episode_config = configs_from_kwargs(options)
        self.render_mode = render_mode
        self.reward_config = reward
        self.stiffness_action = bool(stiffness_action)
        self._camera, self._size = camera, (int(width), int(height))
        self._renderer: Any = None
        self.sim = PegInHoleEnv(scene_config, controller_config, episode_config)
        if mujoco.mj_name2id(self.sim.model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            raise EnvError(f"{ENV_ID}: camera={camera!r} is not a camera of the scene")
        self._rot_stiffness = controller_config.rotational_stiffness
        self.nominal_goal: Pose = self.sim.nominal_goal
        self.action_space = self._action_space()
        first = self.sim.reset(start_pose=self.sim.nominal_start())
        self.observation_space = self._observation_space(first)

    # ------------------------------------------------------------------------------------------- spaces

    def _action_space(self) -> spaces.Box:
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
        return _box(low, high)

    def _observation_space(self, first: Observation) -> spaces.Dict:
        nq, nv = np.asarray(first.qpos).size, np.asarray(first.qvel).size
        q_low, q_high = joint_position_bounds(self.sim.model, nq)
        workspace = (np.full(3, -WORKSPACE_HALF_WIDTH_M), np.full(3, WORKSPACE_HALF_WIDTH_M))
        return spaces.Dict({
            "tcp_pos": _box(*workspace),
            "tcp_quat": _box(-np.ones(4), np.ones(4)),
            "peg_tip_pos": _box(*workspace),
            "peg_tip_quat": _box(-np.ones(4), np.ones(4)),
            "qpos": _box(q_low, q_high),
            "qvel": _box(np.full(nv, -np.inf), np.full(nv, np.inf)),
            "wrist_wrench": _box(np.full(6, -np.inf), np.full(6, np.inf)),
            "contact_force_n": _box([0.0], [np.inf]),
            "gripper_width_m": _box([0.0], [MAX_GRIPPER_WIDTH_M]),
            "insertion": _box(INSERTION_LOW, INSERTION_HIGH),
            "in_hole": spaces.Discrete(2),
            "inserted": spaces.Discrete(2),
            "time_s": _box([0.0], [self.sim.config.time_limit_s + self.sim.control_period_s]),
        })

    def _observe(self, obs: Observation) -> dict[str, Any]:
        ins = obs.insertion
        values: dict[str, Any] = {
            "tcp_pos": obs.tcp.pos,
            "tcp_quat": obs.tcp.quat,
            "peg_tip_pos": obs.peg_tip.pos,
            "peg_tip_quat": obs.peg_tip.quat,
            "qpos": obs.qpos,
            "qvel": obs.qvel,
            "wrist_wrench": obs.wrist_wrench,
            "contact_force_n": [obs.contact_force_n],
            "gripper_width_m": [obs.gripper_width_m],
            "insertion": [ins.depth_m, ins.lateral_m, ins.tilt_deg, ins.yaw_error_deg],
            "in_hole": int(ins.in_hole),
            "inserted": int(obs.inserted),
            "time_s": [obs.time_s],
        }
        return {key: value if isinstance(value, int) else np.asarray(value, dtype=np.float32)
                for key, value in values.items()}

    # ------------------------------------------------------------------------------------------- episode

    def command(self, action: npt.ArrayLike) -> tuple[Pose, np.ndarray | None]:
        """The peg_tip pose (and 6x6 stiffness, or None) an action commands, after clipping to the Box."""
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != self.action_space.shape:
            raise EnvError(f"{ENV_ID}: action must have shape {self.action_space.shape}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise EnvError(f"{ENV_ID}: action {a.tolist()} contains NaN or inf")
        a = np.clip(a, self.action_space.low, self.action_space.high)
        quat = quat_mul(quat_from_rotvec(a[3:6]), self.nominal_goal.quat)
        pose = Pose(pos=a[:3], quat=quat / norm(quat))
        if not self.stiffness_action:
            return pose, None
        return pose, np.diag(np.concatenate([a[6:9], np.full(3, self._rot_stiffness)]))

    def reward(self, obs: Observation) -> float:
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
        ``options={"start_pose": (pos, quat)}`` fixes the start (the perturbation is still drawn)."""
        super().reset(seed=seed)
        unknown = set(options or {}) - {"start_pose"}
        if unknown:
            raise EnvError(f"{ENV_ID}: unknown reset option(s) {sorted(unknown)}; the only one is 'start_pose'")
        obs = self.sim.reset(seed=int(self.np_random.integers(2**63 - 1)), start_pose=(options or {}).get("start_pose"))
        return self._observe(obs), {"start_pos": self.sim.start.pos.copy(), "start_quat": self.sim.start.quat.copy(),
                                    "perturbation": self.sim.perturbation}

    def step(self, action: npt.ArrayLike) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        """One control period at the commanded pose; returns (obs, reward, terminated, truncated, info)."""
        pose, stiffness = self.command(action)
        result = self.sim.step(pose, stiffness)
        truncated = result.done and result.reason == REASON_TIME_LIMIT
        terminated = result.done and not truncated
        info = {"reason": result.reason, "is_success": bool(result.obs.success), "time_s": result.obs.time_s,
                "target_pos": pose.pos, "target_quat": pose.quat}
        return self._observe(result.obs), self.reward(result.obs), terminated, truncated, info

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        """An RGB frame (height, width, 3) from ``camera`` with render_mode "rgb_array"; None otherwise."""
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            from envs.video import OffscreenRenderer

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
