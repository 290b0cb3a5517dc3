"""Nothing a user owns is overwritten (issue 23 §2).

Every file shinro-ctrl writes carries its marker (PNG ``tEXt`` chunk, GIF
comment, HTML ``<meta name="generator">``, PDF ``Creator``, NPZ member, MP4
comment); a folder carries the manifest. An existing file or folder is
replaced only when it carries the marker, a symbolic link is never followed,
and a trade-off's three files are one set. Each kind is tested both ways: our
earlier output is replaced, the user's own file (same format, made by another
program) is refused with one line and left byte for byte.
"""

from __future__ import annotations

import io
import json
import os
import zipfile

import numpy as np
import pytest

from shinro_ctrl.cli import main
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.files import GENERATOR, RUN_MANIFEST, check_output_folder, written_by_us
from shinro_ctrl.planning import Trajectory
from shinro_ctrl.plots.linearization import EpsSweep, plot_eps_sweep
from shinro_ctrl.video import write_gif

SWEEP = EpsSweep(np.logspace(-8, -2, 4), np.array([1e-4, 1e-7, 1e-6, 1e-3]), 1e-12, 1e-6)


# ------------------------------------------------------------ user's own files
def _matplotlib_png() -> bytes:
    """A PNG written by matplotlib itself (the user's own plot: Software=Matplotlib)."""
    from matplotlib.figure import Figure

    buf = io.BytesIO()
    Figure(figsize=(1, 1)).savefig(buf, format="png")
    return buf.getvalue()


def _matplotlib_pdf() -> bytes:
    from matplotlib.figure import Figure

    buf = io.BytesIO()
    Figure(figsize=(1, 1)).savefig(buf, format="pdf")
    return buf.getvalue()


def _pillow_gif(comment: bytes | None = None) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    kw = {"comment": comment} if comment else {}
    Image.new("RGB", (4, 4), (200, 10, 10)).save(buf, format="GIF", **kw)
    return buf.getvalue()


def _numpy_npz() -> bytes:
    buf = io.BytesIO()
    np.savez(buf, t=np.arange(3.0), x=np.zeros((3, 1)))
    return buf.getvalue()


USER_FILES = {
    "png": _matplotlib_png,
    "pdf": _matplotlib_pdf,
    "gif": _pillow_gif,
    "npz": _numpy_npz,
    "html": lambda: b"<!DOCTYPE html>\n<html><head><title>my notes</title></head><body>mine</body></html>\n",
    "html-ours-lookalike": lambda: b"<!DOCTYPE html><html><body>shinro-ctrl is mentioned here</body></html>",
}


def _trajectory() -> Trajectory:
    t = np.linspace(0.0, 1.0, 5)
    x = np.stack([t, np.ones_like(t)], axis=1)
    return Trajectory(t=t, x=x, u=np.zeros((5, 1)), xdot=np.stack([np.ones_like(t), 0 * t], axis=1))


def _write_ours(kind: str, path) -> None:
    """Write ``path`` with the library's own writer of that kind."""
    if kind in ("png", "pdf"):
        plot_eps_sweep(SWEEP, path)
    elif kind == "gif":
        write_gif([np.zeros((8, 8, 3), np.uint8), np.full((8, 8, 3), 255, np.uint8)], path, 10.0)
    elif kind == "npz":
        _trajectory().save(path)
    else:  # pragma: no cover
        raise AssertionError(kind)


@pytest.mark.parametrize("kind", ["png", "pdf", "gif", "npz"])
def test_our_files_carry_the_marker_and_are_replaced(kind, tmp_path):
    path = tmp_path / f"out.{kind}"
    _write_ours(kind, path)
    assert written_by_us(path)
    first = path.read_bytes()
    os.utime(path, (0, 0))
    _write_ours(kind, path)  # our own earlier output: replaced
    assert written_by_us(path) and path.stat().st_mtime > 0
    if kind == "pdf":
        assert first.startswith(b"%PDF")
        assert b"/Creator (" + GENERATOR.encode() + b")" in first
    if kind == "png":
        assert first.startswith(b"\x89PNG")


@pytest.mark.parametrize("kind", ["png", "pdf", "gif", "npz"])
def test_a_users_file_of_the_same_format_is_refused_unchanged(kind, tmp_path):
    path = tmp_path / f"mine.{kind}"
    data = USER_FILES[kind]()
    path.write_bytes(data)
    assert not written_by_us(path)
    with pytest.raises(InvalidArgument, match=r"not .* written by shinro-ctrl; refusing to overwrite") as info:
        _write_ours(kind, path)
    assert len(str(info.value).splitlines()) == 1
    assert path.read_bytes() == data


@pytest.mark.parametrize("content", [b"", b"my notes", b"\x89PNG\r\n\x1a\n" + b"\0" * 40, b"GIF89a" + b"\0" * 40])
def test_empty_text_and_truncated_files_are_not_ours(content, tmp_path):
    path = tmp_path / "x.png"
    path.write_bytes(content)
    assert not written_by_us(path)
    with pytest.raises(InvalidArgument):
        plot_eps_sweep(SWEEP, path)
    assert path.read_bytes() == content


def test_a_gif_with_another_comment_or_a_mention_in_html_is_not_ours(tmp_path):
    gif = tmp_path / "a.gif"
    gif.write_bytes(_pillow_gif(b"made with shinro-ctrl? no"))
    assert not written_by_us(gif)
    html = tmp_path / "a.html"
    html.write_bytes(USER_FILES["html-ours-lookalike"]())
    assert not written_by_us(html)
    html.write_text(f'<!DOCTYPE html><html><head><meta name="generator" content="{GENERATOR}"></head></html>')
    assert written_by_us(html)


def test_an_npz_with_the_member_but_another_value_is_not_ours(tmp_path):
    path = tmp_path / "p.npz"
    np.savez(path, generator=np.array("numpy"))
    assert not written_by_us(path)
    with zipfile.ZipFile(path, "a") as z:
        z.writestr("junk.txt", "x")
    assert not written_by_us(path)


# ----------------------------------------------------------------- symlinks
@pytest.mark.parametrize("kind", ["png", "pdf", "gif", "npz"])
@pytest.mark.parametrize("target_is_ours", [False, True])
def test_a_symlink_is_never_followed_to_replace_its_target(kind, target_is_ours, tmp_path):
    target = tmp_path / f"target.{kind}"
    if target_is_ours:
        _write_ours(kind, target)
    else:
        target.write_bytes(USER_FILES[kind]())
    before = target.read_bytes()
    link = tmp_path / f"link.{kind}"
    link.symlink_to(target)
    with pytest.raises(InvalidArgument, match="symbolic link"):
        _write_ours(kind, link)
    assert link.is_symlink() and target.read_bytes() == before


def test_a_dangling_symlink_is_refused(tmp_path):
    link = tmp_path / "plot.png"
    link.symlink_to(tmp_path / "elsewhere" / "x.png")
    with pytest.raises(InvalidArgument, match="symbolic link"):
        plot_eps_sweep(SWEEP, link)
    assert not (tmp_path / "elsewhere").exists()


# ------------------------------------------------------------- the command line
def _one_error_line(capsys) -> str:
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "running" not in out
    return lines[0]


@pytest.mark.parametrize("kind", ["png", "pdf"])
def test_cli_plot_refuses_a_users_plot_and_replaces_its_own(kind, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    user = tmp_path / f"mine.{kind}"
    user.write_bytes(USER_FILES[kind]())
    before = user.read_bytes()
    for args in (
        ["run", "--plot", user.name, "--duration", "0.1"],
        ["crosscheck", "pendulum", "--plot", user.name],
        ["linearize", "pendulum", "--eps-sweep", "--plot", user.name],
    ):
        assert main(args) == 2
        assert "refusing to overwrite" in _one_error_line(capsys)
    assert user.read_bytes() == before
    ours = tmp_path / f"ours.{kind}"
    for _ in range(2):  # the second run replaces the first one's plot
        assert main(["crosscheck", "pendulum", "--plot", ours.name]) == 0
        assert written_by_us(ours)
    assert ours.read_bytes().startswith(b"%PDF" if kind == "pdf" else b"\x89PNG")


def test_cli_plot_through_a_symlink_is_refused(tmp_path, capsys):
    target = tmp_path / "photo.png"
    target.write_bytes(USER_FILES["png"]())
    link = tmp_path / "plot.png"
    link.symlink_to(target)
    assert main(["crosscheck", "pendulum", "--plot", str(link)]) == 2
    assert "symbolic link" in _one_error_line(capsys)
    assert target.read_bytes() == USER_FILES["png"]()


def test_cli_video_refuses_a_users_gif(tmp_path, capsys):
    user = tmp_path / "holiday.gif"
    user.write_bytes(USER_FILES["gif"]())
    assert main(["run", "pendulum_lqr_mujoco", "--video", str(user), "--duration", "0.1"]) == 2
    assert "not a GIF file written by shinro-ctrl" in _one_error_line(capsys)
    assert user.read_bytes() == USER_FILES["gif"]()
    link = tmp_path / "v.gif"
    link.symlink_to(user)
    assert main(["run", "pendulum_lqr_mujoco", "--video", str(link), "--duration", "0.1"]) == 2
    assert "symbolic link" in _one_error_line(capsys)


def test_cli_report_refuses_a_users_html_and_replaces_its_own(tmp_path, capsys):
    user = tmp_path / "notes.html"
    user.write_bytes(USER_FILES["html"]())  # a real HTML page with a doctype: still the user's
    assert main(["design", "lqr", "cartpole_lqr", "--report", str(user)]) == 2
    assert "not an HTML report written by shinro-ctrl" in _one_error_line(capsys)
    assert user.read_bytes() == USER_FILES["html"]()
    ours = tmp_path / "report.html"
    for _ in range(2):
        assert main(["design", "lqr", "cartpole_lqr", "--report", str(ours)]) == 0
        assert f'<meta name="generator" content="{GENERATOR}">' in ours.read_text()
    capsys.readouterr()


def test_cli_plan_out_refuses_a_users_npz(tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    user = out / "cartpole_swingup_mujoco_plan.npz"
    user.write_bytes(USER_FILES["npz"]())
    assert main(["plan", "cartpole_swingup_mujoco", "--out", str(out)]) == 2
    assert "not an NPZ file written by shinro-ctrl" in _one_error_line(capsys)
    assert user.read_bytes() == USER_FILES["npz"]()


# ----------------------------------------------------------------- folders
@pytest.mark.parametrize(
    "names", [["metrics.json"], ["sweep.csv"], ["result.npz", "metrics.json", "scenario.toml", "run.png"]]
)
def test_a_folder_without_our_manifest_is_refused_even_with_our_file_names(names, tmp_path, capsys):
    out = tmp_path / "results"
    out.mkdir()
    for n in names:
        (out / n).write_text("the user's own data")
    names_before = sorted(p.name for p in out.iterdir())
    for args in (
        ["run", "--out", str(out), "--duration", "0.1"],
        ["sweep", "cartpole_lqr", "--param", "plant.cart_mass=0.5:1", "--samples", "2", "--out", str(out)],
    ):
        assert main(args) == 2
        assert "not a run output" in _one_error_line(capsys)
    assert sorted(p.name for p in out.iterdir()) == names_before
    assert all((out / n).read_text() == "the user's own data" for n in names)


def test_run_out_replaces_its_own_folder_and_refuses_a_linked_one(tmp_path, capsys):
    out = tmp_path / "run"
    for _ in range(2):
        assert main(["run", "--out", str(out), "--duration", "0.1"]) == 0
    manifest = json.loads((out / RUN_MANIFEST).read_text())
    assert set(manifest["files"]) == {"result.npz", "metrics.json", "scenario.toml", "run.png"}
    link = tmp_path / "link"
    link.symlink_to(out)
    capsys.readouterr()
    assert main(["run", "--out", str(link), "--duration", "0.1"]) == 2
    assert "symbolic link" in _one_error_line(capsys)
    assert out.is_dir() and link.is_symlink()


def test_plot_inside_out_joins_the_set(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "--out", str(out), "--plot", str(out / "loop.pdf"), "--duration", "0.1"]) == 0
    files = json.loads((out / RUN_MANIFEST).read_text())["files"]
    assert set(files) == {"result.npz", "metrics.json", "scenario.toml", "loop.pdf"}
    assert (out / "loop.pdf").read_bytes().startswith(b"%PDF") and written_by_us(out / "loop.pdf")
    capsys.readouterr()
    for plot in (out / "sub" / "x.png", out / "metrics.json"):
        assert main(["run", "--out", str(out), "--plot", str(plot), "--duration", "0.1"]) == 2
        assert "inside --out" in _one_error_line(capsys)
    for video in (out / "sub" / "v.gif", out / "result.npz"):
        assert main(["run", "--out", str(out), "--video", str(video), "--duration", "0.1"]) == 2
        assert "inside --out" in _one_error_line(capsys)


def test_plot_and_video_on_one_file_are_refused(tmp_path, capsys):
    for a, b in (("x.gif", "x.gif"), ("x.gif", "./x.gif")):
        assert main(["run", "--plot", str(tmp_path / a), "--video", str(tmp_path / b), "--duration", "0.1"]) == 2
        assert "same file" in _one_error_line(capsys)
    assert not list(tmp_path.iterdir())


def test_check_output_folder_accepts_new_empty_and_own_folders(tmp_path):
    check_output_folder(tmp_path / "new", ["a.csv"])
    (tmp_path / "empty").mkdir()
    check_output_folder(tmp_path / "empty", ["a.csv"])
    own = tmp_path / "own"
    own.mkdir()
    (own / "a.csv").write_text("x\n")
    (own / RUN_MANIFEST).write_text(json.dumps({"files": {"a.csv": 2}}))
    check_output_folder(own, ["a.csv"])
    (own / RUN_MANIFEST).write_text("not json")
    with pytest.raises(InvalidArgument, match="not a run output"):
        check_output_folder(own, ["a.csv"])


# ------------------------------------------------------------ trade-off set
def test_tradeoff_writes_its_three_files_as_one_set(tmp_path, monkeypatch):
    from shinro_ctrl.analysis import tradeoff

    out = tmp_path / "t"
    first = tradeoff.run_tradeoff("cartpole_lqr", "R", 0.1, 1.0, points=2, workers=1, out=out)
    assert set(json.loads((out / RUN_MANIFEST).read_text())["files"]) == set(tradeoff.OUTPUT_FILES)
    before = {n: (out / n).read_bytes() for n in tradeoff.OUTPUT_FILES}
    assert written_by_us(out / "tradeoff.png")

    def killed(self, path):  # the process dies after the CSV and JSON are written, before the plot
        raise KeyboardInterrupt

    monkeypatch.setattr(tradeoff.TradeoffResult, "plot", killed)
    with pytest.raises(KeyboardInterrupt):
        first.save(out)
    assert {n: (out / n).read_bytes() for n in tradeoff.OUTPUT_FILES} == before  # the old set, whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t"]  # no temporaries left
    user = tmp_path / "u"
    user.mkdir()
    (user / "tradeoff.csv").write_text("mine")
    monkeypatch.undo()
    with pytest.raises(InvalidArgument, match="not a run output"):
        first.save(user)
    assert (user / "tradeoff.csv").read_text() == "mine"
