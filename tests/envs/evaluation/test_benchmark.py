"""The success-rate protocol's statistics and `pih benchmark`'s checks (no physics)."""

import json

import numpy as np
import pytest
from scipy import stats

from envs.errors import EnvError
from envs.evaluation.benchmark import (
    ProtocolConfig,
    ReplicateOutcome,
    between_seed_interval,
    fit_beta_binomial,
    parse_seeds,
    summarise,
    summary_lines,
)
from scripts.cli import main


def test_seed_lists_and_ranges_parse():
    assert parse_seeds("0-4") == (0, 1, 2, 3, 4)
    assert parse_seeds("0,3, 9-10") == (0, 3, 9, 10)


@pytest.mark.parametrize("spec", ["", "a", "3-1", "-1", "0,-2"])
def test_bad_seed_lists_are_refused(spec):
    with pytest.raises(EnvError, match="seeds"):
        parse_seeds(spec)


def test_start_seeds_never_equal_a_demo_seed():
    with pytest.raises(EnvError, match="equal demo seeds"):
        ProtocolConfig(demo_seeds=(0, 5), start_seed_offset=5)
    assert ProtocolConfig(demo_seeds=(0, 1)).start_seeds() == [1000, 1001]


def test_between_seed_interval_is_the_t_interval_over_seeds():
    rates = [0.85, 0.98, 0.95, 0.97, 0.99]
    low, high = between_seed_interval(rates)
    half = stats.t.ppf(0.975, 4) * np.std(rates, ddof=1) / np.sqrt(5)
    assert low == pytest.approx(np.mean(rates) - half) and high == pytest.approx(min(1.0, np.mean(rates) + half))


def test_spread_between_seeds_widens_the_interval_beyond_the_pooled_wilson():
    spread = summarise([ReplicateOutcome(s, s + 1000, k, 200) for s, k in enumerate([170, 196, 190, 194, 198])])
    same = summarise([ReplicateOutcome(s, s + 1000, k, 200) for s, k in enumerate([190, 189, 190, 190, 189])])
    width = lambda ci: ci[1] - ci[0]  # noqa: E731
    assert width(spread["between_seeds"]["mean_rate_ci95"]) > 2 * width(spread["pooled"]["rate_ci95"])
    # replicates that agree: no narrower than the pooled interval (their episodes' binomial noise remains)
    assert same["between_seeds"]["mean_rate_ci95"] == pytest.approx(same["pooled"]["rate_ci95"])


def test_beta_binomial_fit_recovers_a_known_spread():
    rng = np.random.default_rng(3)
    rates = rng.beta(18.0, 2.0, size=400)  # mean 0.9, rho 1/21
    k = rng.binomial(200, rates)
    fit = fit_beta_binomial(k, np.full(k.size, 200))
    assert fit["mean"] == pytest.approx(0.9, abs=0.01) and fit["rho"] == pytest.approx(1 / 21, rel=0.25)
    assert fit["new_seed_rate_95"][0] < 0.8 < 0.97 < fit["new_seed_rate_95"][1]


def test_binomial_replicates_fit_no_spread():
    k = np.random.default_rng(4).binomial(200, 0.95, size=50)
    assert fit_beta_binomial(k, np.full(k.size, 200))["rho"] < 0.01


def test_a_replicate_that_could_not_run_makes_the_protocol_incomplete():
    summary = summarise([ReplicateOutcome(0, 1000, 190, 200, {"time_limit": 10}),
                         ReplicateOutcome(1, 1001, error="the scripted expert gave up")])
    assert not summary["complete"] and summary["failed_replicates"] == [1]
    assert summary["pooled"]["episodes"] == 200
    assert any("gave up" in line for line in summary_lines(summary))


@pytest.mark.parametrize("argv, message", [
    (["--demo-seeds", "4-1"], "seeds"),
    (["--episodes", "0"], "argument --episodes"),
    (["--shape", "star"], "shape='star' is unknown"),
    (["--demo-seeds", "0,1000"], "equal demo seeds"),
    (["--adaptation-off", "push,blob"], "--adaptation-off 'push,blob'"),
])
def test_benchmark_refuses_bad_options_before_any_work(tmp_path, capsys, argv, message):
    out = tmp_path / "bench"
    assert main(["benchmark", "--out", str(out), *argv]) == 2
    assert message in capsys.readouterr().err and not out.exists()


def test_benchmark_never_writes_into_a_foreign_folder(tmp_path, capsys):
    (tmp_path / "thesis.tex").write_text("mine")
    assert main(["benchmark", "--out", str(tmp_path), "--episodes", "1"]) == 2
    assert "not a `pih benchmark` folder" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["thesis.tex"]


def test_benchmark_refuses_to_continue_a_protocol_with_other_settings(tmp_path, capsys):
    (tmp_path / "protocol.json").write_text(json.dumps({"command": "pih benchmark", "demo_seeds": [7]}))
    assert main(["benchmark", "--out", str(tmp_path), "--episodes", "1"]) == 2
    assert "other settings" in capsys.readouterr().err

