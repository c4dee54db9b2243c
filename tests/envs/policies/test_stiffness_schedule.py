"""envs.policies.stiffness_schedule: the scripted expert's stiffness, stiff in free space and compliant across the hole
axis."""

from __future__ import annotations

import numpy as np
import pytest

from controllers.impedance import ImpedanceConfig
from envs.errors import EnvError
from envs.policies.stiffness_schedule import StiffnessSchedule, expert_stiffness

OPENING = np.array([0.6, -0.05, 0.2])
SCHEDULE = StiffnessSchedule()


def _axis(tilt_deg: float) -> np.ndarray:
    t = np.deg2rad(tilt_deg)
    return np.array([np.sin(t), 0.0, np.cos(t)])


def test_free_space_is_the_controllers_default_stiffness():
    k = expert_stiffness(OPENING + [0.05, 0.0, 0.2], OPENING, [0, 0, 1], SCHEDULE)
    assert np.allclose(k, ImpedanceConfig().translational_stiffness * np.eye(3))


@pytest.mark.parametrize("tilt_deg", [0.0, 20.0])
def test_in_the_hole_compliant_across_the_axis_stiffer_along_it(tilt_deg):
    axis = _axis(tilt_deg)
    k = expert_stiffness(OPENING - 0.01 * axis, OPENING, axis, SCHEDULE)
    assert np.allclose(k @ axis, SCHEDULE.axial_hole_n_m * axis)
    across = np.cross(axis, [0.0, 1.0, 0.0])
    across /= np.linalg.norm(across)
    assert np.allclose(k @ across, SCHEDULE.lateral_hole_n_m * across)
    assert np.allclose(k, SCHEDULE.goal_stiffness(axis))


def test_blend_is_geometric_and_monotone_in_height():
    heights = np.linspace(0.04, -0.01, 201)
    k = expert_stiffness(OPENING + heights[:, None] * np.array([0, 0, 1.0]), OPENING, [0, 0, 1], SCHEDULE)
    lateral = k[:, 0, 0]
    assert np.all(np.diff(lateral) <= 1e-9)  # descending into the hole only softens
    mid = 0.5 * (SCHEDULE.free_height_m + SCHEDULE.hole_height_m)
    k_mid = expert_stiffness(OPENING + [0, 0, mid], OPENING, [0, 0, 1], SCHEDULE)
    assert np.isclose(k_mid[0, 0], np.sqrt(SCHEDULE.free_n_m * SCHEDULE.lateral_hole_n_m))


def test_blend_starts_and_ends_with_zero_slope():
    h = 1e-5
    for height in (SCHEDULE.free_height_m, SCHEDULE.hole_height_m):
        ks = [expert_stiffness(OPENING + [0, 0, height + d], OPENING, [0, 0, 1], SCHEDULE)[0, 0] for d in (-h, h)]
        assert abs(ks[1] - ks[0]) / (2 * h) < 1.0  # N/m per m: flat, against ~1e5 N/m/m in the middle


def test_every_sample_is_spd():
    rng = np.random.default_rng(0)
    pts = OPENING + rng.uniform(-0.1, 0.1, (500, 3))
    lam = np.linalg.eigvalsh(expert_stiffness(pts, OPENING, _axis(10.0), SCHEDULE))
    assert lam.min() >= min(SCHEDULE.lateral_hole_n_m, SCHEDULE.free_n_m) * (1 - 1e-12)


def test_bad_inputs_raise_env_error():
    with pytest.raises(EnvError):
        expert_stiffness(OPENING, OPENING, [0, 0, 0], SCHEDULE)
    with pytest.raises(EnvError):
        expert_stiffness([np.nan, 0, 0], OPENING, [0, 0, 1], SCHEDULE)
    with pytest.raises(EnvError):
        StiffnessSchedule(lateral_hole_n_m=0.0)
    with pytest.raises(EnvError):
        StiffnessSchedule(free_height_m=0.001, hole_height_m=0.005)
