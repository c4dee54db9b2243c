"""The compiled physics-rate sensing (envs.sim.sensing_kernel) against plain numpy/Python evaluations of its
equations."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import scipy.spatial.transform

from envs.errors import EnvError
from envs.sim import sensing_kernel as kernel
from envs.sim.sensing import PegContacts, ToolLoad, WristSensor
from envs.task.sensor_config import SENSOR_SIZE, WristSensorConfig

GRAVITY = np.array([0.0, 0.0, -9.81])
DT, WINDOW_S, LIMIT_N = 0.001, 0.005, 40.0
WINDOW = round(WINDOW_S / DT)


@pytest.mark.parametrize("n_bodies", [1, 3, 4, 6, 9])  # below, at and past the four partial sums
def test_wrist_wrench_equals_the_docstring_equations(n_bodies: int) -> None:
    rng = np.random.default_rng(n_bodies)
    rot = scipy.spatial.transform.Rotation.random(random_state=n_bodies).as_matrix()
    site_pos, force, torque = rng.normal(size=3), rng.normal(0.0, 20.0, 3), rng.normal(0.0, 2.0, 3)
    xipos = rng.normal(size=(12, 3))
    bodies = rng.choice(12, n_bodies, replace=False)
    masses = rng.uniform(0.1, 2.0, n_bodies)
    gravity = GRAVITY + rng.normal(0.0, 1.0, 3)  # a general direction: every term of the cross product counts
    mass = masses.sum()
    centre = masses @ xipos[bodies] / mass
    want = np.concatenate([-(force - rot.T @ (-mass * gravity)),
                           -(torque - rot.T @ -np.cross(mass * (centre - site_pos), gravity))])
    out = np.zeros(6)
    kernel.wrist_wrench(rot.ravel(), site_pos, xipos, force, torque, bodies, np.concatenate([[mass], gravity, masses]),
                        out)
    np.testing.assert_allclose(out, want, rtol=1e-12, atol=1e-12)


def _counted_table(ngeom: int, peg: set[int], ignored: set[int]) -> np.ndarray:
    return np.array([[(a in peg) != (b in peg) and not ({a, b} - peg) & ignored for b in range(ngeom)]
                     for a in range(ngeom)])


def test_contact_forces_count_only_the_environment_on_the_peg() -> None:
    """Peg geoms 0, 1; geom 2 a finger (ignored); 3, 4 the environment."""
    counted = _counted_table(5, {0, 1}, {2})
    geom = np.array([[0, 3], [2, 0], [4, 1], [3, 4], [0, 1], [1, 3], [3, 0]], dtype=np.int32)
    efc_address = np.array([0, 3, -1, 6, 9, 12, 15], dtype=np.int32)  # [4, 1] has no constraint rows
    efc_force = np.arange(18, dtype=float) * -1.5
    want = [abs(efc_force[a]) for (g1, g2), a in zip(geom, efc_address)
            if (g1 in (0, 1)) != (g2 in (0, 1)) and 2 not in (g1, g2) and a >= 0]  # pairs 0, 5, 6
    scratch = np.full_like(kernel.contact_scratch(), 1e9)  # left over from earlier reads: must not leak in
    total, single = kernel.normal_forces(geom, efc_address, efc_force, counted, scratch)
    assert len(want) == 3 and (total, single) == (sum(want), max(want))


def test_no_counted_contact_reads_zero() -> None:
    counted = _counted_table(3, {0}, {1})
    geom = np.array([[0, 1]], dtype=np.int32)
    assert kernel.normal_forces(geom, np.array([0], np.int32), np.array([5.0]), counted,
                                kernel.contact_scratch()) == (0.0, 0.0)


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 23, 128, 129, 300, 1000, 5000])
def test_pairwise_sum_is_numpys_to_the_last_bit(n: int) -> None:
    values = np.abs(np.random.default_rng(n).normal(size=n)) * 10.0 ** np.random.default_rng(n + 1).integers(-6, 6, n)
    assert kernel.pairwise_sum(values, n) == np.sum(values)


def test_more_contacts_than_the_scratch_holds_still_sum_like_numpy() -> None:
    n = 3 * kernel.contact_scratch().size
    forces = np.random.default_rng(0).uniform(0.0, 50.0, n)
    geom = np.tile(np.array([[0, 1]], dtype=np.int32), (n, 1))
    counted = _counted_table(2, {0}, set())
    total, single = kernel.normal_forces(geom, np.arange(n, dtype=np.int32), forces, counted,
                                         kernel.contact_scratch())
    assert (total, single) == (np.sum(forces), np.max(forces))


def _sense(state: np.ndarray, force_n: float, sensor: np.ndarray | None = None,
           noise: np.ndarray | None = None) -> bool:
    """One physics step of the fused update with a massless tool (so F_ext = -F_s), no contacts and (default) the
    ideal sensor."""
    load = np.concatenate([[0.0], GRAVITY, [0.0]])
    empty = np.zeros((0, 2), np.int32)
    return kernel.sense_substep(np.eye(3).ravel(), np.zeros(3), np.zeros((1, 3)), np.array([0.0, 0.0, force_n]),
                                np.zeros(3), np.zeros(1, np.int64), load, empty, np.zeros(0, np.int32), np.zeros(0),
                                np.zeros((1, 1), bool), kernel.contact_scratch(),
                                np.array([LIMIT_N, WINDOW_S, DT]), np.zeros(SENSOR_SIZE) if sensor is None else sensor,
                                np.zeros((1, 6)) if noise is None else noise, state, np.zeros(6))


def test_force_limit_fires_after_exactly_the_window_above_the_limit() -> None:
    state = kernel.sense_state(WINDOW)
    hits = [_sense(state, 50.0) for _ in range(WINDOW + 1)]
    assert hits == [False] * (WINDOW - 1) + [True, True]


def test_force_limit_restarts_when_the_force_drops() -> None:
    state = kernel.sense_state(WINDOW)
    forces = [50.0] * (WINDOW - 1) + [LIMIT_N] + [50.0] * (WINDOW - 1)  # exactly at the limit is not above it
    assert not any(_sense(state, f) for f in forces)
    assert state[kernel.ABOVE_LIMIT_S] == pytest.approx((WINDOW - 1) * DT)


def test_sustained_force_is_the_largest_minimum_over_full_windows() -> None:
    forces = np.random.default_rng(3).uniform(0.0, 30.0, 40)
    state = kernel.sense_state(WINDOW)
    for f in forces:
        _sense(state, f)
    want = max(min(forces[i:i + WINDOW]) for i in range(len(forces) - WINDOW + 1))
    assert state[kernel.PEAK_SUSTAINED] == want and state[kernel.PEAK_FORCE] == max(forces)


_XML = """<mujoco><option cone="elliptic"/><worldbody><body name="hand" pos="0 0 1"><freejoint/>
<geom size="0.05" mass="1"/><site name="ft"/></body></worldbody>
<sensor><force site="ft"/><torque site="ft"/></sensor></mujoco>"""


def test_inputs_the_model_does_not_have_are_refused_at_construction() -> None:
    model = mujoco.MjModel.from_xml_string(_XML)
    with pytest.raises(EnvError, match="torque address 4"):
        WristSensor(model, 0, 0, 4, ToolLoad((1,)))
    with pytest.raises(EnvError, match="bodies"):
        WristSensor(model, 0, 0, 3, ToolLoad(()))
    with pytest.raises(EnvError, match="geoms"):
        PegContacts(model, (0,), (1,))


def _sensed_errors(alpha: float, bias: np.ndarray, sigma: np.ndarray, steps: int = 20_000) -> np.ndarray:
    """(steps, 6) sensed minus true wrench of the sensor model over a constant true force of 10 N, periods of 10
    physics steps with their noise drawn as EpisodeSensing.start_period draws it."""
    state = kernel.sense_state(WINDOW)
    sensor = np.concatenate([[1.0, alpha], bias])
    rng = np.random.default_rng(11)
    noise = np.zeros((10, 6))
    true = None
    errors = []
    for k in range(steps):
        if k % 10 == 0:
            noise[:] = rng.standard_normal(noise.shape) * sigma
            state[kernel.SUBSTEP] = 0.0
        _sense(state, 10.0, sensor, noise)
        true = state[kernel.WRENCH:kernel.WRENCH + 6].copy()
        errors.append(state[kernel.SENSED:kernel.SENSED + 6] - true)
    return np.array(errors[200:])  # after the filter's start from 0


def test_the_sensor_reads_the_true_wrench_plus_bias_and_white_noise() -> None:
    bias, sigma = np.array([0.5, -0.3, 1.0, 0.02, -0.01, 0.0]), np.array([0.2, 0.2, 0.2, 0.01, 0.01, 0.01])
    errors = _sensed_errors(1.0, bias, sigma)
    n = errors.shape[0]
    assert np.all(np.abs(errors.mean(axis=0) - bias) < 4.0 * sigma / np.sqrt(n))
    assert errors.std(axis=0) == pytest.approx(sigma, rel=0.03)


def test_the_low_pass_filter_shrinks_the_noise_as_a_first_order_filter() -> None:
    """White noise through y <- y + alpha (m - y) has variance sigma^2 alpha / (2 - alpha)."""
    alpha = WristSensorConfig(sensor_mode="wrist", sensor_cutoff_hz=100.0).alpha(DT)
    sigma = np.full(6, 0.2)
    errors = _sensed_errors(alpha, np.zeros(6), sigma, steps=60_000)
    assert errors.std(axis=0) == pytest.approx(sigma * np.sqrt(alpha / (2.0 - alpha)), rel=0.06)


def test_the_force_limit_reads_the_sensor_and_the_peaks_the_truth() -> None:
    """A true 30 N under the 40 N limit, read with a +15 N bias along it: the limit fires after its window, while
    the record's peak stays the true 30 N."""
    state = kernel.sense_state(WINDOW)
    sensor = np.concatenate([[1.0, 1.0], [0.0, 0.0, -15.0, 0.0, 0.0, 0.0]])  # F_ext = -F_s: -15 N on F_s's z
    hits = [_sense(state, 30.0, sensor, np.zeros((WINDOW + 1, 6))) for _ in range(WINDOW)]
    assert hits[-1] and not any(hits[:-1])
    assert state[kernel.PEAK_FORCE] == 30.0 and abs(state[kernel.SENSED + 2]) == pytest.approx(45.0)
