"""The statistics of success rates and paired comparisons (numpy and scipy only): fixed-sample intervals and tests
(`fixed_sample`: Wilson, McNemar, Newcombe, Barnard, Wilcoxon), the sequential paired test (`sequential`), the
pairing of two evaluations' records (`pairing`), the comparison of two evaluations (`comparison`) and the regression
check for a user's tests (`regression`).
"""

from pihutil.lazy import lazy_exports

EXPORTS: dict[str, str] = {
    "compare_metric": "envs.statistics.fixed_sample",
    "compare_success": "envs.statistics.fixed_sample",
    "wilson_interval": "envs.statistics.fixed_sample",
    "SequentialPairedTest": "envs.statistics.sequential",
    "pair_records": "envs.statistics.pairing",
    "Comparison": "envs.statistics.comparison",
    "compare_evaluations": "envs.statistics.comparison",
    "load_evaluation": "envs.statistics.comparison",
    "assert_no_regression": "envs.statistics.regression",
}
"""The public names (name -> the module that defines it), imported on first use."""

__all__ = sorted(EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
