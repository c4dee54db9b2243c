"""envs.media.rendering, the one place that chooses MuJoCo's OpenGL backend."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from envs.media.rendering import DEFAULT_GL_BACKEND, use_headless_rendering
from tests.helpers import REPO



def test_egl_unless_the_user_chose_a_backend(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    assert use_headless_rendering() == DEFAULT_GL_BACKEND == os.environ["MUJOCO_GL"] == "egl"
    monkeypatch.setenv("MUJOCO_GL", "osmesa")
    assert use_headless_rendering() == "osmesa" == os.environ["MUJOCO_GL"]


def test_the_pih_entry_point_chooses_it_before_a_command_imports_mujoco() -> None:
    probe = ("import json, os, sys\nfrom scripts.cli import main\nmain(['render', '--no-such-option'])\n"
             "print(json.dumps({'gl': os.environ.get('MUJOCO_GL'), 'mujoco': 'mujoco' in sys.modules}))")
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    out = subprocess.run([sys.executable, "-c", probe], cwd=REPO, env=env, capture_output=True, text=True, check=True)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == {"gl": "egl", "mujoco": True}
