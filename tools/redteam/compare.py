"""Compare two red-team result files (before -> after): counts per class and the probes whose class changed.

Usage::

    python tools/redteam/compare.py tools/redteam/results/before.json tools/redteam/results/after.json
"""

from __future__ import annotations

import argparse
import collections
import json
from pathlib import Path

CLASSES = ("ok", "data_loss", "wrong_answer_exit0", "hang", "traceback", "misleading_message", "segfault", "n/a")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("before", type=Path)
    p.add_argument("after", type=Path)
    p.add_argument("--changed", action="store_true", help="list every probe whose class changed")
    args = p.parse_args()
    a = {r["id"]: r for r in json.loads(args.before.read_text())["probes"]}
    b = {r["id"]: r for r in json.loads(args.after.read_text())["probes"]}
    common = sorted(a.keys() & b.keys())
    ca = collections.Counter(a[i]["class"] for i in common)
    cb = collections.Counter(b[i]["class"] for i in common)
    print(f"{len(common)} probes in both ({len(a) - len(common)} only before, {len(b) - len(common)} only after)\n")
    print("| class | before | after |\n|---|---|---|")
    for c in sorted(set(ca) | set(cb), key=lambda c: CLASSES.index(c) if c in CLASSES else 99):
        print(f"| {c} | {ca[c]} | {cb[c]} |")
    moved = collections.Counter((a[i]["class"], b[i]["class"]) for i in common if a[i]["class"] != b[i]["class"])
    print("\n| before -> after | probes |\n|---|---|")
    for (x, y), n in moved.most_common():
        print(f"| {x} -> {y} | {n} |")
    if args.changed:
        for i in common:
            if a[i]["class"] != b[i]["class"]:
                print(f"{i}: {a[i]['class']} -> {b[i]['class']}: {b[i]['detail'][:160]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
