"""The project's statistics of success rates and of paired skill comparisons (numpy and scipy only).

Success rate. p = k/n with its Wilson score interval (scipy.stats.binomtest(k, n).proportion_ci(method="wilson")):
    (p + z^2/2n -+ z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n),   z the (1 + confidence)/2 normal quantile.

Paired comparison. Two evaluations with the same --seed and --episodes run every episode from the same start
and the same hole-pose error, so episode i of the base skill and episode i of the candidate form a pair
(envs.statistics.pairing.pair_records checks it). With s_b, s_c in {0, 1} the successes of a pair, the pairs fall
into the 2x2 table
    both = #(s_b = s_c = 1),  base_only = #(s_b = 1, s_c = 0),  cand_only = #(s_b = 0, s_c = 1),  neither,
and the rates are p_b = (both + base_only)/n, p_c = (both + cand_only)/n. The comparison (`compare_success`):
  * McNemar's exact test: under H0 p_c = p_b a discordant pair is base-only with probability 1/2, so given
    m = base_only + cand_only, base_only ~ Bin(m, 1/2) (scipy.stats.binomtest): a two-sided p-value and the
    one-sided p-value of "candidate worse" P(Bin(m, 1/2) >= base_only).
  * the difference D = p_c - p_b with Newcombe's (1998) hybrid score interval for paired data, his method 10
    (`paired_difference_interval`).
  * the non-inferiority decision with margin M >= 0 at level alpha: H0 "p_c - p_b >= -M" (not worse by more than
    M) against H1 "p_c - p_b < -M". "regression" when the one-sided (1 - alpha) upper confidence bound of D,
    the upper end of the two-sided (1 - 2 alpha) Newcombe interval, lies below -M; otherwise "no regression"
    (which means "not shown to be worse by more than M", not "shown equal").
  * for reference, Barnard's exact unconditional test of the same two samples taken as independent
    (scipy.stats.barnard_exact), which ignores the pairing and so needs more episodes for the same p-value.

Finer metrics (`compare_metric`). Paired differences d_i = x_c,i - x_b,i of a per-episode figure (depth reached,
time to seat, held force): median, a percentile bootstrap interval of the median (scipy.stats.bootstrap, fixed
seed), counts of better / worse / tied pairs, and Wilcoxon's signed-rank p-values (scipy.stats.wilcoxon, zero
differences dropped).

The sequential test of paired comparisons is envs.statistics.sequential; the pairing of two evaluations' records,
envs.statistics.pairing.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import numpy.typing as npt
from scipy import stats

from envs.errors import EnvError

FloatArray = npt.NDArray[np.float64]

DECISIONS: tuple[str, str] = ("regression", "no regression")
BOOTSTRAP_RESAMPLES: int = 2000
BOOTSTRAP_SEED: int = 0


def check_confidence(confidence: float, name: str = "confidence") -> float:
    """A level strictly between 0 and 1. Raises EnvError naming ``name``."""
    if not (isinstance(confidence, (int, float)) and 0.0 < confidence < 1.0):
        raise EnvError(f"{name}={confidence!r} must lie strictly between 0 and 1")
    return float(confidence)


def check_margin_alpha(margin: float, alpha: float) -> None:
    """Margin in [0, 1) (rate points as a fraction) and alpha in (0, 0.5). Raises EnvError."""
    if not (isinstance(margin, (int, float)) and 0.0 <= margin < 1.0):
        raise EnvError(f"margin={margin!r} must lie in [0, 1) (a rate difference, 0.05 = 5 points)")
    if not (isinstance(alpha, (int, float)) and 0.0 < alpha < 0.5):
        raise EnvError(f"alpha={alpha!r} must lie strictly between 0 and 0.5")


@functools.lru_cache(maxsize=4096)
def wilson_interval(successes: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (equation in the module docstring); (0, 1) for no trials.
    Cached: the paired interval and simulations ask for the same few (k, n) again and again.

    Raises:
        EnvError: trials < 0, successes outside [0, trials], or a confidence outside (0, 1).
    """
    check_confidence(confidence)
    if trials < 0 or not 0 <= successes <= max(trials, 0):
        raise EnvError(f"need 0 <= successes <= trials, got {successes} of {trials}")
    if trials == 0:
        return 0.0, 1.0
    ci = stats.binomtest(int(successes), int(trials)).proportion_ci(confidence_level=confidence, method="wilson")
    return max(0.0, float(ci.low)), min(1.0, float(ci.high))


# ------------------------------------------------------------------------------------------ paired success


@dataclass(frozen=True)
class PairedCounts:
    """The 2x2 table of paired successes (module docstring)."""

    both: int
    base_only: int
    cand_only: int
    neither: int

    @classmethod
    def of(cls, base: Sequence[bool] | npt.ArrayLike, candidate: Sequence[bool] | npt.ArrayLike) -> "PairedCounts":
        """Count the pairs of two equally long success sequences. Raises EnvError on unequal lengths."""
        b = np.asarray(base, dtype=bool)
        c = np.asarray(candidate, dtype=bool)
        if b.shape != c.shape or b.ndim != 1:
            raise EnvError(f"paired successes need two sequences of one length, got {b.shape} and {c.shape}")
        return cls(int(np.sum(b & c)), int(np.sum(b & ~c)), int(np.sum(~b & c)), int(np.sum(~b & ~c)))

    @property
    def pairs(self) -> int:
        """n."""
        return self.both + self.base_only + self.cand_only + self.neither

    @property
    def base_successes(self) -> int:
        """Successes of the base skill."""
        return self.both + self.base_only

    @property
    def cand_successes(self) -> int:
        """Successes of the candidate."""
        return self.both + self.cand_only

    @property
    def difference(self) -> float:
        """p_c - p_b (0 for no pairs)."""
        return (self.cand_only - self.base_only) / max(self.pairs, 1)


def mcnemar_exact(counts: PairedCounts) -> tuple[float, float]:
    """McNemar's exact test of H0 p_c = p_b on the discordant pairs.

    Returns:
        (two-sided p, one-sided p of "candidate worse" = P(Bin(m, 1/2) >= base_only)); (1, 1) without discordant pairs.
    """
    m = counts.base_only + counts.cand_only
    if m == 0:
        return 1.0, 1.0
    return (float(stats.binomtest(counts.base_only, m, 0.5).pvalue),
            float(stats.binomtest(counts.base_only, m, 0.5, alternative="greater").pvalue))


def paired_difference_interval(counts: PairedCounts, confidence: float = 0.95) -> tuple[float, float]:
    """Confidence interval of D = p_c - p_b from paired data: Newcombe's hybrid score method 10.

    With (l_b, u_b), (l_c, u_c) the Wilson intervals of p_b, p_c at ``confidence`` and phi Newcombe's estimate of
    the correlation of the two rates, phi = A' / sqrt((a+b)(c+d)(a+c)(b+d)) with A = a d - b c (a = both,
    b = base_only, c = cand_only, d = neither) corrected for continuity, A' = A - n/2 when A > n/2, 0 when
    0 <= A <= n/2, A when A < 0 (phi = 0 when a margin of the table is empty),
        L = D - sqrt((p_c - l_c)^2 - 2 phi (p_c - l_c)(u_b - p_b) + (u_b - p_b)^2),
        U = D + sqrt((u_c - p_c)^2 - 2 phi (u_c - p_c)(p_b - l_b) + (p_b - l_b)^2).
    Chosen because it is closed-form on the Wilson intervals the project already reports, stays inside [-1, 1],
    is defined for empty cells and all-success samples (where the Wald interval collapses to a point), and
    keeps close to nominal coverage in the comparison of Fagerland, Lydersen and Laake, "Recommended tests and
    confidence intervals for paired binomial proportions", Stat. Med. 33 (2014), which recommends it.
    Reference: Newcombe, "Improved confidence intervals for the difference between binomial proportions based
    on paired data", Stat. Med. 17 (1998) 2635-2650.

    Raises:
        EnvError: no pairs, or a confidence outside (0, 1).
    """
    n = counts.pairs
    if n == 0:
        raise EnvError("a paired difference needs at least one pair")
    p_b, p_c = counts.base_successes / n, counts.cand_successes / n
    l_b, u_b = wilson_interval(counts.base_successes, n, confidence)
    l_c, u_c = wilson_interval(counts.cand_successes, n, confidence)
    a, b, c, d = counts.both, counts.base_only, counts.cand_only, counts.neither
    denominator = (a + b) * (c + d) * (a + c) * (b + d)
    cross = a * d - b * c
    corrected = cross - n / 2.0 if cross > n / 2.0 else min(cross, 0)
    phi = corrected / math.sqrt(denominator) if denominator > 0 else 0.0
    diff = p_c - p_b
    down = math.sqrt(max((p_c - l_c) ** 2 - 2.0 * phi * (p_c - l_c) * (u_b - p_b) + (u_b - p_b) ** 2, 0.0))
    up = math.sqrt(max((u_c - p_c) ** 2 - 2.0 * phi * (u_c - p_c) * (p_b - l_b) + (p_b - l_b) ** 2, 0.0))
    return max(-1.0, diff - down), min(1.0, diff + up)


def unpaired_exact_test(counts: PairedCounts) -> tuple[float, float]:
    """Barnard's exact unconditional test of the two samples as if independent (the pairing ignored).

    Returns:
        (two-sided p of p_c = p_b, one-sided p of "candidate worse"); (1, 1) when no episode or every episode
        of both samples succeeded or failed (nothing to test).
    """
    n = counts.pairs
    k_b, k_c = counts.base_successes, counts.cand_successes
    if n == 0 or k_b + k_c in (0, 2 * n):
        return 1.0, 1.0
    table = [[k_b, k_c], [n - k_b, n - k_c]]  # columns: the two samples; "greater": the base's rate is higher
    return (float(stats.barnard_exact(table).pvalue),
            float(stats.barnard_exact(table, alternative="greater").pvalue))


@dataclass(frozen=True)
class SuccessComparison:
    """The paired success comparison of `compare_success` (module docstring).

    Attributes:
        counts: the 2x2 table.
        margin, alpha: the non-inferiority margin and level.
        base_ci, cand_ci: 95 % Wilson intervals of the two rates.
        difference_ci: Newcombe interval of p_c - p_b at 1 - 2 alpha (its upper end: the one-sided bound).
        mcnemar_p, mcnemar_p_worse: McNemar's exact p-values (two-sided; "candidate worse").
        unpaired_p, unpaired_p_worse: Barnard's exact p-values of the same samples taken as independent.
        decision: "regression" when difference_ci[1] < -margin, else "no regression".
    """

    counts: PairedCounts
    margin: float
    alpha: float
    base_ci: tuple[float, float]
    cand_ci: tuple[float, float]
    difference_ci: tuple[float, float]
    mcnemar_p: float
    mcnemar_p_worse: float
    unpaired_p: float
    unpaired_p_worse: float
    decision: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record."""
        c = self.counts
        return {
            "pairs": c.pairs,
            "base": {"successes": c.base_successes, "rate": c.base_successes / c.pairs, "ci95": list(self.base_ci)},
            "candidate": {"successes": c.cand_successes, "rate": c.cand_successes / c.pairs,
                          "ci95": list(self.cand_ci)},
            "paired_counts": {"both": c.both, "base_only": c.base_only, "cand_only": c.cand_only,
                              "neither": c.neither},
            "difference": {"estimate": c.difference, "ci": list(self.difference_ci),
                           "confidence": 1.0 - 2.0 * self.alpha, "upper_bound_one_sided": self.difference_ci[1],
                           "method": "Newcombe (1998) hybrid score, method 10"},
            "mcnemar_exact": {"p_two_sided": self.mcnemar_p, "p_candidate_worse": self.mcnemar_p_worse},
            "unpaired_barnard_exact": {"p_two_sided": self.unpaired_p, "p_candidate_worse": self.unpaired_p_worse},
            "margin": self.margin,
            "alpha": self.alpha,
            "decision": self.decision,
        }


def compare_success(base: Sequence[bool] | npt.ArrayLike, candidate: Sequence[bool] | npt.ArrayLike,
                    margin: float = 0.0, alpha: float = 0.05) -> SuccessComparison:
    """Paired comparison of two success sequences (pair i: episode i of each) and the non-inferiority decision.

    Tested: H0 p_c - p_b >= -margin against H1 p_c - p_b < -margin at level ``alpha``, by the one-sided upper
    confidence bound of the Newcombe interval (module docstring).

    Raises:
        EnvError: unequal lengths, no pairs, margin outside [0, 1) or alpha outside (0, 0.5).
    """
    check_margin_alpha(margin, alpha)
    counts = PairedCounts.of(base, candidate)
    if counts.pairs == 0:
        raise EnvError("a paired comparison needs at least one pair")
    interval = paired_difference_interval(counts, 1.0 - 2.0 * alpha)
    mcnemar = mcnemar_exact(counts)
    unpaired = unpaired_exact_test(counts)
    return SuccessComparison(
        counts, float(margin), float(alpha), wilson_interval(counts.base_successes, counts.pairs),
        wilson_interval(counts.cand_successes, counts.pairs), interval, mcnemar[0], mcnemar[1], unpaired[0],
        unpaired[1], noninferiority_decision(interval, margin))


def noninferiority_decision(interval: tuple[float, float], margin: float) -> str:
    """"regression" when the upper end of the (1 - 2 alpha) interval of p_c - p_b lies below -margin."""
    return DECISIONS[0] if interval[1] < -margin else DECISIONS[1]


# ------------------------------------------------------------------------------------------ finer metrics


@dataclass(frozen=True)
class MetricComparison:
    """Paired differences d = candidate - base of one per-episode figure (`compare_metric`).

    Attributes:
        pairs: pairs where both values are finite (the others are left out).
        higher_is_better: the figure's direction.
        median_difference, mean_difference: of d (None without pairs).
        median_ci: percentile bootstrap interval of the median of d (None with fewer than 2 pairs).
        better, worse, tied: pairs where the candidate is better, worse, equal.
        wilcoxon_p, wilcoxon_p_worse: signed-rank p-values, two-sided and "candidate worse" (1 when all d = 0).
    """

    pairs: int
    higher_is_better: bool
    median_difference: float | None
    mean_difference: float | None
    median_ci: tuple[float, float] | None
    better: int
    worse: int
    tied: int
    wilcoxon_p: float
    wilcoxon_p_worse: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record."""
        out = dict(self.__dict__)
        out["median_ci"] = None if self.median_ci is None else list(self.median_ci)
        return out


def compare_metric(base: npt.ArrayLike, candidate: npt.ArrayLike, higher_is_better: bool,
                   confidence: float = 0.95) -> MetricComparison:
    """Summary of the paired differences of a per-episode figure (module docstring); NaN marks a missing value.

    Raises:
        EnvError: arrays of different shapes or not 1-D.
    """
    check_confidence(confidence)
    b = np.asarray(base, dtype=np.float64)
    c = np.asarray(candidate, dtype=np.float64)
    if b.shape != c.shape or b.ndim != 1:
        raise EnvError(f"paired values need two 1-D arrays of one length, got {b.shape} and {c.shape}")
    keep = np.isfinite(b) & np.isfinite(c)
    d = c[keep] - b[keep]
    sign = 1.0 if higher_is_better else -1.0
    better, worse = int(np.sum(sign * d > 0)), int(np.sum(sign * d < 0))
    median_ci = None
    if d.size >= 2:
        ci = stats.bootstrap((d,), np.median, method="percentile", n_resamples=BOOTSTRAP_RESAMPLES,
                             confidence_level=confidence, rng=np.random.default_rng(BOOTSTRAP_SEED)).confidence_interval
        median_ci = (float(ci.low), float(ci.high))
    p = p_worse = 1.0
    if np.any(d != 0.0):
        p = float(stats.wilcoxon(d, zero_method="wilcox").pvalue)
        p_worse = float(stats.wilcoxon(d, zero_method="wilcox", alternative="less" if higher_is_better else "greater").pvalue)
    return MetricComparison(int(d.size), higher_is_better, float(np.median(d)) if d.size else None,
                            float(np.mean(d)) if d.size else None, median_ci, better, worse, int(d.size) - better - worse,
                            p, p_worse)


__all__ = [
    "DECISIONS",
    "MetricComparison",
    "PairedCounts",
    "SuccessComparison",
    "check_margin_alpha",
    "compare_metric",
    "compare_success",
    "mcnemar_exact",
    "noninferiority_decision",
    "paired_difference_interval",
    "unpaired_exact_test",
    "wilson_interval",
]
