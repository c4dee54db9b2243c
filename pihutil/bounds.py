"""The range of every number a user gives pih (an option, a task-file field, a checkpoint field), one place per
quantity, each derived from what the code that consumes it can take and naming that code.

A value outside its range would not fail where it is given but later, inside the work: an OverflowError of a timer
in every episode, a controller refusing every command, a MemoryError after building a list of 10^11 seeds. So the
command line (scripts.options), the task (envs.task.task), the evaluation's config (envs.evaluation.config), the batch
(batch.config) and the controller (controllers.impedance) all check against the `Bound` here, and a value outside is
one line and exit status 2 before any work. Stdlib only: every layer imports it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Bound:
    """A closed interval [low, high] (``low_open``: (low, high]) of a quantity in ``unit``, integers only with
    ``integer``; ``high`` may be inf where infinity means "no limit" (``infinite``)."""

    low: float
    high: float
    unit: str = ""
    low_open: bool = False
    integer: bool = False
    infinite: bool = False

    def contains(self, value: Any) -> bool:
        """Whether ``value`` is a number (not a bool; an int for ``integer``; not NaN) inside the interval."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return False
        if self.integer and not isinstance(value, int):
            return False
        if isinstance(value, float) and (math.isnan(value) or (math.isinf(value) and not (self.infinite and
                                                                                          value == math.inf))):
            return False
        above = value > self.low if self.low_open else value >= self.low
        return above and value <= self.high

    def text(self) -> str:
        """The interval for a message: "in (0, 1e+06] s", "in 1..1,024"."""
        if self.integer:
            return f"in {self.low:,.0f}..{self.high:,.0f}{' ' + self.unit if self.unit else ''}"
        high = "inf" if math.isinf(self.high) else f"{self.high:g}"
        return f"in {'(' if self.low_open else '['}{self.low:g}, {high}]{' ' + self.unit if self.unit else ''}"


# ---- counts: memory and time per item, and the seeds' own range --------------------------------------------------

SEED = Bound(0, 2**32 - 1, integer=True)
"""A seed: NumPy's and torch's seed range (numpy.random.default_rng, torch.manual_seed)."""
EPISODES = Bound(1, 100_000, integer=True)
"""Episodes of one evaluation or sweep cell: each holds a start (and, in a journal and a JSON, a ~2 KB record); an
episode index of a result lies below it (envs.evaluation.replay)."""
DEMOS = Bound(1, 1_000, integer=True)
"""Demonstrations recorded at once (each ~4000 samples x 7 numbers, recorded in physics)."""
SAMPLES = Bound(2, 100_000, integer=True)
"""Samples per demo (M = 4000 in the paper)."""
WORKERS = Bound(1, 1_024, integer=True)
"""Worker processes or Ray actors of a batch (batch.config.BatchConfig): each a process with its own simulator."""
EPOCHS = Bound(1, 1_000_000, integer=True)
TRIALS = Bound(1, 100_000, integer=True)
REPLICATES = Bound(1, 1_000, integer=True)
"""Demo seeds of one success-rate protocol (envs.evaluation.benchmark.parse_seeds: counted before the list is
built), each a folder with demos, a checkpoint and an evaluation."""

# ---- time ---------------------------------------------------------------------------------------------------------

TIMEOUT_S = Bound(0.0, 1e6, "s", low_open=True)
"""A wall-clock limit (a unit's, a worker start's; batch.config.BatchConfig). The timers that enforce it: SIGALRM's
setitimer takes at most 9.2e9 s (int64 nanoseconds), a lockstep group's limit is the unit's times its at most
256 units (envs.evaluation.config.MAX_LOCKSTEP), and poll(2) takes int milliseconds (2,147,483 s; the process
backend's waits are cut to it). 1e6 s (11.6 days) keeps a group inside all of them."""
TIME_LIMIT_S = Bound(0.0, 3600.0, "s", low_open=True)
"""Simulated seconds of one episode (envs.task.task.Task.time_limit_s): 360,000 control periods at 100 Hz; a replay
keeps a trace of every period (envs.rollout.episode.EpisodeTrace)."""
LOOKAHEAD_S = Bound(0.0, TIME_LIMIT_S.high, "s", low_open=True)
"""The closed loop's lookahead along the learned flow (envs.policies.flow_skill): no further than the longest
episode; the flow's step matrix exp(A t) overflows long before 1e300 s."""

# ---- the controller -----------------------------------------------------------------------------------------------

STIFFNESS = Bound(1e-3, 1e6, "N/m")
"""A commanded stiffness eigenvalue (N/m or N m/rad), what controllers.impedance.validate_stiffness takes: below
1e-3 the feed-forward lead K^-1 D xi overflows, above 1e6 (200x a Panda's Cartesian stiffness of record) the law's
torque does."""
FEEDFORWARD_GAIN = Bound(0.0, 100.0)
"""The gain on the impedance feed-forward lead (envs.policies.feedforward; 1 is the quasi-static lead, 0 none). The
controller takes any finite lead (it clips the pose error), but the led pose's quaternion loses every digit once the
lead's rotation vector passes ~1e15 rad (a gain of ~1e200 here); 100 times the physical lead is far past any use."""
SPEED = Bound(0.0, 10.0, low_open=True)
"""The time scaling of the learned flow an evaluation runs: up to 10x the demonstrated speed."""

# ---- geometry and recordings ----------------------------------------------------------------------------------------

TOOL_OFFSET_M = Bound(0.0, 1.0, "m")
"""The length of a recorded tool's offset from the flange (envs.demos.importing.parse_tool_offset): a tool longer
than the Panda's 0.855 m reach is no tool it carries."""
SAMPLE_PERIOD_S = Bound(0.0, 1.0, "s", low_open=True)
"""A recording's sample period (`pih demos --import --dt-s`): the 100 Hz control loop interpolates between samples;
a recording slower than 1 Hz holds no motion it could follow."""
ENTRY_SPEED_M_S = Bound(0.0, 0.5, "m/s", low_open=True)
"""The scripted expert's insertion speed (envs.policies.expert_plan): the feed-forward twist is cut to 0.5 m/s
(envs.policies.feedforward.MAX_SPEED_M_S)."""

# ---- the task's sensing and success (envs.task.sensor_config, envs.task.task.SuccessConfig) -------------------------

SENSOR_FORCE_N = Bound(0.0, 1e4, "N")
"""A wrist sensor's force noise or bias (sigma, N): a force/torque sensor's range is some hundreds to a few thousand
newtons; past 1e4 N every reading is the noise, and every episode ends at the force limit in free space."""
SENSOR_TORQUE_NM = Bound(0.0, 1e3, "N m")
"""A wrist sensor's torque noise or bias (sigma, N m)."""
JOINT_TORQUE_NM = Bound(0.0, 87.0, "N m")
"""A joint torque sensor's noise or bias (sigma, N m): no larger than the largest torque a Panda joint takes
(controllers.impedance.PANDA_TORQUE_LIMITS_NM)."""
SENSOR_CUTOFF_HZ = Bound(0.0, 1e6, "Hz")
"""A sensor's low-pass cutoff (0: none): above the 1 kHz reading rate it no longer filters."""
SEAT_TOLERANCE_M = Bound(0.0, 0.01, "m")
"""How far from the seated depth a peg still counts as seated (envs.task.success): past 1 cm a peg resting on the
hole's mouth counts."""
PENETRATION_TOLERANCE_M = Bound(0.0, 0.001, "m")
"""The wall penetration still counted as inside (envs.task.success): past 1 mm a peg beside the hole counts."""
REST_SPEED_M_S = Bound(0.0, 1.0, "m/s")
"""The speed under which a peg is at rest (envs.task.success)."""
FLOOR_FORCE_N = Bound(0.0, 1e4, "N")
"""The force a seated peg must press on the hole's floor (and below the task's force limit, envs.task.task)."""

# ---- learning -------------------------------------------------------------------------------------------------------

LEARNING_RATE = Bound(0.0, 1.0, low_open=True)
"""Adam's step size (rflow.train): each step moves a weight by up to lr on normalised data (order 1); above 1
every run diverges."""
LOG_SCALE_CLAMP = Bound(0.0, 88.0, low_open=True)
"""The bound c of a coupling layer's log-scale (rflow.model): its scale exp(c) must be a float32 (training runs in
float32, exp(88.7) is its largest)."""
PRIOR_WEIGHT = Bound(0.0, 1e6)
"""The weight of the off-data prior in the float32 loss (rflow.train)."""
PRIOR_RADIUS = Bound(0.0, 1e6, low_open=True)
"""The prior box's half-width in multiples of the demos' extent, a float32 (rflow.train)."""


__all__ = ["Bound", "DEMOS", "FLOOR_FORCE_N", "JOINT_TORQUE_NM", "PENETRATION_TOLERANCE_M", "REST_SPEED_M_S",
           "SEAT_TOLERANCE_M", "SENSOR_CUTOFF_HZ", "SENSOR_FORCE_N", "SENSOR_TORQUE_NM", "ENTRY_SPEED_M_S", "EPISODES", "EPOCHS", "FEEDFORWARD_GAIN", "LEARNING_RATE",
           "LOG_SCALE_CLAMP", "LOOKAHEAD_S", "PRIOR_RADIUS", "PRIOR_WEIGHT", "REPLICATES", "SAMPLES",
           "SAMPLE_PERIOD_S", "SEED", "SPEED", "STIFFNESS", "TIMEOUT_S", "TIME_LIMIT_S", "TOOL_OFFSET_M", "TRIALS",
           "WORKERS"]
