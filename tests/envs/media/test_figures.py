"""Figures a researcher reads: the outcomes by reason and the protocol's per-seed rates."""

import pytest

from envs.evaluation.benchmark import ReplicateOutcome, summarise
from envs.media.figures import outcome_kind, plot_outcomes, plot_protocol


def _record(success, reason, depth_mm, **perturbation):
    return {"success": success, "reason": reason, "insertion_depth_mm": depth_mm, "tilt_deg": 0.5,
            "perturbation": perturbation}


@pytest.mark.parametrize("record, kind", [
    (_record(True, "success", 30.0), "seated"),
    (_record(False, "time_limit (depth 1.0 mm, lateral 0.2 mm)", 1.0), "time_limit"),
    (_record(False, "force_limit (wrist 45.0 N held 5 ms)", 12.0), "force_limit"),
    (_record(False, "error: boom", None), "error"),
])
def test_every_outcome_has_its_kind(record, kind):
    assert outcome_kind(record) == kind


def test_the_outcome_figure_shows_each_reason_in_its_own_colour(tmp_path):
    records = [_record(True, "success", 29.9, hole_offset_mm=0.5, hole_tilt_deg=0.2, hole_yaw_deg=0.1),
               _record(False, "time_limit (...)", 1.0, hole_offset_mm=0.9, hole_tilt_deg=0.9, hole_yaw_deg=-0.8),
               _record(False, "error: no episode", None)]  # no final state: drawn on the left only
    path = plot_outcomes(records, tmp_path / "o.png", "t")
    assert path.stat().st_size > 10_000


def test_the_protocol_figure_draws_seeds_that_ran_and_skips_those_that_did_not(tmp_path):
    summary = summarise([ReplicateOutcome(0, 1000, 190, 200, {"time_limit": 10}),
                         ReplicateOutcome(1, 1001, 200, 200), ReplicateOutcome(2, 1002, error="expert gave up")])
    assert plot_protocol(summary, tmp_path / "p.png", "square").stat().st_size > 10_000


def test_the_force_figure_draws_each_episode_and_the_limit(tmp_path):
    import numpy as np

    from envs.media.figures import plot_force_traces

    t = np.linspace(0.0, 2.0, 201)
    traces = [("episode 0: success", True, t, 5.0 * t), ("episode 3: time_limit", False, t, 20.0 + 0.0 * t)]
    assert plot_force_traces(traces, 40.0, tmp_path / "f.png", "t").stat().st_size > 10_000
    assert plot_force_traces(traces, float("inf"), tmp_path / "g.png").stat().st_size > 10_000  # no limit drawn
