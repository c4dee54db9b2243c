"""Headless rendering: the one place that chooses MuJoCo's OpenGL backend and makes its context.

MuJoCo (and dm_control) read ``MUJOCO_GL`` when they are imported and default to GLFW, which needs a display;
on a server, a CI runner or a worker process there is none. `use_headless_rendering` sets ``MUJOCO_GL=egl``
(Mesa's or the GPU driver's EGL, no display) unless the user chose a backend, before MuJoCo is imported: the
`pih` entry point (scripts.cli.main) calls it first, and worker processes inherit the environment.
`gl_context` then makes the offscreen context itself, so a machine without EGL still renders through OSMesa.

Imports nothing heavy: no MuJoCo until a context is made.
"""

from __future__ import annotations

import os
from typing import Any

from envs.errors import EnvError

MAX_FRAME_PX = 4096
"""The largest frame side (pixels) an offscreen buffer is asked for (the GL drivers' usual limit is 4096-16384)."""
DEFAULT_GL_BACKEND = "egl"
"""The headless backend used unless ``MUJOCO_GL`` names another (egl, osmesa or glfw)."""


def use_headless_rendering() -> str:
    """Choose a headless OpenGL backend for MuJoCo unless the user did: ``MUJOCO_GL`` if set, else EGL.

    Call it before ``import mujoco`` (or dm_control) for it to reach them; `gl_context` reads the variable
    whenever it makes a context. Returns the backend now in ``MUJOCO_GL``.
    """
    return os.environ.setdefault("MUJOCO_GL", DEFAULT_GL_BACKEND)


def headless_without_display() -> str | None:
    """Where there is no display (neither ``DISPLAY`` nor ``WAYLAND_DISPLAY``) and the user chose no backend, choose
    a headless one for MuJoCo and dm_control: EGL when its library loads, else OSMesa when its library loads.

    Without it dm_control picks GLFW when it is first imported, and GLFW prints "GLFWError: (65550) ... DISPLAY
    environment variable is missing" on a server. With a display nothing changes (GLFW works there, and a viewer
    may want it). ``envs`` calls it when imported, before any module loads dm_control. Returns ``MUJOCO_GL``.
    """
    if os.environ.get("MUJOCO_GL") or os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return os.environ.get("MUJOCO_GL")
    import ctypes

    for backend, libraries in (("egl", ("libEGL.so.1", "libEGL.so")), ("osmesa", ("libOSMesa.so.8", "libOSMesa.so"))):
        for library in libraries:
            try:
                ctypes.CDLL(library)
            except OSError:
                continue
            return os.environ.setdefault("MUJOCO_GL", backend)
    return None


def gl_context(width: int, height: int) -> tuple[Any, str]:
    """Create and make current a headless GL context of ``width`` x ``height``: the backend ``MUJOCO_GL`` names,
    or, when that is EGL (the default), EGL and then OSMesa.

    Returns:
        (the context, the backend that made it).

    Raises:
        EnvError: no backend could make a context (the message lists each backend's failure).
    """
    requested = os.environ.get("MUJOCO_GL", "").strip().lower() or DEFAULT_GL_BACKEND
    candidates = ["egl", "osmesa"] if requested == "egl" else [requested]
    failures = []
    for backend in candidates:
        try:
            if backend == "egl":
                from mujoco.egl import GLContext
            elif backend == "osmesa":
                if os.environ.get("PYOPENGL_PLATFORM", "osmesa") != "osmesa":
                    os.environ["PYOPENGL_PLATFORM"] = "osmesa"  # an EGL attempt set it before failing
                from mujoco.osmesa import GLContext
            elif backend == "glfw":
                from mujoco.glfw import GLContext
            else:
                failures.append(f"{backend}: unknown backend (use egl, osmesa or glfw)")
                continue
            context = GLContext(width, height)
            context.make_current()
            return context, backend
        except Exception as err:  # noqa: BLE001 -- any backend failure means: try the next one
            failures.append(f"{backend}: {type(err).__name__}: {err}")
    raise EnvError(f"no headless OpenGL context (MUJOCO_GL={requested!r}): " + "; ".join(failures))


__all__ = ["DEFAULT_GL_BACKEND", "gl_context", "headless_without_display", "use_headless_rendering"]
