"""Test-session defaults: headless rendering through Mesa EGL unless the caller chose a backend."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
