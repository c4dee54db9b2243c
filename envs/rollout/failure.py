"""What went wrong in a failed episode, from what the simulated peg did: one kind per failure.

An episode that ends without success ends for a reason of the simulator (envs.sim.env: "force_limit", "instability:
...", "time_limit") or of the loop ("unreachable start: ...", "error: ..."). A time limit alone does not say what
happened, so it is told apart from the peg's last ``window_s`` of control periods (`ProgressWindow`):

    left_grasp          the peg moved in the fingers by more than ``grasp_slip_m`` since the start (|peg_tip - tcp|
                        changed): it slipped out or turned in the grasp, whatever the contact did
    free_space_timeout  no contact force above ``contact_n`` on the peg during the window: it never arrived (or left)
    jammed              held against the walls (contact force above ``jam_force_n`` throughout the window) while its
                        depth in the hole changed by less than ``jam_progress_m``: stuck under load
    time_limit          none of these: in contact and moving, too slowly or back and forth

The other reasons map to "force_limit", "instability", "unreachable_start", "error" and "policy_error" (a user's
policy raised or returned an action that cannot be commanded, envs.rollout.episode: not a failed insertion, and not
scored, envs.evaluation.evaluate_policy). The defaults: 1 s of no
progress is 100 control periods, longer than the contact adaptation's stall search takes to sweep once (1 s period);
0.5 mm of depth is the chamfer's slope at the 0.2 mm clearance seen over a second of sliding; 5 N is above the
wrist sensor's dynamic residue in free space (< 1 N) and below the 40 N force limit; 5 mm of slip is beyond the
sampled grasp offsets' effect on |peg_tip - tcp| (which is compared to its own start value).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

FAILURE_KINDS: tuple[str, ...] = ("left_grasp", "free_space_timeout", "jammed", "time_limit", "force_limit",
                                  "instability", "unreachable_start", "error", "policy_error")
"""The kinds `ProgressWindow.failure` gives, in the order they are checked for a time limit, then the others."""


@dataclass(frozen=True)
class FailureCriteria:
    """Thresholds of the failure kinds (module docstring).

    Attributes:
        window_s: the last seconds of the episode that are judged.
        jam_force_n: contact force on the peg (N) that counts as held against the walls.
        jam_progress_m: least change of insertion depth (m) over the window that counts as progress.
        contact_n: contact force (N) below which the peg is in free space.
        grasp_slip_m: change of |peg_tip - tcp| (m) since the start that counts as leaving the grasp.
    """

    window_s: float = 1.0
    jam_force_n: float = 5.0
    jam_progress_m: float = 0.0005
    contact_n: float = 1.0
    grasp_slip_m: float = 0.005


class ProgressWindow:
    """The last ``window_s`` of an episode's control periods (depth, contact force) and its grasp shift at the start,
    added once per period (`add`), judged at the end (`failure`)."""

    def __init__(self, period_s: float, criteria: FailureCriteria = FailureCriteria()) -> None:
        self.criteria = criteria
        self._rows: deque[tuple[float, float]] = deque(maxlen=max(1, int(round(criteria.window_s / period_s))))
        self._start_shift_m: float | None = None
        self._last_shift_m = 0.0

    def add(self, depth_m: float, contact_force_n: float, grasp_shift_m: float) -> None:
        """One control period's insertion depth (m), contact force on the peg (N) and |peg_tip - tcp| (m); the
        first call is the start."""
        if self._start_shift_m is None:
            self._start_shift_m = grasp_shift_m
        self._last_shift_m = grasp_shift_m
        self._rows.append((depth_m, contact_force_n))

    def failure(self, reason: str) -> str:
        """The failure kind (FAILURE_KINDS) of an episode that ended for ``reason`` without success."""
        for prefix, kind in (("force_limit", "force_limit"), ("instability", "instability"),
                             ("unreachable start", "unreachable_start"), ("error", "error"),
                             ("policy_error", "policy_error")):
            if reason.startswith(prefix):
                return kind
        c = self.criteria
        if self._start_shift_m is not None and abs(self._last_shift_m - self._start_shift_m) > c.grasp_slip_m:
            return "left_grasp"
        rows = list(self._rows)
        if not rows or max(f for _, f in rows) <= c.contact_n:
            return "free_space_timeout"
        depths = [d for d, _ in rows]
        full = len(rows) == self._rows.maxlen
        if full and min(f for _, f in rows) > c.jam_force_n and max(depths) - min(depths) < c.jam_progress_m:
            return "jammed"
        return "time_limit"
