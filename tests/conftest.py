"""Test-session defaults: the CPU dispatch `pih` pins (before any test imports numpy or torch, so the tests run the
arithmetic the commands run), headless rendering through Mesa EGL unless the caller chose a backend, Ctrl-C handled
even when pytest was started with it ignored; the small trained skill that the slow physics tests share; how the
tests are shared among xdist workers."""

import os

from numerics.cpu_dispatch import pin_cpu_dispatch

pin_cpu_dispatch()  # first, before any test module imports numpy or torch: the arithmetic `pih` runs

import signal  # noqa: E402

import pytest  # noqa: E402

os.environ.setdefault("MUJOCO_GL", "egl")

if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    # Started as a background job of a script (a shell ignores SIGINT there): the tests' commands, which stand for a
    # terminal's, start with Ctrl-C handled, as the tests that send it expect (pihutil.interrupts).
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session")
def paper_checkpoint(tmp_path_factory):
    """A small RiemannianFlow skill in the paper's setting (the "paper" preset: grasped peg, 1 mm clearance, the
    hole where the demos ended), trained once per session: 7 scripted demos of 400 samples, 40 epochs. It seats
    20 of 20 closed-loop starts of seed 1. Its tests share one file, tests/end_to_end/test_paper_skill.py, so under
    xdist one worker trains it (pytest_collection_modifyitems)."""
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



def file_of(item: pytest.Item) -> str:
    """The file of a test: the unit of work an xdist worker takes whole (``--dist loadfile``)."""
    return item.nodeid.split("::", 1)[0]


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Share the tests among `pytest -n N` workers as a list scheduler does, longest first.

    pyproject.toml sets ``--dist loadfile --no-loadscope-reorder``: xdist hands an idle worker the next whole test
    file in collection order, so a file's module fixtures are built once, on one worker. The files that hold a
    `slow` test come first, in their own order, then the rest: a worker is not left with a long test at the end
    while the other idles. Without ``-n`` only the order changes (files stay whole).

    The session's `paper_checkpoint` is trained by every worker that runs a test of it, so its tests share one
    file; a second file is refused here."""
    paper = sorted({file_of(item) for item in items if "paper_checkpoint" in item.fixturenames})
    if len(paper) > 1:
        raise pytest.UsageError(f"tests of paper_checkpoint in {', '.join(paper)}: keep them in one file, so that one "
                                "xdist worker trains it, once")
    slow = {file_of(item) for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: file_of(item) not in slow)  # stable: each file keeps its order
