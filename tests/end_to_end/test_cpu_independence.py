"""Records do not depend on the x86-64 CPU: the same training and evaluation with the CPU features restricted
(numba compiled for a generic x86-64, numpy's AVX2 loops off, MKL and oneDNN held to SSE4) equal the unrestricted
run field for field, and torch runs the pinned kernels (numerics.cpu_dispatch). Trains a tiny skill and runs two
episodes in each of two fresh processes (the generic one's kernels come from numba's cache when `pih warmup
--generic-too` compiled them, as setup.sh does)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from numerics.cpu_dispatch import GENERIC_CPU_ENVIRONMENT, PINNED_ENVIRONMENT, generic_cpu_environment
from tests.helpers import REPO

SCRIPT = """
import json, sys
from pathlib import Path
import numerics  # first, as pih does: numpy then loads with the pinned loops
from tests.helpers.skill_fixtures import tiny_skill
from rflow.skill_io import save_skill
from envs.evaluation.evaluate import EvaluationConfig, evaluate
from envs.task.task import Task
import torch
out = Path(sys.argv[1])
save_skill(out / "model", tiny_skill())
result = evaluate(out / "model", EvaluationConfig(episodes=2, seed=5, task=Task(time_limit_s=1.5)), progress=False)
weights = {k: v.tolist() for k, v in torch.load(out / "model" / "position" / "weights.pt", weights_only=True).items()
           if hasattr(v, "tolist")}
json.dump({"records": [r.to_dict() for r in result.records], "weights": weights,
           "capability": torch.backends.cpu.get_cpu_capability()}, open(out / "out.json", "w"))
"""


def _run(tmp: Path, env: dict[str, str]) -> dict:
    tmp.mkdir()
    subprocess.run([sys.executable, "-c", SCRIPT, str(tmp)], env=env, check=True, capture_output=True, timeout=900,
                   cwd=REPO)
    out = json.loads((tmp / "out.json").read_text())
    for record in out["records"]:
        record.pop("wall_s")
    return out


@pytest.mark.slow
def test_training_and_episodes_equal_with_the_cpu_features_restricted(tmp_path):
    plain = _run(tmp_path / "plain", {k: v for k, v in os.environ.items()
                                      if k not in GENERIC_CPU_ENVIRONMENT and k not in PINNED_ENVIRONMENT})
    restricted = _run(tmp_path / "restricted", generic_cpu_environment())
    assert plain["capability"] == restricted["capability"] == "DEFAULT"  # the pin, not the host's AVX2/AVX512
    assert plain["weights"] == restricted["weights"]
    assert plain["records"] == restricted["records"]
