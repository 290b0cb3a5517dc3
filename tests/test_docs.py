"""The docs site: it builds in strict mode, and the prose pages keep up with the code."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def mkdocs_build(config: Path, site: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    return subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(config), "-d", str(site)],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=ROOT,
        env=env,
    )


def warnings_of(res: subprocess.CompletedProcess) -> str:
    return "\n".join(line for line in res.stderr.splitlines() if "WARNING" in line or "ERROR" in line)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    res = mkdocs_build(ROOT / "mkdocs.yml", out)
    assert res.returncode == 0, f"mkdocs build --strict failed:\n{warnings_of(res) or res.stderr[-3000:]}"
    return out


def test_site_builds_strict_with_every_page(site):
    for page in ("index", "concepts", "scenarios", "cli", "videos"):
        assert (site / f"{page}.html").is_file()
    api = {p.stem for p in (site / "api").glob("*.html")}
    assert {"plants", "controllers", "engine", "sim", "config", "linearization", "errors", "regression"} <= api
    assert {"testing", "video", "crosscheck", "support"} <= api
    assert not (site / "griffe_shinro.py").exists()


@pytest.mark.parametrize(
    "page,anchors",
    [
        ("plants", ["shinro_ctrl.plants.base.Plant.linearize", "shinro_ctrl.plants.cartpole.CartPole"]),
        ("controllers", ["shinro_ctrl.controllers.lqr.LQR.from_plant", "shinro_ctrl.controllers.mpc.LinearMPC"]),
        ("engine", ["shinro_ctrl.engine.MujocoEngine.for_plant", "shinro_ctrl.engine.OffscreenRenderer.render"]),
        ("sim", ["shinro_ctrl.sim.RobotSim.run", "shinro_ctrl.sim.SimResult"]),
        ("config", ["shinro_ctrl.config.load_scenario", "shinro_ctrl.config.REFERENCE_KINDS"]),
        ("errors", ["shinro_ctrl.errors.ShinroError", "shinro_ctrl.errors.SimulationDiverged"]),
        ("regression", ["shinro_ctrl.regression.run_regression", "shinro_ctrl.regression.DEFAULT_TOLERANCES"]),
        ("testing", ["shinro_ctrl.testing.assert_matches_baseline"]),
        ("video", ["shinro_ctrl.video.render_rollout", "shinro_ctrl.video.select_gl_backend"]),
    ],
)
def test_api_pages_are_generated_from_docstrings(site, page, anchors):
    html = (site / "api" / f"{page}.html").read_text(encoding="utf-8")
    for anchor in anchors:
        assert f'id="{anchor}"' in html, f"{anchor} missing from api/{page}.html"


def test_docstring_markup_is_rendered_not_shown_raw(site):
    for html_file in (site / "api").glob("*.html"):
        html = html_file.read_text(encoding="utf-8")
        assert not re.search(r":(class|meth|func|attr|data|mod|exc):<code>", html), html_file.name
        assert ".. math::" not in html, html_file.name
        assert "<autoref" not in html, html_file.name
    # Sphinx roles became real links between pages.
    plants = (site / "api" / "plants.html").read_text(encoding="utf-8")
    assert 'href="errors.html#shinro_ctrl.errors.NonFiniteError"' in plants


def test_broken_cross_reference_fails_the_strict_build(tmp_path):
    """The guard CI relies on: a reference to something that does not exist stops the build."""
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "index.md").write_text(
        "# Probe\n\nSee [the root error][shinro_ctrl.errors.ShinroError] "
        "and [a typo][shinro_ctrl.errors.ShinroEror].\n\n::: shinro_ctrl.errors\n",
        encoding="utf-8",
    )
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    config = re.sub(r"(?ms)^nav:.*", "", config).replace("docs_dir: docs", f"docs_dir: {docs}")
    # mkdocstrings resolves these relative to the config file: point them back at the repository.
    config = config.replace("docs/griffe_shinro.py", str(DOCS / "griffe_shinro.py")).replace(
        "paths: [.]", f"paths: [{ROOT}]"
    )
    (tmp_path / "mkdocs.yml").write_text(config, encoding="utf-8")
    res = mkdocs_build(tmp_path / "mkdocs.yml", tmp_path / "site")
    assert res.returncode != 0
    assert "shinro_ctrl.errors.ShinroEror" in res.stderr


# ------------------------------------------------------- prose pages vs code
def test_cli_page_documents_every_subcommand_and_option():
    from shinro_ctrl.cli import build_parser

    text = (DOCS / "cli.md").read_text(encoding="utf-8")
    parser = build_parser()
    (subparsers,) = [a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction"]
    for name, sub in subparsers.choices.items():
        assert f"## `{name}`" in text, f"docs/cli.md has no section for `{name}`"
        section = text.split(f"## `{name}`", 1)[1].split("\n## ", 1)[0]
        for action in sub._actions:
            for opt in action.option_strings:
                if opt not in ("-h", "--help"):
                    assert opt in section, f"docs/cli.md: `{name}` section does not mention {opt}"
    assert "--debug" in text
    from shinro_ctrl.plants import PLANT_ALIASES

    for alias in PLANT_ALIASES:
        assert f"`{alias}`" in text, f"docs/cli.md does not list the plant alias {alias}"


def test_scenarios_page_documents_every_table_key_and_reference_kind():
    from shinro_ctrl.config import ENGINE_KEYS, REFERENCE_KINDS, SIM_KEYS, TABLES
    from shinro_ctrl.controllers import CONTROLLERS, controller_class, controller_keys
    from shinro_ctrl.plants import PLANT_ALIASES, PLANTS
    from shinro_ctrl.sim.metrics import METRICS

    text = (DOCS / "scenarios.md").read_text(encoding="utf-8")
    for table in TABLES:
        assert f"## `[{table}]`" in text
    for key in (*ENGINE_KEYS, *SIM_KEYS, *METRICS):
        assert f"`{key}`" in text, key
    for kind, (required, optional) in REFERENCE_KINDS.items():
        assert f"| `{kind}` |" in text, kind
        for key in (*required, *optional):
            assert f"`{key}`" in text, f"reference kind {kind}: {key}"
    aliases = {cls: alias for alias, cls in PLANT_ALIASES.items()}
    for name, cls in PLANTS.items():
        assert f"`{name}`" in text, name
        if name in aliases:
            assert f"`{name}` (`{aliases[name]}`)" in text, f"alias of {name}"
        for key in cls.config_keys():
            assert f"`{key}`" in text, f"[plant] {name}: {key}"
    for name in CONTROLLERS:
        assert f"`{name}`" in text, name
        for key in controller_keys(controller_class(name)):
            assert f"`{key}`" in text, f"[controller] {name}: {key}"


def test_every_error_is_exported_from_the_package_and_named_in_the_readme():
    import shinro_ctrl
    import shinro_ctrl.errors

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    table = readme.split("## Errors", 1)[1].split("\n## ", 1)[0]
    for name in shinro_ctrl.errors.__all__:
        assert getattr(shinro_ctrl, name) is getattr(shinro_ctrl.errors, name) and name in shinro_ctrl.__all__, name
        assert re.search(rf"`(shinro_ctrl\.errors\.)?{name}`", table), f"README's Errors section does not name {name}"


def test_no_source_file_points_at_a_file_that_is_not_in_the_repository():
    """Docstrings and comments once cited a project note (API-NOTES) that ships elsewhere."""
    bad = [
        str(path.relative_to(ROOT))
        for path in [*(ROOT / "shinro_ctrl").rglob("*.py"), *DOCS.glob("*.md"), ROOT / "README.md"]
        if re.search(r"API[-_ ]NOTES", path.read_text(encoding="utf-8"))
    ]
    assert not bad, bad


# ------------------------------------------------------- the griffe extension
@pytest.fixture(scope="module")
def ext():
    spec = importlib.util.spec_from_file_location("griffe_shinro", DOCS / "griffe_shinro.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_grouped_entries_become_one_per_name(ext):
    doc = (
        "Summary.\n\nArgs:\n    a, b: Bounds ``(m,)``.\n        More text.\n    c: Alone.\n\n"
        "Returns:\n    x, y: kept.\n"
    )
    out = ext.expand_grouped_entries(doc)
    assert (
        "    a: Bounds ``(m,)``.\n        More text.\n    b: Bounds ``(m,)``.\n        More text.\n    c: Alone." in out
    )
    assert "    x, y: kept." in out  # only argument, attribute and raises sections are touched


def test_grouped_names_may_wrap(ext):
    doc = "Args:\n    plant: P.\n    u_min, u_max,\n    soft:\n        As above.\n"
    out = ext.expand_grouped_entries(doc)
    assert out.splitlines() == [
        "Args:",
        "    plant: P.",
        "    u_min:",
        "        As above.",
        "    u_max:",
        "        As above.",
        "    soft:",
        "        As above.",
    ]


def test_math_blocks_become_fenced_latex(ext):
    doc = "Text\n\n.. math::\n\n    a = b\n      + c\n\nAfter."
    assert ext.convert_math_blocks(doc) == "Text\n\n```latex\na = b\n  + c\n```\n\nAfter."
