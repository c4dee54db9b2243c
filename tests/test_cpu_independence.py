"""Records do not depend on the x86-64 CPU: the same training and evaluation with the CPU features restricted
(numba compiled for a generic x86-64, numpy's AVX2 loops off, MKL and oneDNN held to SSE4) equal the unrestricted
run field for field, and torch runs the pinned kernels (numerics.cpu_dispatch)."""

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from numerics.cpu_dispatch import PINNED_ENVIRONMENT

RESTRICTED = {"NUMBA_CPU_NAME": "generic", "NPY_DISABLE_CPU_FEATURES": "X86_V3",
              "MKL_ENABLE_INSTRUCTIONS": "SSE4_2", "ONEDNN_MAX_CPU_ISA": "SSE41"}

SCRIPT = """
import json, sys
from pathlib import Path
sys.path.insert(0, {tests!r})
import numerics  # first, as pih does: numpy then loads with the pinned loops
from skill_fixtures import tiny_skill
from rflow.skill_io import save_skill
from envs.evaluation.evaluate import EvaluationConfig, evaluate
from envs.task.task import Task
import torch
out = Path(sys.argv[1])
save_skill(out / "model", tiny_skill())
result = evaluate(out / "model", EvaluationConfig(episodes=2, seed=5, task=Task(time_limit_s=1.5)), progress=False)
weights = {{k: v.tolist() for k, v in torch.load(out / "model" / "position" / "weights.pt", weights_only=True).items()
           if hasattr(v, "tolist")}}
json.dump({{"records": [r.to_dict() for r in result.records], "weights": weights,
           "capability": torch.backends.cpu.get_cpu_capability()}}, open(out / "out.json", "w"))
"""


def _run(tmp: Path, extra_env: dict[str, str]) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in RESTRICTED and k not in PINNED_ENVIRONMENT}
    env.update(extra_env)
    tmp.mkdir()
    code = SCRIPT.format(tests=str(Path(__file__).parent))
    subprocess.run([sys.executable, "-c", code, str(tmp)], env=env, check=True, capture_output=True, timeout=900)
    out = json.loads((tmp / "out.json").read_text())
    for record in out["records"]:
        record.pop("wall_s")
    return out


@pytest.mark.slow
def test_training_and_episodes_equal_with_the_cpu_features_restricted(tmp_path):
    plain = _run(tmp_path / "plain", {})
    restricted = _run(tmp_path / "restricted", RESTRICTED)
    assert plain["capability"] == restricted["capability"] == "DEFAULT"  # the pin, not the host's AVX2/AVX512
    assert plain["weights"] == restricted["weights"]
    assert plain["records"] == restricted["records"]



def test_numpy_runs_its_pinned_loops_here():
    """This process runs numpy as `pih` pins it: its AVX-512 loops (whose arctan2, arccos, exp... round otherwise than
    the baseline) are off, on any host."""
    from numpy._core._multiarray_umath import __cpu_features__

    assert os.environ["NPY_DISABLE_CPU_FEATURES"] == PINNED_ENVIRONMENT["NPY_DISABLE_CPU_FEATURES"]
    assert not any(__cpu_features__.get(group, False) for group in ("X86_V4", "AVX512_SKX", "AVX512_ICL",
                                                                      "AVX512_SPR"))


def test_the_test_session_pins_numpy_before_a_test_module_imports_it():
    """Most test modules import numpy before any package of the project, so the pin has to come from tests/conftest.py
    for the tests to run the arithmetic the commands run: the check above, in a fresh session, after a module that
    imports numpy first."""
    tests = Path(__file__).parent
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           f"{tests / 'test_success.py'}::test_goal_pose_is_inserted",
                           f"{Path(__file__)}::test_numpy_runs_its_pinned_loops_here"],
                          capture_output=True, text=True, timeout=300, cwd=tests.parent,
                          env={k: v for k, v in os.environ.items() if k not in PINNED_ENVIRONMENT})
    assert done.returncode == 0 and "2 passed" in done.stdout, done.stdout[-3000:]


NUMPY_IMPORT_WATCH = """
import importlib.abc, os, sys
seen = []
class Watch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "numpy" and not seen:
            seen.append(os.environ.get("NPY_DISABLE_CPU_FEATURES"))
        return None
sys.meta_path.insert(0, Watch())
import {package}
import numpy
print(seen[0])
"""


@pytest.mark.parametrize("package", ["envs", "controllers", "envs.gym_env", "numerics"])
def test_importing_a_package_of_the_project_pins_numpy_before_numpy_loads(package):
    """A script that starts with `import envs` (or the Gym module, the controllers, numerics) runs numpy's loops as
    `pih` does: each package calls numerics.cpu_dispatch.pin_cpu_dispatch first, which sets NPY_DISABLE_CPU_FEATURES,
    before anything imports numpy (what the setting was when numpy was first imported is recorded, so the order is
    checked on any host)."""
    done = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", "-c",
                           NUMPY_IMPORT_WATCH.format(package=package)], capture_output=True, text=True, timeout=300,
                          cwd=Path(__file__).parent.parent,
                          env={k: v for k, v in os.environ.items() if k not in PINNED_ENVIRONMENT})
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == PINNED_ENVIRONMENT["NPY_DISABLE_CPU_FEATURES"]


def test_a_users_own_numpy_feature_choice_is_left_as_it_is():
    """NPY_ENABLE_CPU_FEATURES is a choice of numpy's loops too, and numpy refuses to load with both variables set:
    the pin leaves numpy alone then (and still pins torch and MKL)."""
    from numerics.cpu_dispatch import pin_cpu_dispatch

    environ = {"NPY_ENABLE_CPU_FEATURES": "AVX2"}
    pin_cpu_dispatch(environ)
    assert "NPY_DISABLE_CPU_FEATURES" not in environ and environ["ATEN_CPU_CAPABILITY"] == "default"
    done = subprocess.run([sys.executable, "-c", "import envs, numpy"], capture_output=True, text=True, timeout=300,
                          cwd=Path(__file__).parent.parent,
                          env={**{k: v for k, v in os.environ.items() if k not in PINNED_ENVIRONMENT},
                               "NPY_ENABLE_CPU_FEATURES": "AVX2"})
    assert done.returncode == 0, done.stderr[-2000:]


def test_numpy_imported_first_with_loops_the_pin_turns_off_is_warned_about():
    """numpy reads NPY_DISABLE_CPU_FEATURES only when it loads: loops it runs that the setting names are reported
    (a host without AVX-512 runs none, so the features are given here)."""
    from numerics.cpu_dispatch import check_numpy_dispatch

    pinned = {"NPY_DISABLE_CPU_FEATURES": PINNED_ENVIRONMENT["NPY_DISABLE_CPU_FEATURES"]}
    with pytest.warns(RuntimeWarning, match="runs its X86_V4 AVX512_ICL loops"):
        check_numpy_dispatch({"X86_V3": True, "X86_V4": True, "AVX512_ICL": True, "AVX512_SPR": False}, pinned)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_numpy_dispatch({"X86_V3": True, "X86_V4": False, "AVX512_ICL": False}, pinned)  # the pin took
        check_numpy_dispatch({"X86_V4": True}, {"NPY_DISABLE_CPU_FEATURES": ""})  # the user's own choice, as pih's
