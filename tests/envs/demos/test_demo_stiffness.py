"""The demo file's optional stiffness: round trip, and one-line errors for NaN, non-SPD or a missed goal."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from envs.demos.file import load_demos, save_demos
from envs.errors import EnvError
from scripts.cli import main
from tests.helpers.stiffness_fixtures import stiffness_demos


def test_round_trip_keeps_the_stiffness(tmp_path):
    demos = stiffness_demos(n=3, m=20)
    loaded = load_demos(save_demos(tmp_path / "d.npz", demos))
    assert np.array_equal(loaded.stiffness, demos.stiffness)
    assert np.array_equal(loaded.goal_stiffness, demos.goal_stiffness)


def test_demos_without_stiffness_still_load(tmp_path):
    demos = replace(stiffness_demos(n=2, m=10), stiffness=None, goal_stiffness=None)
    assert load_demos(save_demos(tmp_path / "d.npz", demos)).stiffness is None


def _broken(kind: str):
    demos = stiffness_demos(n=3, m=20)
    k = demos.stiffness.copy()
    if kind == "nan":
        k[1, 5, 0, 0] = np.nan
    elif kind == "not_pd":
        k[2, 4] = np.diag([500.0, -10.0, 500.0])
    elif kind == "asymmetric":
        k[0, 3, 0, 1] += 1.0
    elif kind == "off_goal":
        k[1, -1] *= 1.01
    elif kind == "shape":
        k = k[:, :-1]
    elif kind == "goal_missing":
        return replace(demos, goal_stiffness=None)
    return replace(demos, stiffness=k)


@pytest.mark.parametrize("kind,words", [("nan", "NaN"), ("not_pd", "positive definite"), ("asymmetric", "symmetric"),
                                        ("off_goal", "goal stiffness"), ("shape", "shape"),
                                        ("goal_missing", "goal_stiffness")])
def test_bad_stiffness_is_refused_with_one_line(tmp_path, kind, words):
    with pytest.raises(EnvError, match=words) as info:
        save_demos(tmp_path / "d.npz", _broken(kind))
    assert "\n" not in str(info.value)
    assert not list(tmp_path.iterdir())  # nothing half-written


@pytest.mark.parametrize("kind,words", [("not_pd", "positive definite"), ("nan", "NaN"),
                                        ("off_goal", "does not end at the goal stiffness")])
def test_pih_train_refuses_a_file_with_bad_stiffness(tmp_path, capsys, kind, words):
    demos = _broken(kind)
    path = tmp_path / "bad.npz"
    np.savez(path, pos=demos.pos, quat=demos.quat, dt=demos.dt, goal_pos=demos.goal_pos, goal_quat=demos.goal_quat,
             shape=np.str_(demos.shape), clearance_m=demos.clearance_m, config_json=np.str_("{}"),
             stiffness=demos.stiffness, goal_stiffness=demos.goal_stiffness)
    assert main(["train", "--demos", str(path), "--out", str(tmp_path / "ck"), "--stiffness", "expert"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pih train: error:") and words in err and "\n" not in err
    assert not (tmp_path / "ck").exists()


def test_loading_a_demo_file_runs_no_compiled_kernel(tmp_path):
    """`pih train` validates its demo file in the process that then forks the training workers, and nothing else
    there needs numba: the validation (shapes, unit quaternions, the goal, SPD stiffness) is numpy, so that process
    does not start numba's compiler (~0.45 s) for it."""
    import subprocess
    import sys

    path = save_demos(tmp_path / "d.npz", stiffness_demos(n=3, m=20))
    code = ("import numba.core.dispatcher as dispatcher\n"
            "def refuse(self, *args, **kwargs):\n"
            "    raise AssertionError(f'numba kernel {self.py_func.__qualname__} ran')\n"
            "dispatcher.Dispatcher._compile_for_args = refuse\n"
            "from envs.demos.file import load_demos\n"
            f"print(load_demos({str(path)!r}).num_demos)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "3"
