"""envs.demos.noise and demos that end apart: the final-pose scatter has exactly the asked root-mean-square and is a
rigid move of each demo's target on its approach (so anchoring each demo at its own end gives one clean approach
back); the bow, the jitter and the sensor noise have their sizes; the goal is the mean end; the file keeps it all;
`pih train` learns such demos relative to their own ends; bad specifications are one-line errors."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from envs.demos.file import DemoSet, anchored_at_goal, load_demos, save_demos, validate_demos
from envs.demos.noise import MOUTH_MARGIN_M, DemoNoise, _approach, add_demo_noise
from envs.errors import EnvError
from envs.poses import quat_angle_rad, quat_conj, quat_mul
from numerics.quaternion import quat_to_mat
from tests.helpers.skill_fixtures import synthetic_demos

PIH = str(Path(sys.executable).with_name("pih"))


@pytest.fixture(scope="module")
def clean() -> DemoSet:
    return synthetic_demos(n=5, m=400)


def rms(values) -> float:
    return math.sqrt(float(np.mean(np.square(values))))


def test_the_end_scatter_has_the_asked_size_and_the_goal_is_the_mean_end(clean):
    noisy = add_demo_noise(clean, DemoNoise.parse("realistic"), seed=3)
    assert noisy.ends_apart and noisy.stiffness is None
    ends, end_quats = noisy.pos[:, -1], noisy.quat[:, -1]
    assert np.allclose(noisy.goal_pos, ends.mean(axis=0), atol=1e-12)
    assert rms(np.linalg.norm(ends - noisy.goal_pos, axis=1)) == pytest.approx(0.003, rel=1e-9)
    assert rms(np.rad2deg(quat_angle_rad(end_quats, noisy.goal_quat))) == pytest.approx(3.0, rel=0.02)
    assert noisy.config["noise"]["end_scatter_rms_mm"] == pytest.approx(3.0, rel=1e-9)
    assert np.allclose(noisy.pos[:, 0], clean.pos[:, 0], atol=5 * 5e-5)  # the starts: only the sensor noise
    validate_demos(noisy)
    again = add_demo_noise(clean, DemoNoise.parse("realistic"), seed=3)
    other = add_demo_noise(clean, DemoNoise.parse("realistic"), seed=4)
    assert np.array_equal(again.pos, noisy.pos) and not np.allclose(other.pos, noisy.pos)


def test_the_scatter_is_a_rigid_move_of_the_approach_that_anchoring_undoes(clean):
    """With the scatter alone, every demo's approach and insertion, anchored at its own end, is the clean one moved
    by one rigid motion (the clean goal onto the mean goal): nothing of the scatter is left there."""
    noise = DemoNoise(final_pos_scatter_m=0.003, final_rot_scatter_deg=3.0)
    noisy = add_demo_noise(clean, noise, seed=1)
    pos, quat = anchored_at_goal(noisy)
    end, end_quat = clean.pos[0, -1], clean.quat[0, -1]
    turn = quat_mul(noisy.goal_quat, quat_conj(end_quat))
    for n in range(clean.num_demos):
        first = _approach(clean.pos[n], MOUTH_MARGIN_M, noise.approach_length_m)[0]
        expected = noisy.goal_pos + (clean.pos[n, first:] - end) @ quat_to_mat(turn).T
        assert np.allclose(pos[n, first:], expected, atol=1e-12)
        assert np.allclose(np.abs(np.sum(quat[n, first:] * quat_mul(turn[None], clean.quat[n, first:]), axis=1)), 1.0,
                           atol=1e-12)
        assert np.allclose(pos[n, -1], noisy.goal_pos) and np.allclose(quat[n, -1], noisy.goal_quat)
    moved = np.linalg.norm(noisy.pos[:, -1] - clean.pos[:, -1], axis=1)
    assert moved.max() > 0.002  # the raw ends did scatter


def test_the_approach_bows_by_its_amplitude_and_not_at_its_ends(clean):
    noisy = add_demo_noise(clean, DemoNoise(approach_bow_m=0.0015, approach_length_m=0.05), seed=2)
    for n in range(clean.num_demos):
        first, last = _approach(clean.pos[n], MOUTH_MARGIN_M, 0.05)
        deviation = np.linalg.norm(noisy.pos[n] - clean.pos[n], axis=1)
        assert deviation.max() == pytest.approx(0.0015, rel=0.05)
        assert deviation[:first + 1].max() < 1e-12 and deviation[last:].max() < 1e-12


def test_the_sensor_noise_and_the_jitter_have_their_sizes(clean):
    noisy = add_demo_noise(clean, DemoNoise(pos_noise_m=1e-4, rot_noise_deg=0.1), seed=5)
    error = (noisy.pos - clean.pos)[:, :-1].reshape(-1)
    assert np.std(error) == pytest.approx(1e-4, rel=0.1) and abs(np.mean(error)) < 1e-5
    angle = np.rad2deg(quat_angle_rad(noisy.quat[:, :-1], clean.quat[:, :-1])).reshape(-1)
    assert rms(angle) == pytest.approx(0.1 * math.sqrt(3), rel=0.1)  # 3 axes of 0.1 deg
    sigma = 0.2 * clean.dt
    jittered = add_demo_noise(clean, DemoNoise(timing_jitter_s=sigma), seed=5)
    speed = np.linalg.norm(np.diff(clean.pos, axis=1), axis=2).max() / clean.dt
    assert np.abs(jittered.pos - clean.pos).max() <= 5 * sigma * speed
    assert np.abs(jittered.pos - clean.pos).max() > 0.5 * sigma * speed * 0.01


def test_the_file_keeps_demos_that_end_apart(clean, tmp_path):
    noisy = add_demo_noise(clean, DemoNoise.parse("realistic"), seed=3)
    back = load_demos(save_demos(tmp_path / "noisy.npz", noisy))
    assert back.ends_apart and np.array_equal(back.pos, noisy.pos) and back.config["noise"] == noisy.config["noise"]
    assert not load_demos(save_demos(tmp_path / "clean.npz", clean)).ends_apart


def test_demos_that_end_apart_are_checked(clean):
    noisy = add_demo_noise(clean, DemoNoise.parse("realistic"), seed=3)
    with pytest.raises(EnvError, match="does not end at the goal .*ends_apart"):
        validate_demos(replace(noisy, ends_apart=False))
    with pytest.raises(EnvError, match="not the mean of their ends"):
        validate_demos(replace(noisy, goal_pos=noisy.goal_pos + 1e-4))
    far = noisy.pos.copy()
    far[0, -1] += 0.05
    with pytest.raises(EnvError, match="demo 0 ends .* from the demos' mean goal"):
        validate_demos(replace(noisy, pos=far, goal_pos=far[:, -1].mean(axis=0)))
    with pytest.raises(EnvError, match="already end apart"):
        add_demo_noise(noisy, DemoNoise.parse("realistic"), seed=1)


@pytest.mark.parametrize("spec, message", [("loud", "not a preset"), ("foo=1", "field 'foo' is unknown"),
                                           ("pos_noise_m=abc", "not a number"), ("pos_noise_m=-1", ">= 0"),
                                           ("final_pos_scatter_m=0.05", "not demos of one hole"),
                                           ("approach_length_m=0", r"\(0, 0.5\]")])
def test_bad_noise_specifications_are_one_line_errors(spec, message):
    with pytest.raises(EnvError, match=message):
        DemoNoise.parse(spec)
    assert DemoNoise.parse("realistic,timing_jitter_s=0").timing_jitter_s == 0.0


def test_pih_demos_refuses_a_bad_noise_before_recording(tmp_path):
    out = tmp_path / "d.npz"
    done = subprocess.run([PIH, "demos", "--num", "2", "--noise", "realistic,foo=1", "--out", str(out)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "field 'foo' is unknown" in done.stderr and len(done.stderr.splitlines()) == 1
    assert not out.exists()


def test_pih_train_learns_demos_that_end_apart_relative_to_their_ends(clean, tmp_path):
    from rflow.skill_io import load_skill
    from scripts.train import train_skill
    from tests.helpers.skill_fixtures import TINY

    noisy = add_demo_noise(clean, DemoNoise.parse("realistic"), seed=3)
    path = save_demos(tmp_path / "noisy.npz", replace(noisy, config={**noisy.config, "source": "synthetic"}))
    skill = load_skill(train_skill(path, tmp_path / "model", TINY, subsample=4, progress=False))
    assert np.allclose(skill.goal_pos, noisy.goal_pos, atol=1e-9)
    assert float(quat_angle_rad(skill.goal_quat, noisy.goal_quat)) < 1e-6
    assert skill.metadata["ends_apart"] is True
