"""controllers.interface: the episode stepping runs any Controller, and the impedance controller is one."""

from __future__ import annotations

from typing import Callable

import mujoco
import numpy as np
import numpy.typing as npt
import pytest

from controllers.action import Action
from controllers.impedance import CartesianImpedanceController
from controllers.interface import Controller
from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.errors import EnvError
from envs.poses import Pose
from envs.rollout.episode import StartPose, run_episode
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig


class JointHold:
    """A joint-space PD with gravity compensation that holds the arm's posture at the episode's start and ignores
    the commanded pose: tau = K_p (q_0 - q) - K_d qdot + c(q, qdot)."""

    def __init__(self, model: mujoco.MjModel, kp: float = 400.0, kd: float = 40.0) -> None:
        joints = model.actuator_trnid[:, 0]
        self.model, self.kp, self.kd = model, kp, kd
        self.qpos, self.dof = model.jnt_qposadr[joints], model.jnt_dofadr[joints]
        self.q_hold: npt.NDArray[np.float64] | None = None
        self.tool_load: tuple[float, float] | None = None
        self.substeps = 0

    def start(self, data: mujoco.MjData) -> None:
        self.q_hold = data.qpos[self.qpos].copy()

    def settled(self) -> None:
        pass  # nothing to calibrate

    def set_tool_load(self, mass_kg: float, depth_m: float) -> None:
        self.tool_load = (mass_kg, depth_m)

    def command(self, data: mujoco.MjData, action: Action, feedforward_gain: float = 1.0) -> tuple[Pose, None]:
        return action.pose, None  # it holds its posture: no Cartesian stiffness, and no lead for a pose it ignores

    def checked_stiffness(self, stiffness: npt.ArrayLike | None) -> None:
        return None  # no Cartesian stiffness to set

    def step(self, data: mujoco.MjData, target_pos: npt.ArrayLike, target_quat: npt.ArrayLike,
             stiffness: npt.ArrayLike | None, q_nullspace: npt.ArrayLike | None, n_substeps: int, *,
             after_substep: Callable[[], bool] | None = None) -> int:
        for done in range(1, n_substeps + 1):
            mujoco.mj_step1(self.model, data)
            error = self.q_hold - data.qpos[self.qpos]
            data.ctrl[:] = self.kp * error - self.kd * data.qvel[self.dof] + data.qfrc_bias[self.dof]
            mujoco.mj_step2(self.model, data)
            self.substeps += 1
            if after_substep is not None and after_substep():
                return done
        return n_substeps


@pytest.fixture(scope="module")
def scene():
    return build_scene(SceneConfig())


def test_the_impedance_controller_is_a_controller(scene) -> None:
    assert isinstance(CartesianImpedanceController(scene.model, "tcp"), Controller)
    assert isinstance(JointHold(scene.model), Controller)


def test_the_env_steps_a_controller_of_the_test_through_the_protocol(scene, monkeypatch) -> None:
    hold = JointHold(scene.model)
    env = PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=1.0), scene=scene, controller=hold)
    start = env.nominal_start()
    env.reset(start_pose=start)
    assert hold.tool_load is not None and hold.tool_load[0] > 0.0  # the grasped peg's weight was handed over
    settled = hold.substeps  # the grasp settled under this controller
    sensed, sense = [0], env._sense

    def counting_sense() -> bool:
        sensed[0] += 1
        return sense()

    monkeypatch.setattr(env, "_sense", counting_sense)  # the hook the env hands the controller
    away = (start.pos + [0.0, 0.0, 0.03], start.quat)
    results = [env.step(away) for _ in range(20)]
    assert hold.substeps - settled == sensed[0] == 20 * env.n_substeps
    assert not any(r.done for r in results)
    obs = results[-1].obs
    assert obs.time_s == pytest.approx(20 * env.control_period_s)
    assert np.linalg.norm(obs.tcp.pos - start.pos) < 2e-3  # held the start, not the commanded pose 3 cm above


class _Hold:
    """A policy that commands its start pose with a twist (which a joint hold does not lead)."""

    def reset(self, observation, period_s):
        self.start = observation.tcp

    def act(self, observation):
        return Action(self.start, twist=np.full(6, 0.01))


def test_the_episode_loop_runs_a_controller_of_the_test(scene) -> None:
    """A policy's episode under the joint hold: its actions through ``command``, no Cartesian stiffness to record."""
    env = PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=0.2), scene=scene, controller=JointHold(scene.model))
    record, trace = run_episode(env, _Hold(), StartPose(0, -1, env.nominal_start()), record_trace=True)
    assert record.steps == 20 and record.reason.startswith("time_limit")
    assert np.isnan(record.min_stiffness_n_m) and np.isnan(trace.stiffness).all()
    assert np.array_equal(trace.cmd_pos[1:], np.tile(trace.tcp_pos[0], (20, 1)))


def test_the_env_refuses_what_is_no_controller_or_has_no_scene(scene) -> None:
    with pytest.raises(EnvError, match="must implement controllers.interface.Controller"):
        PegInHoleEnv(scene=scene, controller=object())  # type: ignore[arg-type]
    with pytest.raises(EnvError, match="pass the scene"):
        PegInHoleEnv(controller=JointHold(scene.model))
