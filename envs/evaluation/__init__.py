"""Scoring a skill or a policy over many episodes: the settings (`config`), where episodes start (`starts`), the batch
evaluation of a trained skill (`evaluate`) or of a user's policy (`evaluate_policy`), its result (`result`), sweeps
(`sweep`), the cost of each imperfection of the cell (`sensitivity`), the success-rate protocol over demo seeds
(`benchmark`), replays of recorded episodes (`replay`) and the split of a control period's wall time (`profile`).
"""

from pihutil.lazy import lazy_exports

EXPORTS: dict[str, str] = {
    "EvaluationConfig": "envs.evaluation.config",
    "EvaluationResult": "envs.evaluation.result",
    "run_sensitivity": "envs.evaluation.sensitivity",
    "ProtocolConfig": "envs.evaluation.benchmark",
    "replay_evaluation": "envs.evaluation.replay",
}
"""The public names (name -> the module that defines it), imported on first use. The functions named as their
modules (`evaluate.evaluate`, `evaluate_policy.evaluate_policy`, `sweep.sweep`) are re-exported by `envs`."""

__all__ = sorted(EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
