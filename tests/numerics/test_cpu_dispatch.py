"""numerics.cpu_dispatch: every package of the project, `pih` and the test session pin numpy's, torch's and MKL's
CPU-dependent code paths before numpy loads, a user's own choice of numpy's loops is left alone, and a numpy loaded
too early is warned about. That the records then do not depend on the CPU: tests/end_to_end/test_cpu_independence.py.
"""

import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from numerics.cpu_dispatch import PINNED_ENVIRONMENT
from tests.helpers import REPO


def test_numpy_runs_its_pinned_loops_here():
    """This process runs numpy as `pih` pins it: its AVX-512 loops (whose arctan2, arccos, exp... round otherwise than
    the baseline) are off, on any host."""
    from numpy._core._multiarray_umath import __cpu_features__

    assert os.environ["NPY_DISABLE_CPU_FEATURES"] == PINNED_ENVIRONMENT["NPY_DISABLE_CPU_FEATURES"]
    assert not any(__cpu_features__.get(group, False) for group in ("X86_V4", "AVX512_SKX", "AVX512_ICL",
                                                                      "AVX512_SPR"))


@pytest.mark.slow
def test_the_test_session_pins_numpy_before_a_test_module_imports_it():
    """Most test modules import numpy before any package of the project, so the pin has to come from tests/conftest.py
    for the tests to run the arithmetic the commands run: the check above, in a fresh session, after a module that
    imports numpy first."""
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           f"{REPO / 'tests' / 'envs' / 'task' / 'test_success.py'}::test_goal_pose_is_inserted",
                           f"{Path(__file__)}::test_numpy_runs_its_pinned_loops_here"],
                          capture_output=True, text=True, timeout=300, cwd=REPO,
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
                          cwd=REPO,
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
                          cwd=REPO,
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
