"""Headless offscreen rendering of a MuJoCo scene to MP4 (H.264 through imageio-ffmpeg).

The OpenGL backend is chosen by envs.media.rendering (the one place): ``MUJOCO_GL`` if set (egl, osmesa or glfw),
otherwise EGL with a fall-back to OSMesa. Frames are rendered at ``fps`` frames per second of
SIMULATED time (not every physics step). The commanded peg_tip path is drawn as a polyline (line
geoms, a few pixels wide: capsules cost far more with a software renderer) and the goal as an RGB
frame (x red, y green, z blue), both as user geoms of the scene. From the "cutaway" camera the sorter is drawn
translucent (CUTAWAY_ALPHA), so the peg shows inside the hole; a frame may carry a text overlay (MuJoCo's own font,
top left: the episode, its outcome, the time and the wrist force, `episode_overlay`).
The MP4 is written to a temporary file beside the target (envs.io.owned_output.AtomicOutput) and renamed only when
ffmpeg wrote a whole file; a full disk or a dead ffmpeg is an OSError, never a truncated MP4.
"""

from __future__ import annotations

import atexit
import errno
import os
import struct
import time
import weakref
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Callable, Sequence

import numpy as np
import numpy.typing as npt

from envs.media.rendering import MAX_FRAME_PX, gl_context, use_headless_rendering

use_headless_rendering()  # for a library user who imports mujoco after us; we make our own context

import imageio.v2 as imageio  # noqa: E402
import mujoco  # noqa: E402

from envs.errors import EnvError  # noqa: E402
from envs.io.owned_output import AtomicOutput  # noqa: E402
from envs.poses import Pose, rotate  # noqa: E402

FloatArray = npt.NDArray[np.float64]

#: Colours (rgba) of the overlays.
PATH_RGBA = np.array([1.0, 0.55, 0.0, 0.9], dtype=np.float32)
GOAL_AXES_RGBA = (
    np.array([0.9, 0.1, 0.1, 1.0], dtype=np.float32),
    np.array([0.1, 0.8, 0.1, 1.0], dtype=np.float32),
    np.array([0.1, 0.2, 0.9, 1.0], dtype=np.float32),
)


CUTAWAY_CAMERA = "cutaway"
"""The camera from which the sorter is drawn translucent (envs.cell.scene.CAMERAS)."""
CUTAWAY_ALPHA: float = 0.18
"""The sorter's opacity from the cutaway camera."""
SORTER_BODY = "sorter/"
"""The sorter's body in the scene (its geoms are what the cutaway makes translucent)."""


def episode_overlay(label: str, outcome: str | None, time_s: float, wrist_force_n: float) -> str:
    """The text over a frame: "episode 3: success" (the label and the outcome) on one line, "t 1.23 s   |F| 4.5 N"
    (the episode's time and the wrist force) below."""
    head = label + (f": {outcome}" if outcome else "")
    return f"{head}\nt {time_s:5.2f} s   |F| {wrist_force_n:5.1f} N"


@dataclass(frozen=True)
class VideoConfig:
    """Video settings.

    Attributes:
        width, height: frame size in pixels (multiples of 8, the H.264 macro-block size used).
        fps: frames per second of simulated time, also the playback rate.
        camera: a named camera of the scene (e.g. front, side, top, wrist).
        quality: imageio-ffmpeg quality 0..10 (10 best); 7 is ~2 Mbit/s at 640x480.
        draw_path: draw the commanded peg_tip path.
        path_width_px: width of the path lines in pixels.
        max_path_segments: the path is subsampled to at most this many line segments.
        goal_axis_length_m: length of the goal frame's axes (0 hides the frame).
        shadows: render shadows (costly with a software renderer).
        multisamples: MSAA samples per pixel (MuJoCo's ``vis.quality.offsamples``); 0, the default, renders
            much faster with Mesa's software renderer (README: `pih bench`) at the cost of jagged edges; 4 is
            MuJoCo's default.
    """

    width: int = 640
    height: int = 480
    fps: int = 30
    camera: str = "front"
    quality: int = 7
    draw_path: bool = True
    path_width_px: float = 3.0
    max_path_segments: int = 300
    goal_axis_length_m: float = 0.04
    shadows: bool = False
    multisamples: int = 0

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if not isinstance(value, int) or not 16 <= value <= MAX_FRAME_PX or value % 8:
                raise EnvError(f"VideoConfig: {name} must be a multiple of 8 in [16, {MAX_FRAME_PX}] pixels, got "
                               f"{value!r}")
        if not isinstance(self.fps, int) or not 1 <= self.fps <= 240:
            raise EnvError(f"VideoConfig: fps must be an integer in [1, 240], got {self.fps!r}")
        if not 0 <= self.quality <= 10:
            raise EnvError(f"VideoConfig: quality must be in [0, 10], got {self.quality}")
        if self.max_path_segments < 1:
            raise EnvError(f"VideoConfig: max_path_segments must be >= 1, got {self.max_path_segments}")
        if not isinstance(self.multisamples, int) or not 0 <= self.multisamples <= 16:
            raise EnvError(f"VideoConfig: multisamples must be an integer in [0, 16], got {self.multisamples!r}")


class _CloseAtExit:
    """Closes a renderer that is still open when the interpreter exits, before the GL library's own exit handler
    (EGL's ``eglTerminate``, registered when its first context was made, so it runs after this one) tears the display
    down: a context freed after that prints an EGLError traceback from its ``__del__``."""

    def __init__(self, renderer: OffscreenRenderer):
        self.renderer = weakref.ref(renderer)

    def __call__(self) -> None:
        renderer = self.renderer()
        if renderer is not None:
            renderer.close()


class OffscreenRenderer:
    """Renders RGB frames of ``model`` from a named camera into an offscreen buffer.

    Raises EnvError when no OpenGL context can be created. Call :meth:`close` (or use ``with``); one left open is
    closed at the interpreter's exit (quietly, `_CloseAtExit`).
    The model's offscreen buffer size (``vis.global_.offwidth/offheight``) is raised to the frame
    size if smaller, and its multisampling (``vis.quality.offsamples``) set to ``multisamples`` (render settings
    only: physics does not read them).
    """

    def __init__(self, model: mujoco.MjModel, width: int = 640, height: int = 480, max_geom: int = 10000,
                 multisamples: int = 0):
        self.model = model
        self.width, self.height = int(width), int(height)
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, self.width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, self.height)
        model.vis.quality.offsamples = int(multisamples)
        self._gl, self.backend = gl_context(self.width, self.height)
        self._at_exit = _CloseAtExit(self)
        atexit.register(self._at_exit)  # after the context: it runs before the GL library's own exit handler
        self._context: mujoco.MjrContext | None = None
        try:
            self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        except Exception:
            self.close()
            raise
        self.scene = mujoco.MjvScene(model, maxgeom=max_geom)
        self.option = mujoco.MjvOption()
        self._perturb = mujoco.MjvPerturb()
        self._camera = mujoco.MjvCamera()
        self._translucent: frozenset[int] = frozenset()  # geoms drawn translucent (from the cutaway camera)
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)

    def camera_names(self) -> list[str]:
        """Names of the model's cameras."""
        return [mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_CAMERA, i) or str(i)
                for i in range(self.model.ncam)]

    def set_camera(self, name: str) -> None:
        """Render from the named fixed camera.

        Raises:
            EnvError: no camera of that name.
        """
        cam_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, name)
        if cam_id < 0:
            raise EnvError(f"camera {name!r} not in the scene (available: {self.camera_names()})")
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._camera.fixedcamid = cam_id
        self._translucent = frozenset()
        sorter = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, SORTER_BODY)
        if name == CUTAWAY_CAMERA and sorter >= 0:
            self._translucent = frozenset(int(g) for g in np.flatnonzero(self.model.geom_bodyid == sorter))

    def update_scene(self, data: mujoco.MjData) -> mujoco.MjvScene:
        """Fill :attr:`scene` from ``data`` (from the cutaway camera with the sorter translucent); add user geoms to
        it afterwards, then call :meth:`render`."""
        mujoco.mjv_updateScene(self.model, data, self.option, self._perturb, self._camera,
                               mujoco.mjtCatBit.mjCAT_ALL, self.scene)
        if self._translucent:
            for i in range(self.scene.ngeom):
                geom = self.scene.geoms[i]
                if geom.objtype == mujoco.mjtObj.mjOBJ_GEOM and geom.objid in self._translucent:
                    geom.rgba[3] = CUTAWAY_ALPHA
        return self.scene

    def render(self, shadows: bool = False, text: str | None = None) -> npt.NDArray[np.uint8]:
        """Render :attr:`scene` (with ``text`` over its top left corner) and return the RGB image (height, width,
        3), top row first (a view)."""
        if self._context is None:
            raise EnvError("renderer is closed")
        self._gl.make_current()
        self.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = shadows
        self.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = shadows
        mujoco.mjr_render(self._rect, self.scene, self._context)
        if text:
            mujoco.mjr_overlay(mujoco.mjtFont.mjFONT_NORMAL, mujoco.mjtGridPos.mjGRID_TOPLEFT, self._rect, text, "",
                               self._context)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._context)
        return self._rgb[::-1]

    def close(self) -> None:
        """Free the MuJoCo render context and the GL context (idempotent)."""
        if self._context is not None:
            self._context.free()
            self._context = None
        if self._gl is not None:
            self._gl.free()
            self._gl = None
            atexit.unregister(self._at_exit)

    def __enter__(self) -> OffscreenRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_ORIGIN = np.zeros(3)
_IDENTITY = np.eye(3).ravel()


def add_segment(scene: mujoco.MjvScene, start: npt.ArrayLike, end: npt.ArrayLike, width_px: float,
                rgba: npt.ArrayLike) -> bool:
    """Append a line user geom from ``start`` to ``end``, ``width_px`` wide; False when the scene is full."""
    if scene.ngeom >= scene.maxgeom:
        return False
    geom = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(geom, mujoco.mjtGeom.mjGEOM_LINE, _ORIGIN, _ORIGIN, _IDENTITY,
                        np.asarray(rgba, dtype=np.float32))
    mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_LINE, width_px, np.asarray(start, dtype=float),
                         np.asarray(end, dtype=float))
    geom.category = mujoco.mjtCatBit.mjCAT_DECOR
    scene.ngeom += 1
    return True


def polyline_segments(points: npt.ArrayLike, max_segments: int) -> list[tuple[FloatArray, FloatArray]]:
    """The (start, end) pairs that draw points (K, 3) as a chain of at most ``max_segments`` line segments
    (evenly subsampled, zero-length ones dropped): computed once per path, drawn every frame."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[0] < 2:
        return []
    idx = np.unique(np.linspace(0, pts.shape[0] - 1, min(pts.shape[0], max_segments + 1)).round().astype(int))
    return [(pts[a], pts[b]) for a, b in zip(idx[:-1], idx[1:]) if np.linalg.norm(pts[b] - pts[a]) >= 1e-9]


def add_polyline(scene: mujoco.MjvScene, points: npt.ArrayLike, width_px: float, rgba: npt.ArrayLike,
                 max_segments: int) -> int:
    """Draw points (K, 3) as a chain of line segments, subsampled to <= max_segments; returns the count."""
    return add_segments(scene, polyline_segments(points, max_segments), width_px, rgba)


def add_segments(scene: mujoco.MjvScene, segments: Sequence[tuple[FloatArray, FloatArray]], width_px: float,
                 rgba: npt.ArrayLike) -> int:
    """Draw (start, end) pairs as line geoms until the scene is full; returns the count drawn."""
    color = np.asarray(rgba, dtype=np.float32)
    count = 0
    for start, end in segments:
        if not add_segment(scene, start, end, width_px, color):
            break
        count += 1
    return count


def add_frame(scene: mujoco.MjvScene, pose: Pose, length: float, width_px: float) -> None:
    """Draw the axes of a pose as three lines (x red, y green, z blue)."""
    for axis, rgba in zip(np.eye(3), GOAL_AXES_RGBA):
        add_segment(scene, pose.pos, pose.pos + length * rotate(pose.quat, axis), width_px, rgba)


class Mp4Writer:
    """H.264 MP4 writer into an envs.io.owned_output.AtomicOutput: renamed to ``path`` on :meth:`close` only when ffmpeg
    wrote a whole MP4 (`check_mp4`), deleted otherwise.

    Raises (append, close):
        OSError: ffmpeg could not write the video (a full disk, a write error): one line naming the path.
    """

    def __init__(self, path: str | os.PathLike[str], fps: int, quality: int = 7):
        self.path = Path(path)
        if self.path.suffix.lower() != ".mp4":
            raise EnvError(f"video path {self.path} must end in .mp4")
        if not self.path.parent.is_dir():
            raise EnvError(f"cannot write video {self.path}: folder {self.path.parent} does not exist")
        self._output = AtomicOutput(self.path, register=True)
        self.temporary_path = self._output.temporary
        try:
            self._writer = imageio.get_writer(self.temporary_path, format="FFMPEG", mode="I", fps=fps,
                                              codec="libx264", quality=quality, pixelformat="yuv420p",
                                              macro_block_size=8, ffmpeg_log_level="quiet")
        except BaseException:
            self._output.abort()
            raise
        self.frames = 0

    def _failed(self, what: str) -> OSError:
        return OSError(errno.EIO, f"ffmpeg could not write the video ({what}; disk full?)", str(self.path))

    def append(self, frame: npt.NDArray[np.uint8]) -> None:
        """Encode one RGB frame (H, W, 3) uint8."""
        try:
            self._writer.append_data(frame)
        except OSError:  # ffmpeg is gone (its pipe broke): imageio's message spans many lines
            self.abort()
            raise self._failed(f"stopped at frame {self.frames}") from None
        self.frames += 1

    def close(self) -> Path:
        """Finish encoding, check the file is a whole MP4, and move it into place."""
        try:
            self._writer.close()
        except OSError:
            self._output.abort()
            raise self._failed("it did not finish") from None
        if self.frames == 0:
            self._output.abort()
            raise EnvError(f"video {self.path}: no frame was rendered")
        problem = check_mp4(self.temporary_path)
        if problem is not None:
            self._output.abort()
            raise self._failed(problem)
        return self._output.commit()

    def abort(self) -> None:
        """Stop encoding and delete the temporary file."""
        try:
            self._writer.close()
        except OSError:
            pass  # ffmpeg already failed; the partial file goes anyway
        finally:
            self._output.abort()


def check_mp4(path: str | os.PathLike[str]) -> str | None:
    """None if ``path`` is a whole MP4, else what is wrong: its top-level boxes (ISO/IEC 14496-12: 32-bit
    big-endian size, 4-byte type; size 1 = a 64-bit size follows, 0 = to the end of the file) must tile the
    file exactly and include "ftyp", "moov" and "mdat" (ffmpeg writes "moov" last, so a cut file lacks it)."""
    p = Path(path)
    size = p.stat().st_size
    if size == 0:
        return "the file is empty"
    found, offset = set(), 0
    with open(p, "rb") as handle:
        while offset < size:
            handle.seek(offset)
            header = handle.read(8)
            if len(header) < 8:
                return f"a box header is cut at byte {offset}"
            length, kind = struct.unpack(">I4s", header)
            if length == 1:
                extended = handle.read(8)
                if len(extended) < 8:
                    return f"a box header is cut at byte {offset}"
                length = struct.unpack(">Q", extended)[0]
            elif length == 0:
                length = size - offset
            if length < 8 or offset + length > size:
                return f"box {kind!r} at byte {offset} runs past the end of the file ({size} bytes)"
            found.add(kind)
            offset += length
    missing = [k.decode() for k in (b"ftyp", b"moov", b"mdat") if k not in found]
    return f"no {', '.join(missing)} box" if missing else None


class EpisodeVideo:
    """Records an episode to MP4: call :meth:`capture` after every control step.

    A frame is rendered at the first capture whose time reaches t0 + k / fps (t0 = time of the first
    capture), so a T-second episode gives floor(T * fps) + 1 frames whatever the control rate, as long
    as captures come at least fps times per second of simulated time.

    Usage::

        with EpisodeVideo(model, "out.mp4", VideoConfig(camera="side"), goal=goal) as video:
            video.capture(data)
            ...            # step, then video.capture(data)
        # file renamed into place on normal exit, deleted if an exception escaped

    Args (besides the model, the path and the config):
        goal: a pose drawn as a frame (config.goal_axis_length_m).
        commanded_path: a polyline drawn over the scene (config.draw_path).
        on_frame: called with every frame written (e.g. to sample frames for a dataset's statistics).

    Attributes:
        render_s, encode_s: wall-clock seconds spent rendering and encoding (for benchmarks).
    """

    def __init__(self, model: mujoco.MjModel, path: str | os.PathLike[str], config: VideoConfig = VideoConfig(),
                 goal: Pose | None = None, commanded_path: npt.ArrayLike | None = None,
                 on_frame: Callable[[npt.NDArray[np.uint8]], None] | None = None):
        self.config = config
        self.on_frame = on_frame
        self.goal = goal
        self._path_points: FloatArray | None = None
        self._path_segments: list[tuple[FloatArray, FloatArray]] = []
        self.set_commanded_path(commanded_path)
        self._writer = Mp4Writer(path, config.fps, config.quality)
        try:
            self._renderer = OffscreenRenderer(model, config.width, config.height, multisamples=config.multisamples)
            self._renderer.set_camera(config.camera)
        except BaseException:
            self._writer.abort()
            if hasattr(self, "_renderer"):
                self._renderer.close()
            raise
        self._next_due_s: float | None = None
        self.render_s = 0.0
        self.encode_s = 0.0
        self._closed = False

    @property
    def frames(self) -> int:
        """Frames written so far."""
        return self._writer.frames

    def set_commanded_path(self, points: npt.ArrayLike | None) -> None:
        """Replace the drawn commanded path (K, 3) (None: draw nothing)."""
        if points is None:
            self._path_points = None
            self._path_segments = []
            return
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise EnvError(f"commanded path must have shape (K, 3), got {pts.shape}")
        self._path_points = pts
        self._path_segments = polyline_segments(pts, self.config.max_path_segments)

    def new_episode(self) -> None:
        """Restart the frame clock: the next capture renders at once (for several episodes in one video)."""
        self._next_due_s = None

    def capture(self, data: mujoco.MjData, time_s: float | None = None, force: bool = False,
                text: str | Callable[[], str] | None = None) -> bool:
        """Render and encode a frame if one is due (or ``force``); True if a frame was written.

        Args:
            data: the simulation state to draw.
            time_s: episode time of ``data`` (default data.time).
            force: render regardless of the frame clock.
            text: drawn over the frame's top left corner (`episode_overlay`), or a function making it (called only
                when a frame is rendered).
        """
        if self._closed:
            raise EnvError("video is already closed")
        now = float(data.time if time_s is None else time_s)
        if self._next_due_s is None:
            self._next_due_s = now
        if not force and now < self._next_due_s - 1e-9:
            return False
        if now >= self._next_due_s - 1e-9:
            self._next_due_s += 1.0 / self.config.fps
        start = time.perf_counter()
        scene = self._renderer.update_scene(data)
        if self.config.draw_path and self._path_points is not None:
            add_segments(scene, self._path_segments, self.config.path_width_px, PATH_RGBA)
        if self.goal is not None and self.config.goal_axis_length_m > 0.0:
            add_frame(scene, self.goal, self.config.goal_axis_length_m, 2.0 * self.config.path_width_px)
        frame = self._renderer.render(shadows=self.config.shadows, text=text() if callable(text) else text)
        mid = time.perf_counter()
        self._writer.append(frame)
        self.render_s += mid - start
        self.encode_s += time.perf_counter() - mid
        if self.on_frame is not None:
            self.on_frame(frame)
        return True

    def close(self) -> Path:
        """Finish the MP4 (rename into place) and free the renderer."""
        if self._closed:
            return self._writer.path
        self._closed = True
        try:
            self._renderer.close()
        finally:
            start = time.perf_counter()
            path = self._writer.close()
            self.encode_s += time.perf_counter() - start
        return path

    def abort(self) -> None:
        """Free the renderer and delete the partial video."""
        if self._closed:
            return
        self._closed = True
        try:
            self._renderer.close()
        finally:
            self._writer.abort()

    def __enter__(self) -> EpisodeVideo:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
