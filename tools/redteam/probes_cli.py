"""CLI arguments: every subcommand with bad numbers, empty strings, huge counts, malformed vectors, conflicting
flags, missing files and wrong extensions."""

from __future__ import annotations

from pathlib import Path

from fixtures import chain, user_file, write_text
from harness import Probe, RunInfo, huge_entries_oracle

CAT = "cli"
PLANTS = {"cartpole": 4, "pendulum": 2, "double_pendulum": 4, "quadrotor": 12, "holonomic": 3, "arm6": 6}
INPUTS = {"cartpole": 1, "pendulum": 1, "double_pendulum": 2, "quadrotor": 4, "holonomic": 3, "arm6": 6}
BAD_VECTORS = {
    "empty": "",
    "blank": "   ",
    "double_comma": "0,,0",
    "trailing_comma": "0,",
    "letters": "a,b",
    "nan": "nan",
    "inf": "inf",
    "huge": "1e308",
    "overflow": "1e400",
    "one_too_few": None,  # filled per plant
    "one_too_many": None,
    "semicolons": "0;0",
    "pi_div0": "pi/0",
    "nested": "[[0]]",
}


def _vec(n: int, v: str = "0") -> str:
    return ",".join([v] * n)


def _file_exists(name: str, magic: bytes | None = None):
    def oracle(info: RunInfo) -> str | None:
        p = info.workdir / name
        if not p.exists():
            return f"exit 0 but {name} was not written"
        if magic is not None and not p.read_bytes().startswith(magic):
            return f"{name} is not a {magic[:5]!r} file (wrong format for its extension)"
        return None

    return oracle


def probes(configs: Path) -> list[Probe]:
    out: list[Probe] = []

    def add(name: str, argv: list[str], expect: str = "either", needles: tuple[str, ...] = (), **kw) -> None:
        out.append(Probe(f"{CAT}/{name}", CAT, argv=argv, expect=expect, needles=needles, **kw))

    # ---- top level
    add("no_args", [], "ok")
    add("help", ["--help"], "ok")
    add("unknown_command", ["bogus"], "refuse", ("bogus",), bad_flag=True)
    add("empty_command", [""], "refuse", ("invalid choice", "command"), bad_flag=True)
    add("unknown_top_flag", ["--bogus"], "refuse", ("--bogus",), bad_flag=True)
    add("debug_only", ["--debug"], "ok")
    add("list", ["list"], "ok")
    add("list_extra_arg", ["list", "extra"], "refuse", ("extra",), bad_flag=True)
    valid = {
        "run": ["run", "cartpole_lqr"],
        "plan": ["plan", "cartpole_swingup_mujoco"],
        "design": ["design", "lqr", "cartpole_lqr"],
        "regress": ["regress"],
        "sweep": ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.05:0.5", "--out", "sw"],
        "linearize": ["linearize", "cartpole"],
        "crosscheck": ["crosscheck", "cartpole"],
    }
    for cmd, args in valid.items():
        add(f"{cmd}_unknown_flag", [*args, "--frobnicate", "1"], "refuse", ("--frobnicate",), bad_flag=True)
        add(f"{cmd}_help", [cmd, "--help"], "ok")

    # ---- linearize / crosscheck: vectors and eps over every plant
    for cmd in ("linearize", "crosscheck"):
        plants = PLANTS if cmd == "linearize" else {k: PLANTS[k] for k in ("cartpole", "pendulum", "quadrotor")}
        for plant, n in plants.items():
            add(f"{cmd}_{plant}_default", [cmd, plant], "ok")
            m = INPUTS[plant]
            for vname, vec in BAD_VECTORS.items():
                for flag, dim in (("--x0", n), ("--u0", m)):
                    if vec is None:
                        v = _vec(dim - 1) if vname == "one_too_few" else _vec(dim + 1)
                        if dim - 1 == 0 and vname == "one_too_few":
                            continue
                    else:
                        v = vec
                    if vname in ("nan", "inf", "huge", "overflow") and dim > 1:
                        v = ",".join([vec] + ["0"] * (dim - 1))
                    expect = "refuse" if vname not in ("huge",) else "either"
                    needles = (flag.lstrip("-"), "state", "input")
                    if vname in ("one_too_few", "one_too_many", "empty", "blank", "double_comma", "trailing_comma"):
                        needles = (flag.lstrip("-"),)
                    if vname == "huge":
                        needles = (*needles, "eps")
                    add(f"{cmd}_{plant}_{flag[2:]}_{vname}", [cmd, plant, flag + "=" + v], expect, needles)
            for eps in ("0", "-1e-6", "nan", "inf", "1e-300", "1e300", "abc", ""):
                expect = "refuse"
                add(f"{cmd}_{plant}_eps_{eps or 'empty'}", [cmd, plant, "--eps=" + eps], expect, ("eps",))
        add(f"{cmd}_unknown_plant", [cmd, "acrobat"], "refuse", ("acrobat",))
        add(f"{cmd}_empty_plant", [cmd, ""], "refuse", ("plant", "''", "empty"))
        add(f"{cmd}_missing_file", [cmd, "nothere.xml"], "refuse", ("nothere.xml",))
        add(f"{cmd}_scenario_file", [cmd, str(configs / "cartpole_lqr.toml")], "ok")
        add(f"{cmd}_scenario_name", [cmd, "cartpole_lqr"], "either", ("cartpole_lqr",))
        add(f"{cmd}_directory", [cmd, "."], "refuse", ("'.'", "folder", "directory", "."))
        add(f"{cmd}_plot_txt", [cmd, "cartpole", "--plot", "p.txt"], "either", ("plot", ".txt"))
    add("linearize_eps_sweep", ["linearize", "cartpole", "--eps-sweep"], "ok")
    add(
        "linearize_eps_sweep_plot",
        ["linearize", "cartpole", "--eps-sweep", "--plot", "s.png"],
        "ok",
        oracle=_file_exists("s.png", b"\x89PNG"),
    )
    add("linearize_plot_without_sweep", ["linearize", "cartpole", "--plot", "s.png"], "either", ("--plot", "eps-sweep"))
    add("linearize_eps_sweep_plot_pdf", ["linearize", "cartpole", "--eps-sweep", "--plot", "s.pdf"], "either", ("pdf",))
    add(
        "crosscheck_plot", ["crosscheck", "cartpole", "--plot", "c.png"], "ok", oracle=_file_exists("c.png", b"\x89PNG")
    )
    add(
        "crosscheck_plot_pdf",
        ["crosscheck", "cartpole", "--plot", "c.pdf"],
        "either",
        ("pdf",),
        oracle=_file_exists("c.pdf", b"%PDF"),
    )
    add("crosscheck_holonomic", ["crosscheck", "holonomic"], "either", ("holonomic",))
    for pitch in ("pi/2", "-pi/2", "1.5707963267948966", "1.5707963", "1.57079632679"):
        x0 = ",".join(["0", "0", "0", "0", pitch, "0"] + ["0"] * 6)
        for cmd in ("linearize", "crosscheck"):
            add(
                f"{cmd}_quadrotor_gimbal_{pitch}",
                [cmd, "quadrotor", "--x0=" + x0],
                "either",
                ("pitch", "singular", "gimbal", "euler"),
                oracle=huge_entries_oracle(1e8),
            )

    # ---- run
    add("run_default", ["run"], "ok")
    add("run_empty_config", ["run", ""], "refuse", ("config", "empty", "''"))
    add("run_missing_config", ["run", "nothere.toml"], "refuse", ("nothere",))
    add("run_unknown_name", ["run", "cartpole_lqrr"], "refuse", ("cartpole_lqrr",))
    add("run_directory", ["run", "."], "refuse", ("'.'", "folder", "directory"))
    add("run_json_ext", ["run", "s.json"], "refuse", ("s.json", "toml"), setup=write_text("s.json", "{}"))
    add("run_yaml_ext", ["run", "s.yaml"], "refuse", ("s.yaml", "toml"), setup=write_text("s.yaml", "a: 1\n"))
    add(
        "run_noext",
        ["run", "scen"],
        "either",
        ("scen",),
        setup=write_text("scen", (configs / "cartpole_lqr.toml").read_text()),
    )
    add(
        "run_upper_ext",
        ["run", "S.TOML"],
        "either",
        ("S.TOML",),
        setup=write_text("S.TOML", (configs / "cartpole_lqr.toml").read_text()),
    )
    add("run_empty_file", ["run", "e.toml"], "refuse", ("plant", "empty", "e.toml"), setup=write_text("e.toml", ""))
    add(
        "run_binary_file",
        ["run", "b.toml"],
        "refuse",
        ("b.toml", "utf-8", "toml"),
        setup=write_text("b.toml", b"\x00\xff\xfe\x80garbage"),
    )
    add("run_engine_bogus", ["run", "cartpole_lqr", "--engine", "bogus"], "refuse", ("engine",))
    add("run_engine_empty", ["run", "cartpole_lqr", "--engine", ""], "refuse", ("engine",))
    add("run_engine_both", ["run", "cartpole_lqr", "--engine", "both"], "ok")
    add("run_engine_mujoco", ["run", "cartpole_lqr", "--engine", "mujoco"], "ok")
    add(
        "run_engine_mujoco_arm",
        ["run", "arm_ikqp", "--engine", "mujoco", "--duration", "0.5"],
        "either",
        ("engine", "mujoco"),
    )
    for d in ("", "abc", "nan", "inf", "-inf", "-1", "0", "1e-9", "0.005", "0.015", "1e308", "1e400", "0x10", "1,2"):
        expect = "refuse" if d not in ("0x10",) else "either"
        add(f"run_duration_{d or 'empty'}", ["run", "cartpole_lqr", "--duration=" + d], expect, ("duration",))
    add("run_duration_ok", ["run", "cartpole_lqr", "--duration", "1"], "ok")
    add("run_duration_twice", ["run", "cartpole_lqr", "--duration", "1", "--duration", "2"], "either", ("duration",))
    add("run_plot_png", ["run", "cartpole_lqr", "--plot", "r.png"], "ok", oracle=_file_exists("r.png", b"\x89PNG"))
    add(
        "run_plot_pdf",
        ["run", "cartpole_lqr", "--plot", "r.pdf"],
        "either",
        ("pdf",),
        oracle=_file_exists("r.pdf", b"%PDF"),
    )
    add(
        "run_plot_svg",
        ["run", "cartpole_lqr", "--plot", "r.svg"],
        "either",
        ("svg",),
        oracle=_file_exists("r.svg", b"<?xml"),
    )
    add("run_plot_noext", ["run", "cartpole_lqr", "--plot", "r"], "either", ("plot", "extension"))
    add("run_plot_csv", ["run", "cartpole_lqr", "--plot", "r.csv"], "refuse", ("csv", "plot"))
    add("run_plot_empty", ["run", "cartpole_lqr", "--plot", ""], "refuse", ("plot",))
    add("run_plot_missing_dir", ["run", "cartpole_lqr", "--plot", "nodir/r.png"], "either", ("nodir", "plot"))
    add(
        "run_plot_is_dir",
        ["run", "cartpole_lqr", "--plot", "d"],
        "refuse",
        ("'d'", "plot", "folder", "directory"),
        setup=lambda wd: (wd / "d").mkdir(),
    )
    add(
        "run_plot_equals_video",
        ["run", "cartpole_lqr", "--plot", "x.gif", "--video", "x.gif"],
        "refuse",
        ("--plot", "--video", "same"),
    )
    add(
        "run_plot_inside_out",
        ["run", "cartpole_lqr", "--out", "o", "--plot", "o/extra.png"],
        "either",
        ("--plot", "--out"),
    )
    add("run_video_avi", ["run", "cartpole_lqr", "--duration", "0.2", "--video", "v.avi"], "refuse", ("avi", "video"))
    add("run_video_empty", ["run", "cartpole_lqr", "--video", ""], "refuse", ("video",))
    add(
        "run_video_gif",
        ["run", "pendulum_lqr_mujoco", "--duration", "0.3", "--video", "v.gif"],
        "ok",
        oracle=_file_exists("v.gif", b"GIF8"),
    )
    add("run_out_empty", ["run", "cartpole_lqr", "--out", ""], "refuse", ("out",))
    add(
        "run_out_is_file",
        ["run", "cartpole_lqr", "--out", "f.txt"],
        "refuse",
        ("f.txt", "out"),
        setup=write_text("f.txt", "x"),
    )
    add("run_out_twice_ours", ["run", "cartpole_lqr", "--out", "o"], "ok", setup=_previous_out())
    add("run_plan_missing", ["run", "cartpole_swingup_mujoco", "--plan", "nothere.npz"], "refuse", ("nothere",))
    add(
        "run_plan_garbage",
        ["run", "cartpole_swingup_mujoco", "--plan", "g.npz"],
        "refuse",
        ("g.npz", "plan"),
        setup=write_text("g.npz", b"garbage not a zip"),
    )
    add(
        "run_plan_text",
        ["run", "cartpole_swingup_mujoco", "--plan", "g.txt"],
        "refuse",
        ("g.txt", "plan"),
        setup=write_text("g.txt", "hello"),
    )
    add(
        "run_plan_empty_zip",
        ["run", "cartpole_swingup_mujoco", "--plan", "z.npz"],
        "refuse",
        ("z.npz", "plan"),
        setup=write_text("z.npz", b"PK\x05\x06" + b"\x00" * 18),
    )
    add(
        "run_plan_on_lqr",
        ["run", "cartpole_lqr", "--plan", "g.npz"],
        "refuse",
        ("plan",),
        setup=write_text("g.npz", b"x"),
    )
    add(
        "run_plan_wrong_plant",
        ["run", "heavy.toml", "--plan", "p.npz"],
        "refuse",
        ("cart_mass", "plan", "plant"),
        setup=_foreign_plan(configs),
        timeout=90,
    )
    add("run_two_configs", ["run", "cartpole_lqr", "cartpole_mpc"], "refuse", ("cartpole_mpc",), bad_flag=True)

    # ---- plan
    add("plan_ok", ["plan", "cartpole_swingup_mujoco", "--out", "o"], "ok")
    add("plan_no_plan_table", ["plan", "cartpole_lqr"], "refuse", ("plan",))
    add("plan_missing_config", ["plan", "nothere.toml"], "refuse", ("nothere",))
    add("plan_empty_config", ["plan", ""], "refuse", ("config", "empty", "''"))
    add(
        "plan_out_is_file",
        ["plan", "cartpole_swingup_mujoco", "--out", "f.txt"],
        "refuse",
        ("f.txt", "out"),
        setup=write_text("f.txt", "x"),
    )
    add(
        "plan_plot_csv", ["plan", "cartpole_swingup_mujoco", "--out", "o", "--plot", "p.csv"], "refuse", ("csv", "plot")
    )
    add(
        "plan_plot_png",
        ["plan", "cartpole_swingup_mujoco", "--out", "o", "--plot", "p.png"],
        "ok",
        oracle=_file_exists("p.png", b"\x89PNG"),
    )

    # ---- design
    for kind, scen in (("lqr", "cartpole_lqr"), ("mpc", "cartpole_mpc")):
        add(f"design_{kind}", ["design", kind, scen], "ok")
        add(f"design_{kind}_missing", ["design", kind, "nothere.toml"], "refuse", ("nothere",))
        add(f"design_{kind}_empty", ["design", kind, ""], "refuse", ("config", "''", "empty"))
        add(f"design_{kind}_report", ["design", kind, scen, "--report", "r.html"], "ok", oracle=_file_exists("r.html"))
        add(f"design_{kind}_report_txt", ["design", kind, scen, "--report", "r.txt"], "either", ("html", "report"))
        add(f"design_{kind}_report_empty", ["design", kind, scen, "--report", ""], "refuse", ("report",))
    add("design_bogus_kind", ["design", "pid", "cartpole_lqr"], "refuse", ("pid", "kind"), bad_flag=True)
    add("design_lqr_on_ikqp", ["design", "lqr", "arm_ikqp"], "either", ("lqr", "controller", "IKQP"))
    add("design_mpc_on_lqr_scenario", ["design", "mpc", "cartpole_lqr"], "either", ("mpc", "horizon"))
    add("design_lqr_on_nmpc", ["design", "lqr", "pendulum_nmpc_mujoco"], "either", ("lqr",))
    add("design_mpc_quadrotor", ["design", "mpc", "quadrotor_mpc_mujoco"], "either", ("mpc",))
    tradeoffs = {
        "missing_eq": ("R", "refuse"),
        "empty_range": ("R=", "refuse"),
        "half_range": ("R=1:", "refuse"),
        "letters": ("R=a:b", "refuse"),
        "reversed": ("R=2:1", "either"),
        "zero_lo": ("R=0:1", "refuse"),
        "negative": ("R=-1:1", "refuse"),
        "nan": ("R=nan:1", "refuse"),
        "inf": ("R=1:inf", "refuse"),
        "index_out": ("Q[9]=1:10", "refuse"),
        "index_neg": ("Q[-1]=1:10", "either"),
        "index_bad": ("Q[x]=1:10", "refuse"),
        "unknown_key": ("X=1:2", "refuse"),
        "empty": ("", "refuse"),
        "equal_bounds": ("R=1:1", "either"),
    }
    for name, (spec, expect) in tradeoffs.items():
        needles = ("tradeoff", "R", "Q")
        add(
            f"design_tradeoff_{name}",
            ["design", "lqr", "cartpole_lqr", "--tradeoff", spec, "--points", "3", "--workers", "1", "--out", "t"],
            expect,
            needles,
        )
    add(
        "design_tradeoff_ok",
        ["design", "lqr", "cartpole_lqr", "--tradeoff", "R=1e-2:1", "--points", "3", "--workers", "1", "--out", "t"],
        "ok",
        timeout=120,
    )
    add(
        "design_tradeoff_q_ok",
        ["design", "lqr", "cartpole_lqr", "--tradeoff", "Q[2]=1:1000", "--points", "3", "--workers", "1", "--out", "t"],
        "ok",
        timeout=120,
    )
    for pts, expect in (
        ("0", "refuse"),
        ("-1", "refuse"),
        ("1", "either"),
        ("1e9", "refuse"),
        ("1000000000", "refuse"),
        ("10000000000000000000000", "refuse"),
        ("abc", "refuse"),
        ("", "refuse"),
    ):
        add(
            f"design_tradeoff_points_{pts or 'empty'}",
            [
                "design",
                "lqr",
                "cartpole_lqr",
                "--tradeoff",
                "R=1e-2:1",
                "--points=" + pts,
                "--workers",
                "1",
                "--out",
                "t",
            ],
            expect,
            ("points",),
        )
    for w, expect in (("0", "refuse"), ("-1", "refuse"), ("1000", "either"), ("x", "refuse")):
        add(
            f"design_tradeoff_workers_{w}",
            [
                "design",
                "lqr",
                "cartpole_lqr",
                "--tradeoff",
                "R=1e-2:1",
                "--points",
                "3",
                "--workers=" + w,
                "--out",
                "t",
            ],
            expect,
            ("workers",),
            timeout=120,
        )
    add(
        "design_tradeoff_mpc",
        ["design", "mpc", "cartpole_mpc", "--tradeoff", "R=1e-2:1", "--points", "3", "--out", "t"],
        "either",
        ("tradeoff", "lqr", "mpc"),
    )
    add("design_out_without_tradeoff", ["design", "lqr", "cartpole_lqr", "--out", "t"], "either", ("--out", "tradeoff"))
    add(
        "design_points_without_tradeoff",
        ["design", "lqr", "cartpole_lqr", "--points", "5"],
        "either",
        ("--points", "tradeoff"),
    )
    add(
        "design_tradeoff_out_is_file",
        [
            "design",
            "lqr",
            "cartpole_lqr",
            "--tradeoff",
            "R=1e-2:1",
            "--points",
            "3",
            "--workers",
            "1",
            "--out",
            "f.txt",
        ],
        "refuse",
        ("f.txt", "out"),
        setup=write_text("f.txt", "x"),
    )

    # ---- regress
    add("regress_missing_dir", ["regress", "nothere"], "refuse", ("nothere",))
    add("regress_empty_dir", ["regress", "d"], "either", ("d", "scenario", "no "), setup=lambda wd: (wd / "d").mkdir())
    add("regress_not_toml", ["regress", "x.txt"], "refuse", ("x.txt", "toml"), setup=write_text("x.txt", "hello"))
    add("regress_one_shipped", ["regress", str(configs / "regression" / "cartpole_lqr.toml")], "ok", ok_rcs=(1,))
    add(
        "regress_no_baseline",
        ["regress", "d"],
        "either",
        ("baseline",),
        ok_rcs=(1,),
        setup=_copy(configs / "cartpole_lqr.toml", "d/s.toml"),
    )
    add(
        "regress_update_copy",
        ["regress", "d", "--update"],
        "ok",
        setup=_copy(configs / "cartpole_lqr.toml", "d/s.toml"),
    )
    add(
        "regress_bad_baseline",
        ["regress", "d"],
        "refuse",
        ("baseline", "s.baseline.json"),
        ok_rcs=(1,),
        setup=chain(_copy(configs / "cartpole_lqr.toml", "d/s.toml"), write_text("d/s.baseline.json", "{not json")),
    )
    add(
        "regress_nan_baseline",
        ["regress", "d"],
        "either",
        ("baseline", "nan"),
        ok_rcs=(1,),
        setup=chain(
            _copy(configs / "cartpole_lqr.toml", "d/s.toml"),
            write_text("d/s.baseline.json", '{"metrics": {"rms_error": NaN}}'),
        ),
    )
    add("regress_empty_arg", ["regress", ""], "refuse", ("dir", "''", "empty"))

    # ---- sweep
    base = ["sweep", "cartpole_lqr", "--out", "sw", "--samples", "3"]
    params = {
        "empty": ("", "refuse"),
        "no_eq": ("plant.pole_mass", "refuse"),
        "no_range": ("plant.pole_mass=1", "either"),
        "letters": ("plant.pole_mass=a:b", "refuse"),
        "unknown_key": ("plant.bogus=0:1", "refuse"),
        "unknown_table": ("bogus.pole_mass=0:1", "refuse"),
        "reversed": ("plant.pole_mass=0.5:0.05", "either"),
        "negative_mass": ("plant.pole_mass=-1:-0.5", "refuse"),
        "zero_mass": ("plant.pole_mass=0:0", "refuse"),
        "nan": ("plant.pole_mass=nan:1", "refuse"),
        "inf": ("plant.pole_mass=0.1:inf", "refuse"),
        "huge": ("plant.pole_mass=1e300:1e301", "either"),
        "string_key": ("plant.type=0:1", "refuse"),
        "dt": ("plant.dt=0.001:0.05", "either"),
        "ok": ("plant.pole_mass=0.05:0.5", "ok"),
        "controller_key": ("controller.R=0.01:1", "either"),
        "controller_vector": ("controller.Q=1:2", "either"),
    }
    for name, (spec, expect) in params.items():
        needles = ("param", spec.split("=")[0] or "param")
        add(f"sweep_param_{name}", [*base, "--param", spec], expect, needles, timeout=90)
    ok_param = ["--param", "plant.pole_mass=0.05:0.5"]
    for s, expect in (("0", "refuse"), ("-1", "refuse"), ("1", "ok"), ("1000000000", "refuse"), ("x", "refuse")):
        add(
            f"sweep_samples_{s}",
            ["sweep", "cartpole_lqr", "--out", "sw", *ok_param, "--samples=" + s],
            expect,
            ("samples",),
            timeout=90,
        )
    for w, expect in (("0", "refuse"), ("-1", "refuse"), ("2", "ok"), ("1000", "either")):
        add(f"sweep_workers_{w}", [*base, *ok_param, "--workers=" + w], expect, ("workers",), timeout=120)
    add("sweep_seed_negative", [*base, *ok_param, "--seed=-1"], "either", ("seed",))
    add("sweep_grid", [*base, *ok_param, "--grid"], "ok")
    add(
        "sweep_grid_huge",
        [
            "sweep",
            "cartpole_lqr",
            "--out",
            "sw",
            *ok_param,
            "--param",
            "plant.cart_mass=0.3:1",
            "--grid",
            "--samples",
            "100000",
        ],
        "refuse",
        ("samples", "grid"),
    )
    add("sweep_no_out", ["sweep", "cartpole_lqr", *ok_param], "refuse", ("--out",), bad_flag=True)
    add("sweep_no_param", ["sweep", "cartpole_lqr", "--out", "sw"], "refuse", ("--param",), bad_flag=True)
    add(
        "sweep_scheduler_malformed",
        [*base, *ok_param, "--scheduler", "tcp://[::1"],
        "refuse",
        ("scheduler", "tcp://[::1"),
    )
    add("sweep_scheduler_empty", [*base, *ok_param, "--scheduler", ""], "refuse", ("scheduler",))
    add(
        "sweep_method_dask_no_scheduler",
        [*base, *ok_param, "--method", "dask"],
        "either",
        ("dask", "scheduler"),
        timeout=90,
    )
    add(
        "sweep_method_batch_workers",
        [*base, *ok_param, "--method", "batch", "--workers", "2"],
        "either",
        ("batch", "workers"),
    )
    add("sweep_method_serial", [*base, *ok_param, "--method", "serial"], "ok")
    add("sweep_method_pool", [*base, *ok_param, "--method", "pool", "--workers", "2"], "ok", timeout=120)
    add("sweep_method_bogus", [*base, *ok_param, "--method", "bogus"], "refuse", ("method",))
    for tol, expect in (("-1", "refuse"), ("0", "either"), ("nan", "refuse"), ("inf", "either"), ("x", "refuse")):
        add(f"sweep_stable_tol_{tol}", [*base, *ok_param, "--stable-tol=" + tol], expect, ("stable-tol", "stable_tol"))
    add("sweep_metric_bogus", [*base, *ok_param, "--metric", "bogus"], "refuse", ("bogus", "metric"))
    add("sweep_metric_empty", [*base, *ok_param, "--metric", ""], "refuse", ("metric",))
    add(
        "sweep_out_is_file",
        ["sweep", "cartpole_lqr", "--out", "f.txt", "--samples", "3", *ok_param],
        "refuse",
        ("f.txt", "out"),
        setup=write_text("f.txt", "x"),
    )
    add("sweep_engine_mujoco", [*base, *ok_param, "--engine", "mujoco"], "ok", timeout=90)
    add("sweep_missing_config", ["sweep", "nothere.toml", "--out", "sw", *ok_param], "refuse", ("nothere",))
    return out


def _copy(src: Path, dst: str):
    return write_text(dst, src.read_text())


def _previous_out():
    """A folder written by an earlier `run --out` of ours (must be replaceable)."""

    def setup(wd: Path) -> None:
        import os

        from shinro_ctrl.cli import main

        cwd = os.getcwd()
        os.chdir(wd)
        try:
            import contextlib
            import io

            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                main(["run", "cartpole_lqr", "--duration", "0.5", "--out", "o"])
        finally:
            os.chdir(cwd)

    return setup


def _foreign_plan(configs: Path):
    """A plan solved for a 0.5 kg cart, tracked on a 5 kg cart."""

    text = (configs / "cartpole_swingup_mujoco.toml").read_text()

    def setup(wd: Path) -> None:
        import contextlib
        import io
        import os

        from shinro_ctrl.cli import main

        cwd = os.getcwd()
        os.chdir(wd)
        try:
            (wd / "light.toml").write_text(text)
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                main(["plan", "light.toml", "--out", "planned"])
            found = sorted((wd / "planned").glob("*.npz"))
            if found:
                found[0].rename(wd / "p.npz")
            heavy = text.replace("cart_mass = 0.5", "cart_mass = 5.0")
            (wd / "heavy.toml").write_text(heavy)
        finally:
            os.chdir(cwd)

    return setup


__all__ = ["probes", "user_file"]
