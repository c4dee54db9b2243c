"""envs.sim.period_kernel: a control period in one compiled call is the per-step path (controller.step with the sensing
hook) to the last bit, and controllers.mujoco_layout reads mjData's contacts where the bindings see them."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
import pytest

from controllers.impedance import CartesianImpedanceController
from controllers.mujoco_layout import check_layout
from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.poses import Pose
from envs.sim import sensing_kernel
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.task.perturbation import Perturbation


class PerStep:
    """The impedance controller behind the Controller protocol only, so the env takes its per-step path (``step``
    with the sensing hook after every physics step) instead of the compiled period."""

    def __init__(self, controller: CartesianImpedanceController) -> None:
        self.inner = controller

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def start(self, data: mujoco.MjData) -> None:
        self.inner.start(data)

    def settled(self) -> None:
        self.inner.settled()

    def set_tool_load(self, mass_kg: float, depth_m: float) -> None:
        self.inner.set_tool_load(mass_kg, depth_m)

    def command(self, data: mujoco.MjData, action: Any, feedforward_gain: float = 1.0) -> Any:
        return self.inner.command(data, action, feedforward_gain)

    def checked_stiffness(self, stiffness: Any) -> Any:
        return self.inner.checked_stiffness(stiffness)

    def step(self, *args: Any, **kwargs: Any) -> int:
        return self.inner.step(*args, **kwargs)


@pytest.fixture(scope="module")
def scene():
    return build_scene(SceneConfig())


def _episode(env: PegInHoleEnv, steps: int) -> list[np.ndarray]:
    """Drive the peg down toward the nominal goal, 1 mm beside the real hole: it lands on the chamfer's edge and
    pushes there, with wall contacts, until the force limit; one row of state and sense state per period."""
    env.reset(start_pose=Pose(env.nominal_goal.pos + 0.035 * env.hole_axis, env.nominal_goal.quat),
              perturbation=Perturbation(hole_dx_m=0.001))
    rows = []
    for k in range(steps):
        if env.done:
            break
        height = max(0.035 - 0.0005 * k, -0.002)  # 50 mm/s down to 2 mm below the nominal goal
        env.step(Pose(env.nominal_goal.pos + height * env.hole_axis, env.nominal_goal.quat))
        rows.append(np.concatenate([env.data.qpos, env.data.qvel, env.data.ctrl, env.sensing.inputs.state,
                                    [env.data.ncon]]))
    return rows


def test_the_compiled_period_equals_the_per_step_path_bit_for_bit(scene) -> None:
    config = EpisodeConfig(time_limit_s=1.5)
    compiled = PegInHoleEnv(episode_config=config, scene=scene)
    per_step = PegInHoleEnv(episode_config=config, scene=scene,
                            controller=PerStep(CartesianImpedanceController(scene.model, scene.ids.tcp_site)))
    a, b = _episode(compiled, 150), _episode(per_step, 150)
    assert len(a) == len(b) > 50  # it lands on the chamfer and pushes until the force limit
    assert max(row[-1] for row in a) > 10  # contacts with the walls, not only the fingers'
    assert compiled.stats.peak_contact_force_n > 5.0
    for k, (x, y) in enumerate(zip(a, b)):
        assert np.array_equal(x, y), f"period {k} differs"
    assert compiled.stats == per_step.stats and compiled.reason == per_step.reason


def test_the_force_limit_stops_the_compiled_period_where_the_hook_does(scene) -> None:
    """A limit of 1 uN over 3 ms hits at physics step 3 of the first period: both paths stop there."""
    config = EpisodeConfig(time_limit_s=1.0, force_limit_n=1e-6, force_limit_window_s=0.003)
    envs = [PegInHoleEnv(episode_config=config, scene=scene),
            PegInHoleEnv(episode_config=config, scene=scene,
                         controller=PerStep(CartesianImpedanceController(scene.model, scene.ids.tcp_site)))]
    times = []
    for env in envs:
        env.reset(start_pose=Pose(env.goal.pos + 0.04 * env.hole_axis, env.goal.quat))
        start_s = env.data.time
        result = env.step(Pose(env.goal.pos + 0.03 * env.hole_axis, env.goal.quat))
        assert result.reason == "force_limit"
        times.append(round((env.data.time - start_s) / float(scene.model.opt.timestep)))
    assert times == [3, 3]


def test_the_layout_reads_the_contacts_the_bindings_see(scene) -> None:
    env = PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=1.0), scene=scene)
    _episode(env, 60)
    data = env.data
    assert data.ncon > 2
    table = check_layout(data)  # raises on any mismatch
    geom, efc_address, efc_force = sensing_kernel.contacts_at(data._address, table)
    assert np.array_equal(geom, data.contact.geom) and np.array_equal(efc_address, data.contact.efc_address)
    assert np.array_equal(efc_force, data.efc_force)
