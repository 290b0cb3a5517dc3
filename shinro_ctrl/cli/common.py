"""Shared pieces of the command line: the parser class, number and vector parsing, argument and output checks,
matrix printing and the one-line error report."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

import argparse
import math
import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from shinro_ctrl._interrupts import caused_by_interrupt
from shinro_ctrl.errors import InvalidArgument, ShinroError

__all__ = ["parse_number", "parse_vector", "path_arg", "side_by_side"]

EXIT_USER_ERROR = 2
_USER_ERRORS = (ShinroError, OSError)  # anything else is a bug and keeps its traceback


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors and our exit status."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise _UsageError(f"{self.prog}: {message}")


class _UsageError(Exception):
    pass


_PI_TERM = re.compile(r"^([+-]?)(\d*\.?\d*)\*?pi(?:/(\d+\.?\d*))?$")


def parse_number(text: str) -> float:
    """A float, also accepting ``pi``, ``-pi``, ``2pi``, ``pi/2``, ``0.5*pi``."""
    text = text.strip().lower()
    try:
        return float(text)
    except ValueError:
        pass
    m = _PI_TERM.match(text)
    if not m:
        raise InvalidArgument(f"not a number: '{text}'")
    sign = -1.0 if m.group(1) == "-" else 1.0
    factor = float(m.group(2)) if m.group(2) not in ("", ".") else 1.0
    div = float(m.group(3)) if m.group(3) else 1.0
    if div == 0.0:
        raise InvalidArgument(f"not a number: '{text}' (division by zero)")
    return sign * factor * math.pi / div


def parse_vector(text: str, *, what: str = "vector") -> np.ndarray:
    """A comma- or space-separated list of finite numbers (see :func:`parse_number`), optionally in ``[...]``.

    Raises:
        InvalidArgument: an empty vector or entry (``'0,,0'``, ``'0,'``), an unbalanced bracket,
            a token that is not a number, or a non-finite value; naming ``what`` and the text.
    """
    import numpy as np

    body = text.strip()
    if body.startswith("[") or body.endswith("]"):
        if not (body.startswith("[") and body.endswith("]")):
            raise InvalidArgument(f"{what}: unbalanced bracket in '{text}'")
        body = body[1:-1].strip()
    if not body:
        raise InvalidArgument(f"{what}: empty vector '{text}'")
    if "," in body:
        parts = [p.strip() for p in body.split(",")]
        if not all(parts):
            raise InvalidArgument(f"{what}: empty entry in '{text}' (two commas in a row, or a comma at an end)")
    else:
        parts = body.split()
    values = []
    for p in parts:
        try:
            v = parse_number(p)
        except InvalidArgument as exc:
            raise InvalidArgument(f"{what}: {exc} in '{text}'") from None
        if not math.isfinite(v):
            raise InvalidArgument(f"{what}: '{p}' is not a finite number in '{text}'")
        values.append(v)
    return np.array(values)


def _matrix_lines(M: np.ndarray, width: int = 11) -> list[str]:
    import numpy as np

    return [" ".join(f"{v + 0.0:{width}.5g}" for v in row) for row in np.atleast_2d(M)]


def side_by_side(blocks: Sequence[tuple[str, np.ndarray]], gap: str = "   ") -> str:
    """Render matrices next to each other under their titles."""
    cols = []
    for title, M in blocks:
        lines = _matrix_lines(M)
        w = max([len(title), *(len(s) for s in lines)])
        cols.append([title.ljust(w)] + [s.ljust(w) for s in lines])
    height = max(len(c) for c in cols)
    for c in cols:
        c.extend([" " * len(c[0])] * (height - len(c)))
    return "\n".join(gap.join(c[i] for c in cols).rstrip() for i in range(height))


# ------------------------------------------------------------ argument checks
def path_arg(text: str) -> str:
    """The argparse ``type`` of every path argument (``--out``, ``--plot``, ``--video``, ``--report``, ``--plan``,
    ``regress DIR``): an empty or blank path (an unset shell variable) is refused, never taken for ``'.'`` or
    ignored; argparse names the option in its one-line error (``argument --out: empty path ...``).

    Raises:
        argparse.ArgumentTypeError: the path is empty or blank.
    """
    if not text.strip():
        raise argparse.ArgumentTypeError(f"empty path {text!r} (an unset shell variable?): give a file or folder name")
    return text


RUN_FILES = ("result.npz", "metrics.json", "scenario.toml", "run.png")
RUN_FILES_BOTH = ("standalone", "mujoco", "run.png")
SWEEP_FILES = ("sweep.csv", "sweep.json", "sweep.png")
CROSSCHECK_PLANTS = ("pendulum", "cartpole", "double_pendulum", "quadrotor")  # plants with a MuJoCo state map
MAX_SAMPLES = 1_000_000
MAX_WORKERS = 256


#: The finite-difference steps ``--eps`` accepts: below, rounding swamps the difference (1e-300 divides
#: by a step that ``x + eps`` does not even register); above, truncation error swamps the derivative.
EPS_RANGE = (1e-12, 1e-1)


def _check_step(option: str, value: float) -> None:
    """A finite-difference step in :data:`EPS_RANGE`, finite (named with the range in the message)."""
    lo, hi = EPS_RANGE
    if not (math.isfinite(value) and lo <= value <= hi):
        raise InvalidArgument(f"{option} must be a finite step in [{lo:g}, {hi:g}] (finite differences), got {value:g}")


def _check_count(option: str, value: int, limit: int, *, low: int = 1) -> None:
    """An integer option in ``[low, limit]``; the limit is named in the message."""
    if not low <= value <= limit:
        raise InvalidArgument(f"{option} must be an integer in [{low}, {limit:,}] (the limit), got {value}")


#: The plot formats, for the help of every ``--plot`` (:data:`shinro_ctrl.plots._figure.PLOT_FORMATS`).
PLOT_HELP = "PNG, PDF or SVG by its extension: .png, .pdf, .svg"


def _check_output(path: str, inputs: Sequence[str | None] = ()) -> None:
    """``--plot``: a .png, .pdf or .svg name; no input, link, folder or file shinro-ctrl did not write."""
    from shinro_ctrl.files import check_not_input, check_output_file
    from shinro_ctrl.plots._figure import plot_format

    inputs = [i for i in inputs if i]
    try:
        fmt = plot_format(path, what="--plot")  # refuses another extension, naming --plot and the allowed ones
    except InvalidArgument:
        check_not_input(path, inputs, what="--plot")  # naming the input file is the first thing to say
        raise
    check_output_file(path, inputs=inputs, what="--plot", kind=fmt.upper())


def _same_path(a: str | Path, b: str | Path) -> bool:
    """The same file name after resolving links and ``..`` (whether it exists or not)."""
    return os.path.realpath(a) == os.path.realpath(b)


def _inside(path: str | Path, folder: str | Path) -> bool:
    """``path`` lies in ``folder`` or below it (links and ``..`` resolved)."""
    p, d = Path(os.path.realpath(path)), Path(os.path.realpath(folder))
    return d == p or d in p.parents


#: The Dask comm protocols a ``--scheduler`` address may name (``tcp://`` when it names none).
SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")


def _check_scheduler_address(address: str) -> tuple[str, int]:
    """``--scheduler`` as ``[PROTOCOL://]HOST:PORT``: its host and port, or one line naming --scheduler.

    Raises:
        InvalidArgument: an empty address, another protocol, a missing host or port, a port outside
            [1, 65535], or text that is not an address (``'tcp://[::1'``, ``'a b'``).
    """
    from urllib.parse import urlparse

    form = f"--scheduler must look like tcp://HOST:PORT (protocol one of {', '.join(SCHEDULER_SCHEMES)})"
    if not address.strip():
        raise InvalidArgument(f"{form}, got an empty address (an unset shell variable?)")
    if any(c.isspace() for c in address):
        raise InvalidArgument(f"{form}, got '{address}' (it holds a space)")
    try:  # urlparse itself raises on a malformed IPv6 host ('tcp://[::1'), .port on a port out of range
        url = urlparse(address if "://" in address else f"tcp://{address}")
        host, port = url.hostname, url.port
    except ValueError:
        raise InvalidArgument(f"{form}, got '{address}' (not a host and a port in [1, 65535])") from None
    if url.scheme not in SCHEDULER_SCHEMES:
        raise InvalidArgument(f"{form}, got the protocol '{url.scheme}' in '{address}'")
    if url.path not in ("", "/") or url.query or url.fragment:
        raise InvalidArgument(f"{form}, got '{address}' (text after the port)")
    if not host:
        raise InvalidArgument(f"{form}, got '{address}' (no host)")
    if not port:
        raise InvalidArgument(f"{form}, got '{address}' (no port, or port 0)")
    return host, port


def _check_scheduler(address: str, timeout: float = 5.0) -> None:
    """Fail fast (one line, a few seconds) when a Dask scheduler address is malformed or cannot be reached."""
    import socket

    host, port = _check_scheduler_address(address)
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as exc:
        raise InvalidArgument(f"cannot reach the Dask scheduler at '{address}': {exc.strerror or exc}") from None


# ------------------------------------------------------------ error report
_NUMERIC_ERRORS = (OverflowError, FloatingPointError, RecursionError, MemoryError)


_caused_by_interrupt = caused_by_interrupt  # one definition, shared with the console entry point


def _one_line(exc: BaseException) -> str:
    msg = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    if isinstance(exc, KeyError) and msg.startswith(("'", '"')):
        msg = msg[1:-1]
    if isinstance(exc, _NUMERIC_ERRORS) and not isinstance(exc, ShinroError):  # ours already say what overflowed
        what = {
            RecursionError: "input nested too deeply",
            MemoryError: "out of memory (reduce the problem size)",
        }.get(type(exc), "numeric overflow (a value too large for float64)")
        return f"{what}: {msg}" if msg else what
    return msg or type(exc).__name__


def _silence_stdout() -> None:
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _looks_like_value(token: str) -> bool:
    """A token starting with '-' that is a (vector of) number(s), not an option: '-0.1,0', '-pi,0', '-1e-3'."""
    if not token.startswith("-") or token.startswith("--"):
        return False
    try:
        parse_vector(token)
    except InvalidArgument:
        return False
    return True


def _join_negative_values(parser: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """``--x0 -0.1,0`` → ``--x0=-0.1,0``: argparse takes a value starting with '-' for an option."""
    takes_value = set()
    subparsers = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            subparsers.extend(action.choices.values())
    for p in subparsers:
        for action in p._actions:
            if action.option_strings and action.nargs is None:  # an option that takes one value
                takes_value.update(action.option_strings)
    out: list[str] = []
    i = 0
    while i < len(argv):
        token = argv[i]
        if token in takes_value and i + 1 < len(argv) and _looks_like_value(argv[i + 1]):
            out.append(f"{token}={argv[i + 1]}")
            i += 2
            continue
        out.append(token)
        i += 1
    return out
