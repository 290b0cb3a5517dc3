"""Offscreen MuJoCo videos: the `run --video` command end to end, and the pieces around it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from shinro_ctrl import video
from shinro_ctrl.errors import InvalidArgument, ShinroError
from shinro_ctrl.plants import CartPole
from shinro_ctrl.video import VideoError, frame_indices, render_rollout, select_gl_backend, write_gif, write_mp4


def headless_env(**extra: str) -> dict[str, str]:
    """The environment of a headless machine with no OpenGL choice made (video.py must make it)."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL")}
    env.pop("PYOPENGL_PLATFORM", None)
    env.update(extra)
    return env


def run_cli(*args: str, cwd: Path, env: dict[str, str], timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "shinro_ctrl.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=cwd,
        env=env,
    )


def gif_frames(path: Path) -> tuple[list[np.ndarray], list[int]]:
    with Image.open(path) as im:
        frames, durations = [], []
        for i in range(im.n_frames):
            im.seek(i)
            frames.append(np.asarray(im.convert("RGB")))
            durations.append(im.info["duration"])
    return frames, durations


# ----------------------------------------------------------------- end to end
@pytest.mark.parametrize(
    "scenario,duration",
    [
        ("cartpole_lqr_mujoco", "1"),  # MuJoCo loop
        ("pendulum_lqr", "0.5"),  # standalone loop: a MuJoCo model is built just for rendering
    ],
)
def test_run_video_writes_a_moving_gif(tmp_path, scenario, duration):
    res = run_cli(
        "run",
        scenario,
        "--duration",
        duration,
        "--plot",
        str(tmp_path / "p.png"),
        "--video",
        "tmp.gif",
        cwd=tmp_path,
        env=headless_env(),
    )
    assert res.returncode == 0, res.stderr
    assert "video: tmp.gif" in res.stdout
    frames, durations = gif_frames(tmp_path / "tmp.gif")
    assert len(frames) > 5
    assert frames[0].shape == (240, 320, 3)
    assert not np.array_equal(frames[0], frames[-1])
    assert frames[0].std() > 5  # not a blank image
    # Real time: dt = 0.01 s and a stride of 3 give 30 ms per frame.
    assert durations[0] == 30


def test_invalid_gl_backend_is_one_line_exit_2(tmp_path):
    res = run_cli(
        "run",
        "cartpole_lqr_mujoco",
        "--duration",
        "0.1",
        "--video",
        "v.gif",
        cwd=tmp_path,
        env=headless_env(MUJOCO_GL="bogus"),
    )
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert "MUJOCO_GL" in res.stderr and "apt-get install libosmesa6" in res.stderr
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "v.gif").exists()


def test_unsupported_format_fails_before_the_run(tmp_path):
    res = run_cli("run", "cartpole_lqr_mujoco", "--video", "v.avi", cwd=tmp_path, env=headless_env())
    assert res.returncode == 2
    assert res.stderr.strip() == "error: unsupported video format '.avi': use .gif or .mp4"
    assert "running" not in res.stdout  # checked before anything was simulated


# ------------------------------------------------------------- GL selection
@pytest.fixture
def clean_gl_env(monkeypatch):
    """No display, no MUJOCO_GL; whatever select_gl_backend exports is undone afterwards."""
    for name in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.setenv(name, "x")  # records the original value for the undo
        monkeypatch.delenv(name)
    return monkeypatch


def test_missing_osmesa_names_the_package(clean_gl_env):
    clean_gl_env.setenv("MUJOCO_GL", "osmesa")
    clean_gl_env.setattr(video, "_find_library", lambda name: None)
    with pytest.raises(VideoError, match=r"apt-get install libosmesa6") as info:
        select_gl_backend()
    assert isinstance(info.value, ShinroError)  # the CLI prints one line and exits 2


def test_no_backend_at_all_names_the_package(clean_gl_env):
    clean_gl_env.delitem(sys.modules, "mujoco", raising=False)
    clean_gl_env.setattr(video, "_find_library", lambda name: None)
    with pytest.raises(VideoError, match=r"no offscreen OpenGL backend.*apt-get install libosmesa6"):
        select_gl_backend()
    assert "MUJOCO_GL" not in os.environ


def test_headless_default_is_osmesa_then_egl(clean_gl_env):
    clean_gl_env.delitem(sys.modules, "mujoco", raising=False)
    clean_gl_env.setattr(video, "_find_library", lambda name: "lib" + name)
    assert select_gl_backend() == "osmesa"
    assert os.environ["MUJOCO_GL"] == "osmesa"
    clean_gl_env.delenv("MUJOCO_GL")
    clean_gl_env.setattr(video, "_find_library", lambda name: "libEGL.so.1" if name == "EGL" else None)
    assert select_gl_backend() == "egl"


def test_display_keeps_glfw_and_late_choice_is_explained(clean_gl_env):
    clean_gl_env.setenv("DISPLAY", ":0")
    assert select_gl_backend() == "glfw"
    assert "MUJOCO_GL" not in os.environ
    clean_gl_env.delenv("DISPLAY")
    clean_gl_env.setitem(sys.modules, "mujoco", SimpleNamespace())
    with pytest.raises(VideoError, match=r"mujoco was imported before.*MUJOCO_GL=osmesa"):
        select_gl_backend()
    clean_gl_env.setenv("MUJOCO_GL", "glfw")
    with pytest.raises(VideoError, match="needs a display"):
        select_gl_backend()


def test_plant_without_model_is_a_clear_error(tmp_path):
    class NoModel(CartPole):
        asset = None

    sim = SimpleNamespace(plant=NoModel(), scenario=SimpleNamespace(engine=None, plant=SimpleNamespace(params={})))
    result = SimpleNamespace(t=np.arange(3) * 0.01, x=np.zeros((3, 4)))
    with pytest.raises(VideoError, match="NoModel has no MuJoCo model"):
        render_rollout(sim, result, tmp_path / "v.gif")


# ------------------------------------------------------------------- frames
def test_frame_indices_real_time_and_last_state():
    idx, stride = frame_indices(101, 0.01)  # 1 s at 100 Hz
    assert stride == 3 and idx[0] == 0 and idx[-1] == 100
    assert np.all(np.diff(idx)[:-1] == 3)


def test_frame_indices_gif_quantum_keeps_real_time():
    # dt = 5 ms: the ideal stride 7 (35 ms) is not a whole number of centiseconds; 6 (30 ms) is.
    assert frame_indices(1001, 0.005)[1] == 7
    _, stride = frame_indices(1001, 0.005, quantum=0.01)
    assert stride == 6


def test_frame_indices_caps_long_runs():
    idx, stride = frame_indices(100_001, 0.01, max_frames=600)
    assert len(idx) <= 600 and stride > 3


@pytest.mark.parametrize("kwargs", [{"n_states": 0, "dt": 0.01}, {"n_states": 5, "dt": 0.0}, {"n_states": 5, "dt": -1}])
def test_frame_indices_rejects_bad_arguments(kwargs):
    with pytest.raises(InvalidArgument):
        frame_indices(**kwargs)


def _synthetic_frames(n: int = 8, h: int = 48, w: int = 64) -> list[np.ndarray]:
    frames = []
    for k in range(n):
        f = np.zeros((h, w, 3), dtype=np.uint8)
        f[:, : (k + 1) * w // n] = (200, 80, 30)
        frames.append(f)
    return frames


def test_write_gif_round_trips_frames_and_timing(tmp_path):
    frames = _synthetic_frames()
    path = write_gif(frames, tmp_path / "sub" / "a.gif", fps=100 / 3)
    read, durations = gif_frames(path)
    assert len(read) == len(frames)
    assert durations == [30] * len(frames)
    for a, b in zip(read, frames, strict=True):
        assert np.array_equal(a, b)


def test_write_mp4_with_ffmpeg_or_a_clear_error(tmp_path):
    frames = _synthetic_frames(h=40, w=64)
    if video.find_ffmpeg() is None:
        with pytest.raises(VideoError, match="pip install imageio-ffmpeg"):
            write_mp4(frames, tmp_path / "a.mp4", fps=30)
    else:
        path = write_mp4(frames, tmp_path / "a.mp4", fps=30)
        assert path.stat().st_size > 0
        assert path.read_bytes()[4:8] == b"ftyp"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary left behind


def test_a_video_inside_out_joins_the_run_folder(tmp_path):
    import json

    from shinro_ctrl.files import RUN_MANIFEST, written_by_us

    out = tmp_path / "run"
    args = ["run", "pendulum_lqr", "--duration", "0.5", "--out", str(out), "--video", str(out / "flight.gif")]
    res = run_cli(*args, cwd=tmp_path, env=headless_env())
    assert res.returncode == 0, res.stderr
    files = json.loads((out / RUN_MANIFEST).read_text())["files"]
    assert set(files) == {"result.npz", "metrics.json", "scenario.toml", "run.png", "flight.gif"}
    assert written_by_us(out / "flight.gif") and len(gif_frames(out / "flight.gif")[0]) > 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no temporaries beside it


def test_mp4_carries_the_marker_and_a_users_mp4_is_refused(tmp_path):
    from shinro_ctrl.errors import InvalidArgument
    from shinro_ctrl.files import written_by_us

    if video.find_ffmpeg() is None:
        pytest.skip("no ffmpeg (pip install imageio-ffmpeg)")
    frames = _synthetic_frames(h=40, w=64)
    ours = write_mp4(frames, tmp_path / "a.mp4", fps=30)
    assert written_by_us(ours)
    write_mp4(frames, ours, fps=30)  # our own earlier video: replaced
    user = tmp_path / "holiday.mp4"
    user.write_bytes(b"\0\0\0\x18ftypmp42" + bytes(64))  # an MP4 header without our comment
    with pytest.raises(InvalidArgument, match="not an MP4 file written by shinro-ctrl"):
        write_mp4(frames, user, fps=30)
    assert user.read_bytes() == b"\0\0\0\x18ftypmp42" + bytes(64)
