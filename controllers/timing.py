"""Throughput of the controllers, the speed `pih bench` reports: closed-loop physics steps/s, IK solves/s and the
nullspace reference's update per control step.

Timings are medians over repeats on one core; run them on an otherwise idle machine for comparable figures.
"""

from __future__ import annotations

import time

import mujoco
import numpy as np
import numpy.typing as npt

from controllers.errors import ControllerError
from controllers.ik import NullspaceReference, solve_ik
from controllers.impedance import CartesianImpedanceController, ImpedanceConfig
from controllers.validation import site_id


def physics_state(model: mujoco.MjModel, data: mujoco.MjData) -> npt.NDArray[np.float64]:
    """A copy of the full physics state of ``data`` (mjSTATE_INTEGRATION: positions, velocities, controls, applied
    forces, mocap poses), for `replayed_step_rate`."""
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    state = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, state, spec)
    return state


def replayed_step_rate(model: mujoco.MjModel, states: list[npt.NDArray[np.float64]], steps_per_state: int) -> float:
    """Bare mj_step steps/s over recorded states: from each state (restored untimed, in a fresh MjData),
    ``steps_per_state`` plain mj_steps with its controls and applied forces held. Timing physics over the states
    a loop visited makes it pay for the same contacts as that loop."""
    data = mujoco.MjData(model)
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    elapsed = 0.0
    for state in states:
        mujoco.mj_setState(model, data, state, spec)
        t0 = time.perf_counter()
        for _ in range(steps_per_state):
            mujoco.mj_step(model, data)
        elapsed += time.perf_counter() - t0
    return len(states) * steps_per_state / elapsed if elapsed > 0 else float("nan")


BARE_SEGMENT = 10
"""Plain mj_steps timed from each recorded state of the closed loop (one control period at 1 kHz / 100 Hz)."""


def measure_control_rate(
    model: mujoco.MjModel,
    site: int | str = "peg_mount",
    n_steps: int = 2000,
    repeats: int = 7,
    config: ImpedanceConfig = ImpedanceConfig(),
) -> dict[str, float]:
    """Time the closed loop (mj_step1 + controller + mj_step2) against bare mj_step on one core.

    The arm starts at the keyframe "home" when the model has one (else qpos0) and is commanded 5 cm below its
    start pose, so the controller runs its full law. Bare mj_step is timed over the same states: the closed
    loop's state is recorded every BARE_SEGMENT steps, and from each record BARE_SEGMENT plain mj_steps are
    timed (the restores untimed), so both loops pay for the same contacts -- an uncontrolled arm would fall and
    touch other things. Each repeat times n_steps of each loop; medians are reported.

    Args:
        model: model to time (the Panda alone, or a scene with the peg).
        site: controlled site name or id.
        n_steps: physics steps per timed repeat.
        repeats: timed repeats (median taken).
        config: controller gains and limits.

    Returns:
        {"closed_loop_steps_per_s", "bare_steps_per_s", "ratio" (closed / bare), "controller_us_per_step"}.

    Raises:
        ControllerError: n_steps or repeats < 1, or a model the controller cannot drive.
    """
    if n_steps < 1 or repeats < 1:
        raise ControllerError(f"n_steps={n_steps} and repeats={repeats} must be >= 1")
    controller = CartesianImpedanceController(model, site, config)
    data = mujoco.MjData(model)
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")

    def start() -> tuple[npt.NDArray, npt.NDArray]:
        if key >= 0:
            mujoco.mj_resetDataKeyframe(model, data, key)
        else:
            mujoco.mj_resetData(model, data)
        mujoco.mj_forward(model, data)
        controller.reset(data.qfrc_bias[controller.dof_slice])
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, data.site_xmat[controller.site_id])
        return data.site_xpos[controller.site_id] - np.array([0.0, 0.0, 0.05]), quat

    states: list[npt.NDArray] = []

    def record() -> bool:
        if len(states) * BARE_SEGMENT < n_steps and round(data.time / model.opt.timestep) % BARE_SEGMENT == 0:
            states.append(physics_state(model, data))
        return False

    pos, quat = start()
    controller.step(data, pos, quat, n_substeps=n_steps, after_substep=record)  # the states bare mj_step replays
    closed, bare = [], []
    for _ in range(repeats):
        pos, quat = start()
        t0 = time.perf_counter()
        controller.step(data, pos, quat, n_substeps=n_steps)
        closed.append(n_steps / (time.perf_counter() - t0))
        bare.append(replayed_step_rate(model, states, BARE_SEGMENT))
    closed_rate, bare_rate = float(np.median(closed)), float(np.median(bare))
    return {
        "closed_loop_steps_per_s": closed_rate,
        "bare_steps_per_s": bare_rate,
        "ratio": closed_rate / bare_rate,
        "controller_us_per_step": 1e6 * (1.0 / closed_rate - 1.0 / bare_rate),
    }


def _home_posture(model: mujoco.MjModel) -> npt.NDArray[np.float64]:
    """The joints of the "home" keyframe, or qpos0 when the model has none."""
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")
    return model.key_qpos[key].copy() if key >= 0 else model.qpos0.copy()


def _timed_workload(model: mujoco.MjModel, n: int, name: str) -> tuple[npt.NDArray[np.float64], mujoco.MjData]:
    """The home posture and fresh data of ``model`` for a timing of ``n`` calls.

    Raises:
        ControllerError: n < 1 (named ``name``).
    """
    if n < 1:
        raise ControllerError(f"{name}={n} must be >= 1")
    return _home_posture(model), mujoco.MjData(model)


def _site_pose(model: mujoco.MjModel, data: mujoco.MjData, site: int) -> tuple[npt.NDArray, npt.NDArray]:
    """The site's world position and quaternion (w, x, y, z) at ``data.qpos`` (runs mj_kinematics)."""
    mujoco.mj_kinematics(model, data)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[site])
    return data.site_xpos[site].copy(), quat


def measure_ik_rate(
    model: mujoco.MjModel,
    site: int | str = "peg_mount",
    n_solves: int = 20,
    spread_rad: float = 0.4,
    seed: int = 0,
) -> dict[str, float]:
    """Time `solve_ik` on poses of random configurations near the "home" keyframe (or qpos0).

    Args:
        model: the arm or a scene containing it.
        site: the site to place.
        n_solves: number of timed solves (the median time is reported).
        spread_rad: half-width of the uniform joint perturbation that generates the target poses.
        seed: seed of the perturbations (the same workload on every run).

    Returns:
        {"ik_solves_per_s": median rate, "ik_ms_median": median time per solve in ms}.

    Raises:
        ControllerError: n_solves < 1, or a generated pose that cannot be reached.
    """
    q_home, data = _timed_workload(model, n_solves, "n_solves")
    target_site = site_id(model, site)
    rng = np.random.default_rng(seed)
    times = []
    for _ in range(n_solves):
        data.qpos[:] = np.clip(
            q_home + rng.uniform(-spread_rad, spread_rad, model.nq), model.jnt_range[:, 0], model.jnt_range[:, 1]
        )
        pos, quat = _site_pose(model, data, target_site)
        start = time.perf_counter()
        solve_ik(model, site, pos, quat, q_home)
        times.append(time.perf_counter() - start)
    median = float(np.median(times))
    return {"ik_solves_per_s": 1.0 / median, "ik_ms_median": 1e3 * median}


def measure_nullspace_update(
    model: mujoco.MjModel,
    site: int | str = "peg_mount",
    n_updates: int = 1000,
    amplitude_m: float = 0.02,
) -> dict[str, float]:
    """Time `NullspaceReference.update` (3 warm-started IK iterations, as every control step runs it) along a target
    circling the home pose of the site at 1 Hz, sampled at 100 Hz.

    Args:
        model: the arm or a scene containing it.
        site: the controlled site.
        n_updates: timed updates (the median is reported).
        amplitude_m: radius of the circle.

    Returns:
        {"nullspace_update_us_median": median time per update in us}.

    Raises:
        ControllerError: n_updates < 1, or a model the reference cannot run on.
    """
    q_home, data = _timed_workload(model, n_updates, "n_updates")
    data.qpos[:] = q_home
    centre, quat = _site_pose(model, data, site_id(model, site))
    reference = NullspaceReference(model, site, q_home)
    times = []
    for k in range(n_updates):
        phase = 2.0 * np.pi * k / 100.0
        pos = centre + amplitude_m * np.array([np.cos(phase) - 1.0, np.sin(phase), 0.0])
        start = time.perf_counter()
        reference.update(pos, quat)
        times.append(time.perf_counter() - start)
    return {"nullspace_update_us_median": 1e6 * float(np.median(times))}
