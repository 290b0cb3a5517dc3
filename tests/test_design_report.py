"""The HTML design report: CLI output, self-contained page, rendered in headless Chromium with every image loaded."""

from __future__ import annotations

import base64
import re
import shutil
import subprocess

import pytest

from shinro_ctrl.cli import main

CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--hide-scrollbars",
]
# Appended to a copy of the page: counts the images that failed to decode once everything has loaded.
CHECK_SCRIPT = """<script>window.addEventListener("load", () => {
  const im = [...document.images];
  const bad = im.filter(i => !i.complete || i.naturalWidth === 0).length;
  const p = document.createElement("pre"); p.id = "imgcheck";
  p.textContent = "IMAGES " + im.length + " BROKEN " + bad; document.body.appendChild(p);
});</script>"""


def _chromium() -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:  # .ci/run installs Debian's chromium; a missing browser is a failure, not a skip
        pytest.fail("chromium is not installed (apt-get install chromium; .ci/run does it)")
    return exe


def _image_check(html_path, profile) -> tuple[int, int]:
    page = html_path.with_name(html_path.stem + "_check.html")
    page.write_text(
        html_path.read_text(encoding="utf-8").replace("</body>", CHECK_SCRIPT + "</body>"), encoding="utf-8"
    )
    out = subprocess.run(
        [
            _chromium(),
            *CHROMIUM_FLAGS,
            f"--user-data-dir={profile}",
            "--virtual-time-budget=10000",
            "--dump-dom",
            page.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    m = re.search(r"IMAGES (\d+) BROKEN (\d+)", out.stdout)
    assert m, f"the check script did not run; chromium said: {out.stderr[-500:]}"
    return int(m.group(1)), int(m.group(2))


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    d = tmp_path_factory.mktemp("report")
    path = d / "cartpole.html"
    return path


def test_design_prints_analysis_and_writes_report(report, capsys):
    assert main(["design", "lqr", "cartpole_lqr.toml", "--report", str(report)]) == 0
    out = capsys.readouterr().out
    for text in ("ζ_min", "controllability rank 4/4", "GM low", "disk α", "Ms = ", "initial: theta", "report:"):
        assert text in out
    html = report.read_text(encoding="utf-8")
    assert html.startswith("<!DOCTYPE html>")
    # self-contained: every image is an embedded PNG that decodes, no external resource
    images = re.findall(r'<img [^>]*src="([^"]+)"', html)
    assert len(images) == 5
    for src in images:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    assert not re.search(r'(src|href)="(https?:|file:|//)', html)
    for heading in ("Closed-loop poles", "Controllability and observability", "Stability margins", "Gain K"):
        assert heading in html


def test_report_renders_in_chromium_with_every_image(report, tmp_path):
    if not report.exists():
        assert main(["design", "lqr", "cartpole_lqr.toml", "--report", str(report)]) == 0
    assert _image_check(report, tmp_path / "profile1") == (5, 0)
    shot = tmp_path / "report.png"
    subprocess.run(
        [
            _chromium(),
            *CHROMIUM_FLAGS,
            f"--user-data-dir={tmp_path / 'profile2'}",
            "--window-size=1100,5200",
            f"--screenshot={shot}",
            report.as_uri(),
        ],
        capture_output=True,
        timeout=120,
    )
    data = shot.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 50_000  # a page with plots, not a blank one


def test_image_check_detects_a_broken_image(report, tmp_path):
    # the check must be able to fail: corrupt one embedded PNG
    if not report.exists():
        assert main(["design", "lqr", "cartpole_lqr.toml", "--report", str(report)]) == 0
    html = report.read_text(encoding="utf-8")
    broken = tmp_path / "broken.html"
    broken.write_text(html.replace("data:image/png;base64,iVBOR", "data:image/png;base64,AAAAA", 1), encoding="utf-8")
    assert _image_check(broken, tmp_path / "profile") == (5, 1)


def test_report_for_mimo_and_mpc(tmp_path, capsys):
    quad = tmp_path / "quad.html"
    assert main(["design", "lqr", "quadrotor_lqr.toml", "--report", str(quad)]) == 0
    assert "simultaneous disk margin" in capsys.readouterr().out
    assert quad.read_text(encoding="utf-8").count("data:image/png;base64,") == 5
    assert main(["design", "mpc", "cartpole_mpc.toml"]) == 0
    assert "unconstrained first move" in capsys.readouterr().out


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--report", "cartpole_lqr.toml"], "FILE.html"),
        (["--report", "notes.html"], "not an HTML report"),
        (["--points", "5"], "go with --tradeoff"),
    ],
)
def test_report_and_option_errors_are_one_line(extra, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.html").write_text("my notes", encoding="utf-8")
    assert main(["design", "lqr", "cartpole_lqr.toml", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert (tmp_path / "notes.html").read_text(encoding="utf-8") == "my notes"


def test_the_response_plots_carry_units_and_the_tables_whole_names():
    import numpy as np

    from shinro_ctrl.analysis import analyze_controller, loop_margins
    from shinro_ctrl.analysis.report import report_figures
    from shinro_ctrl.controllers import LQR
    from shinro_ctrl.plants import CartPole

    plant = CartPole(dt=0.01)
    ctrl = LQR.from_plant(plant, [10, 1, 100, 1, 1], [0.1], integral=["x"])
    a = analyze_controller(ctrl, x_init=[0, 0, 0.2, 0], tracked=["x"])  # names from the plant, not passed
    assert a.state_names == (*plant.state_names, "∫x") and a.input_names == plant.input_names
    figures = report_figures(a)
    response = next(fig for caption, fig in figures.items() if "response" in caption.lower())
    labels = [ax.get_ylabel() for ax in response.axes if ax.get_visible()]
    for want in ("x [m]", "x_dot [m/s]", "theta [rad]", "theta_dot [rad/s]", "∫x [m s]", "force [N] (input)"):
        assert want in labels, (want, labels)
    # a long input name is printed whole (it was cut to 'elbow_moto')
    A, B = np.diag([0.9, 0.8]), np.eye(2)
    text = loop_margins((A, B), 0.5 * np.eye(2), dt=0.01, input_names=["shoulder_motor", "elbow_motor"]).format()
    rows = [line for line in text.splitlines() if "motor" in line]
    assert rows[0].split()[0] == "shoulder_motor" and rows[1].split()[0] == "elbow_motor"
    assert len({line.index(" ", 4 + len("shoulder_motor")) for line in rows}) == 1  # the columns still align
