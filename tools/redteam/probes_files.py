"""File safety: every output path pointed at a user's own file (PNG, GIF, HTML, CSV, JSON, ...), directly and
through a symlink, and every output folder holding a user's own files; the user's bytes must survive."""

from __future__ import annotations

from pathlib import Path

from fixtures import USER_FILES, chain, user_file, user_folder
from harness import Probe

CAT = "files"
TRADEOFF = ["design", "lqr", "cartpole_lqr", "--tradeoff", "R=1e-2:1", "--points", "3", "--workers", "1"]

# (name, argv with {f} for the output path, the output's natural extension)
WRITERS: list[tuple[str, list[str], str]] = [
    ("run_plot", ["run", "cartpole_lqr", "--duration", "0.5", "--plot", "{f}"], "png"),
    ("run_video", ["run", "pendulum_lqr_mujoco", "--duration", "0.2", "--video", "{f}"], "gif"),
    ("design_report", ["design", "lqr", "cartpole_lqr", "--report", "{f}"], "html"),
    ("linearize_plot", ["linearize", "cartpole", "--eps-sweep", "--plot", "{f}"], "png"),
    ("crosscheck_plot", ["crosscheck", "cartpole", "--plot", "{f}"], "png"),
    ("plan_plot", ["plan", "cartpole_swingup_mujoco", "--out", "o", "--plot", "{f}"], "png"),
]


def probes(configs: Path) -> list[Probe]:
    out: list[Probe] = []
    for wname, argv, natural in WRITERS:
        for kind in (natural, "csv", "json", "html" if natural != "html" else "png", "txt"):
            for link in (False, True):
                fname = f"mine.{natural}" if kind == natural else f"mine.{kind}"
                if kind != natural and link:
                    continue
                setup, check = user_file(fname, kind if kind != natural else natural, link=link)
                if kind != natural:
                    # a user's file of another type under the output's natural extension
                    fname = f"mine.{natural}"
                    setup, check = user_file(fname, kind)
                tag = f"{wname}/user_{kind}_as_{natural}{'_symlink' if link else ''}"
                out.append(
                    Probe(
                        f"{CAT}/{tag}",
                        CAT,
                        argv=[a.replace("{f}", fname) for a in argv],
                        expect="refuse",
                        needles=(fname, "exists", "overwrite", "not written by"),
                        setup=setup,
                        check=check,
                        timeout=90,
                    )
                )
        # a user's file behind a symlink to another folder, named differently
        setup, check = user_file(f"sub/mine.{natural}", natural, link=True)
        out.append(
            Probe(
                f"{CAT}/{wname}/symlink_in_subfolder",
                CAT,
                argv=[a.replace("{f}", f"sub/mine.{natural}") for a in argv],
                expect="refuse",
                needles=("mine", "exists", "overwrite"),
                setup=setup,
                check=check,
                timeout=90,
            )
        )
    # output folders holding a user's own files
    folders = [
        (
            "run_out_metrics",
            ["run", "cartpole_lqr", "--duration", "0.5", "--out", "d"],
            {"metrics.json": USER_FILES["json"]},
        ),
        ("run_out_run_png", ["run", "cartpole_lqr", "--duration", "0.5", "--out", "d"], {"run.png": USER_FILES["png"]}),
        (
            "run_out_scenario",
            ["run", "cartpole_lqr", "--duration", "0.5", "--out", "d"],
            {"scenario.toml": USER_FILES["toml"]},
        ),
        (
            "run_out_other_file",
            ["run", "cartpole_lqr", "--duration", "0.5", "--out", "d"],
            {"thesis.txt": USER_FILES["txt"]},
        ),
        (
            "run_out_result_npz",
            ["run", "cartpole_lqr", "--duration", "0.5", "--out", "d"],
            {"result.npz": USER_FILES["npz"]},
        ),
        (
            "sweep_out_csv",
            ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.05:0.5", "--samples", "2", "--out", "d"],
            {"sweep.csv": USER_FILES["csv"]},
        ),
        (
            "sweep_out_json",
            ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.05:0.5", "--samples", "2", "--out", "d"],
            {"sweep.json": USER_FILES["json"]},
        ),
        (
            "sweep_out_png",
            ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.05:0.5", "--samples", "2", "--out", "d"],
            {"sweep.png": USER_FILES["png"]},
        ),
        (
            "sweep_out_other",
            ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.05:0.5", "--samples", "2", "--out", "d"],
            {"notes.txt": USER_FILES["txt"]},
        ),
        ("tradeoff_out_csv", [*TRADEOFF, "--out", "d"], {"tradeoff.csv": USER_FILES["csv"]}),
        ("tradeoff_out_json", [*TRADEOFF, "--out", "d"], {"tradeoff.json": USER_FILES["json"]}),
        ("tradeoff_out_png", [*TRADEOFF, "--out", "d"], {"tradeoff.png": USER_FILES["png"]}),
        (
            "plan_out_npz",
            ["plan", "cartpole_swingup_mujoco", "--out", "d"],
            {"cartpole_swingup_mujoco_plan.npz": USER_FILES["npz"]},
        ),
    ]
    for name, argv, files in folders:
        setup, check = user_folder("d", files)
        if name.startswith("regress"):
            scen = (configs / "cartpole_lqr.toml").read_text()

            def write_scen(wd: Path, scen: str = scen) -> None:
                (wd / "d").mkdir(exist_ok=True)
                (wd / "d" / "s.toml").write_text(scen)

            setup = chain(setup, write_scen)
        out.append(
            Probe(
                f"{CAT}/folder/{name}",
                CAT,
                argv=argv,
                expect="either",
                needles=("d", "exists", "overwrite", "not written by"),
                setup=setup,
                check=check,
                timeout=120,
            )
        )
        # the same folder reached through a symlink
        setup_l, check_l = user_folder("real", files)

        def link(wd: Path) -> None:
            (wd / "d").symlink_to(wd / "real")

        if not name.startswith("regress"):
            out.append(
                Probe(
                    f"{CAT}/folder/{name}_symlink",
                    CAT,
                    argv=argv,
                    expect="either",
                    needles=("d", "exists", "overwrite", "not written by"),
                    setup=chain(setup_l, link),
                    check=check_l,
                    timeout=120,
                )
            )
    # --out naming a user's file
    for cmd in (
        ["run", "cartpole_lqr", "--duration", "0.5"],
        ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.05:0.5", "--samples", "2"],
        TRADEOFF,
        ["plan", "cartpole_swingup_mujoco"],
    ):
        setup, check = user_file("mine.json", "json")
        out.append(
            Probe(
                f"{CAT}/out_is_user_file/{cmd[0]}{'_tradeoff' if '--tradeoff' in cmd else ''}",
                CAT,
                argv=[*cmd, "--out", "mine.json"],
                expect="refuse",
                needles=("mine.json", "out"),
                setup=setup,
                check=check,
                timeout=90,
            )
        )
    # --plot into the --out folder of the same run, over a user's file there
    setup, check = user_folder("d", {"mine.png": USER_FILES["png"]})
    out.append(
        Probe(
            f"{CAT}/plot_inside_out_over_user_png",
            CAT,
            argv=["run", "cartpole_lqr", "--duration", "0.5", "--out", "d", "--plot", "d/mine.png"],
            expect="refuse",
            needles=("mine.png", "--plot", "--out"),
            setup=setup,
            check=check,
        )
    )
    return out
