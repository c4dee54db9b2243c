"""Tiny stiffness demos written in a dataset layout, and the check that a layout read them back (no physics)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from envs.datasets.features import episodes_from_demos
from envs.demos.file import DemoSet
from envs.demos.importing import RecordedDemos
from tests.helpers.stiffness_fixtures import stiffness_demos


def export_demos(root: Path, layout: str) -> tuple[DemoSet, Path]:
    """Three stiffness demos of 30 samples written as ``layout`` into the new folder ``root``; (demos, what was
    written: LeRobot's info.json or robomimic's HDF5 file)."""
    demos = stiffness_demos(n=3, m=30)
    meta, episodes = episodes_from_demos(demos, "demos.npz", fps=None)  # the demos' own samples: exact layouts
    root.mkdir()
    if layout == "lerobot":
        from envs.datasets.lerobot import write_lerobot

        write_lerobot(root, meta, episodes)
        return demos, root / "meta" / "info.json"
    from envs.datasets.robomimic import RobomimicWriter

    writer = RobomimicWriter(root, meta)
    for episode in episodes:
        writer.add(episode)
    return demos, writer.close()


def assert_read_back(recorded: RecordedDemos, demos: DemoSet) -> None:
    """Positions and stiffness bit for bit, quaternions to float64 rounding (they are renormalised on reading),
    and what an export of ours names: dt, the tcp frame, shape and clearance."""
    np.testing.assert_array_equal(np.stack(recorded.pos), demos.pos)
    np.testing.assert_allclose(np.stack(recorded.quat), demos.quat, rtol=0, atol=3e-16)
    np.testing.assert_array_equal(np.stack(recorded.stiffness), demos.stiffness)
    assert (recorded.dt, recorded.tool_frame, recorded.shape, recorded.clearance_m) == \
        (demos.dt, "tcp", demos.shape, demos.clearance_m)
