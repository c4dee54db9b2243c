"""Training a skill's models in parallel processes (rflow.fit_processes): same weights, clear failures."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from rflow.errors import RFlowError
from rflow.fit_processes import fit_in_processes
from rflow.skill_io import fit_pose_skill
from tests.skill_fixtures import TINY, synthetic_demos


def _weights(skill) -> dict[str, torch.Tensor]:
    return {f"{name}.{key}": value for name, model in skill.models.items()
            for key, value in model.network.state_dict().items()}


def test_parallel_training_gives_the_sequential_weights_bit_for_bit() -> None:
    demos = synthetic_demos()
    one_by_one = fit_pose_skill(demos.pos, demos.quat, demos.dt, TINY, "separate", progress=False, workers=1)
    parallel = fit_pose_skill(demos.pos, demos.quat, demos.dt, TINY, "separate", progress=False, workers=2)
    a, b = _weights(one_by_one), _weights(parallel)
    assert a.keys() == b.keys() and len(a) > 0
    for key in a:
        assert torch.equal(a[key], b[key]), key
    for name in ("position", "orientation"):
        assert (one_by_one.training[name]["history"]["train_loss"]
                == parallel.training[name]["history"]["train_loss"])
        np.testing.assert_array_equal(one_by_one.models[name].goal, parallel.models[name].goal)


def test_a_model_that_fails_to_train_is_named_in_the_error() -> None:
    demos = synthetic_demos()
    pos = demos.pos.copy()
    pos[0, -1] += 0.05  # one demo ends 5 cm from the others: no shared goal
    with pytest.raises(RFlowError, match=r"^position model: .*goal"):
        fit_in_processes({"position": (pos, "euclidean"), "orientation": (demos.quat, "sphere")},
                         demos.dt, TINY, workers=2, progress=False)


def test_workers_must_be_a_positive_integer() -> None:
    demos = synthetic_demos()
    with pytest.raises(RFlowError, match="workers=0"):
        fit_in_processes({"position": (demos.pos, "euclidean")}, demos.dt, TINY, workers=0)
