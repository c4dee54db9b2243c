"""Test-session defaults: the CPU dispatch `pih` pins (before any test imports numpy or torch, so the tests run the
arithmetic the commands run), headless rendering through Mesa EGL unless the caller chose a backend; the small
trained skill that the slow physics tests share."""

import os

from numerics.cpu_dispatch import pin_cpu_dispatch

pin_cpu_dispatch()  # first, before any test module imports numpy or torch: the arithmetic `pih` runs

import pytest  # noqa: E402

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(scope="session")
def paper_checkpoint(tmp_path_factory):
    """A small RiemannianFlow skill in the paper's setting (the "paper" preset: grasped peg, 1 mm clearance, the
    hole where the demos ended), trained once per session: 7 scripted demos of 400 samples, 40 epochs. It seats
    20 of 20 closed-loop starts of seed 1 (tests/end_to_end/test_paper_skill.py)."""
    from envs.demos.file import save_demos
    from envs.demos.record import collect_demos
    from envs.policies.expert_plan import ExpertConfig
    from envs.task.task import preset
    from scripts.train import skill_train_config, train_skill

    folder = tmp_path_factory.mktemp("paper_skill")
    demos = collect_demos(7, seed=0, scene_config=preset("paper").scene_config(),
                          expert=ExpertConfig(num_samples=400)).demos
    path = save_demos(folder / "demos.npz", demos)
    return train_skill(path, folder / "model", skill_train_config(epochs=40), subsample=1, progress=False)
