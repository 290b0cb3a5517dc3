"""Scenario keys: the shipped configs with every key mutated (wrong types, NaN/inf, negative/zero/huge, empty
arrays, wrong lengths, unknown and misspelled keys) plus whole-file damage (BOM, non-UTF-8, broken TOML)."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path
from typing import Any

from fixtures import Raw, dump_toml, write_text
from harness import Probe

CAT = "scenario"
BASES = (
    "cartpole_lqr",
    "cartpole_mpc",
    "cartpole_lqg",
    "cartpole_lqi_disturbance_mujoco",
    "pendulum_nmpc_mujoco",
    "quadrotor_lqr",
    "arm_ikqp",
    "cartpole_swingup_mujoco",
    "holonomic_mujoco",
    "double_pendulum_lqr",
    "furuta_lqr_mujoco",
    "pendulum_ekf_mujoco",
    "quadrotor_wind_mpc_mujoco",
)
MAX_DURATION = 3.0  # keep each run short; the mutated key decides the outcome, not the length of the run


PER_BASE = 48  # mutations kept per base scenario (a deterministic spread over its keys), plus the file-level ones


def _thin(out: list[Probe], start: int, keep: int) -> None:
    """Keep ``keep`` of the probes added since ``start``, evenly spread (the first, unchanged one always)."""
    added = out[start:]
    if len(added) <= keep:
        return
    step = len(added) / keep
    del out[start:]
    out.extend(added[int(i * step)] for i in range(keep))


def _leaves(doc: dict[str, Any], prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], Any]]:
    out = []
    for k, v in doc.items():
        if isinstance(v, dict):
            out.extend(_leaves(v, (*prefix, k)))
        else:
            out.append(((*prefix, k), v))
    return out


def _set(doc: dict[str, Any], path: tuple[str, ...], value: Any) -> None:
    for k in path[:-1]:
        doc = doc[k]
    doc[path[-1]] = value


def _delete(doc: dict[str, Any], path: tuple[str, ...]) -> None:
    for k in path[:-1]:
        doc = doc[k]
    del doc[path[-1]]


def _mutations(value: Any) -> list[tuple[str, Any, str]]:
    """(name, new value, expectation) for one leaf value."""
    if isinstance(value, bool):
        return [("str", "yes", "refuse"), ("int", 1, "either")]
    if isinstance(value, int | float):
        return [
            ("str", "abc", "refuse"),
            ("nan", float("nan"), "refuse"),
            ("inf", float("inf"), "either"),
            ("neg", -abs(value) - 1.0, "either"),
            ("zero", 0, "either"),
            ("huge", 1e300, "either"),
            ("list", [value], "either"),
            ("bool", True, "refuse"),
        ]
    if isinstance(value, str):
        return [("int", 123, "refuse"), ("empty", "", "refuse"), ("bogus", "bogus_value", "either")]
    if isinstance(value, list):
        muts: list[tuple[str, Any, str]] = [
            ("empty", [], "either"),
            ("scalar", 1.0 if value and not isinstance(value[0], str) else "x", "either"),
        ]
        if value and all(isinstance(x, int | float) and not isinstance(x, bool) for x in value):
            muts += [
                ("longer", [*value, value[-1]], "either"),
                ("shorter", value[:-1], "either"),
                ("elem_nan", [float("nan"), *value[1:]], "refuse"),
                ("elem_str", ["a", *value[1:]], "refuse"),
                ("elem_neg", [-abs(x) - 1.0 for x in value], "either"),
                ("nested", [value], "either"),
            ]
        elif value and all(isinstance(x, str) for x in value):
            muts += [("elem_bogus", ["bogus", *value[1:]], "refuse"), ("elem_int", [1, *value[1:]], "refuse")]
        return muts
    return []


def probes(configs: Path) -> list[Probe]:
    out: list[Probe] = []
    for base in BASES:
        path = configs / f"{base}.toml"
        if not path.exists():
            continue
        doc = tomllib.loads(path.read_text())
        sim = doc.setdefault("sim", {})
        if isinstance(sim.get("duration"), int | float):
            sim["duration"] = min(float(sim["duration"]), MAX_DURATION)
        if doc.get("plant", {}).get("type") == "MjcfPlant":
            model = doc["plant"].get("model")
            if isinstance(model, str) and not Path(model).is_absolute():
                found = next((p for p in (configs / model, configs.parent / "assets" / model) if p.exists()), None)
                if found is not None:
                    doc["plant"]["model"] = str(found)

        def add(name: str, text: str | bytes, expect: str, needles: tuple[str, ...], base: str = base) -> None:
            fname = f"{base}.toml"
            out.append(
                Probe(
                    f"{CAT}/{base}/{name}",
                    CAT,
                    argv=["run", fname],
                    expect=expect,
                    needles=needles,
                    setup=write_text(fname, text),
                    timeout=60,
                )
            )

        start = len(out)
        add("unchanged", dump_toml(doc), "ok", ())
        for keypath, value in _leaves(doc):
            dotted = ".".join(keypath)
            leaf = keypath[-1]
            needles = (leaf,)
            if leaf in ("dt", "duration"):
                needles = ("dt", "duration")
            if leaf == "model":
                continue  # the model file has its own category
            for mname, new, expect in _mutations(value):
                found = needles
                if leaf == "type" and keypath[0] in ("plant", "controller", "engine"):
                    if mname == "bogus":
                        expect = "refuse"
                    found = (*needles, f"unknown {keypath[0]}")
                if expect == "either":  # a valid value whose run diverges may be refused as such
                    found = (*found, "became non-finite", "diverged", "infeasible")
                d = copy.deepcopy(doc)
                _set(d, keypath, new)
                add(f"{dotted}={mname}", dump_toml(d), expect, found)
            d = copy.deepcopy(doc)
            _delete(d, keypath)
            add(f"{dotted}=missing", dump_toml(d), "either", (leaf,))
        _thin(out, start + 1, PER_BASE)
        for table in [k for k, v in doc.items() if isinstance(v, dict)]:
            d = copy.deepcopy(doc)
            d[table]["bogus_key"] = 1.0
            add(f"{table}.bogus_key=unknown", dump_toml(d), "refuse", ("bogus_key",))
            keys = [k for k in doc[table] if len(k) > 3 and k != "type"]
            if keys:
                k = keys[0]
                d = copy.deepcopy(doc)
                d[table][k[:-1]] = d[table].pop(k)
                add(f"{table}.{k}=misspelled", dump_toml(d), "refuse", (k[:-1],))
        d = copy.deepcopy(doc)
        d["bogus_table"] = {"a": 1}
        add("bogus_table=unknown", dump_toml(d), "refuse", ("bogus_table",))
        text = dump_toml(doc)
        add("file=bom", b"\xef\xbb\xbf" + text.encode(), "either", ("BOM", "byte order"))
        add("file=latin1_comment", b"# caf\xe9 \xff\n" + text.encode(), "refuse", ("utf-8", "utf8", "encoding"))
        add("file=utf16", text.encode("utf-16"), "refuse", ("utf-8", "utf-16", "encoding", "BOM"))
        add("file=broken_toml", text + "\n[plant\n", "refuse", ("line", "toml"))
        add(
            "file=duplicate_key",
            text.replace("[plant]\n", "[plant]\ndt = 0.01\ndt = 0.02\n", 1),
            "refuse",
            ("dt", "duplicate"),
        )
        add("file=crlf", text.replace("\n", "\r\n"), "ok", ())
        add(
            "file=raw_token",
            text.replace("[sim]\n", f"[sim]\nbad = {Raw('1.2.3')}\n", 1),
            "refuse",
            ("line", "toml", "bad"),
        )
    # specific findings of the earlier red-team, as scenario files
    lqr = tomllib.loads((configs / "cartpole_lqr.toml").read_text())

    def variant(name: str, expect: str, needles: tuple[str, ...], **tables: dict[str, Any]) -> None:
        d = copy.deepcopy(lqr)
        for t, kv in tables.items():
            d.setdefault(t, {}).update(kv)
        out.append(
            Probe(
                f"{CAT}/finding/{name}",
                CAT,
                argv=["run", "s.toml"],
                expect=expect,
                needles=needles,
                setup=write_text("s.toml", dump_toml(d)),
            )
        )

    variant("lqr_u_max_1_rise_time", "either", ("u_max",), controller={"u_max": [1.0], "u_min": [-1.0]})
    variant("lqr_x0_not_equilibrium", "refuse", ("x0", "equilibrium"), controller={"x0": [0.0, 1.0, 0.0, 0.0]})
    variant("lqr_u0_not_equilibrium", "refuse", ("u0", "equilibrium"), controller={"u0": [1.0]})
    variant("track_limits_zero_width", "refuse", ("track_limits",), plant={"track_limits": [0.0, 0.0]})
    variant("track_limits_reversed", "refuse", ("track_limits",), plant={"track_limits": [1.0, -1.0]})
    variant("dt_longer_than_duration", "refuse", ("dt", "duration"), plant={"dt": 10.0}, sim={"duration": 0.5})
    variant("duration_not_whole_steps", "refuse", ("duration", "dt"), sim={"duration": 1.005})
    variant("dt_tiny", "either", ("dt",), plant={"dt": 1e-9}, sim={"duration": 1e-6})
    variant("R_zero", "refuse", ("R",), controller={"R": [0.0]})
    variant("Q_negative", "refuse", ("Q",), controller={"Q": [-1.0, 1.0, 1.0, 1.0]})
    mpc = tomllib.loads((configs / "cartpole_mpc.toml").read_text())
    d = copy.deepcopy(mpc)
    d["controller"].update({"horizon": 1, "terminal_cost": "Q"})
    out.append(
        Probe(
            f"{CAT}/finding/mpc_horizon1_terminal_Q",
            CAT,
            argv=["run", "s.toml"],
            expect="refuse",
            needles=("horizon", "terminal"),
            setup=write_text("s.toml", dump_toml(d)),
        )
    )
    d = copy.deepcopy(mpc)
    d["controller"].update({"osqp_settings": {"eps_abs": float("nan")}})
    out.append(
        Probe(
            f"{CAT}/finding/mpc_osqp_settings_nan",
            CAT,
            argv=["run", "s.toml"],
            expect="refuse",
            needles=("eps_abs", "osqp_settings"),
            setup=write_text("s.toml", dump_toml(d)),
        )
    )
    d = copy.deepcopy(mpc)
    d["controller"].update({"soft": True, "x_min": [-0.05, -1e9, -1e9, -1e9], "x_max": [0.05, 1e9, 1e9, 1e9]})
    out.append(
        Probe(
            f"{CAT}/finding/mpc_soft_tight_bounds",
            CAT,
            argv=["run", "s.toml"],
            expect="either",
            needles=("soft", "x_max"),
            setup=write_text("s.toml", dump_toml(d)),
        )
    )
    nm = tomllib.loads((configs / "pendulum_nmpc_mujoco.toml").read_text())
    d = copy.deepcopy(nm)
    d["sim"]["duration"] = 2.0
    d["controller"].update({"soft": True, "x_min": [-0.01, -0.01], "x_max": [0.01, 0.01]})
    out.append(
        Probe(
            f"{CAT}/finding/nmpc_soft_infeasible_bounds",
            CAT,
            argv=["run", "s.toml"],
            expect="ok",
            setup=write_text("s.toml", dump_toml(d)),
        )
    )
    d = copy.deepcopy(nm)
    d["sim"]["duration"] = 2.0
    d["controller"].update(
        {"soft": True, "x_min": [-0.01, -0.01], "x_max": [0.01, 0.01], "iterations": 1, "cold_start": "ipopt"}
    )
    out.append(
        Probe(
            f"{CAT}/finding/nmpc_soft_ipopt",
            CAT,
            argv=["run", "s.toml"],
            expect="ok",
            setup=write_text("s.toml", dump_toml(d)),
        )
    )
    sw = tomllib.loads((configs / "cartpole_swingup_mujoco.toml").read_text())
    for key, val in (("knots", 20000), ("knots", 1), ("knots", 0), ("substeps", 100000000), ("method", "bogus")):
        d = copy.deepcopy(sw)
        d["plan"][key] = val
        out.append(
            Probe(
                f"{CAT}/finding/plan_{key}_{val}",
                CAT,
                argv=["plan", "s.toml", "--out", "o"],
                expect="refuse",
                needles=(key,),
                setup=write_text("s.toml", dump_toml(d)),
            )
        )
    return out
