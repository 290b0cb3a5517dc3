"""Real robot files through MjcfPlant: does each load, and how well does it agree with MuJoCo?

Reads every ``*.xml`` / ``*.urdf`` in a folder the user points it at (no file ships with
shinro_ctrl and nothing is fetched). Robot description collections ship meshes beside their
MJCF files; without them MuJoCo cannot load the file. ``--strip-meshes`` first writes, into
``<folder>/stripped/``, a copy of each file with every ``<mesh>`` asset and every geom that
uses one (``mesh=`` attribute, or ``type="mesh"`` given on the geom) removed; in a URDF, every
``<visual>``/``<collision>`` block whose geometry is a ``<mesh>``. That changes:

* contacts with those geoms are lost (the primitive geoms -- capsules, spheres, boxes -- stay);
* a body's inertia taken from its mesh geoms is lost where the body has no explicit
  ``<inertial>``: MuJoCo then refuses a moving massless body, counted as "needs meshes";
* nothing else (joints, actuators, options, keyframes, tendons, equalities are untouched).

For each file:

1. ``MjcfPlant(path)`` loads, or the one-line reason it does not.
2. ``f``: the plant's ``q̈`` against MuJoCo's ``qacc_smooth`` (the unconstrained acceleration;
   ``ctrlrange``/``forcerange``/``actuatorfrcrange`` clamps off) at 3 random states with ``q``
   uniform inside the joint ranges (``[-π, π]`` for an unlimited joint), ``q̇ ~ N(0, 1)`` and
   ``u`` uniform in ``ctrlrange`` (``N(0, 1)`` where none): ``max |Δ| / max(1, |qacc|)``.
   A plant with equality constraints (its state: the independent joints) is compared with MuJoCo's ``qacc``
   with only the equality constraints on, at 3 states near ``x0``, with every equality's impedance set to
   0.999999 (MuJoCo's constraints are soft; the file's own softness is given in the note).
3. Jacobians: ``plant.linearize(x0, u0)`` (exact) against central differences
   (``ε = 1e-6``) of ``[q̇; qacc_smooth]`` computed by MuJoCo at the operating point,
   ``max |Δ| / max(1, |A|, |B|)``; for a constrained plant, against central differences of the plant's own
   ``f`` (Newton completion + KKT solve; the exact Jacobians come from the implicit function theorem).
4. Open-loop hold: the plant in its MuJoCo loop (the file as written: its integrator, contacts,
   limits, friction loss, clamps; the file's timestep) held at ``u0`` from ``x0`` for 1 s:
   ``max |q − q0|`` [rad or m].
5. LQR hold: ``LQR.from_plant`` (``Q = I``, ``R = 1e-2 I``; discrete at the plant's step, input
   bounds from ``ctrlrange``) from ``x0 + 0.02`` on every joint, 2 s in the same MuJoCo loop:
   ``|q − q0|`` max over the last 0.5 s, and the time the error first exceeds 1 rad if it does.
6. ``crosscheck``: the exact Jacobians against ``mjd_transitionFD`` on the matched twin,
   ``mujoco_max_rel_error``.

Run: ``python benchmarks/real_robot_files.py FOLDER [--strip-meshes] [--markdown]``.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from shinro_ctrl.controllers import LQR
from shinro_ctrl.crosscheck import crosscheck
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.engine.model_tree import urdf_with_motors
from shinro_ctrl.plants import MjcfPlant

_MESH_ASSET = re.compile(r"<mesh\b[^>]*/>\s*", re.S)
_MESH_GEOM = re.compile(r"<geom\b(?=[^>]*(?:\bmesh=|\btype=\"mesh\"))[^>]*/>\s*", re.S)


_URDF_BLOCK = re.compile(r"<(visual|collision)\b[^>]*>.*?</\1>\s*", re.S)


def strip_meshes(text: str) -> str:
    """The file without its meshes (module docstring).

    MJCF: without ``<mesh>`` assets and the geoms that use one. URDF: without the ``<visual>`` and
    ``<collision>`` blocks whose geometry is a ``<mesh>``.
    """
    if "<robot" in text and "<mujoco" not in text:
        return _URDF_BLOCK.sub(lambda b: "" if "<mesh" in b.group(0) else b.group(0), text)
    return _MESH_GEOM.sub("", _MESH_ASSET.sub("", text))


@dataclass
class Row:
    name: str
    loads: str
    nq: int = 0
    nu: int = 0
    integrator: str = ""
    f_err: float | None = None
    jac_err: float | None = None
    hold_drift: float | None = None
    lqr_tail: float | None = None
    lqr_blowup: float | None = None
    lqr_design: float | None = None
    crosscheck: float | None = None
    note: str = ""


def _unclamped(path: Path) -> mujoco.MjModel:
    """The file in MuJoCo, clamps off; a URDF through the plant's own translation (a motor per joint)."""
    m = mujoco.MjModel.from_xml_path(str(urdf_with_motors(path)))
    m.actuator_ctrllimited[:] = 0
    m.actuator_forcelimited[:] = 0
    m.jnt_actfrclimited[:] = 0
    return m


def _random_state(m: mujoco.MjModel, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    q = np.empty(m.nq)
    for j in range(m.njnt):
        a = m.jnt_qposadr[j]
        lo, hi = m.jnt_range[j] if m.jnt_limited[j] else (-math.pi, math.pi)
        q[a] = rng.uniform(lo, hi)
    v = rng.standard_normal(m.nv)
    u = np.where(
        m.actuator_ctrllimited.astype(bool),
        rng.uniform(m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1]),
        rng.standard_normal(m.nu),
    )
    return q, v, u


def _qacc_smooth(m: mujoco.MjModel, d: mujoco.MjData, q: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
    d.qpos[:], d.qvel[:], d.ctrl[:] = q, v, u
    mujoco.mj_forward(m, d)
    return d.qacc_smooth.copy()


def _max_rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / max(1.0, float(np.max(np.abs(b)))))


def _constrained_f(plant: MjcfPlant, x0: np.ndarray, na: int, seed: int, *, hard: bool = False) -> float:
    """``q̈_I`` of a constrained plant against MuJoCo's ``qacc`` with only the equality constraints on (soft).

    3 states: ``x0`` with each independent joint moved by U(-0.05, 0.05) and ``q̇_I ~ N(0, 0.1²)``; ``u`` the
    operating input plus N(0, 0.1²). MuJoCo's constraints are soft (``solref``/``solimp``): the two agree to
    within that softness, not to rounding; ``hard`` sets every equality's impedance to 0.999999 first.
    """
    engine = MujocoEngine.for_plant(plant, model="matched")  # Euler, contacts/limits/friction loss/clamps off
    m, d = engine.model, engine.data
    if hard:  # impedance d -> 1: the regularizer R = (1 - d) / d · diag(A) that softens the solution -> 1e-6 · A
        m.eq_solimp[:, 0] = m.eq_solimp[:, 1] = 0.999999
    nqi = (plant.state_dim - na) // 2
    names = [n for n in plant.state_names[:nqi]]
    dofs = [int(m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)]) for n in names]
    rng = np.random.default_rng(seed)
    _, u0 = plant.equilibrium()
    worst = 0.0
    for _ in range(3):
        x = x0.copy()
        x[:nqi] += rng.uniform(-0.05, 0.05, nqi)
        x[nqi : 2 * nqi] = 0.1 * rng.standard_normal(nqi)
        u = u0 + 0.1 * rng.standard_normal(len(u0))
        try:
            xdot = plant.dynamics(x, u)
        except Exception:  # off the constraints' reach: a smaller move
            continue
        plant.engine_write(engine, x)
        plant.engine_apply(engine, u)
        mujoco.mj_forward(m, d)
        worst = max(worst, _max_rel(xdot[nqi : 2 * nqi], d.qacc[dofs]))
    return worst


def evaluate(path: Path, seed: int = 0) -> Row:
    name = path.name
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            plant = MjcfPlant(path)
    except Exception as exc:  # the one-line reason is the result
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        kind = "needs meshes" if "mass" in msg.lower() and "inertia" in msg.lower() else "no"
        return Row(name, kind, note=f"{type(exc).__name__}: {msg}")
    m = _unclamped(path)
    d = mujoco.MjData(m)
    integrator = mujoco.mjtIntegrator(m.opt.integrator).name.removeprefix("mjINT_")
    row = Row(name, "yes", m.nq, plant.input_dim, integrator)
    constrained = plant.constraints is not None
    x0, u0 = plant.equilibrium()
    nq = m.nq
    if constrained:
        row.f_err = _constrained_f(plant, x0, m.na, seed, hard=True)
        soft = _constrained_f(plant, x0, m.na, seed)
        A, B = plant.linearize(x0, u0, method="exact")  # the implicit function theorem
        A_fd, B_fd = plant.linearize(x0, u0, method="fd", eps=1e-6)  # central differences of Newton + KKT
        row.jac_err = _max_rel(np.hstack([A_fd, B_fd]), np.hstack([A, B]))
        row.note = (
            f"equality constraints (state = independent joints): f against MuJoCo's equality solution with "
            f"impedance 0.999999 (the file's own softness: {soft:.1e})"
        )
    elif m.na == 0:
        rng = np.random.default_rng(seed)
        errs = []
        for _ in range(3):
            q, v, u = _random_state(m, rng)
            xdot = plant.dynamics(np.concatenate([q, v]), u)
            errs.append(_max_rel(xdot[nq:], _qacc_smooth(m, d, q, v, u)))
        row.f_err = max(errs)
        A, B = plant.linearize(x0, u0, method="exact")
        eps = 1e-6

        def g(x: np.ndarray, u: np.ndarray) -> np.ndarray:
            return np.concatenate([x[nq:], _qacc_smooth(m, d, x[:nq], x[nq:], u)])

        A_fd = np.column_stack([(g(x0 + eps * e, u0) - g(x0 - eps * e, u0)) / (2 * eps) for e in np.eye(len(x0))])
        B_fd = np.column_stack([(g(x0, u0 + eps * e) - g(x0, u0 - eps * e)) / (2 * eps) for e in np.eye(len(u0))])
        row.jac_err = _max_rel(np.hstack([A_fd, B_fd]), np.hstack([A, B]))
    # open-loop hold in the MuJoCo loop, the file as written
    engine = MujocoEngine.for_plant(plant)
    plant.physics_engine(engine)
    nqi = (plant.state_dim - m.na) // 2  # the (independent) joint coordinates
    steps = round(1.0 / plant.dt)
    plant.set_state(x0)
    drift = 0.0
    for _ in range(steps):
        x = plant.step(u0)
        drift = max(drift, float(np.max(np.abs(x[:nqi] - x0[:nqi]))))
        if not np.all(np.isfinite(x)):
            drift = math.inf
            break
    row.hold_drift = drift
    # LQR hold
    try:
        n = plant.state_dim
        ctrl = LQR.from_plant(plant, np.eye(n), 1e-2 * np.eye(plant.input_dim))
        xs = x0.copy()
        xs[:nqi] += 0.02
        lo, hi = plant.state_bounds if plant.state_bounds is not None else (None, None)
        if lo is not None:
            xs = np.clip(xs, lo, hi)
        plant.set_state(xs)
        steps = round(2.0 / plant.dt)
        tail = 0.0
        for k in range(steps):
            x = plant.get_state()
            err = float(np.max(np.abs(x[:nqi] - x0[:nqi])))
            if not np.isfinite(err) or err > 1.0:
                row.lqr_blowup = (k + 1) * plant.dt
                break
            if k * plant.dt >= 1.5:
                tail = max(tail, err)
            plant.step(ctrl(x))
        row.lqr_tail = tail if row.lqr_blowup is None else math.inf
        plant.physics_engine(None)  # the same design in the plant's own standalone loop, for comparison
        plant.set_state(xs)
        tail = 0.0
        for k in range(steps):
            x = plant.get_state()
            if k * plant.dt >= 1.5:
                tail = max(tail, float(np.max(np.abs(x[:nqi] - x0[:nqi]))))
            plant.step(ctrl(x))
        row.lqr_design = tail
    except Exception as exc:
        row.note += f" LQR: {type(exc).__name__}: {str(exc).splitlines()[0]}"
    plant.physics_engine(None)
    if not constrained:
        try:
            row.crosscheck = crosscheck(plant).mujoco_max_rel_error
        except Exception as exc:
            row.note += f" crosscheck: {type(exc).__name__}: {str(exc).splitlines()[0]}"
    return row


def _g(v: float | None) -> str:
    if v is None:
        return "–"
    if math.isinf(v):
        return "diverges"
    return f"{v:.1e}"


def _short(note: str, width: int = 240) -> str:
    note = " ".join(note.split()).replace("|", "/")
    return note if len(note) <= width else note[: width - 1] + "…"


def table(rows: list[Row]) -> str:
    head = (
        "| file | loads | nq | nu | integrator | f vs qacc_smooth | Jacobians vs central diff | open-loop 1 s max|Δq| "
        "| LQR 2 s: max|Δq| over the last 0.5 s, MuJoCo (standalone) | crosscheck | note |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|"
    )
    lines = [head]
    for r in rows:
        lqr = f"diverges at t = {r.lqr_blowup:.3f} s" if r.lqr_blowup is not None else _g(r.lqr_tail)
        if r.lqr_design is not None:
            lqr += f" ({_g(r.lqr_design)})"
        lines.append(
            f"| {r.name} | {r.loads} | {r.nq or ''} | {r.nu or ''} | {r.integrator} | {_g(r.f_err)} | "
            f"{_g(r.jac_err)} | {_g(r.hold_drift)} | {lqr} | {_g(r.crosscheck)} | {_short(r.note)} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--strip-meshes", action="store_true")
    args = ap.parse_args(argv)
    files = sorted(p for p in args.folder.iterdir() if p.suffix in (".xml", ".urdf"))
    if args.strip_meshes:
        out = args.folder / "stripped"
        out.mkdir(exist_ok=True)
        for p in files:
            (out / p.name).write_text(strip_meshes(p.read_text()))
        files = sorted(out.iterdir())
    rows = []
    for p in files:
        t0 = time.perf_counter()
        rows.append(evaluate(p))
        print(f"{p.name}: {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    print(table(rows))
    print(f"\nloaded {sum(r.loads == 'yes' for r in rows)} of {len(rows)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
