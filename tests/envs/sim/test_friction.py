"""envs.sim.friction: an episode's sampled frictions are the ones the physics uses -- read back from a sliding peg
and from the force at which the peg slips in the pads -- and sampling them leaves the rest of the episode's draws
as they were."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from envs.cell.scene import build_scene
from envs.cell.scene_config import SceneConfig
from envs.errors import EnvError
from envs.poses import Pose
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.task.perturbation import Perturbation, PerturbationRanges, sample_perturbation
from numerics.small_linalg import norm

GRASP_FORCE_N = SceneConfig().grasp_force_n


@pytest.fixture(scope="module")
def env() -> PegInHoleEnv:
    return PegInHoleEnv(scene=build_scene(SceneConfig()),
                        episode_config=EpisodeConfig(time_limit_s=5.0, force_limit_n=1000.0))


def _on_the_plate(env: PegInHoleEnv, height_m: float, perturbation: Perturbation) -> tuple[np.ndarray, np.ndarray]:
    """Reset with the peg ``height_m`` above the plate, 5 cm from the target hole; (that point, goal quat)."""
    beside = env.nominal_hole.pos + np.array([0.05, 0.0, 0.0])
    env.reset(start_pose=Pose(beside + [0.0, 0.0, height_m], env.nominal_goal.quat), perturbation=perturbation)
    return beside, env.nominal_goal.quat


@pytest.mark.parametrize("mu", [0.3, 0.8])
def test_a_peg_sliding_on_the_plate_reads_back_the_sampled_friction(env, mu) -> None:
    """Pressed on the plate with ~12-15 N and dragged sideways at 10 mm/s: over the peg-sorter contacts,
    sum |f_t| / sum f_n is mu (within 5 %), and the wrist sensor's sideways / vertical force agrees within 10 %
    (it also carries the arm's own dynamics)."""
    beside, quat = _on_the_plate(env, 0.004, Perturbation(hole_friction=mu))
    stiffness = np.diag([3000.0, 3000.0, 1000.0, 100.0, 100.0, 100.0])
    peg, sorter = set(env.scene.ids.peg_geoms), set(env.scene.ids.sorter_geoms)
    model, data = env.model, env.data
    force = np.zeros(6)
    rows = []
    start_y = None
    for k in range(150):
        env.step(Pose(beside + [0.0, max(0.0, (k - 30) * 1e-4), -0.012], quat), stiffness)
        if k <= 60:  # pressed, then sliding steadily
            continue
        normal = tangential = 0.0
        for i in range(data.ncon):
            pair = {int(data.contact.geom1[i]), int(data.contact.geom2[i])}
            if pair & peg and pair & sorter:
                mujoco.mj_contactForce(model, data, i, force)
                normal, tangential = normal + force[0], tangential + float(np.hypot(force[1], force[2]))
        wrist = data.site_xmat[env.scene.ids.ft_site].reshape(3, 3) @ env.observation.wrist_wrench[:3]
        rows.append((normal, tangential, abs(wrist[1]), abs(wrist[2])))
        start_y = env.observation.peg_tip.pos[1] if start_y is None else start_y
    rows_arr = np.array(rows)
    assert env.observation.peg_tip.pos[1] - start_y > 0.007  # it slid
    assert np.median(rows_arr[:, 0]) > 8.0
    assert rows_arr[:, 1].sum() / rows_arr[:, 0].sum() == pytest.approx(mu, rel=0.05)
    assert rows_arr[:, 2].sum() / rows_arr[:, 3].sum() == pytest.approx(mu, rel=0.10)


@pytest.mark.parametrize("mu_pad", [0.2, 0.3])
def test_the_peg_slips_in_the_pads_at_twice_mu_pad_times_the_grasp_force(env, mu_pad) -> None:
    """Pushed down onto the plate ever harder (30 N/s), the peg slides up in the fingers when the push reaches
    the two pads' friction, 2 mu_pad F_grasp (within 5 %)."""
    beside, quat = _on_the_plate(env, 0.002, Perturbation(pad_friction=mu_pad))
    stiffness = np.diag([3000.0, 3000.0, 3000.0, 100.0, 100.0, 100.0])
    obs = env.observation
    shift0 = norm(obs.peg_tip.pos - obs.tcp.pos)
    slipped_at = None
    for k in range(300):
        env.step(Pose(beside + [0.0, 0.0, 0.002 - 1e-4 * k], quat), stiffness)
        obs = env.observation
        if abs(norm(obs.peg_tip.pos - obs.tcp.pos) - shift0) > 5e-4:
            slipped_at = float(np.linalg.norm(obs.wrist_wrench[:3]))
            break
    assert slipped_at == pytest.approx(2.0 * mu_pad * GRASP_FORCE_N, rel=0.05)


def test_neutral_frictions_leave_the_scene_values(env) -> None:
    model = env.model
    sorter, pads = list(env.scene.ids.sorter_geoms), list(env.scene.ids.finger_geoms)
    before = build_scene(SceneConfig()).model.geom_friction
    env.friction.apply(Perturbation(hole_friction=0.7, pad_friction=0.4))
    assert np.all(model.geom_friction[sorter, 0] == 0.7) and np.all(model.geom_friction[pads, 0] == 0.4)
    env.friction.apply(Perturbation())
    assert np.array_equal(model.geom_friction, before)


def test_friction_draws_keep_the_other_draws_of_the_episode() -> None:
    plain = PerturbationRanges(hole_error_m=0.001, hole_error_deg=1.0, grasp_offset_m=0.002)
    rough = PerturbationRanges(hole_error_m=0.001, hole_error_deg=1.0, grasp_offset_m=0.002, hole_friction_min=0.3,
                               hole_friction_max=0.8, pad_friction_min=0.6, pad_friction_max=1.2)
    a, b = np.random.default_rng(4), np.random.default_rng(4)
    draws = [(sample_perturbation(plain, a), sample_perturbation(rough, b)) for _ in range(200)]
    for p, q in draws:
        assert p.hole_transform()[0].tolist() == q.hole_transform()[0].tolist()
        assert (p.hole_yaw_deg, p.grasp_offset_m) == (q.hole_yaw_deg, q.grasp_offset_m)
        assert p.hole_friction == p.pad_friction == 0.0
    assert a.random() == b.random()  # the same number of draws
    hole = np.array([q.hole_friction for _, q in draws])
    pad = np.array([q.pad_friction for _, q in draws])
    assert 0.3 <= hole.min() < 0.35 and 0.75 < hole.max() <= 0.8 and 0.6 <= pad.min() and pad.max() <= 1.2
    assert abs(np.corrcoef(hole, pad)[0, 1]) < 0.2


@pytest.mark.parametrize("ranges", [dict(hole_friction_min=0.5, hole_friction_max=0.3),
                                    dict(pad_friction_min=0.0, pad_friction_max=0.5),
                                    dict(hole_friction_min=0.3, hole_friction_max=3.0)])
def test_bad_friction_ranges_are_refused(ranges) -> None:
    with pytest.raises(EnvError, match="friction"):
        PerturbationRanges(**ranges)
