"""Infeasibility diagnosis of a sparse MPC QP: which constraint group, at which stage.

When OSQP fails, :func:`diagnose` turns its output into one sentence naming
the culprit: from the primal infeasibility certificate when there is one,
otherwise from the largest constraint violation of the last iterate.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from shinro_ctrl.controllers.qp.sparse import RowGroup

__all__ = ["OsqpInfo", "OsqpIterate", "describe_groups", "diagnose", "explain_certificate", "fmt"]


class OsqpInfo(Protocol):
    """What :func:`diagnose` reads of a solver's info (OSQP's ``result.info``)."""

    @property
    def status(self) -> str:
        """The solver's status text (``"primal infeasible"`` …)."""
        ...

    @property
    def iter(self) -> int:
        """Iterations taken."""
        ...


class OsqpIterate(Protocol):
    """What :func:`diagnose` reads of a solver's last iterate (OSQP's ``result``)."""

    @property
    def x(self) -> ArrayLike:
        """The primal iterate ``(n_var,)``."""
        ...

    @property
    def prim_inf_cert(self) -> ArrayLike | None:
        """The primal infeasibility certificate ``(n_con,)``, when the solver found one."""
        ...


def fmt(v: ArrayLike) -> str:
    """A short rendering of a vector for messages."""
    return np.array2string(np.asarray(v), precision=4, suppress_small=True)


def describe_groups(groups: Sequence[RowGroup]) -> str:
    """The row groups of a QP in one line: name, rows, width and stages."""
    return ", ".join(f"{g.name} [{g.start}:{g.stop}] ({g.width} x {g.stages} stages)" for g in groups)


def diagnose(
    x: np.ndarray,
    info: OsqpInfo,
    sol: OsqpIterate,
    A: sp.csc_matrix,
    l: np.ndarray,
    u: np.ndarray,
    groups: list[RowGroup],
) -> str:
    """Name the constraint group and stage behind a failed solve.

    Args:
        x: The measured state ``(n,)``.
        info: OSQP's info (``status``, ``iter``).
        sol: OSQP's solution (``x``, ``prim_inf_cert``).
        A: Constraint matrix ``(n_con, n_var)``.
        l: Lower bounds ``(n_con,)`` of the failed solve.
        u: Upper bounds ``(n_con,)``.
        groups: The row groups of ``A``.
    """
    status = info.status
    head = f"MPC problem infeasible (OSQP status '{status}', {info.iter} iterations) at x = {fmt(x)}"
    cert = np.asarray(sol.prim_inf_cert, dtype=float)
    if "primal infeasible" in status and cert.size and np.all(np.isfinite(cert)) and np.any(cert != 0):
        return head + ": " + explain_certificate(cert, groups)
    if "dual infeasible" in status:
        return head + ": the cost is unbounded below (dual infeasible); check Q, R and the terminal cost"
    z = np.asarray(sol.x, dtype=float)
    if z.size and np.all(np.isfinite(z)):
        Az = A @ z
        viol = np.maximum(l - Az, 0.0) + np.maximum(Az - u, 0.0)
        row = int(np.argmax(viol))
        g = _group_of(groups, row)
        k, label = g.locate(row)
        return (
            head + f": largest violation of the last iterate is {viol[row]:.3g} in the {g.name} at stage {k} "
            f"({label}); the problem is likely infeasible or too hard within the iteration/time limit"
        )
    return head + ": OSQP returned no usable iterate"


def _group_of(groups: list[RowGroup], row: int) -> RowGroup:
    for g in groups:
        if g.start <= row < g.stop:
            return g
    raise IndexError(row)  # pragma: no cover - rows always belong to a group


def explain_certificate(cert: np.ndarray, groups: list[RowGroup]) -> str:
    """Turn a primal infeasibility certificate into a sentence (OSQP's, or the condensed QP's elastic-LP one).

    The certificate ``δy`` (``Aᵀ δy = 0``, ``uᵀ δy₊ + lᵀ δy₋ < 0``) is
    nonzero on the rows that together cannot hold. Its entries spread over
    later stages, so the stage named is the *first* one where the culprit
    group (state, then rate, then input bounds) enters the certificate: the
    first stage that cannot be met.
    """
    peak = float(np.max(np.abs(cert)))
    involved: dict[str, list[int]] = {}
    first: dict[str, int] = {}
    for g in groups:
        seg = np.abs(cert[g.start : g.stop])
        gmax = float(seg.max(initial=0.0))
        if gmax <= 1e-9 * peak:
            continue
        hits = np.flatnonzero(seg > 1e-3 * gmax)
        involved[g.name] = sorted({g.first_stage + int(h) // g.width for h in hits})
        first[g.name] = g.start + int(hits[0])
    culprit = next((name for name in ("state bounds", "rate bounds", "input bounds") if name in first), None)
    if culprit is None:  # pragma: no cover - equalities alone are always feasible; a certificate always has a row
        if not involved:
            return "the infeasibility certificate is empty"
        return "the certificate involves only the dynamics (" + ", ".join(involved) + ")"
    k, label = next(g for g in groups if g.name == culprit).locate(first[culprit])
    others = [
        f"{name} at stages {_stages(s)}"
        for name, s in involved.items()
        if name not in (culprit, "initial state", "dynamics")
    ]
    return (
        f"{culprit} at stage {k} ({label}) cannot be met from this state under the dynamics"
        f" (conflict over stages {_stages(involved[culprit])})"
        + (" together with the " + "; ".join(others) if others else "")
    )


def _stages(stages: list[int]) -> str:
    """``[0, 1, 2, 5]`` -> ``"0-2, 5"``."""
    out: list[str] = []
    start = prev = stages[0]
    for s in [*stages[1:], None]:
        if s is not None and s == prev + 1:
            prev = s
            continue
        out.append(f"{start}" if start == prev else f"{start}-{prev}")
        if s is not None:
            start = prev = s
    return ", ".join(out)
