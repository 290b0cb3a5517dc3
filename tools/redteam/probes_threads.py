"""Threads: one controller, estimator or plant object called from 4 threads against a serial run.

Stateless calls (LQR, plant dynamics) get varied inputs and must match the serial results exactly. Stateful
objects (MPC warm starts, NMPC iterations, the Kalman filter) get the same input on every call, so that any
per-call-atomic behaviour gives outputs from the serial sequence (MPC) or the same final state (filter). An
object that detects the concurrent use and raises a clear error also passes; a crash of the child is a segfault.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from api import clean_error, get
from harness import Outcome, Probe

CAT = "threads"
THREADS = 4
_CONCURRENCY_WORDS = ("thread", "concurren", "simultaneous", "reentr", "re-entr", "in use")


def _concurrent(fn: Callable[[Any], Any], inputs: list[Any]) -> tuple[list[Any], list[BaseException]]:
    """Every input called once, split over :data:`THREADS` threads started together."""
    results: list[Any] = [None] * len(inputs)
    errors: list[BaseException] = []
    barrier = threading.Barrier(THREADS)

    def worker(k: int) -> None:
        barrier.wait()
        for i in range(k, len(inputs), THREADS):
            try:
                results[i] = np.array(fn(inputs[i]), dtype=float, copy=True)
            except BaseException as exc:  # collected and judged below
                errors.append(exc)
                return

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(THREADS)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return results, errors


def _errors_outcome(errors: list[BaseException]) -> Outcome | None:
    if not errors:
        return None
    exc = errors[0]
    text = f"{type(exc).__name__}: {str(exc)[:160]}"
    if any(w in str(exc).lower() for w in _CONCURRENCY_WORDS):
        return Outcome("ok", f"concurrent use detected: {text}")
    if clean_error(exc):  # a refusal that does not say why: a race surfacing as a spurious error
        return Outcome("wrong_answer_exit0", f"spurious error under concurrent calls: {text}")
    return Outcome("traceback", f"uncaught {text} in a thread")


def stateless(
    make: Callable[[], Callable[[Any], Any]], gen: Callable[[np.random.Generator], Any], calls: int, seed: int
):
    def probe(wd: Path) -> Outcome:
        fn = make()
        rng = np.random.default_rng(seed)
        inputs = [gen(rng) for _ in range(calls)]
        serial = [np.array(fn(x), dtype=float, copy=True) for x in inputs]
        conc, errors = _concurrent(fn, inputs)
        bad = _errors_outcome(errors)
        if bad is not None:
            return bad
        wrong = [
            i
            for i, (a, b) in enumerate(zip(serial, conc, strict=True))
            if b is None or not np.allclose(a, b, rtol=1e-9, atol=1e-12)
        ]
        if wrong:
            i = wrong[0]
            return Outcome(
                "wrong_answer_exit0",
                f"{len(wrong)}/{calls} concurrent results differ from serial (first at {i}: {conc[i]} vs {serial[i]})",
            )
        return Outcome("ok", f"{calls} calls x {THREADS} threads match serial")

    return probe


def same_input(make: Callable[[], Any], x: Any, calls: int, tol: float):
    """A stateful controller called with one state: every concurrent output must be one a serial run gives."""

    def probe(wd: Path) -> Outcome:
        ctrl = make()
        serial = [np.array(ctrl(x), dtype=float, copy=True) for _ in range(calls)]
        ctrl = make()
        conc, errors = _concurrent(ctrl, [x] * calls)
        bad = _errors_outcome(errors)
        if bad is not None:
            return bad
        ref = np.array(serial)
        scale = max(1.0, float(np.max(np.abs(ref))))
        wrong = [
            i for i, b in enumerate(conc) if b is None or float(np.min(np.max(np.abs(ref - b), axis=1))) > tol * scale
        ]
        if wrong:
            i = wrong[0]
            return Outcome(
                "wrong_answer_exit0",
                f"{len(wrong)}/{calls} concurrent outputs match no serial output (e.g. {conc[i]} vs {ref[-1]})",
            )
        return Outcome("ok", f"{calls} calls x {THREADS} threads consistent with serial")

    return probe


def kalman(calls: int):
    def probe(wd: Path) -> Outcome:
        KF = get("shinro_ctrl.estimators.kalman", "KalmanFilter")
        plant = get("shinro_ctrl.plants", "CartPole")()

        def make() -> Any:
            return KF.from_plant(plant, Qn=[1e-3], Rn=[1e-4, 1e-4], measured=["x", "theta"])

        y, u = np.array([0.01, 0.02]), np.zeros(1)
        kf2 = make()
        _conc, errors = _concurrent(lambda _: kf2.update(y, u), [None] * calls)
        bad = _errors_outcome(errors)
        if bad is not None:
            return bad
        final = np.array(kf2.update(y, u), dtype=float)
        ref_kf = make()
        for _ in range(calls + 1):
            ref_final = np.array(ref_kf.update(y, u), dtype=float)
        if not np.allclose(final, ref_final, rtol=1e-9, atol=1e-12):
            return Outcome(
                "wrong_answer_exit0",
                f"final estimate after concurrent updates differs from serial: {final} vs {ref_final}",
            )
        return Outcome("ok", "same final estimate as serial")

    return probe


def probes() -> list[Probe]:
    out: list[Probe] = []
    Q4, R1 = np.array([10.0, 1, 100, 1]), np.array([0.1])

    def cartpole() -> Any:
        return get("shinro_ctrl.plants", "CartPole")()

    def lqr() -> Any:
        return get("shinro_ctrl.controllers", "LQR").from_plant(cartpole(), Q4, R1)

    def mpc(solver: str) -> Callable[[], Any]:
        def make() -> Any:
            LinearMPC = get("shinro_ctrl.controllers", "LinearMPC")
            plant = get("shinro_ctrl.plants", "CartPole")(dt=0.02)
            return LinearMPC.from_plant(plant, Q4, R1, horizon=30, u_min=[-3.0], u_max=[3.0], solver=solver)

        return make

    def nmpc() -> Any:
        NMPC = get("shinro_ctrl.controllers", "NonlinearMPC")
        plant = get("shinro_ctrl.plants", "InvertedPendulum")(dt=0.05)
        return NMPC.from_plant(plant, np.array([10.0, 0.1]), np.array([1.0]), horizon=20, u_min=[-1.0], u_max=[1.0])

    def mjcf_dyn() -> Callable[[Any], Any]:
        p = get("shinro_ctrl.plants", "MjcfPlant")()
        return lambda xu: p.dynamics(xu[0], xu[1])

    def cart_dyn() -> Callable[[Any], Any]:
        p = cartpole()
        return lambda xu: p.dynamics(xu[0], xu[1])

    def lin_x(n: int, m: int) -> Callable[[np.random.Generator], Any]:
        return lambda rng: (rng.normal(scale=0.3, size=n), rng.normal(scale=0.5, size=m))

    for rep in range(6):
        out.append(
            Probe(
                f"{CAT}/LQR/rep{rep}",
                CAT,
                kind="py",
                func=stateless(lqr, lambda rng: rng.normal(scale=0.3, size=4), 1000, rep),
                timeout=60,
            )
        )
        out.append(
            Probe(
                f"{CAT}/CartPole.dynamics/rep{rep}",
                CAT,
                kind="py",
                func=stateless(cart_dyn, lin_x(4, 1), 1000, rep),
                timeout=60,
            )
        )
        out.append(
            Probe(
                f"{CAT}/MjcfPlant.dynamics/rep{rep}",
                CAT,
                kind="py",
                func=stateless(mjcf_dyn, lin_x(4, 1), 1000, rep),
                timeout=60,
            )
        )
        out.append(
            Probe(
                f"{CAT}/LinearMPC_osqp/rep{rep}",
                CAT,
                kind="py",
                func=same_input(mpc("osqp"), np.array([0.1, 0.0, 0.15, 0.0]), 1000, 1e-3),
                timeout=90,
            )
        )
        out.append(
            Probe(
                f"{CAT}/LinearMPC_daqp/rep{rep}",
                CAT,
                kind="py",
                func=same_input(mpc("daqp"), np.array([0.1, 0.0, 0.15, 0.0]), 1000, 1e-7),
                timeout=90,
            )
        )
        out.append(
            Probe(
                f"{CAT}/NonlinearMPC/rep{rep}",
                CAT,
                kind="py",
                func=same_input(nmpc, np.array([0.3, 0.0]), 250, 1e-3),
                timeout=120,
            )
        )
        out.append(Probe(f"{CAT}/KalmanFilter/rep{rep}", CAT, kind="py", func=kalman(1000), timeout=60))
    # stateless MPC check with varied states: each call must be the serial answer for that state (daqp is exact)
    for rep in range(3):

        def fresh_daqp_varied(seed: int = rep) -> Any:
            def probe(wd: Path) -> Outcome:
                make = mpc("daqp")
                return stateless(make, lambda rng: rng.normal(scale=0.1, size=4), 500, seed)(wd)

            return probe

        out.append(Probe(f"{CAT}/LinearMPC_daqp_varied/rep{rep}", CAT, kind="py", func=fresh_daqp_varied(), timeout=90))
    return out
