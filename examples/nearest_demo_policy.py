"""Evaluate your own policy: a nearest-neighbour replay of demonstrations read from a LeRobot dataset.

This is the shape of a policy trained elsewhere and scored here (README, "Evaluate your own policy"):

    pih demos --num 7 --seed 0 --out demos.npz
    pih export --demos demos.npz --format lerobot --out ds
    pih evaluate --policy examples.nearest_demo_policy:make --policy-option dataset=ds --demos demos.npz \\
        --episodes 20 --json mine.json

`pih evaluate` imports this module (the current folder first on the path), calls ``make(task, dataset="ds")`` once
per process and scores the returned policy on the demos' scene, starts and hole-pose errors, exactly as it scores
the RiemannianFlow skill. "Training" here is reading the dataset: the Parquet table data/chunk-*/file-*.parquet holds
one row per frame with ``episode_index``, ``frame_index``, ``observation.state`` (the measured tcp pose [x, y, z,
qw, qx, qy, qz], metres, world frame) and ``action.stiffness`` (the 3x3 translational stiffness the expert
commanded, row-major, N/m); meta/info.json gives ``fps``. At each episode's start the policy picks the demo whose
first pose is nearest the measured start (position distance + 0.1 m per radian of rotation) and replays it with
the start offset faded out over ``blend_s`` (envs.policies.replay.ReplayPolicy); within 35 mm of the nominal
goal it lowers the rotational stiffness and aims 5 mm past the goal (a gentle push, as the skill's contact
adaptation does). It sees what a real cell sees (envs.policies.interface.Observation) and
never the hole-pose error, so it seats the peg only where the chamfer catches it.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from envs.errors import EnvError
from envs.policies.interface import Action, Observation, PolicyTask
from envs.policies.replay import ReplayPolicy
from envs.poses import rotate

ROT_WEIGHT_M_PER_RAD = 0.1
COMPLIANT_RADIUS_M = 0.035
"""Within this distance of the nominal goal the policy commands COMPLIANT_ROT_NM_RAD ..."""
COMPLIANT_ROT_NM_RAD = 5.0
"""... a low rotational stiffness, so the walls can turn a tilted or yawed peg into a tilted or turned hole, ..."""
PUSH_M = 0.005
"""... and a target this far past the demos' goal along the hole axis (~5 N at the demos' 1000 N/m along the axis),
so friction on the walls of a displaced hole does not stop the peg short of the floor."""


def read_demos(dataset: Path) -> tuple[float, list[dict[str, np.ndarray]]]:
    """(fps, [{"pos": (T, 3), "quat": (T, 4), "stiffness": (T, 3, 3) or absent}, ...]) of a LeRobot dataset.

    Raises:
        EnvError: no info.json or data files, or a table without observation.state.
    """
    info, files = dataset / "meta" / "info.json", sorted((dataset / "data").glob("chunk-*/file-*.parquet"))
    if not info.is_file() or not files:
        raise EnvError(f"dataset={dataset}: not a LeRobot dataset (meta/info.json and data/chunk-*/file-*.parquet)")
    fps = float(json.loads(info.read_text())["fps"])
    demos = []
    for path in files:
        table = pq.read_table(path)
        if "observation.state" not in table.column_names:
            raise EnvError(f"{path}: no observation.state column (export demos with `pih export --demos`)")
        episode = table.column("episode_index").to_numpy()
        frame = table.column("frame_index").to_numpy()
        state = np.array(table.column("observation.state").to_pylist(), dtype=np.float64)
        stiffness = (np.array(table.column("action.stiffness").to_pylist(), dtype=np.float64).reshape(-1, 3, 3)
                     if "action.stiffness" in table.column_names else None)
        for e in np.unique(episode):
            rows = np.flatnonzero(episode == e)
            rows = rows[np.argsort(frame[rows])]
            demo = {"pos": state[rows, :3], "quat": state[rows, 3:], "times": frame[rows] / fps}
            if stiffness is not None:
                demo["stiffness"] = stiffness[rows]
            demos.append(demo)
    return fps, demos


class NearestDemoPolicy:
    """Replays the demo that starts nearest the measured start pose (module docstring)."""

    def __init__(self, demos: list[dict[str, np.ndarray]], blend_s: float):
        self.replays = [ReplayPolicy(d["times"], d["pos"], d["quat"], d.get("stiffness"), blend_s=blend_s)
                        for d in demos]
        self.starts = [(d["pos"][0], d["quat"][0]) for d in demos]
        self.current: ReplayPolicy | None = None

    def reset(self, observation: Observation, period_s: float) -> None:
        """Choose the nearest demo and start replaying it from the measured start."""
        pos, quat = np.asarray(observation.tcp.pos), np.asarray(observation.tcp.quat)

        def distance(start: tuple[np.ndarray, np.ndarray]) -> float:
            angle = 2.0 * np.arccos(min(1.0, abs(float(np.dot(start[1], quat)))))
            return float(np.linalg.norm(start[0] - pos)) + ROT_WEIGHT_M_PER_RAD * angle

        self.current = self.replays[int(np.argmin([distance(s) for s in self.starts]))]
        self.current.reset(observation, period_s)

    def act(self, observation: Observation) -> Action:
        """The chosen demo's next pose, stiffness and velocity; near the hole rotationally compliant and pushing."""
        if self.current is None:
            raise EnvError("NearestDemoPolicy.act before reset")
        action = self.current.act(observation)
        if np.linalg.norm(np.asarray(observation.tcp.pos) - observation.nominal_goal.pos) < COMPLIANT_RADIUS_M:
            into_hole = -rotate(observation.nominal_hole.quat, [0.0, 0.0, 1.0])
            action = dataclasses.replace(action, rotational_stiffness=COMPLIANT_ROT_NM_RAD,
                                         push=np.concatenate([PUSH_M * into_hole, np.zeros(3)]))
        return action


def make(task: PolicyTask, dataset: str = "ds", blend_s: str = "3.0") -> NearestDemoPolicy:
    """The factory `pih evaluate --policy examples.nearest_demo_policy:make` calls (options arrive as strings)."""
    fps, demos = read_demos(Path(dataset))
    if not demos:
        raise EnvError(f"dataset={dataset}: no episodes")
    return NearestDemoPolicy(demos, float(blend_s))
