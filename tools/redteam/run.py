"""Run the red-team probes against a shinro_ctrl tree and count the outcomes by category and class.

Usage (from anywhere)::

    /work/main/.venv/bin/python tools/redteam/run.py --tree /path/to/checkout --json results/x.json --md results/x.md

See README.md next to this file.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # 2 shared cores; fork-safe BLAS
    os.environ.setdefault(_var, "1")
os.environ["MPLBACKEND"] = "Agg"
if not os.environ.get("MUJOCO_GL") and not os.environ.get("DISPLAY"):
    # MuJoCo reads MUJOCO_GL once, at its import, and the parent imports it before any probe: pick the offscreen
    # backend the CLI would pick (osmesa, else egl) so `--video` probes render as they would from a shell
    import ctypes.util

    os.environ["MUJOCO_GL"] = "osmesa" if ctypes.util.find_library("OSMesa") else "egl"


def _parse() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tree", type=Path, default=HERE.parent.parent, help="checkout whose shinro_ctrl is probed")
    p.add_argument("--workers", type=int, default=2, help="probes at a time (at most 2)")
    p.add_argument("--only", action="append", default=[], help="a category (repeatable), or a probe-id prefix")
    p.add_argument("--json", type=Path, help="write every probe's result here")
    p.add_argument("--md", type=Path, help="write the summary table (Markdown) here")
    p.add_argument("--keep", action="store_true", help="keep the probes' temporary folders")
    p.add_argument("--list", action="store_true", help="list the probes and exit")
    p.add_argument("--quiet", action="store_true", help="no per-failure lines, only progress")
    return p.parse_args()


def _preimport() -> list[str]:
    """Import what the probes use once in the parent, so every forked child starts warm."""
    import importlib

    missing = []
    for name in (
        "numpy",
        "scipy.linalg",
        "casadi",
        "mujoco",
        "matplotlib.pyplot",
        "shinro_ctrl",
        "shinro_ctrl.cli",
        "shinro_ctrl.plants",
        "shinro_ctrl.controllers",
        "shinro_ctrl.estimators",
        "shinro_ctrl.config",
        "shinro_ctrl.sim",
        "shinro_ctrl.planning",
        "shinro_ctrl.analysis",
        "shinro_ctrl.sweep",
        "shinro_ctrl.video",
        "shinro_ctrl.regression",
    ):
        try:
            importlib.import_module(name)
        except Exception:
            missing.append(name)
    try:
        import shinro_ctrl.controllers as c

        c._import_all()
    except Exception:
        pass
    return missing


def _git_status(tree: Path) -> str:
    try:
        return subprocess.run(
            ["git", "-C", str(tree), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=30,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return ""


def main() -> int:
    args = _parse()
    tree = args.tree.resolve()
    sys.path.insert(0, str(HERE))
    sys.path.insert(0, str(tree))
    os.environ["PYTHONPATH"] = str(tree)  # pool workers and subprocesses import the same tree

    import harness
    import probes_cli
    import probes_files
    import probes_models
    import probes_numerics
    import probes_scenario
    import probes_signals
    import probes_threads

    configs = tree / "configs"
    probes = [
        *probes_cli.probes(configs),
        *probes_scenario.probes(configs),
        *probes_models.probes(configs, tree),
        *probes_numerics.probes(),
        *probes_files.probes(configs),
        *probes_signals.probes(configs),
        *probes_threads.probes(),
    ]
    ids = [p.pid for p in probes]
    dup = [i for i, n in collections.Counter(ids).items() if n > 1]
    if dup:
        raise SystemExit(f"duplicate probe ids: {dup[:5]}")
    if args.only:
        probes = [p for p in probes if p.category in args.only or any(p.pid.startswith(o) for o in args.only)]
    if args.list:
        for p in probes:
            print(p.pid, p.kind, p.expect, " ".join(p.argv))
        print(f"{len(probes)} probes")
        return 0

    t0 = time.monotonic()
    missing = _preimport()
    import shinro_ctrl

    print(f"tree {tree} (shinro_ctrl from {Path(shinro_ctrl.__file__).parent})", flush=True)
    if missing:
        print(f"not importable in this tree: {', '.join(missing)}", flush=True)
    import signal

    def _stop(signum: int, frame: object) -> None:  # imports may have replaced the handlers; Ctrl-C must stop us
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    before = _git_status(tree)
    print(f"{len(probes)} probes, {args.workers} workers, import {time.monotonic() - t0:.1f} s", flush=True)

    results: list[dict] = []
    done = collections.Counter()
    total = len(probes)

    def report(probe: harness.Probe, info: harness.RunInfo, cls: str, detail: str) -> None:
        done[cls] += 1
        results.append(
            {
                "id": probe.pid,
                "category": probe.category,
                "kind": probe.kind,
                "argv": probe.argv,
                "expect": probe.expect,
                "class": cls,
                "detail": detail,
                "rc": info.rc,
                "elapsed": round(info.elapsed, 3),
                "stderr_tail": info.stderr[-600:],
            }
        )
        n = len(results)
        if cls not in ("ok", harness.NA) and not args.quiet:
            print(f"  [{cls}] {probe.pid}: {detail[:200]}", flush=True)
        if n % 25 == 0 or n == total:
            counts = " ".join(f"{k}={v}" for k, v in sorted(done.items()))
            print(f"[{n}/{total}] {time.monotonic() - t0:.0f} s  {counts}", flush=True)

    tmp = Path(tempfile.mkdtemp(prefix="shinro-redteam-"))
    try:
        runner = harness.Runner(tmp, tree, sys.executable, workers=args.workers, keep=args.keep)
        runner.run(probes, report)
    finally:
        if not args.keep:
            import shutil

            shutil.rmtree(tmp, ignore_errors=True)
    elapsed = time.monotonic() - t0
    after = _git_status(tree)
    table = summary(results, elapsed, tree, before != after)
    print(table)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        payload = {"tree": str(tree), "elapsed_s": round(elapsed, 1), "probes": sorted(results, key=lambda r: r["id"])}
        args.json.write_text(json.dumps(payload, indent=1) + "\n")
    if args.md:
        args.md.parent.mkdir(parents=True, exist_ok=True)
        args.md.write_text(table + "\n")
    return 0


def summary(results: list[dict], elapsed: float, tree: Path, tree_changed: bool) -> str:
    """Category x class counts as a Markdown table, n/a counted apart."""
    import harness

    cats = list(harness.CATEGORIES)
    classes = [*list(harness.CLASSES), "harness_error"]
    counts: dict[tuple[str, str], int] = collections.Counter((r["category"], r["class"]) for r in results)
    used = [c for c in classes if any(counts[(k, c)] for k in cats) or c in harness.CLASSES]
    lines = [
        f"Red-team of `{tree}`: {sum(1 for r in results if r['class'] != harness.NA)} probes counted "
        f"({sum(1 for r in results if r['class'] == harness.NA)} n/a), {elapsed / 60:.1f} min",
        "",
        "| category | " + " | ".join(used) + " | failures | probes |",
        "|---|" + "---|" * (len(used) + 2),
    ]
    for cat in [*cats, "total"]:
        keys = cats if cat == "total" else [cat]
        row = [sum(counts[(k, c)] for k in keys) for c in used]
        fails = sum(v for c, v in zip(used, row, strict=True) if c != "ok")
        lines.append(f"| {cat} | " + " | ".join(str(v) for v in row) + f" | {fails} | {sum(row)} |")
    if tree_changed:
        lines.append("\nWARNING: the tree's tracked files changed during the run (git status differs).")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
