"""Generation (rflow.generate): exact goal, batched rollouts, closed-loop steps."""

import numpy as np
import pytest

from rflow.errors import RFlowError
from rflow.generate import next_point, rollout, velocity
from rflow.model import ModelConfig
from rflow.train import TrainConfig, fit

GOAL = np.array([0.5, -0.1, 0.2])
XI = 1e-3


@pytest.fixture(scope="module")
def model_and_demos():
    s = np.linspace(0, 1, 200)[None, :, None]
    starts = np.array([[0.3, 0.2, 0.1], [0.35, 0.1, 0.15], [0.25, 0.25, 0.05]])[:, None, :]
    demos = (1 - s) ** 2 * starts + np.sin(np.pi * s) * (1 - s) * np.array([0.0, 0.0, 0.08]) + GOAL
    config = TrainConfig(model=ModelConfig(width=32), epochs=6, transitions_per_epoch=1024, horizon=100, threads=1)
    model, _ = fit(demos, "euclidean", 0.01, config, progress=False)
    return model, demos


def test_random_starts_all_reach_the_goal(model_and_demos):
    model, demos = model_and_demos
    radius = 2 * np.abs(demos - GOAL).max(axis=(0, 1))
    starts = GOAL + np.random.default_rng(0).uniform(-radius, radius, size=(1000, 3))
    out = rollout(model, starts, steps=4000, xi=XI)
    assert out.converged.all(), f"{(~out.converged).sum()} of 1000 rollouts did not reach ||tangent|| < xi"
    assert np.all(np.isfinite(out.tangent))


def test_rollout_holds_the_goal_after_stopping(model_and_demos):
    model, demos = model_and_demos
    out = rollout(model, demos[:, 0], steps=3000, xi=XI)
    k = out.lengths[0]
    assert np.linalg.norm(out.tangent[0, k - 1]) < XI <= np.linalg.norm(out.tangent[0, k - 2])
    assert np.all(out.tangent[0, k:] == 0) and np.allclose(out.points[0, k:], GOAL)


def step_by_step_rollout(model, start, steps, xi):
    """Reference of `rollout` for one start: p_{k+1} = next_point(p_k) (one flow round trip per step), stopping at
    the first point with ||Log_g p|| < xi and holding the goal afterwards; returns (points, length)."""
    points = np.repeat(GOAL[None], steps + 1, axis=0)
    point = np.asarray(start, dtype=np.float64)
    for k in range(steps + 1):
        points[k] = point
        if np.linalg.norm(model.to_tangent(point)) < xi:
            return points, k + 1
        point = next_point(model, point)
    return points, steps + 1


def test_batched_rollout_equals_the_step_by_step_reference(model_and_demos):
    model, demos = model_and_demos
    starts = np.concatenate([demos[:, 0], GOAL + np.random.default_rng(5).uniform(-0.2, 0.2, (3, 3))])
    steps = int(np.median(rollout(model, starts, steps=3000, xi=XI).lengths))  # half of them stop before
    out = rollout(model, starts, steps=steps, xi=XI)
    for i, start in enumerate(starts):
        points, length = step_by_step_rollout(model, start, steps, XI)
        assert out.lengths[i] == length
        np.testing.assert_allclose(out.points[i], points, rtol=0.0, atol=1e-9)
    assert out.converged.any() and not out.converged.all()  # both the stopping and the step limit are covered


def test_rollout_shapes_and_start(model_and_demos):
    model, demos = model_and_demos
    out = rollout(model, demos[:, 0], steps=50)
    assert out.points.shape == (3, 51, 3) and out.tangent.shape == (3, 51, 3) and out.lengths.shape == (3,)
    assert np.allclose(out.points[:, 0], demos[:, 0])


def test_next_point_is_the_first_rollout_step(model_and_demos):
    model, demos = model_and_demos
    out = rollout(model, demos[0, 0], steps=1)
    assert np.allclose(next_point(model, demos[0, 0]), out.points[0, 1], atol=1e-12)


def test_single_point_and_batch_agree(model_and_demos):
    model, demos = model_and_demos
    batch = next_point(model, demos[:, 10])
    assert np.allclose(next_point(model, demos[1, 10]), batch[1], atol=1e-12)
    assert np.allclose(velocity(model, demos[1, 10]), velocity(model, demos[:, 10])[1], atol=1e-9)


def test_velocity_integrates_to_the_next_point(model_and_demos):
    model, demos = model_and_demos
    p = demos[0, 30]
    assert np.allclose(p + velocity(model, p, dt=0.02) * 0.02, next_point(model, p, dt=0.02), atol=1e-12)


def test_velocity_vanishes_at_the_goal(model_and_demos):
    model, _ = model_and_demos
    assert np.allclose(velocity(model, GOAL), 0.0, atol=1e-9)


def test_bad_inputs_raise(model_and_demos):
    model, _ = model_and_demos
    with pytest.raises(RFlowError, match="shape"):
        rollout(model, np.zeros((2, 4)))
    with pytest.raises(RFlowError, match="xi"):
        rollout(model, GOAL, xi=0.0)
    with pytest.raises(RFlowError, match="NaN"):
        next_point(model, np.array([np.nan, 0.0, 0.0]))
    with pytest.raises(RFlowError, match="dt"):
        next_point(model, GOAL, dt=-1.0)


def test_one_lookahead_step_of_a_batch_equals_the_single_point_step_bit_for_bit():
    """The compiled batch of closed-loop steps (Euclidean and quaternion charts) is each point's own `next_point`,
    and a point off the manifold raises what the single point raises."""
    from rflow.generate import lookahead_points
    from tests.helpers.skill_fixtures import GOAL_POS, GOAL_QUAT, tiny_skill

    skill = tiny_skill()
    rng = np.random.default_rng(5)
    pos = GOAL_POS + rng.normal(0.0, 0.03, (9, 3))
    quat = GOAL_QUAT + rng.normal(0.0, 0.1, (9, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    quat[0] = GOAL_QUAT  # the goal itself: the chart's small-angle branch
    for name, points in (("position", pos), ("orientation", quat)):
        model = skill.models[name]
        batch = lookahead_points(model, points, 0.05, 1)[0]
        assert batch.shape == points.shape
        for row, point in zip(batch, points):
            assert np.array_equal(row, next_point(model, point, 0.05))
    bad = quat.copy()
    bad[4] *= 1.01
    with pytest.raises(RFlowError, match="not a unit quaternion"):
        lookahead_points(skill.models["orientation"], bad, 0.05, 1)
    nan = pos.copy()
    nan[2, 1] = np.nan
    with pytest.raises(RFlowError, match="NaN"):
        lookahead_points(skill.models["position"], nan, 0.05, 1)


def test_lookahead_points_chain_the_single_point_step_bit_for_bit():
    """Step s + 1 of the compiled chain is `next_point` of step s (a quaternion first put on the given hemisphere and
    divided by its norm, as the closed loop's next query does), for points on either hemisphere; steps < 1 and a
    bad dt are refused."""
    from rflow.generate import lookahead_points
    from tests.helpers.skill_fixtures import GOAL_POS, GOAL_QUAT, tiny_skill

    skill = tiny_skill()
    rng = np.random.default_rng(11)
    pos = GOAL_POS + rng.normal(0.0, 0.03, (7, 3))
    quat = GOAL_QUAT + rng.normal(0.0, 0.2, (7, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    quat[1] = GOAL_QUAT
    hemisphere = -GOAL_QUAT  # the far hemisphere: every chained query flips its quaternion
    for name, points in (("position", pos), ("orientation", quat)):
        model = skill.models[name]
        chain = lookahead_points(model, points, 0.05, 3, hemisphere=hemisphere)
        assert chain.shape == (3,) + points.shape
        for i, point in enumerate(points):
            here = point
            for s in range(3):
                if name == "orientation" and s > 0:
                    here = -here if np.dot(here, hemisphere) < 0.0 else here
                    w, x, y, z = here.tolist()
                    here = here / np.sqrt(w * w + x * x + y * y + z * z)
                here = next_point(model, here, 0.05)
                assert np.array_equal(chain[s, i], here)
    with pytest.raises(RFlowError, match="steps"):
        lookahead_points(skill.models["position"], pos, 0.05, 0)
    with pytest.raises(RFlowError, match="dt"):
        lookahead_points(skill.models["position"], pos, -0.05, 2)


@pytest.mark.parametrize("hemisphere", [[1.0, 0.0], [], [np.nan, 0.0, 0.0, 1.0]])
def test_a_hemisphere_that_is_no_quaternion_is_refused_not_read_past(hemisphere) -> None:
    from rflow.generate import lookahead_points
    from tests.helpers.skill_fixtures import GOAL_QUAT, tiny_skill

    model = tiny_skill().models["orientation"]
    with pytest.raises(RFlowError, match="hemisphere"):  # a short one was read past its end by the kernel
        lookahead_points(model, np.asarray(GOAL_QUAT)[None], 0.05, 2, hemisphere=hemisphere)


@pytest.mark.parametrize("arguments, words", [
    ({"steps": float("nan")}, "steps=nan"),  # ValueError from int(nan) before
    ({"steps": float("inf")}, "steps=inf"),  # OverflowError
    ({"steps": "5"}, "steps='5'"),  # TypeError from '5' < 0
    ({"steps": None}, "steps=None"),
    ({"steps": True}, "steps=True"),  # ran one step
    ({"xi": float("inf")}, "xi=inf"),  # stopped every rollout at its start, "converged"
    ({"xi": "x"}, "xi='x'"),
    ({"xi": True}, "xi=True"),
    ({"dt": "x"}, "dt='x'"),  # ValueError from float('x')
    ({"dt": [0.1]}, r"dt=\[0.1\]"),  # TypeError
    ({"dt": True}, "dt=True"),  # stepped 1 s
    ({"steps": 10**12}, "steps=1000000000000"),  # a MemoryError (or the machine's swap) before
    ({"dt": 10**400}, "dt=1000"),  # OverflowError from math.isfinite
    ({"xi": 10**400}, "xi=1000"),
    ({"dt": np.full((2, 1), 0.01)}, r"dt=array\(\[\[0.01\], \[0.01\]\]\)"),  # an array's repr is two lines
])
def test_a_rollout_argument_that_is_no_valid_number_is_refused_by_name(model_and_demos, arguments, words):
    model, _ = model_and_demos
    with pytest.raises(RFlowError, match=words) as caught:
        rollout(model, GOAL + 0.05, **{"steps": 5, **arguments})
    assert "\n" not in str(caught.value) and len(str(caught.value)) < 160  # one line, the value cut short


@pytest.mark.parametrize("dt", ["x", [0.1], 1j, True])
def test_a_closed_loop_step_that_is_no_positive_number_is_refused_by_name(model_and_demos, dt):
    """next_point, velocity and lookahead_points raised TypeError (np.isfinite of a string), or stepped 1 s for True."""
    from rflow.generate import lookahead_points

    model, _ = model_and_demos
    for query in (lambda: next_point(model, GOAL + 0.01, dt), lambda: velocity(model, GOAL + 0.01, dt),
                  lambda: lookahead_points(model, (GOAL + 0.01)[None], dt, 2)):
        with pytest.raises(RFlowError, match="dt="):
            query()


@pytest.mark.parametrize("points, hemisphere, words", [
    ("abc", None, "points are not an array of numbers"),  # ValueError from np.asarray before
    (None, "abc", "hemisphere is not an array of numbers"),
    (None, [0.0, 0.0, 0.0, 0.0], "not all zero"),  # a zero hemisphere was taken and flipped nothing
])
def test_lookahead_points_or_a_hemisphere_that_are_no_numbers_are_refused(points, hemisphere, words) -> None:
    from rflow.generate import lookahead_points
    from tests.helpers.skill_fixtures import GOAL_QUAT, tiny_skill

    model = tiny_skill().models["orientation"]
    with pytest.raises(RFlowError, match=words):
        lookahead_points(model, np.asarray(GOAL_QUAT)[None] if points is None else points, 0.05, 2,
                         hemisphere=hemisphere)


def test_a_numpy_integer_is_a_number_of_lookahead_steps(model_and_demos) -> None:
    from rflow.generate import lookahead_points

    model, _ = model_and_demos
    points = (GOAL + 0.01)[None]
    assert np.array_equal(lookahead_points(model, points, 0.05, np.int64(2)), lookahead_points(model, points, 0.05, 2))
