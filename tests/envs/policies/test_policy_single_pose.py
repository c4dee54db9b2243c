"""The one-quaternion maps (envs.poses) and the closed loop's one-pose paths (envs.policies.flow_skill) give the
batched maps' results to the bit."""

import numpy as np

from envs.policies import flow_skill as policy
from envs.poses import quat_conj, quat_from_rotvec, quat_from_rotvec_one, quat_mul, quat_mul_one, quat_to_rotvec


def _pairs(n: int = 2000):
    """Random unit quaternion pairs at angles from 1e-14 rad to a half turn (some on opposite hemispheres)."""
    rng = np.random.default_rng(7)
    for i in range(n):
        q0 = rng.normal(size=4)
        q0 /= np.linalg.norm(q0)
        q1 = q0 + 10.0 ** rng.uniform(-14, 1) * rng.normal(size=4)
        q1 /= np.linalg.norm(q1)
        yield rng.normal(size=3), q0, rng.normal(size=3), (-q1 if i % 3 == 0 else q1)


def test_single_pose_twist_is_the_batched_one_to_the_bit():
    for p0, q0, p1, q1 in _pairs():
        batched = np.concatenate([(p1 - p0) / 0.05, quat_to_rotvec(quat_mul(q1, quat_conj(q0))) / 0.05])
        assert policy.pose_twist(p0, q0, p1, q1, 0.05).tobytes() == batched.tobytes()


def test_single_quat_from_rotvec_product_is_the_batched_one_to_the_bit():
    for i, (p0, q0, _, _) in enumerate(_pairs()):
        r = p0 * 10.0 ** -(i % 15)  # rotation vectors from ~1 rad down to ~1e-14 rad
        single = quat_mul_one(quat_from_rotvec_one(r.tolist()), q0.tolist())
        assert np.array(single).tobytes() == quat_mul(quat_from_rotvec(r), q0).tobytes()


def test_single_hemisphere_and_unit_are_the_batched_ones_to_the_bit():
    for _, q0, p1, q1 in _pairs():
        goal = np.concatenate([p1, q0[:1]])
        batched = q1 * np.where(np.sum(q1 * goal) < 0.0, -1.0, 1.0)
        assert policy.on_goal_hemisphere(q1, goal).tobytes() == batched.tobytes()
        unnormalised = 1.3 * q1
        assert policy._unit(unnormalised).tobytes() == (unnormalised / np.linalg.norm(unnormalised, axis=-1,
                                                                                      keepdims=True)).tobytes()


def test_batched_hemisphere_still_flips_each_row():
    q = np.array([[1.0, 0.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0]])
    assert np.array_equal(policy.on_goal_hemisphere(q, [1.0, 0.0, 0.0, 0.0]), [[1.0, 0, 0, 0], [1.0, 0, 0, 0]])
