"""Build an exported folder with the system compiler, check its objects use no heap, run its test program.

The build runs in a temporary copy (the exported folder keeps only sources); the Makefile's flags are
``-std=c99 -Wall -Wextra -Werror -pedantic``. :func:`heap_symbols` reads ``nm`` of the controller's
objects (everything but the test program) for ``malloc``/``calloc``/``realloc``/``free``.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from shinro_ctrl.errors import ExportError

__all__ = ["HEAP_FUNCTIONS", "BuildResult", "build_and_verify", "heap_symbols", "make"]

HEAP_FUNCTIONS = ("malloc", "calloc", "realloc", "free")


@dataclass(frozen=True)
class BuildResult:
    """The verification of one exported folder.

    Attributes:
        ok: Built, no heap, and every recorded step agreed.
        steps: Recorded steps replayed.
        max_rel_err: Largest ``|u_C − u_Python| / max(1, |u_Python|)``.
        clamped: Steps the C reported ``INPUT_CLAMPED``.
        errors: Steps with an error status.
        disagreements: Input entries beyond the tolerance.
        c_step_ns: Median C step time [ns] measured by the test program (None when not timed).
        heap: Heap functions the controller's objects reference (should be empty).
        output: The test program's output.
    """

    ok: bool
    steps: int
    max_rel_err: float
    clamped: int
    errors: int
    disagreements: int
    c_step_ns: float | None
    heap: tuple[str, ...]
    output: str

    def summary(self) -> str:
        """One line."""
        s = (
            f"{self.steps} steps, max relative error {self.max_rel_err:.2e}, {self.disagreements} disagreements, "
            f"{self.errors} error statuses, {self.clamped} clamped"
        )
        if self.heap:
            s += f"; the controller references {', '.join(self.heap)}"
        return s


def make(folder: Path, *targets: str, cflags: str = "-O2") -> None:
    """Run the folder's Makefile (``make -s CFLAGS=... targets``).

    Raises:
        ExportError: no ``make``/compiler, or the build failed (its first error line).
    """
    if shutil.which("make") is None:
        raise ExportError("building the exported C needs 'make' and a C compiler on PATH")
    proc = subprocess.run(
        ["make", "-s", f"CFLAGS={cflags}", *targets], cwd=folder, capture_output=True, text=True, check=False
    )
    if proc.returncode != 0:
        lines = [ln for ln in (proc.stderr + proc.stdout).splitlines() if "error" in ln.lower()] or [
            (proc.stderr or proc.stdout).strip().splitlines()[-1] if (proc.stderr or proc.stdout).strip() else "?"
        ]
        raise ExportError(f"building {folder} failed: {lines[0].strip()}")


def heap_symbols(objects: list[Path]) -> tuple[str, ...]:
    """Heap functions (``malloc``, ...) that ``nm`` lists as undefined references in ``objects``."""
    if shutil.which("nm") is None:
        raise ExportError("checking the exported objects needs 'nm' (binutils) on PATH")
    found = set()
    for obj in objects:
        proc = subprocess.run(["nm", "-u", str(obj)], capture_output=True, text=True, check=True)
        for line in proc.stdout.splitlines():
            sym = line.split()[-1] if line.split() else ""
            sym = sym.split("@")[0]
            if sym in HEAP_FUNCTIONS:
                found.add(sym)
    return tuple(sorted(found))


def build_and_verify(folder: Path, name: str, *, cflags: str = "-O2", time_step: bool = True) -> BuildResult:
    """Build a copy of ``folder``, check for heap use and run ``NAME_test NAME_data.txt [--time]``.

    Raises:
        ExportError: the build failed or the test program could not run.
    """
    with tempfile.TemporaryDirectory(prefix="shinro_export_build_") as tmp:
        work = Path(tmp) / folder.name
        shutil.copytree(folder, work)
        make(work, f"{name}_test", cflags=cflags)  # the objects, the static library and the test program
        objs = sorted(p for p in work.glob("*.o") if p.name != f"{name}_test.o")
        heap = heap_symbols(objs)
        args = [str(work / f"{name}_test"), str(work / f"{name}_data.txt")]
        if time_step:
            args.append("--time")
        proc = subprocess.run(args, cwd=work, capture_output=True, text=True, check=False)
    out = proc.stdout + proc.stderr
    m = re.search(
        r"agreement steps=(\d+) max_rel_err=(\S+) clamped=(\d+) errors=(\d+) disagreements=(\d+)", proc.stdout
    )
    if m is None:
        raise ExportError(f"the exported test program failed: {out.strip().splitlines()[-1] if out.strip() else '?'}")
    t = re.search(r"timing median_ns=(\S+)", proc.stdout)
    return BuildResult(
        ok=proc.returncode == 0 and not heap,
        steps=int(m.group(1)),
        max_rel_err=float(m.group(2)),
        clamped=int(m.group(3)),
        errors=int(m.group(4)),
        disagreements=int(m.group(5)),
        c_step_ns=float(t.group(1)) if t else None,
        heap=heap,
        output=out,
    )
