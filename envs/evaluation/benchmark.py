"""The success-rate protocol: a pipeline's success rate as a distribution over demo seeds.

One evaluation scores one trained skill, and a skill is one draw of the pipeline that made it: the same task and
hyperparameters give 85 % with one set of demos and 98 % with another. The protocol therefore repeats the whole
pipeline per demo seed s (a replicate) and reports what varies between replicates:

    replicate s:  demos (starts drawn with seed s)  ->  training (seed s)  ->  evaluation of E episodes
                  (starts and hole-pose errors drawn with seed s + start_seed_offset, never equal to a demo seed)

A user's policy (``ProtocolConfig.policy``, `pih benchmark --policy`) runs the same protocol with its own learner in
place of the training: replicate s records the demos as above and calls the policy's factory (in each supervised
worker of the evaluation) with two more options, ``demo_seed`` (s, as a string like every option) and ``demo_file``
(the path of the replicate's demos.npz), so a learner trains per seed inside its factory (`replicate_policy`).

Randomised per replicate: the demo starts, the training seed (initial weights, batches, prior samples), the
evaluation starts and the per-episode perturbations (hole-pose error, grasp offset). Fixed: the task, the number of
demos, the hyperparameters, the number of episodes. Everything is deterministic from the seeds.

Statistics (k_i successes of n_i scored episodes for replicate i = 1..m):
    pooled rate        p = sum k_i / sum n_i with its Wilson interval (treats all episodes as independent: the
                       interval for THESE m skills, too narrow for the pipeline when replicates differ);
    between-seed       the replicate rates r_i = k_i / n_i: mean r_bar, standard deviation s, and the t interval
                       r_bar -+ t_{0.975, m-1} s / sqrt(m) over replicates (clipped to [0, 1]), widened to contain the
                       pooled Wilson interval (replicates that happen to agree, e.g. all at 100 %, give s = 0, yet
                       the binomial noise of their episodes remains): the interval for the pipeline's expected rate,
                       treating the demo seeds as random draws;
    beta-binomial      k_i ~ BetaBinomial(n_i, a, b) fitted by maximum likelihood (scipy.stats.betabinom): the
                       replicates' spread as a Beta(a, b) over the rate of a new replicate, its mean a / (a + b),
                       the intra-seed correlation rho = 1 / (a + b + 1) and the 2.5-97.5 % range of a new seed's
                       rate (what one more `pih demos && pih train && pih evaluate` would likely give; a plug-in range that
                       ignores the fit's own uncertainty, too narrow with few seeds).

Each replicate lives in its own folder (``seed-<s>/``: demos.npz, model/, eval.json and its journal); a stage whose
output is there is not run again, and an interrupted evaluation resumes from its journal, so the protocol can be
stopped and continued at any point with the same result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from envs.errors import EnvError
from envs.evaluation.config import EvaluationConfig
from envs.evaluation.result import failure_kinds
from envs.statistics.fixed_sample import wilson_interval
from envs.task.task import Task
from pihutil.bounds import REPLICATES, SEED

REPLICATE_PREFIX = "seed-"
PROTOCOL_FILE = "protocol.json"
RESULT_FILE = "benchmark.json"


@dataclass(frozen=True)
class ProtocolConfig:
    """What the protocol runs.

    Attributes:
        demo_seeds: one replicate per seed (demo starts and training seed).
        start_seed_offset: replicate s evaluates with start seed s + offset; must keep every start seed apart from
            every demo seed.
        num_demos: demonstrations per replicate.
        epochs: training epochs (None: `pih train`'s default).
        evaluation: the evaluation of every replicate (its ``seed`` is replaced per replicate); its task is the
            protocol's: the demos are recorded in its scene (its shape; None: square).
        demo_noise: record the demos as a real cell would (envs.demos.noise.DemoNoise.parse spec, seeded with the demo
            seed; None: the expert's clean demos). The demos then end apart, and the evaluation must place the hole
            at their mean goal (``evaluation.hole_at_goal``).
        policy: a user's policy (envs.evaluation.evaluate_policy.PolicySpec) evaluated in place of the trained skill,
            its factory given each replicate's demo seed and demo file (module docstring); None: the skill.
    """

    demo_seeds: tuple[int, ...] = (0, 1, 2, 3, 4)
    start_seed_offset: int = 1000
    num_demos: int = 7
    epochs: int | None = None
    evaluation: EvaluationConfig = field(default_factory=lambda: EvaluationConfig(episodes=200))
    demo_noise: str | None = None
    policy: Any = None

    def __post_init__(self) -> None:
        seeds = self.demo_seeds
        if not seeds or any(not isinstance(s, int) or s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
            raise EnvError(f"demo seeds {list(seeds)} must be distinct integers >= 0 (at least one)")
        if not isinstance(self.start_seed_offset, int) or self.start_seed_offset < 1:
            raise EnvError(f"start seed offset {self.start_seed_offset!r} must be an integer >= 1")
        if max(seeds) + self.start_seed_offset > 2**32 - 1:
            raise EnvError(f"start seeds up to {max(seeds) + self.start_seed_offset} (demo seed + offset "
                           f"{self.start_seed_offset}) exceed the seed range 0..2**32-1")
        clash = sorted(set(self.start_seeds()) & set(seeds))
        if clash:
            raise EnvError(f"start seeds {clash} equal demo seeds: choose a larger start seed offset")
        if not isinstance(self.num_demos, int) or self.num_demos < 1:
            raise EnvError(f"num_demos={self.num_demos!r} must be an integer >= 1")
        if self.epochs is not None and (not isinstance(self.epochs, int) or self.epochs < 1):
            raise EnvError(f"epochs={self.epochs!r} must be an integer >= 1")
        if self.policy is not None:
            reserved = sorted(set(REPLICATE_OPTIONS) & {k for k, _ in self.policy.options})
            if reserved:
                raise EnvError(f"--policy-option {reserved[0]}: the protocol gives the factory this option itself "
                               f"(one of {', '.join(REPLICATE_OPTIONS)})")
            if self.epochs is not None:
                raise EnvError("epochs: the protocol trains no skill for a --policy (its factory learns)")
        if self.demo_noise is not None:
            from envs.demos.noise import DemoNoise

            DemoNoise.parse(self.demo_noise)
            if not self.evaluation.hole_at_goal:
                raise EnvError("demos with noise end apart: their evaluation places the hole at their mean goal "
                               "(hole_at_goal)")

    @property
    def task(self) -> Task:
        """The task of every replicate, its shape set (square unless the task says otherwise)."""
        task = self.evaluation.task
        return task if task.shape is not None else replace(task, shape="square")

    def start_seeds(self) -> list[int]:
        """The evaluation start seed of each replicate."""
        return [s + self.start_seed_offset for s in self.demo_seeds]


REPLICATE_OPTIONS: tuple[str, ...] = ("demo_seed", "demo_file")
"""The options the protocol adds to a --policy's factory call in each replicate (module docstring)."""


def replicate_policy(policy: Any, demo_seed: int, demo_file: str) -> Any:
    """The replicate's policy spec: ``policy`` with the options ``demo_seed`` and ``demo_file`` (REPLICATE_OPTIONS)."""
    from dataclasses import replace as replaced

    return replaced(policy, options=(*policy.options, ("demo_seed", str(demo_seed)), ("demo_file", str(demo_file))))


def parse_seeds(spec: str) -> tuple[int, ...]:
    """Seeds from "0-4", "0,2,7" or "0-2,10" (ranges inclusive), each a seed (pihutil.bounds.SEED), at most
    REPLICATES.high of them (counted before the list is built, so "0-99999999999" costs no memory).

    Raises:
        EnvError: malformed list, a seed outside the seed range, an empty range or too many seeds.
    """
    ranges: list[tuple[int, int]] = []
    for part in spec.split(","):
        part = part.strip()
        try:
            low, high = (int(x) for x in part.split("-", 1)) if "-" in part[1:] else (int(part), int(part))
        except ValueError:
            raise EnvError(f"seeds {spec!r}: expected integers and ranges like 0-4,7") from None
        if high < low:
            raise EnvError(f"seeds {spec!r}: the range {part} is empty")
        if not (SEED.contains(low) and SEED.contains(high)):
            raise EnvError(f"seeds {spec!r}: every seed must be {SEED.text()}")
        ranges.append((low, high))
    total = sum(high - low + 1 for low, high in ranges)
    if total > REPLICATES.high:
        raise EnvError(f"seeds {spec!r}: {total:,} replicates, at most {REPLICATES.high:,}")
    return tuple(seed for low, high in ranges for seed in range(low, high + 1))


# --------------------------------------------------------------------------------------------- statistics


@dataclass(frozen=True)
class ReplicateOutcome:
    """One replicate's result: successes of its scored episodes, or why the replicate produced none."""

    demo_seed: int
    start_seed: int
    successes: int = 0
    episodes: int = 0
    failures_by_kind: dict[str, int] = field(default_factory=dict)
    error: str | None = None

    @property
    def rate(self) -> float | None:
        """Successes / episodes (None without episodes)."""
        return self.successes / self.episodes if self.episodes else None


def between_seed_interval(rates: Sequence[float], confidence: float = 0.95) -> tuple[float, float]:
    """t interval of the mean replicate rate, r_bar -+ t_{(1+c)/2, m-1} s / sqrt(m), clipped to [0, 1]
    ((0, 1) for a single replicate: one seed says nothing about the spread).

    Raises:
        EnvError: no rate.
    """
    from scipy import stats

    r = np.asarray(rates, dtype=np.float64)
    if r.size == 0:
        raise EnvError("between-seed interval of no replicate")
    if r.size == 1:
        return 0.0, 1.0
    half = float(stats.t.ppf(0.5 + confidence / 2.0, r.size - 1) * r.std(ddof=1) / math.sqrt(r.size))
    return max(0.0, float(r.mean()) - half), min(1.0, float(r.mean()) + half)


def fit_beta_binomial(successes: Sequence[int], trials: Sequence[int]) -> dict[str, float]:
    """Maximum-likelihood Beta(a, b) of the replicate rates under k_i ~ BetaBinomial(n_i, a, b).

    The likelihood is maximised over (log a, log b) with a + b <= 1e6 (beyond it the replicates are binomial with
    one rate, rho ~ 0). Returns the mean a / (a + b), rho = 1 / (a + b + 1), and the 2.5 % and 97.5 % quantiles of
    Beta(a, b): the range of a new replicate's rate.

    Raises:
        EnvError: mismatched or empty counts.
    """
    from scipy import optimize, stats

    k = np.asarray(successes, dtype=np.int64)
    n = np.asarray(trials, dtype=np.int64)
    if k.shape != n.shape or k.size == 0 or np.any(n < 1) or np.any((k < 0) | (k > n)):
        raise EnvError(f"beta-binomial fit needs 0 <= successes <= trials >= 1, got {k.tolist()} of {n.tolist()}")
    pooled = (k.sum() + 0.5) / (n.sum() + 1.0)
    log_cap = math.log(1e6)

    def negative_log_likelihood(theta: np.ndarray) -> float:
        a, b = np.exp(np.clip(theta, -10.0, log_cap))
        return -float(stats.betabinom.logpmf(k, n, a, b).sum())

    best = None
    for total in (2.0, 20.0, 200.0, 2000.0):  # a few starts: the likelihood is flat along a + b
        start = np.log([pooled * total, (1.0 - pooled) * total])
        res = optimize.minimize(negative_log_likelihood, start, method="Nelder-Mead",
                                options={"xatol": 1e-6, "fatol": 1e-9, "maxiter": 4000})
        if best is None or res.fun < best.fun:
            best = res
    a, b = (float(x) for x in np.exp(np.clip(best.x, -10.0, log_cap)))
    low, high = stats.beta.ppf([0.025, 0.975], a, b)
    return {"a": a, "b": b, "mean": a / (a + b), "rho": 1.0 / (a + b + 1.0),
            "new_seed_rate_95": [float(low), float(high)]}


def summarise(outcomes: Sequence[ReplicateOutcome]) -> dict[str, Any]:
    """The protocol's figures (module docstring) over the replicates that produced episodes; replicates that failed
    before evaluating (e.g. the expert gave up) are listed apart and make the summary incomplete."""
    scored = [o for o in outcomes if o.episodes > 0]
    broken = [o for o in outcomes if o.episodes == 0]
    out: dict[str, Any] = {
        "replicates": [{"demo_seed": o.demo_seed, "start_seed": o.start_seed, "successes": o.successes,
                        "episodes": o.episodes, "rate": o.rate,
                        "rate_ci95": list(wilson_interval(o.successes, o.episodes)) if o.episodes else None,
                        "failures_by_kind": o.failures_by_kind, "error": o.error} for o in outcomes],
        "complete": not broken,
        "failed_replicates": [o.demo_seed for o in broken],
    }
    if not scored:
        return out
    k = sum(o.successes for o in scored)
    n = sum(o.episodes for o in scored)
    rates = [o.rate for o in scored]
    out["pooled"] = {"successes": k, "episodes": n, "rate": k / n, "rate_ci95": list(wilson_interval(k, n))}
    t_low, t_high = between_seed_interval(rates)
    w_low, w_high = out["pooled"]["rate_ci95"]
    out["between_seeds"] = {
        "replicates": len(scored), "mean_rate": float(np.mean(rates)),
        "std_rate": float(np.std(rates, ddof=1)) if len(rates) > 1 else 0.0,
        "min_rate": float(min(rates)), "max_rate": float(max(rates)),
        "mean_rate_ci95": [min(t_low, w_low), max(t_high, w_high)],
    }
    if len(scored) > 1:
        out["beta_binomial"] = fit_beta_binomial([o.successes for o in scored], [o.episodes for o in scored])
    out["failures_by_kind"] = {}
    for o in scored:
        for kind, count in o.failures_by_kind.items():
            out["failures_by_kind"][kind] = out["failures_by_kind"].get(kind, 0) + count
    return out


def outcome_from_records(demo_seed: int, start_seed: int, records: Sequence[Any]) -> ReplicateOutcome:
    """A replicate's outcome from its episode records (EpisodeRecord)."""
    return ReplicateOutcome(demo_seed, start_seed, sum(bool(r.success) for r in records), len(records),
                            failure_kinds(records))


def summary_lines(summary: dict[str, Any]) -> list[str]:
    """The summary as printable lines."""
    lines = []
    for rep in summary["replicates"]:
        if rep["episodes"]:
            low, high = rep["rate_ci95"]
            kinds = ", ".join(f"{k} {v}" for k, v in rep["failures_by_kind"].items()) or "no failure"
            lines.append(f"demo seed {rep['demo_seed']:>3} (starts {rep['start_seed']}): {rep['successes']}/"
                         f"{rep['episodes']} = {100 * rep['rate']:.1f} % [{100 * low:.1f}, {100 * high:.1f}]  ({kinds})")
        else:
            lines.append(f"demo seed {rep['demo_seed']:>3}: no episodes -- {rep['error']}")
    if "pooled" in summary:
        p, b = summary["pooled"], summary["between_seeds"]
        lines.append(f"pooled: {p['successes']}/{p['episodes']} = {100 * p['rate']:.1f} % "
                     f"[{100 * p['rate_ci95'][0]:.1f}, {100 * p['rate_ci95'][1]:.1f}] (Wilson, episodes independent)")
        lines.append(f"between demo seeds: mean {100 * b['mean_rate']:.1f} % [{100 * b['mean_rate_ci95'][0]:.1f}, "
                     f"{100 * b['mean_rate_ci95'][1]:.1f}] (t over {b['replicates']} seeds), per seed "
                     f"{100 * b['min_rate']:.1f}-{100 * b['max_rate']:.1f} %, sd {100 * b['std_rate']:.1f} points")
    if "beta_binomial" in summary:
        bb = summary["beta_binomial"]
        lines.append(f"beta-binomial: mean {100 * bb['mean']:.1f} %, intra-seed correlation {bb['rho']:.3f}, a new "
                     f"seed's rate likely in [{100 * bb['new_seed_rate_95'][0]:.1f}, "
                     f"{100 * bb['new_seed_rate_95'][1]:.1f}] %")
    return lines


__all__ = [
    "ProtocolConfig",
    "ReplicateOutcome",
    "between_seed_interval",
    "fit_beta_binomial",
    "outcome_from_records",
    "parse_seeds",
    "summarise",
    "summary_lines",
]
