"""The Gymnasium environment is quiet on a machine without a display: importing it and making an environment print
nothing on stderr (no GLFWError 65550 from dm_control choosing GLFW), and an environment that rendered and was dropped
without close() prints nothing at the interpreter's exit (no EGLError traceback from a GL context's __del__)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]


def _run_without_display(code: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL",
                                                            "PYOPENGL_PLATFORM")}
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)


def test_importing_and_making_the_environment_prints_nothing() -> None:
    done = _run_without_display("import envs.gym_env, gymnasium\n"
                                "env = gymnasium.make(envs.gym_env.ENV_ID, time_limit_s=0.1)\n"
                                "env.reset(seed=0)\n"
                                "env.close()\n")
    assert done.returncode == 0 and done.stderr == ""


def test_an_environment_dropped_without_close_prints_nothing_at_exit() -> None:
    done = _run_without_display("import envs.gym_env, gymnasium, sys\n"
                                "env = gymnasium.make(envs.gym_env.ENV_ID, render_mode='rgb_array', width=64, "
                                "height=48)\n"
                                "env.reset(seed=0)\n"
                                "try:\n"
                                "    frame = env.render()\n"
                                "except Exception as err:\n"
                                "    print('no GL:', err); sys.exit(0)\n"
                                "print(frame.shape)\n")  # no close(): the interpreter's exit frees the context
    if done.stdout.startswith("no GL:"):
        pytest.skip(done.stdout.strip())
    assert done.returncode == 0 and done.stdout.strip() == "(48, 64, 3)"
    assert done.stderr == ""
