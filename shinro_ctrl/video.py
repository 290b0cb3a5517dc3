"""Offscreen videos of closed-loop runs, rendered with MuJoCo.

:func:`render_rollout` replays a finished run (:class:`~shinro_ctrl.sim.SimResult`)
through a MuJoCo model of the plant and writes a GIF (Pillow) or an MP4
(``ffmpeg``, e.g. from ``pip install imageio-ffmpeg``). It works for both
loops: a standalone run is replayed through a MuJoCo model built for the
plant just for rendering, so any plant with an MJCF asset can be filmed. The
replay writes every k-th recorded state with ``plant.set_state`` (which runs
MuJoCo's forward kinematics) so that the video plays in real time at about
:data:`DEFAULT_FPS` frames per second, or at fewer frames per second for runs
longer than :data:`MAX_FRAMES` frames allow.

**OpenGL backend.** MuJoCo chooses its OpenGL backend from the environment
variable ``MUJOCO_GL`` once, when ``mujoco`` is first imported (by
:mod:`shinro_ctrl.engine`). :func:`select_gl_backend` must therefore run
before that import; :func:`prepare_video` (called by ``shinro-ctrl run
--video`` before it builds anything) and :func:`render_rollout` both call it.
When ``MUJOCO_GL`` is unset and there is no display it selects ``osmesa``
(software rendering; Debian: ``apt-get install libosmesa6``), or ``egl`` when
only EGL is installed. With a display the default (``glfw``) is kept. Code
that imports :mod:`shinro_ctrl.engine` before rendering on a headless machine
should call :func:`select_gl_backend` first, or export ``MUJOCO_GL=osmesa``.

Rendering a 320 × 240 frame with OSMesa takes 5-30 ms without shadows (the
default; with shadows about ten times more), and a whole frame (replay,
render, GIF encoding) 25-45 ms on a busy 2-core machine: a 5 s run at 30
frames per second becomes a GIF in about 5 s.

Example::

    from shinro_ctrl.video import render_rollout
    from shinro_ctrl.sim import RobotSim

    sim = RobotSim.from_config("cartpole_lqr_mujoco")
    render_rollout(sim, sim.run(2.0), "cartpole.gif")
"""

from __future__ import annotations

import ctypes.util
import math
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl._video_camera import _framing, _moving_bounds, _stamp
from shinro_ctrl.errors import InvalidArgument, ShinroError
from shinro_ctrl.progress import Progress

__all__ = [
    "DEFAULT_FPS",
    "FORMATS",
    "MAX_FRAMES",
    "VideoError",
    "VideoInfo",
    "find_ffmpeg",
    "frame_indices",
    "prepare_video",
    "render_rollout",
    "select_gl_backend",
    "write_gif",
    "write_mp4",
]

DEFAULT_FPS = 30.0
"""Target frame rate [frames per simulated second]."""
MAX_FRAMES = 600
"""Largest number of frames of one video; longer runs get a lower frame rate."""
FORMATS = (".gif", ".mp4")
"""Supported file suffixes."""

_LIBRARIES = {"osmesa": ("OSMesa", "libosmesa6"), "egl": ("EGL", "libegl1")}
_GLFW_VALUES = ("", "glfw", "glx", "enable", "enabled", "on", "true", "1")
_DISABLED_VALUES = ("disable", "disabled", "off", "false", "0")


class VideoError(ShinroError, RuntimeError):
    """A video cannot be made: no OpenGL backend, no encoder, an unsupported format or plant."""


@dataclass(frozen=True)
class VideoInfo:
    """What :func:`render_rollout` wrote.

    Attributes:
        path: The video file.
        frames: Number of frames.
        fps: Playback frame rate [1/s] (real time: one frame per ``stride`` steps).
        stride: Recorded steps per frame.
        width, height: Frame size [px].
        seconds: Wall-clock rendering time [s].
    """

    path: Path
    frames: int
    fps: float
    stride: int
    width: int
    height: int
    seconds: float

    @property
    def ms_per_frame(self) -> float:
        """Mean wall-clock time per frame (replay, render and encode) [ms]."""
        return 1e3 * self.seconds / max(self.frames, 1)


# ----------------------------------------------------------------- backends
def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _find_library(name: str) -> str | None:
    return ctypes.util.find_library(name)


def _missing(backend: str) -> VideoError:
    lib, package = _LIBRARIES[backend]
    return VideoError(
        f"MUJOCO_GL={backend} but the {lib} library is not installed: apt-get install {package} "
        f"(Debian/Ubuntu), or choose another backend with MUJOCO_GL=osmesa|egl|glfw"
    )


def select_gl_backend() -> str:
    """Choose MuJoCo's OpenGL backend for offscreen rendering and export it as ``MUJOCO_GL``.

    Must run before ``mujoco`` is first imported to have any effect (MuJoCo
    reads the variable once). An explicit ``MUJOCO_GL`` is kept but checked;
    when it is unset: ``glfw`` with a display, else ``osmesa`` if libOSMesa
    is installed, else ``egl`` if libEGL is.

    Returns:
        The backend: ``"osmesa"``, ``"egl"`` or ``"glfw"``.

    Raises:
        VideoError: an invalid ``MUJOCO_GL`` value, the library of the chosen
            backend is missing (naming the Debian package to install), or no
            backend is available at all.
    """
    value = os.environ.get("MUJOCO_GL", "").strip().lower()
    if value in _DISABLED_VALUES:
        raise VideoError(f"MuJoCo rendering is disabled (MUJOCO_GL={value}); unset it or set MUJOCO_GL=osmesa")
    if value in _LIBRARIES:
        if _find_library(_LIBRARIES[value][0]) is None:
            raise _missing(value)
        return value
    if value not in _GLFW_VALUES:
        raise VideoError(
            f"invalid MUJOCO_GL={value!r}: use osmesa (apt-get install libosmesa6), egl (apt-get install libegl1) "
            "or glfw (needs a display)"
        )
    if value or _has_display():
        if not _has_display():
            raise VideoError(
                f"MUJOCO_GL={value} needs a display and DISPLAY is not set: "
                "set MUJOCO_GL=osmesa (apt-get install libosmesa6) for offscreen rendering"
            )
        return "glfw"
    if "mujoco" in sys.modules:
        # Too late to choose: MuJoCo took its default (glfw), which needs a display.
        raise VideoError(
            "no display, and mujoco was imported before an offscreen OpenGL backend was selected: "
            "export MUJOCO_GL=osmesa (apt-get install libosmesa6) or call shinro_ctrl.video.select_gl_backend() "
            "before importing shinro_ctrl.engine"
        )
    for backend in ("osmesa", "egl"):
        if _find_library(_LIBRARIES[backend][0]) is not None:
            os.environ["MUJOCO_GL"] = backend
            return backend
    raise VideoError(
        "no offscreen OpenGL backend for MuJoCo: apt-get install libosmesa6 (Debian/Ubuntu), or run with a display"
    )


def find_ffmpeg() -> str | None:
    """Path of an ``ffmpeg`` executable: imageio-ffmpeg's bundled binary, else ``ffmpeg`` on PATH."""
    try:
        import imageio_ffmpeg  # type: ignore[import-not-found]
    except ImportError:
        pass
    else:
        try:
            return str(imageio_ffmpeg.get_ffmpeg_exe())
        except RuntimeError:
            pass
    return shutil.which("ffmpeg")


def _check_format(path: str | Path) -> str:
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise VideoError(f"unsupported video format '{suffix or Path(path).name}': use {' or '.join(FORMATS)}")
    if suffix == ".mp4" and find_ffmpeg() is None:
        raise VideoError(
            "writing .mp4 needs ffmpeg: pip install imageio-ffmpeg (or apt-get install ffmpeg), or use .gif"
        )
    return suffix


def prepare_video(path: str | Path) -> str:
    """Check that a video can be written to ``path`` and select the OpenGL backend.

    Call it before anything imports ``mujoco`` (and before a long run), so a
    missing encoder or backend is reported before any work is done.

    Returns:
        The backend chosen by :func:`select_gl_backend`.

    Raises:
        VideoError: unsupported suffix, no MP4 encoder, or no OpenGL backend.
    """
    _check_format(path)
    return select_gl_backend()


# ------------------------------------------------------------------- frames
def frame_indices(
    n_states: int,
    dt: float,
    *,
    fps: float = DEFAULT_FPS,
    max_frames: int = MAX_FRAMES,
    quantum: float | None = None,
) -> tuple[np.ndarray, int]:
    """Which recorded states become frames, for real-time playback near ``fps``.

    Args:
        n_states: Number of recorded states ``T + 1``.
        dt: Time between recorded states [s].
        fps: Target frame rate [1/s].
        max_frames: Upper bound on the number of frames (long runs get a
            larger stride, hence a lower frame rate).
        quantum: Resolution of the container's frame delay [s] (GIF: 0.01).
            Among strides within about a third of the ideal one, the one
            whose frame interval ``stride * dt`` is closest to a multiple of
            ``quantum`` wins, so that playback stays real time.

    Returns:
        ``(indices (F,), stride)``: every ``stride``-th state from the first,
        plus the last state when the stride skips it.
    """
    if n_states < 1:
        raise InvalidArgument(f"n_states must be >= 1, got {n_states}")
    if not (math.isfinite(dt) and dt > 0 and math.isfinite(fps) and fps > 0):
        raise InvalidArgument(f"dt and fps must be positive, got dt={dt!r}, fps={fps!r}")
    if max_frames < 2:
        raise InvalidArgument(f"max_frames must be >= 2, got {max_frames}")
    ideal = 1.0 / (fps * dt)
    floor = max(1, math.ceil((n_states - 1) / (max_frames - 1)))
    stride = max(floor, round(ideal))
    if quantum is not None and stride > floor:

        def timing_error(s: int) -> float:
            interval = s * dt
            return abs(interval - quantum * max(1, round(interval / quantum))) / interval

        candidates = range(max(floor, math.floor(0.75 * ideal)), max(floor, math.ceil(1.34 * ideal)) + 1)
        stride = min(candidates, key=lambda s: (round(timing_error(s), 9), abs(s - ideal)))
    idx = np.arange(0, n_states, stride)
    if idx[-1] != n_states - 1:
        idx = np.append(idx, n_states - 1)
    return idx, stride


def write_gif(frames: Sequence[np.ndarray], path: str | Path, fps: float) -> Path:
    """Write RGB frames ``(H, W, 3) uint8`` as a looping GIF (atomically).

    GIF frame delays are whole centiseconds, so the playback rate is
    ``100 / round(100 / fps)`` frames per second.
    """
    from PIL import Image

    from shinro_ctrl.files import GENERATOR, write_output

    if not frames:
        raise InvalidArgument("no frames to write")
    images = [Image.fromarray(np.ascontiguousarray(f)).quantize(colors=256, dither=Image.Dither.NONE) for f in frames]
    duration = max(10, 10 * round(100.0 / fps))  # [ms], a multiple of 10
    return write_output(
        path,
        lambda f: images[0].save(
            f,
            format="GIF",
            save_all=True,
            append_images=images[1:],
            duration=duration,
            loop=0,
            optimize=False,
            comment=GENERATOR.encode(),  # our marker: a later run may replace this file, never a user's GIF
        ),
        binary=True,
        what="--video",
        kind="GIF",
    )


def write_mp4(frames: Sequence[np.ndarray], path: str | Path, fps: float, *, ffmpeg: str | None = None) -> Path:
    """Write RGB frames ``(H, W, 3) uint8`` as an H.264 MP4 through ``ffmpeg`` (atomically).

    Raises:
        VideoError: no ffmpeg, or ffmpeg failed (with its last message line).
    """
    ffmpeg = ffmpeg or find_ffmpeg()
    if ffmpeg is None:
        raise VideoError("writing .mp4 needs ffmpeg: pip install imageio-ffmpeg (or apt-get install ffmpeg)")
    if not frames:
        raise InvalidArgument("no frames to write")
    from shinro_ctrl.files import GENERATOR, check_replaceable

    path = Path(path)
    check_replaceable(
        path, what="--video", kind="MP4"
    )  # only over a video of ours (its comment tag), never through a link
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = frames[0].shape[:2]
    tmp = path.with_name(f".{path.name}.tmp.mp4")
    cmd = [
        ffmpeg, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}",
        "-r", f"{fps:.6g}", "-i", "-", "-an", "-c:v", "libx264", "-pix_fmt", "yuv420p",
        "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-metadata", f"comment={GENERATOR}",
        "-movflags", "+faststart", str(tmp),
    ]  # fmt: skip
    data = b"".join(np.ascontiguousarray(f, dtype=np.uint8).tobytes() for f in frames)
    try:
        proc = subprocess.run(cmd, input=data, capture_output=True, check=False)
        if proc.returncode != 0:
            lines = proc.stderr.decode(errors="replace").strip().splitlines() or [f"exit status {proc.returncode}"]
            raise VideoError(f"ffmpeg failed writing {path}: {lines[-1]}")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


# ------------------------------------------------------------------ render
def _render_model(sim: Any) -> str | None:
    """The MJCF model the scenario names (None: the plant's asset); raise if there is none."""
    scenario = sim.scenario
    model = scenario.engine.model if scenario.engine is not None else None
    if getattr(sim.plant, "asset", None) is None and model is None:  # MjcfPlant's asset is per instance
        raise VideoError(f"{type(sim.plant).__name__} has no MuJoCo model (MJCF asset) to render; videos need one")
    return model


def _render_plant(sim: Any, model: str | None) -> tuple[Any, Any]:
    """A fresh plant like ``sim.plant`` attached to a MuJoCo model built for rendering only."""
    from shinro_ctrl.engine import MujocoEngine

    plant = type(sim.plant).from_config(sim.scenario.plant.params)
    engine = MujocoEngine.for_plant(plant, model=model)
    plant.physics_engine(engine)
    return plant, engine


def _replay(plant: Any, states: np.ndarray) -> Iterator[int]:
    """Write each state into the plant (and so into its engine); yield the frame number."""
    for k, x in enumerate(states):
        try:
            plant.set_state(x)
        except (ValueError, ShinroError) as exc:
            raise VideoError(f"cannot show the state of frame {k} in MuJoCo: {exc}") from exc
        yield k


def render_rollout(
    sim: Any,
    result: Any,
    path: str | Path,
    *,
    width: int = 320,
    height: int = 240,
    fps: float = DEFAULT_FPS,
    max_frames: int = MAX_FRAMES,
    camera: str | None = None,
    label: bool = True,
    shadows: bool = False,
    progress: bool | None = None,
    on_frame: Callable[[int, np.ndarray], None] | None = None,
) -> VideoInfo:
    """Render a finished run offscreen with MuJoCo and write it as a GIF or MP4.

    The recorded states ``result.x`` are replayed (every ``stride``-th, see
    :func:`frame_indices`) through a MuJoCo model built for ``sim``'s plant
    and parameters, whichever loop produced them. The free camera sees the
    plant from the side (-y, +x to the right), or from above at 50° for
    robots moving in the ground plane, framed once so that every moving part
    stays in view over the whole run.

    Args:
        sim: The :class:`~shinro_ctrl.sim.RobotSim` that ran (for its plant and scenario).
        result: Its :class:`~shinro_ctrl.sim.SimResult`.
        path: Output file, ``.gif`` (Pillow) or ``.mp4`` (ffmpeg).
        width: Frame width [px].
        height: Frame height [px].
        fps: Target frame rate [1/s]; the video plays in real time.
        max_frames: At most this many frames (long runs get a lower frame rate).
        camera: A camera of the MJCF model by name instead of the framed free camera.
        label: Print the simulated time in the top-left corner.
        shadows: Render shadows (about ten times slower with OSMesa).
        progress: Progress bar on stderr (None: when stderr is a terminal and
            the render takes longer than a second).
        on_frame: Optional callback ``(k, image)`` for each rendered frame.

    Returns:
        A :class:`VideoInfo`.

    Raises:
        VideoError: unsupported format, missing encoder or OpenGL backend, a
            plant without an MJCF asset, or a state MuJoCo cannot show.
    """
    suffix = _check_format(path)
    model = _render_model(sim)
    select_gl_backend()
    x = np.asarray(result.x, dtype=float)
    t = np.asarray(result.t, dtype=float)
    dt = float(t[1] - t[0]) if t.shape[0] > 1 else float(sim.plant.dt)
    idx, stride = frame_indices(
        x.shape[0], dt, fps=fps, max_frames=max_frames, quantum=0.01 if suffix == ".gif" else None
    )
    play_fps = 1.0 / (stride * dt)
    plant, engine = _render_plant(sim, model)
    states, times = x[idx], t[idx]

    start = time.perf_counter()
    snapshots, lo, hi = _snapshots(plant, engine, states)  # pass 1
    renderer = _make_renderer(engine, width, height, shadows)
    frames: list[np.ndarray] = []
    bar = Progress(len(snapshots), f"video {Path(path).name}", progress, delay=1.0, unit="frames")
    try:
        if camera is None and np.all(np.isfinite(lo)):
            model = engine.model
            view = _framing(lo, hi, float(model.vis.global_.fovy), width / height, float(model.stat.extent))
            renderer.look_at(view["center"], view["distance"], azimuth=view["azimuth"], elevation=view["elevation"])
        for k, z in enumerate(snapshots):
            engine.set_state_vector(z)
            frames.append(_frame(renderer, camera, f"t = {times[k]:.2f} s" if label else None))
            if on_frame is not None:
                on_frame(k, frames[-1])
            bar.update(k + 1)
    finally:
        renderer.close()
        bar.close()
    out = write_gif(frames, path, play_fps) if suffix == ".gif" else write_mp4(frames, path, play_fps)
    return VideoInfo(Path(out), len(frames), play_fps, stride, width, height, time.perf_counter() - start)


def _snapshots(plant: Any, engine: Any, states: np.ndarray) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Pass 1 of :func:`render_rollout`: MuJoCo's full state for each frame and the box the moving parts sweep.

    The plant writes each state into MuJoCo (its own coordinates, IK for an arm).

    Returns:
        ``(snapshots, lo (3,), hi (3,))``; ``lo`` stays ``+inf`` when no part moves.
    """
    snapshots = []
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for _ in _replay(plant, states):
        engine.forward()  # some plants only write qpos (a pinned base); refresh what the box reads
        snapshots.append(engine.get_state_vector())
        box = _moving_bounds(engine)
        if box is not None:
            lo, hi = np.minimum(lo, box[0]), np.maximum(hi, box[1])
    return snapshots, lo, hi


def _make_renderer(engine: Any, width: int, height: int, shadows: bool) -> Any:
    """The engine's offscreen renderer, or VideoError with the OSMesa hint."""
    try:
        return engine.make_renderer(width, height, shadows=shadows)
    except RuntimeError as exc:
        raise VideoError(f"{exc}; for offscreen rendering: apt-get install libosmesa6 and MUJOCO_GL=osmesa") from exc


def _frame(renderer: Any, camera: str | None, stamp: str | None) -> np.ndarray:
    """One rendered image (a copy), with ``stamp`` printed in its corner when given."""
    try:
        image = renderer.render(camera)
    except (KeyError, ValueError) as exc:
        raise VideoError(f"camera {camera!r}: {exc}") from exc
    return _stamp(image, stamp) if stamp is not None else image.copy()
