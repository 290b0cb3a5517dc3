"""The red-team harness: probes, a fork-per-probe runner and the automatic classifier.

A :class:`Probe` is one input with its expected behaviour. Three kinds:

- ``cli``: the pre-imported parent forks; the child chdirs into the probe's own folder, redirects its stdout and
  stderr to files and calls ``shinro_ctrl.cli.main(argv)``; its return value is the exit status.
- ``py``: the child calls ``probe.func(workdir)``, a function of the Python API that returns an
  :class:`Outcome` (its own oracle); the child writes it as JSON.
- ``proc``: a real ``python -m shinro_ctrl.cli`` subprocess in its own session (the signal probes), signalled by
  the parent at a given moment.

A hang or a crash kills only the child. :func:`classify` turns what happened into one class of :data:`CLASSES`.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

CLASSES = ("ok", "data_loss", "wrong_answer_exit0", "hang", "traceback", "misleading_message", "segfault")
NA = "n/a"
CATEGORIES = ("cli", "scenario", "model", "numerics", "files", "signals", "threads")


@dataclass
class Outcome:
    """What a ``py`` probe saw: a class of :data:`CLASSES` (or ``n/a``) and why."""

    cls: str
    detail: str = ""


@dataclass
class Probe:
    """One red-team input and its expected behaviour.

    Attributes:
        pid: unique id, ``category/name``.
        category: one of :data:`CATEGORIES`.
        kind: ``cli``, ``py`` or ``proc``.
        argv: the command line (``cli``/``proc``), relative paths are inside the probe's folder.
        func: the ``py`` probe's body, ``func(workdir) -> Outcome``.
        expect: ``ok`` (exit 0 and the oracle holds), ``refuse`` (exit 2, one line naming a needle),
            ``either`` (one or the other), ``interrupt`` (exit 130 after the signal, no traceback).
        needles: a refusal must name one of these (case-insensitive); empty: any one-line message.
        oracle: for exit 0: returns a violation (wrong answer) or None.
        setup: writes the probe's input files into its folder (run in the parent before the child starts).
        check: after the child: returns a data-loss description or None.
        timeout: seconds before the probe counts as a hang.
        ok_rcs: exit statuses besides 0, 2 and 130 that are legitimate (``regress`` exits 1 on a regression).
        signal_at: ``proc``: seconds after start, or after ``signal_marker`` appears in the output, to signal.
        signal_marker: text whose appearance in stdout/stderr starts the ``signal_at`` clock.
        signum: the signal sent (SIGINT by default).
        bad_flag: the probe means an unknown flag (else an unknown flag makes the probe n/a on an old tree).
    """

    pid: str
    category: str
    kind: str = "cli"
    argv: list[str] = field(default_factory=list)
    func: Callable[[Path], Outcome] | None = None
    expect: str = "either"
    needles: tuple[str, ...] = ()
    oracle: Callable[[RunInfo], str | None] | None = None
    setup: Callable[[Path], None] | None = None
    check: Callable[[Path], str | None] | None = None
    timeout: float = 60.0
    ok_rcs: tuple[int, ...] = ()
    signal_at: float | None = None
    signal_marker: str | None = None
    signum: int = signal.SIGINT
    bad_flag: bool = False


@dataclass
class RunInfo:
    """What one probe run produced."""

    rc: int | None
    stdout: str
    stderr: str
    elapsed: float
    timed_out: bool
    workdir: Path
    outcome: Outcome | None = None
    signalled: bool = False


# ------------------------------------------------------------------ children
def _redirect(iodir: Path) -> None:
    for fd, name in ((1, "stdout.txt"), (2, "stderr.txt")):
        f = os.open(iodir / name, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(f, fd)
        os.close(f)


def _child(probe: Probe, workdir: Path, iodir: Path) -> None:
    """Body of a forked child: never returns."""
    code = 1
    try:
        os.setpgid(0, 0)  # its own group: a hang kills the child and any pool workers it started
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        _redirect(iodir)
        os.chdir(workdir)
        if probe.kind == "cli":
            from shinro_ctrl.cli import main

            try:
                code = int(main(list(probe.argv)) or 0)
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            except BaseException:
                traceback.print_exc()
                code = 1
        else:
            assert probe.func is not None
            try:
                out = probe.func(workdir)
            except NotApplicable as exc:
                out = Outcome(NA, str(exc))
            except BaseException as exc:  # the probe body itself escaped: a bug of the API it called
                traceback.print_exc()
                out = Outcome("traceback", f"uncaught {type(exc).__name__}: {_first_line(exc)}")
            (iodir / "outcome.json").write_text(json.dumps({"cls": out.cls, "detail": out.detail}))
            code = 0
    except BaseException:
        traceback.print_exc()
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        except BaseException:
            pass
        os._exit(code)


class NotApplicable(Exception):
    """The API a probe exercises does not exist in the target tree: the probe is n/a."""


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:200] if text else ""


# ------------------------------------------------------------------ running
@dataclass
class _Job:
    probe: Probe
    root: Path
    start: float
    pid: int | None = None
    popen: subprocess.Popen[bytes] | None = None
    rc: int | None = None
    timed_out: bool = False
    signalled_at: float | None = None
    marker_seen_at: float | None = None
    hard_killed: bool = False

    @property
    def workdir(self) -> Path:
        return self.root / "wd"

    @property
    def iodir(self) -> Path:
        return self.root / "io"


class Runner:
    """Runs probes on at most ``workers`` children at a time."""

    def __init__(self, tmp: Path, tree: Path, python: str, workers: int = 2, keep: bool = False) -> None:
        self.tmp = tmp
        self.tree = tree
        self.python = python
        self.workers = max(1, min(2, workers))
        self.keep = keep

    def _start(self, probe: Probe, index: int) -> _Job:
        root = self.tmp / f"p{index:05d}"
        (root / "wd").mkdir(parents=True)
        (root / "io").mkdir()
        job = _Job(probe, root, time.monotonic())
        if probe.setup is not None:
            probe.setup(job.workdir)
        if probe.kind == "proc":
            env = dict(os.environ, PYTHONPATH=str(self.tree), PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
            with open(job.iodir / "stdout.txt", "wb") as out, open(job.iodir / "stderr.txt", "wb") as err:
                job.popen = subprocess.Popen(
                    [self.python, "-m", "shinro_ctrl.cli", *probe.argv],
                    cwd=job.workdir,
                    stdout=out,
                    stderr=err,
                    stdin=subprocess.DEVNULL,
                    env=env,
                    start_new_session=True,
                )
            job.pid = job.popen.pid
        else:
            sys.stdout.flush()
            sys.stderr.flush()
            pid = os.fork()
            if pid == 0:
                _child(probe, job.workdir, job.iodir)
            job.pid = pid
        job.start = time.monotonic()
        return job

    def _poll(self, job: _Job) -> bool:
        """True when the job has ended (exited, or killed after its timeout)."""
        now = time.monotonic()
        if job.popen is not None:
            rc = job.popen.poll()
            if rc is not None:
                job.rc = rc
                _killpg(job.pid, signal.SIGKILL)
                return True
            self._maybe_signal(job, now)
        else:
            assert job.pid is not None
            pid, status = os.waitpid(job.pid, os.WNOHANG)
            if pid == job.pid:
                job.rc = os.waitstatus_to_exitcode(status)
                _killpg(job.pid, signal.SIGKILL)  # stray pool workers of the child
                return True
        limit = job.probe.timeout
        if now - job.start > limit:
            job.timed_out = True
            _killpg(job.pid, signal.SIGKILL)
            if job.popen is not None:
                job.rc = job.popen.wait()
            else:
                _, status = os.waitpid(job.pid, 0)
                job.rc = os.waitstatus_to_exitcode(status)
            return True
        return False

    def _maybe_signal(self, job: _Job, now: float) -> None:
        probe = job.probe
        if probe.signal_at is None or job.signalled_at is not None:
            return
        t0 = job.start
        if probe.signal_marker is not None:
            if job.marker_seen_at is None:
                text = _read(job.iodir / "stdout.txt") + _read(job.iodir / "stderr.txt")
                if probe.signal_marker not in text:
                    return
                job.marker_seen_at = now
            t0 = job.marker_seen_at
        if now - t0 >= probe.signal_at:
            _killpg(job.pid, probe.signum)
            job.signalled_at = now

    def _finish(self, job: _Job) -> RunInfo:
        outcome = None
        path = job.iodir / "outcome.json"
        if path.exists():
            try:
                data = json.loads(path.read_text())
                outcome = Outcome(data["cls"], data.get("detail", ""))
            except (ValueError, KeyError):
                outcome = None
        return RunInfo(
            rc=job.rc,
            stdout=_read(job.iodir / "stdout.txt"),
            stderr=_read(job.iodir / "stderr.txt"),
            elapsed=time.monotonic() - job.start,
            timed_out=job.timed_out,
            workdir=job.workdir,
            outcome=outcome,
            signalled=job.signalled_at is not None,
        )

    def run(self, probes: list[Probe], report: Callable[[Probe, RunInfo, str, str], None]) -> None:
        """Run every probe; ``report(probe, info, cls, detail)`` is called as each ends."""
        queue = list(enumerate(probes))
        queue.reverse()
        running: list[_Job] = []
        try:
            while queue or running:
                while queue and len(running) < self.workers:
                    index, probe = queue.pop()
                    running.append(self._start(probe, index))
                for job in list(running):
                    if self._poll(job):
                        running.remove(job)
                        info = self._finish(job)
                        try:
                            cls, detail = classify(job.probe, info)
                        except Exception as exc:  # an oracle of ours failed: say so, do not stop the run
                            cls, detail = "harness_error", f"{type(exc).__name__}: {exc}"
                        report(job.probe, info, cls, detail)
                        if not self.keep:
                            shutil.rmtree(job.root, ignore_errors=True)
                time.sleep(0.01)
        finally:
            for job in running:
                _killpg(job.pid, signal.SIGKILL)
                try:
                    if job.popen is not None:
                        job.popen.wait(timeout=5)
                    elif job.pid is not None:
                        os.waitpid(job.pid, 0)
                except (ChildProcessError, subprocess.TimeoutExpired):
                    pass


def _killpg(pid: int | None, sig: int) -> None:
    if pid is None:
        return
    try:
        os.killpg(pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def _read(path: Path) -> str:
    try:
        return path.read_bytes().decode("utf-8", "replace")
    except OSError:
        return ""


# ------------------------------------------------------------------ classification
_NAN_WORD = re.compile(r"(?<![\w.])[-+]?nan(?![\w])", re.IGNORECASE)
_UNKNOWN_FLAG = re.compile(r"unrecognized arguments: (--?[\w-]+)")


def stderr_lines(text: str) -> list[str]:
    """The non-empty stderr lines that are not our progress output."""
    return [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("\r")]


def names_needle(text: str, needles: tuple[str, ...]) -> bool:
    """True when the message names one of ``needles`` (case-insensitive) or no needle is required."""
    low = text.lower()
    return not needles or any(n.lower() in low for n in needles)


def classify(probe: Probe, info: RunInfo) -> tuple[str, str]:
    """The class of one probe run and a short reason."""
    if probe.check is not None:
        lost = probe.check(info.workdir)
        if lost:
            return "data_loss", lost
    rc = info.rc
    if info.timed_out:
        return "hang", f"no exit within {probe.timeout:g} s"
    if probe.kind == "py":
        if rc is not None and rc < 0:
            return "segfault", f"child died by signal {-rc} ({_signame(-rc)})"
        if info.outcome is None:
            return "traceback", f"no outcome (exit {rc}): {_tail(info.stderr)}"
        return info.outcome.cls, info.outcome.detail
    if rc is not None and rc < 0 and not (info.signalled and -rc == probe.signum):
        if -rc == signal.SIGINT:  # KeyboardInterrupt escaped to the interpreter's top level
            return "traceback", f"died of SIGINT (rc {rc}): {_tail(info.stderr)}"
        return "segfault", f"died by signal {-rc} ({_signame(-rc)})"
    if "Traceback (most recent call last)" in info.stderr:
        return "traceback", _tail(info.stderr)
    if probe.kind == "proc" and probe.expect == "interrupt":
        return _classify_interrupt(probe, info)
    if rc not in (0, 2, 130, *probe.ok_rcs):
        return "traceback", f"exit {rc}: {_tail(info.stderr)}"
    if rc == 2:
        m = _UNKNOWN_FLAG.search(info.stderr)
        if m and not probe.bad_flag:
            return NA, f"the tree has no {m.group(1)}"
        lines = stderr_lines(info.stderr)
        if probe.expect == "ok":
            return "misleading_message", f"valid input refused: {_tail(info.stderr)}"
        if len(lines) > 1:
            return "misleading_message", f"{len(lines)} stderr lines: {' | '.join(lines[:3])[:240]}"
        if not lines:
            return "misleading_message", "exit 2 with no message"
        if not names_needle(lines[0], probe.needles):
            return "misleading_message", f"does not name {'/'.join(probe.needles)}: {lines[0][:240]}"
        return "ok", lines[0][:160]
    if rc == 130:
        return "ok", "interrupted"
    # rc == 0 or an allowed status
    if probe.expect == "refuse":
        return "wrong_answer_exit0", f"accepted (exit {rc}), expected a refusal naming {'/'.join(probe.needles)}"
    violation = default_oracle(info)
    if violation is None and probe.oracle is not None:
        violation = probe.oracle(info)
    if violation:
        return "wrong_answer_exit0", violation
    return "ok", f"exit {rc}"


def _classify_interrupt(probe: Probe, info: RunInfo) -> tuple[str, str]:
    rc = info.rc
    if not info.signalled:
        if rc == 0:
            return "ok", "finished before the signal moment"
        return "traceback" if rc not in (
            0,
            2,
        ) else "misleading_message", f"exit {rc} before the signal: {_tail(info.stderr)}"
    if probe.check is not None:
        lost = probe.check(info.workdir)
        if lost:
            return "data_loss", lost
    if probe.signum == signal.SIGINT:
        if rc == 130:
            extra = [ln for ln in stderr_lines(info.stderr) if "interrupt" not in ln.lower()]
            if len(extra) > 1:
                return "misleading_message", f"exit 130 with extra stderr: {' | '.join(extra[:3])[:200]}"
            return "ok", "exit 130"
        if rc == 0:
            return "ok", "finished before the signal took effect"
        if rc == 2:
            return "misleading_message", f"Ctrl-C reported as a user error: {_tail(info.stderr)}"
        return "traceback", f"exit {rc} after SIGINT: {_tail(info.stderr)}"
    # SIGTERM: dying by the signal (or 143/130) is right; a traceback or another status is not
    if rc in (-probe.signum, 128 + probe.signum, 130, 0):
        return "ok", f"exit {rc}"
    if rc == 2:
        return "misleading_message", f"SIGTERM reported as a user error: {_tail(info.stderr)}"
    return "traceback", f"exit {rc} after SIGTERM: {_tail(info.stderr)}"


def _signame(num: int) -> str:
    try:
        return signal.Signals(num).name
    except ValueError:
        return str(num)


def _tail(text: str) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return (lines[-1] if lines else "")[:240]


# ------------------------------------------------------------------ oracles
_METRIC_LINE = re.compile(r"^\s{1,4}([a-z_]+)\s+(\S+)")


def parse_metrics(stdout: str) -> dict[str, str]:
    """The ``name value`` lines `run` prints (first occurrence of each name)."""
    out: dict[str, str] = {}
    for line in stdout.splitlines():
        m = _METRIC_LINE.match(line)
        if m and m.group(1) not in out:
            out[m.group(1)] = m.group(2)
    return out


def _as_float(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


DIVERGED_ERROR = 50.0


def default_oracle(info: RunInfo) -> str | None:
    """Violations any successful command shows: NaN printed, NaN in a metrics JSON, a diverged run unflagged."""
    for line in info.stdout.splitlines():
        if _NAN_WORD.search(line):
            return f"NaN in the output: {line.strip()[:160]}"
    for path in list(info.workdir.rglob("metrics.json"))[:3] + list(info.workdir.rglob("sweep.json"))[:1]:
        try:
            text = path.read_text()
        except OSError:
            continue
        if re.search(r"\bNaN\b", text):
            return f"NaN in {path.name}"
    metrics = parse_metrics(info.stdout)
    final = _as_float(metrics.get("final_error", ""))
    if final is not None and (not math.isfinite(final) or final > DIVERGED_ERROR):
        flag = metrics.get("stable")
        if flag is None:
            return f"final_error {final:g} and no 'stable' flag printed"
        if flag.lower() in ("true", "yes", "1"):
            return f"final_error {final:g} reported stable"
    return None


def huge_entries_oracle(limit: float = 1e10) -> Callable[[RunInfo], str | None]:
    """Exit 0 printing a number above ``limit`` in magnitude (e.g. a Jacobian at a singularity)."""

    number = re.compile(r"[-+]?\d+\.?\d*[eE][-+]?\d+|[-+]?inf\b")

    def oracle(info: RunInfo) -> str | None:
        for tok in number.findall(info.stdout):
            v = _as_float(tok)
            if v is not None and (not math.isfinite(v) or abs(v) > limit):
                return f"printed {tok} with exit 0"
        return None

    return oracle
