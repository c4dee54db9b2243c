"""A sequential paired comparison of two skills that may stop after any pair: betting e-processes.

`SequentialPairedTest` (one metric), `SequentialComparison` (several). Pairs are fed one at a time and the test may
stop after any of them without losing its error guarantee. For a paired difference d_t in [-1, 1] (success:
d = s_c - s_b in {-1, 0, 1}; a finer metric scaled to [0, 1]: d = x_c - x_b) and margin M in [0, 1) two
test supermartingales are kept,
    regression:     H0 E[d_t | past] >= -M,   K_t = prod_{i<=t} (1 + l_i (-M - d_i)),
    no regression:  H0 E[d_t | past] <= -M,   K_t = prod_{i<=t} (1 + l_i (d_i + M)),
with bets l_i in [0, c / B] chosen from the pairs before i (B = 1 + M resp. 1 - M bounds the loss of a pair, so
every factor is >= 1 - c > 0; c = 1/2). Under its H0 each factor has conditional mean <= 1, so K is a
nonnegative supermartingale with K_0 = 1 and Ville's inequality P(sup_t K_t >= 1/alpha) <= alpha bounds the
error of rejecting at the first t with K_t >= 1/alpha, whenever one looks and stops. With M = 0 the success
bet only moves on discordant pairs, where it is a bet on "base-only" with P(base-only | discordant) <= 1/2
under H0, i.e. a sequential McNemar test. The bet is the truncated approximate GRAPA plug-in of Waudby-Smith
and Ramdas, "Estimating means of bounded random variables by betting", JRSS B 86(1), 2024 (arXiv 2010.09686):
    l_t = clip( S_{t-1} / (1 + Q_{t-1}), 0, c / B ),   S = sum of the past y_i,  Q = sum of the past y_i^2,
the growth-rate optimal fraction E[y]/E[y^2] of the past with one pseudo-observation y^2 = 1 (`betting_log_wealth`).
Several metrics decide together: "regression" when any metric's regression e-process reaches k/alpha (Bonferroni
over the k metrics), "no regression" when every metric's no-regression e-process reaches 1/alpha (an
intersection-union test, which needs no correction); each decision errs with probability <= alpha.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.statistics.fixed_sample import DECISIONS, check_margin_alpha

FloatArray = npt.NDArray[np.float64]

BET_CAP: float = 0.5
"""c of the sequential test: a bet risks at most this fraction of the wealth on one pair."""


def betting_log_wealth(y: npt.ArrayLike, loss_bound: float, cap: float = BET_CAP) -> FloatArray:
    """log K_t of the betting e-process for H0 E[y_t | past] <= 0 with y_t >= -loss_bound, t along the last axis.

    K_t = prod_{i<=t} (1 + l_i y_i) with the predictable truncated aGRAPA bet
    l_i = clip(S_{i-1} / (1 + Q_{i-1}), 0, cap / loss_bound) (module docstring). Vectorised over leading axes
    (independent sequences).

    Raises:
        EnvError: loss_bound <= 0, cap outside (0, 1), or a y below -loss_bound.
    """
    if not loss_bound > 0.0:
        raise EnvError(f"loss_bound={loss_bound!r} must be > 0")
    if not 0.0 < cap < 1.0:
        raise EnvError(f"cap={cap!r} must lie in (0, 1)")
    y = np.asarray(y, dtype=np.float64)
    if np.any(~np.isfinite(y)) or np.any(y < -loss_bound - 1e-12):
        raise EnvError(f"bets need finite outcomes >= {-loss_bound:g}")
    zero = np.zeros(y.shape[:-1] + (1,))
    past_sum = np.concatenate([zero, np.cumsum(y, axis=-1)[..., :-1]], axis=-1)
    past_squares = np.concatenate([zero, np.cumsum(y * y, axis=-1)[..., :-1]], axis=-1)
    bet = np.clip(past_sum / (1.0 + past_squares), 0.0, cap / loss_bound)
    return np.cumsum(np.log1p(bet * y), axis=-1)


@dataclass
class SequentialPairedTest:
    """The two e-processes of one paired metric with differences d in [-1, 1] (module docstring).

    Attributes:
        margin: M in [0, 1).
        differences: the d fed so far, in order.
    """

    margin: float = 0.0
    differences: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not (isinstance(self.margin, (int, float)) and 0.0 <= self.margin < 1.0):
            raise EnvError(f"margin={self.margin!r} must lie in [0, 1)")

    def update(self, difference: float) -> None:
        """Feed the next pair's d = x_c - x_b. Raises EnvError outside [-1, 1] or NaN."""
        if not (isinstance(difference, (int, float, np.floating, np.integer)) and -1.0 <= float(difference) <= 1.0):
            raise EnvError(f"a paired difference must lie in [-1, 1], got {difference!r}")
        self.differences.append(float(difference))

    def _e_value(self, y: FloatArray, loss_bound: float) -> float:
        return float(np.exp(betting_log_wealth(y, loss_bound)[-1])) if y.size else 1.0

    @property
    def e_regression(self) -> float:
        """K_t of H0 "not worse than -margin" (large: evidence of a regression)."""
        return self._e_value(-self.margin - np.asarray(self.differences), 1.0 + self.margin)

    @property
    def e_no_regression(self) -> float:
        """K_t of H0 "worse than -margin" (large: evidence of no regression)."""
        return self._e_value(np.asarray(self.differences) + self.margin, 1.0 - self.margin)


@dataclass
class SequentialComparison:
    """Several paired metrics tested together pair by pair; stops at the first decision (module docstring).

    Attributes:
        margins: metric name -> margin M (the metrics fed to ``update``).
        alpha: error bound of each decision.
        decision: None until decided, then "regression" or "no regression" (kept from then on).
        decided_at: number of pairs at the decision (None before).
    """

    margins: Mapping[str, float]
    alpha: float = 0.05
    decision: str | None = None
    decided_at: int | None = None
    tests: dict[str, SequentialPairedTest] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.margins:
            raise EnvError("a sequential comparison needs at least one metric")
        for name, margin in self.margins.items():
            check_margin_alpha(margin, self.alpha)
            self.tests[name] = SequentialPairedTest(float(margin))

    @property
    def pairs(self) -> int:
        """Pairs fed so far."""
        return len(next(iter(self.tests.values())).differences)

    @property
    def regression_threshold(self) -> float:
        """k / alpha (Bonferroni over the k metrics)."""
        return len(self.tests) / self.alpha

    def update(self, differences: Mapping[str, float]) -> str | None:
        """Feed one pair (a difference per metric) unless already decided; returns the decision so far.

        Raises:
            EnvError: the metrics differ from ``margins`` or a difference lies outside [-1, 1].
        """
        if set(differences) != set(self.tests):
            raise EnvError(f"a pair needs the metrics {sorted(self.tests)}, got {sorted(differences)}")
        if self.decision is not None:
            return self.decision
        for name, test in self.tests.items():
            test.update(differences[name])
        if any(t.e_regression >= self.regression_threshold for t in self.tests.values()):
            self.decision = DECISIONS[0]
        elif all(t.e_no_regression >= 1.0 / self.alpha for t in self.tests.values()):
            self.decision = DECISIONS[1]
        if self.decision is not None:
            self.decided_at = self.pairs
        return self.decision

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record: decision, pairs, thresholds and each metric's e-values."""
        return {
            "decision": self.decision,
            "decided_at_pair": self.decided_at,
            "pairs": self.pairs,
            "alpha": self.alpha,
            "regression_threshold": self.regression_threshold,
            "no_regression_threshold": 1.0 / self.alpha,
            "metrics": {name: {"margin": t.margin, "e_regression": t.e_regression,
                               "e_no_regression": t.e_no_regression} for name, t in self.tests.items()},
            "method": "betting e-processes, truncated aGRAPA bets (Waudby-Smith & Ramdas 2024), Ville's inequality",
        }
