"""Structure: the extension points suffice for a plant and a controller defined here, the shipped arm does
not depend on the working directory, and the import layering holds."""

from __future__ import annotations

import ast
import functools
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

import shinro_ctrl
from shinro_ctrl.controllers import CONTROLLER_REGISTRY, CONTROLLERS, LQR, Controller, controller_class
from shinro_ctrl.errors import ConfigError, InvalidArgument
from shinro_ctrl.estimators import ESTIMATOR_REGISTRY, Estimator, KalmanFilter, estimator_class
from shinro_ctrl.plants import PLANT_REGISTRY, PLANTS, ArmRobot, CartPole, Plant, plant_class
from shinro_ctrl.plants.armrobot import ARM6
from shinro_ctrl.resources import shipped_config
from shinro_ctrl.sim import RobotSim
from shinro_ctrl.validation import as_vector, check_positive

PACKAGE = Path(shinro_ctrl.__file__).resolve().parent
TESTS = Path(__file__).resolve().parent


# ----------------------------------------------------------- a plant and a controller defined only here
class StructureTestSled(Plant):
    """A sled of mass ``m`` pushed by a force: ``p̈ = F / m`` (semi-implicit Euler from the base)."""

    state_names = ("p", "v")
    input_names = ("F",)
    param_names = ("mass",)
    position_indices = (0,)
    velocity_indices = (1,)

    def __init__(self, mass: float = 2.0, dt: float = 0.01):
        self._init(dt=dt, params={"mass": check_positive("mass", mass)})

    def equations(self, bk, x, u, p):
        _, v = bk.unpack(x, 2)
        (force,) = bk.unpack(u, 1)
        return bk.stack([v, force / p["mass"]])


class StructureTestPD(Controller):
    """``F = clip(−kp (p − r_p) − kd v, ±f_max)``."""

    def __init__(self, kp: float, kd: float, f_max: float):
        self.kp, self.kd = kp, kd
        self.u_min, self.u_max = np.array([-f_max]), np.array([f_max])
        self.calls: list[np.ndarray] = []

    @classmethod
    def from_plant(cls, plant, *, kp: float = 4.0, kd: float = 3.0, f_max: float = 5.0) -> StructureTestPD:
        return cls(kp, kd, f_max)

    def __call__(self, x, ref=None):
        x = as_vector("x", x, 2)
        self.calls.append(x.copy())
        r = 0.0 if ref is None else float(np.asarray(ref)[0])
        return np.clip([-self.kp * (x[0] - r) - self.kd * x[1]], self.u_min, self.u_max)


class StructureTestBiased(Estimator):
    """Reports the measurement plus a constant bias (so the test can see what the controller is fed)."""

    stateful = False

    def __init__(self, bias: np.ndarray):
        self.n, self.measured, self.bias = 2, (0, 1), bias

    def reset(self, x0_hat, P0=None) -> None:
        self.reset_to = np.array(x0_hat, dtype=float)

    def update(self, y, u):
        return np.asarray(y, dtype=float) + self.bias


SCENARIO = {
    "plant": {"type": "StructureTestSled", "mass": 2.0, "dt": 0.01},
    "controller": {"type": "StructureTestPD", "kp": 4.0, "kd": 3.0, "f_max": 5.0},
    "sim": {"duration": 8.0, "initial_state": [1.0, 0.0], "reference": {"kind": "constant", "value": [0.0, 0.0]}},
}


def sled_reference(x0, steps: int, dt: float, mass: float, bias=(0.0, 0.0)) -> np.ndarray:
    """The same closed loop written out by hand: PD on the biased state, semi-implicit Euler."""
    p, v = x0
    out = [(p, v)]
    for _ in range(steps):
        pe, ve = p + bias[0], v + bias[1]
        force = min(max(-4.0 * pe - 3.0 * ve, -5.0), 5.0)
        v = v + dt * force / mass
        p = p + dt * v
        out.append((p, v))
    return np.array(out)


def test_a_plant_and_a_controller_defined_in_a_test_run_from_a_dict_scenario():
    assert plant_class("StructureTestSled") is StructureTestSled
    assert controller_class("StructureTestPD") is StructureTestPD
    assert "StructureTestSled" not in PLANTS and "StructureTestPD" not in CONTROLLERS  # shipped views only
    assert StructureTestPD.stateful is False  # no reset of its own: memoryless by default
    sim = RobotSim.from_config(SCENARIO)
    result = sim.run()
    np.testing.assert_allclose(result.x, sled_reference([1.0, 0.0], 800, 0.01, 2.0), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(result.u_max, [5.0])  # the loop read the bounds through the contract
    assert result.metrics["final_error"] < 0.01 and result.metrics["max_abs_input"] <= 5.0


def test_the_controller_is_fed_the_estimate_not_the_plant_state():
    sim = RobotSim.from_config(SCENARIO)
    bias = np.array([0.05, -0.02])
    sim.estimator = StructureTestBiased(bias)
    result = sim.run(1.0)
    np.testing.assert_array_equal(sim.estimator.reset_to, [1.0, 0.0])  # reset to the initial state
    np.testing.assert_allclose(result.x, sled_reference([1.0, 0.0], 100, 0.01, 2.0, bias), rtol=0, atol=1e-12)
    np.testing.assert_allclose(sim.controller.calls[0], [1.05, -0.02])


# ----------------------------------------------------------- the registries
REGISTRIES = [(PLANT_REGISTRY, Plant, "plants"), (CONTROLLER_REGISTRY, Controller, "controllers")]
REGISTRIES.append((ESTIMATOR_REGISTRY, Estimator, "estimators"))


def test_one_registry_convention_for_plants_controllers_and_estimators():
    assert plant_class("cartpole") is CartPole is PLANT_REGISTRY.lookup("CartPole")
    assert controller_class("LQR") is LQR and estimator_class("KalmanFilter") is KalmanFilter
    for registry, _, package in REGISTRIES:  # defined here: registered, not shipped
        assert registry.package == f"shinro_ctrl.{package}"
        mine = {"plants": "StructureTestSled", "controllers": "StructureTestPD", "estimators": "StructureTestBiased"}
        assert mine[package] in registry.names() and mine[package] not in registry.names(shipped=True)
        assert all(cls.__module__.startswith(registry.package + ".") for cls in registry.shipped().values())
    assert set(PLANTS) == set(PLANT_REGISTRY.names(shipped=True)) and set(CONTROLLERS) == set(
        CONTROLLER_REGISTRY.names(shipped=True)
    )
    assert {"LQR", "LinearMPC", "NonlinearMPC", "TVLQR", "IKQP"} <= set(CONTROLLERS)


@pytest.mark.parametrize(
    ("lookup", "typo", "message"),
    [
        (plant_class, "CartPol", "unknown plant type 'CartPol'; did you mean 'CartPole'?"),
        (plant_class, "cartpol", "unknown plant type 'cartpol'; did you mean 'cartpole'?"),
        (controller_class, "LinearMCP", "unknown controller type 'LinearMCP'; did you mean 'LinearMPC'?"),
        (estimator_class, "KalmanFiltr", "unknown estimator type 'KalmanFiltr'; did you mean 'KalmanFilter'?"),
        (estimator_class, "zzzz", "unknown estimator type 'zzzz'; valid: "),
    ],
)
def test_an_unknown_name_says_which_was_meant(lookup, typo, message):
    with pytest.raises(ConfigError) as info:
        lookup(typo)
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


def test_a_taken_name_from_another_module_is_refused_and_the_shipped_class_stays():
    def body(module: str) -> dict:
        return {"__module__": module, "from_plant": classmethod(lambda cls, plant: cls()), "__call__": lambda s, x: x}

    with pytest.raises(InvalidArgument, match=r"controller name 'LQR' of elsewhere.LQR is taken by shinro_ctrl"):
        type("LQR", (Controller,), body("elsewhere"))
    assert controller_class("LQR") is LQR
    with pytest.raises(InvalidArgument, match="plant name 'cartpole'"):
        type("OtherCart", (Plant,), {"__module__": "elsewhere", "aliases": ("cartpole",)})
    assert plant_class("cartpole") is CartPole and "OtherCart" not in PLANT_REGISTRY
    first = type("RedefinedHere", (Controller,), body(__name__))
    second = type("RedefinedHere", (Controller,), body(__name__))  # the same module: a redefinition replaces
    assert first is not second and controller_class("RedefinedHere") is second


def test_abstract_and_private_classes_are_not_registered():
    class AbstractHere(Controller):  # from_plant and __call__ left abstract
        pass

    class _PrivateFilter(Estimator):
        def reset(self, x0_hat, P0=None) -> None: ...

        def update(self, y, u):
            return y

    assert "AbstractHere" not in CONTROLLER_REGISTRY and "_PrivateFilter" not in ESTIMATOR_REGISTRY
    assert "Controller" not in CONTROLLER_REGISTRY and "Estimator" not in ESTIMATOR_REGISTRY


def test_importing_a_package_registers_every_class_its_modules_define():
    """A module the package ``__init__`` forgets to import would register its classes only on a later import."""
    script = (
        "import importlib, pkgutil, shinro_ctrl.{p} as pkg\n"
        "from shinro_ctrl.{p}.base import {r} as reg\n"
        "before = reg.names()\n"
        "for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'):\n"
        "    importlib.import_module(m.name)\n"
        "print(before == reg.names(), before, reg.names())\n"
    )
    names = {"plants": "PLANT_REGISTRY", "controllers": "CONTROLLER_REGISTRY", "estimators": "ESTIMATOR_REGISTRY"}
    for package, registry in names.items():
        out = subprocess.run(
            [sys.executable, "-c", script.format(p=package, r=registry)], capture_output=True, text=True, check=True
        ).stdout
        assert out.startswith("True"), f"{package}: {out}"


def test_no_package_hides_its_names_behind_a_module_getattr():
    """Eager imports: static tools (and ``from shinro_ctrl.controllers import LinearMPC``) see every name."""
    bad = [
        path.relative_to(PACKAGE).as_posix()
        for path in PACKAGE.rglob("__init__.py")
        for node in _tree(path).body
        if isinstance(node, ast.FunctionDef) and node.name in ("__getattr__", "__dir__")
    ]
    assert not bad, bad


def test_each_cli_command_is_registered_beside_its_handler():
    import argparse

    from shinro_ctrl.cli import COMMANDS, build_parser

    seen = []
    for register in COMMANDS:
        sub = argparse.ArgumentParser().add_subparsers()
        register(sub)
        for name, parser in sub.choices.items():
            handler = parser.get_default("func")
            assert handler.__module__ == register.__module__ and handler.__name__ == f"cmd_{name}", name
            seen.append(name)
    commands = build_parser()._subparsers._group_actions[0].choices
    assert seen == list(commands) and {"run", "list", "sweep"} <= set(seen)


# ----------------------------------------------------------- the shipped arm
def test_arm6_ignores_an_arm6_toml_in_the_working_directory(tmp_path, monkeypatch):
    (tmp_path / "arm6.toml").write_text(
        '[plant]\ntype = "ArmRobot"\nnum_dof = 6\ndt = 0.01\njoint_names = ["a", "b", "c", "d", "e", "f"]\n'
        'rot_axes = ["x", "x", "x", "x", "x", "x"]\njoint_offsets = [[1, 0, 0], [1, 0, 0], [1, 0, 0], '
        "[1, 0, 0], [1, 0, 0], [1, 0, 0]]\njoint_limits = [[-1, 1], [-1, 1], [-1, 1], [-1, 1], [-1, 1], [-1, 1]]\n"
    )
    monkeypatch.chdir(tmp_path)
    arm = ArmRobot()
    shipped = tomllib.loads(shipped_config("arm6.toml").read_text())["plant"]  # the shipped file, read here
    np.testing.assert_array_equal(arm.joint_offsets, shipped["joint_offsets"])
    np.testing.assert_array_equal(arm.joint_limits, shipped["joint_limits"])
    assert arm.axes == tuple(shipped["rot_axes"]) and arm.joint_names == tuple(shipped["joint_names"])
    assert arm.dt == shipped["dt"]
    assert {k: v for k, v in shipped.items() if k != "type"} == ARM6  # the constant and the scenario agree


# ----------------------------------------------------------- layering
@functools.cache
def _tree(path: Path) -> ast.Module:
    """The parsed source of ``path``, parsed once per test process (the rules below each read every module)."""
    return ast.parse(path.read_text(), str(path))


def _imports(path: Path) -> set[str]:
    """Absolute names of every module ``path`` imports (relative imports resolved)."""
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = list(rel.parts)
    package = parts[:-1]  # the package of a module, and of an __init__ its own
    out: set[str] = set()
    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)
    return out


def _modules(sub: str) -> list[Path]:
    return sorted((PACKAGE / sub).rglob("*.py")) if sub else sorted(PACKAGE.rglob("*.py"))


def _under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


#: The one agreed exception: MjcfPlant reads MJCF/URDF models with the engine's model-file readers
#: (model_tree: the model itself; model_gap: what MuJoCo has that the smooth model leaves out).
PLANT_ENGINE_EXCEPTIONS = {
    ("plants/mjcf.py", "shinro_ctrl.engine.model_tree"),
    ("plants/mjcf.py", "shinro_ctrl.engine.model_gap"),
}


def _from_exception(path: Path, allowed: list[str]) -> bool:
    """True when every statement naming ``shinro_ctrl.engine`` in ``path`` imports from an ``allowed`` module."""

    def ok(name: str) -> bool:
        return any(_under(name, m) for m in allowed)

    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.ImportFrom) and _under(node.module or "", "shinro_ctrl.engine"):
            if not ok(node.module):
                return False
        if isinstance(node, ast.Import) and any(_under(a.name, "shinro_ctrl.engine") for a in node.names):
            if not all(ok(a.name) for a in node.names):
                return False
    return True


def test_plants_import_neither_controllers_nor_the_engine():
    bad = []
    for path in _modules("plants"):
        rel = path.relative_to(PACKAGE).as_posix()
        allowed = [m for r, m in PLANT_ENGINE_EXCEPTIONS if r == rel]
        for name in _imports(path):
            if _under(name, "shinro_ctrl.controllers"):
                bad.append(f"{rel}: {name}")
            elif _under(name, "shinro_ctrl.engine") and not any(_under(name, m) for m in allowed):
                # "from shinro_ctrl.engine.model_tree import x" also yields its parent "shinro_ctrl.engine"
                if not (name == "shinro_ctrl.engine" and allowed and _from_exception(path, allowed)):
                    bad.append(f"{rel}: {name}")
    assert not bad, bad


def test_controllers_import_neither_the_engine_nor_the_scenario_layer():
    banned = ("shinro_ctrl.engine", "shinro_ctrl.config", "shinro_ctrl.sim", "shinro_ctrl.sweep", "shinro_ctrl.cli")
    bad = [
        f"{path.relative_to(PACKAGE).as_posix()}: {name}"
        for path in _modules("controllers")
        for name in _imports(path)
        if any(_under(name, b) for b in banned)
    ]
    assert not bad, bad


def test_only_the_engine_package_imports_mujoco():
    bad = [
        f"{path.relative_to(PACKAGE).as_posix()}: {name}"
        for path in _modules("")
        if not path.relative_to(PACKAGE).as_posix().startswith("engine/")
        for name in _imports(path)
        if _under(name, "mujoco")
    ]
    assert not bad, bad


def test_resources_imports_nothing_else_from_the_package():
    """The engine finds its assets through shinro_ctrl.resources, so that module stays a leaf of the core."""
    path = PACKAGE / "resources.py"
    bad = [name for name in _imports(path) if _under(name, "shinro_ctrl")]
    assert not bad, bad


def test_no_private_name_in_any_all():
    bad = []
    for path in _modules(""):
        for node in _tree(path).body:
            targets = (
                node.targets
                if isinstance(node, ast.Assign)
                else [node.target]
                if isinstance(node, ast.AnnAssign)
                else []
            )
            if any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets) and node.value is not None:
                names = ast.literal_eval(node.value)
                bad += [
                    f"{path.relative_to(PACKAGE).as_posix()}: {n}"
                    for n in names
                    if n.startswith("_") and n != "__version__"
                ]
    assert not bad, bad


# ----------------------------------------------------------- composition, not mixins
def _self_attributes(cls: ast.ClassDef) -> tuple[set[str], dict[str, int]]:
    """Names ``cls`` defines (its body, and ``self.x = ...`` in its methods) and the ``self.x`` it reads (-> line)."""
    defined: set[str] = set()
    reads: dict[str, int] = {}
    for node in cls.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            defined.add(node.name)
        elif isinstance(node, ast.Assign):
            defined |= {t.id for t in node.targets if isinstance(t, ast.Name)}
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            defined.add(node.target.id)
    for fn in cls.body:
        if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef) or not fn.args.args:
            continue
        if any(isinstance(d, ast.Name) and d.id == "staticmethod" for d in fn.decorator_list):
            continue
        me = fn.args.args[0].arg  # self (or cls)
        for node in ast.walk(fn):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == me:
                if isinstance(node.ctx, ast.Load):
                    reads.setdefault(node.attr, node.lineno)
                else:
                    defined.add(node.attr)
    return defined, reads


def _package_classes() -> dict[str, list[tuple[str, ast.ClassDef]]]:
    out: dict[str, list[tuple[str, ast.ClassDef]]] = {}
    for path in _modules(""):
        for node in ast.walk(_tree(path)):
            if isinstance(node, ast.ClassDef):
                out.setdefault(node.name, []).append((path.relative_to(PACKAGE).as_posix(), node))
    return out


def test_no_mixin_reads_attributes_it_does_not_define():
    """A class named ``*Mixin`` uses only what it defines itself (issue 24 Keep: composition, not mixins)."""
    bad = []
    for name, entries in _package_classes().items():
        for rel, node in entries:
            if name.endswith("Mixin"):
                defined, reads = _self_attributes(node)
                missing = sorted(a for a in reads if a not in defined and not (a.startswith("__") and a.endswith("__")))
                bad += [f"{rel}:{reads[a]} {name} reads self.{a}" for a in missing]
    assert not bad, bad


def test_no_class_reads_a_private_attribute_that_only_another_class_defines():
    """``self._x`` read in a class must be defined by it or by one of its bases in the package (issue 24.1: no
    mixin reads another class's private attributes)."""
    classes = _package_classes()

    def bases(node: ast.ClassDef) -> list[str]:
        names = []
        for b in node.bases:
            b = b.value if isinstance(b, ast.Subscript) else b
            names.append(b.id if isinstance(b, ast.Name) else b.attr if isinstance(b, ast.Attribute) else "")
        return names

    def defined_with_bases(node: ast.ClassDef, seen: set[int]) -> set[str]:
        defined = _self_attributes(node)[0]
        for base in bases(node):
            for _, base_node in classes.get(base, []):
                if id(base_node) not in seen:
                    seen.add(id(base_node))
                    defined |= defined_with_bases(base_node, seen)
        return defined

    bad = []
    for name, entries in classes.items():
        for rel, node in entries:
            reads = _self_attributes(node)[1]
            defined = defined_with_bases(node, set())
            missing = sorted(a for a in reads if a.startswith("_") and not a.startswith("__") and a not in defined)
            bad += [f"{rel}:{reads[a]} {name} reads self.{a}" for a in missing]
    assert not bad, bad


# ----------------------------------------------------------- solver objects stay inside their backends
#: The modules that may create or call a solver object (package-relative). Every other module reaches a
#: solver through one of these objects' methods. Adjust when a backend moves.
SOLVER_BACKENDS = {
    "controllers/_osqp.py": "OsqpQP, the adapter owning OSQP's solver object (and its compiled solver)",
    "controllers/qp/backend_osqp.py": "LinearMPC's OSQP backend (holds an OsqpQP)",
    "controllers/qp/backend_daqp.py": "LinearMPC's DAQP backend (holds the condensed QP)",
    "controllers/qp/condensed.py": "the condensed QP and its daqp.Model",
    "controllers/qp/ltv.py": "NonlinearMPC's condensed LTV QP (daqp.solve)",
    "controllers/qp/ltv_sparse.py": "NonlinearMPC's sparse LTV QP (holds an OsqpQP)",
    "controllers/qp/prestabilized.py": "NonlinearMPC's QP around its Riccati step (daqp.solve)",
    "controllers/_nmpc_rti.py": "NonlinearMPC's real-time-iteration strategy",
    "controllers/_nmpc_ipopt.py": "NonlinearMPC's IPOPT strategy (casadi.nlpsol)",
    "multibody/contacts.py": "the standing-equilibrium QP of a contact model (casadi.nlpsol, IPOPT)",
    "controllers/_ik_parts.py": "IKQP's box QP (holds an OsqpQP)",
    "planning/collocation.py": "trajectory optimization (casadi.nlpsol with IPOPT)",
    "identification/estimate.py": "grey-box identification (casadi.nlpsol with IPOPT)",
}
#: Solver package -> the names that create or call a solver object; casadi's solver factories; our adapter.
SOLVER_ENTRIES = {"osqp": {"OSQP"}, "daqp": {"Model", "solve"}}
CASADI_SOLVERS = {"nlpsol", "qpsol", "conic"}
SOLVER_WRAPPERS = {"OsqpQP"}


def _solver_uses(path: Path) -> set[str]:
    tree = _tree(path)
    alias: dict[str, str] = {}
    uses: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            alias.update({a.asname or a.name: a.name for a in node.names if a.name in SOLVER_ENTRIES})
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module in SOLVER_ENTRIES:
            uses |= {f"{node.module}.{a.name}" for a in node.names if a.name in SOLVER_ENTRIES[node.module]}
        if isinstance(node, ast.ImportFrom):
            uses |= {a.name for a in node.names if a.name in SOLVER_WRAPPERS}
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            owner = node.value.id if isinstance(node.value, ast.Name) else None
            if owner in alias and node.attr in SOLVER_ENTRIES[alias[owner]]:
                uses.add(f"{alias[owner]}.{node.attr}")
            if node.attr in CASADI_SOLVERS or node.attr in SOLVER_WRAPPERS:
                uses.add(node.attr)
        elif isinstance(node, ast.Name) and node.id in SOLVER_WRAPPERS:
            uses.add(node.id)
    return uses


def test_nothing_outside_a_solver_backend_touches_a_solver_object():
    found = {path.relative_to(PACKAGE).as_posix(): _solver_uses(path) for path in _modules("")}
    bad = [f"{rel}: {sorted(uses)}" for rel, uses in sorted(found.items()) if uses and rel not in SOLVER_BACKENDS]
    assert not bad, bad
    assert found["controllers/_osqp.py"] and found["planning/collocation.py"]  # the check sees real uses


def test_only_the_osqp_adapter_mentions_the_private_solver():
    word = re.compile(r"\b" + "_" + "solver" + r"\b")  # split so this file does not mention it
    files = [*PACKAGE.rglob("*.py"), *TESTS.rglob("*.py"), *(PACKAGE.parent / "benchmarks").rglob("*.py")]
    bad = [str(p) for p in files if p != PACKAGE / "controllers" / "_osqp.py" and word.search(p.read_text())]
    assert not bad, bad


#: Private names of other libraries the package reads on purpose (each documented where it is read).
FOREIGN_PRIVATE = {
    "_" + "solver",  # osqp.OSQP's compiled solver object (controllers/_osqp.py: the fast path)
    "_actions",  # argparse parsers' actions (cli/common.py: listing the options of a command)
    "_SubParsersAction",  # argparse's subparser type (type hints of each command's register())
    "_processes",  # a ProcessPoolExecutor's workers (sweep/executors.py: naming a killed worker)
}


def test_no_module_reads_a_private_attribute_of_another_object():
    """``obj._x`` (or ``getattr(obj, "_x")``) with ``obj`` other than ``self``/``cls`` reaches into another
    object's internals (issue 24.1); only the listed private names of other libraries are read."""
    bad = []
    for path in _modules(""):
        rel = path.relative_to(PACKAGE).as_posix()
        tree = _tree(path)
        own = {"self", "cls"}  # and objects a classmethod makes with cls.__new__(cls)
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Assign)
                and isinstance(node.value, ast.Call)
                and isinstance(node.value.func, ast.Attribute)
                and node.value.func.attr == "__new__"
            ):
                own |= {t.id for t in node.targets if isinstance(t, ast.Name)}
        for node in ast.walk(tree):
            name = None
            if (
                isinstance(node.value if isinstance(node, ast.Attribute) else None, ast.Call)
                and isinstance(node.value.func, ast.Name)
                and node.value.func.id == "super"
            ):
                continue  # super()._x: the class's own base
            if isinstance(node, ast.Attribute) and not (isinstance(node.value, ast.Name) and node.value.id in own):
                name = node.attr
            elif (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name)
                and node.func.id in ("getattr", "hasattr", "setattr")
                and len(node.args) >= 2
                and isinstance(node.args[1], ast.Constant)
                and isinstance(node.args[1].value, str)
            ):
                name = node.args[1].value
            if name and name.startswith("_") and not name.startswith("__") and name not in FOREIGN_PRIVATE:
                bad.append(f"{rel}:{node.lineno} {ast.unparse(node)}")
    assert not bad, bad
