"""Commands that inspect models: ``linearize``, ``crosscheck`` and ``list``."""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from typing import TYPE_CHECKING

from shinro_ctrl.cli.common import (
    CROSSCHECK_PLANTS,
    PLOT_HELP,
    _check_output,
    _check_step,
    parse_vector,
    path_arg,
    side_by_side,
)
from shinro_ctrl.errors import InvalidArgument

if TYPE_CHECKING:
    import numpy as np

    from shinro_ctrl.engine.model_gap import ModelGap

__all__ = ["cmd_crosscheck", "cmd_linearize", "cmd_list", "register"]


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``linearize``, ``crosscheck`` and ``list`` to the ``shinro-ctrl`` parser (``sub``: its subparsers)."""
    from shinro_ctrl.plants import PLANT_ALIASES

    p = sub.add_parser("linearize", help="exact (CasADi) and finite-difference Jacobians side by side")
    _model_arguments(p, PLANT_ALIASES)
    p.add_argument("--eps-sweep", action="store_true", help="FD error against the step size (complex-step reference)")
    p.add_argument(
        "--plot", type=path_arg, metavar="FILE", help=f"with --eps-sweep: plot the V-shaped error curve ({PLOT_HELP})"
    )
    p.set_defaults(func=cmd_linearize)

    p = sub.add_parser("crosscheck", help="exact vs finite differences vs MuJoCo's mjd_transitionFD")
    _model_arguments(p, CROSSCHECK_PLANTS)
    p.add_argument(
        "--plot", type=path_arg, metavar="FILE", help=f"draw the exact / FD / MuJoCo comparison ({PLOT_HELP})"
    )
    p.set_defaults(func=cmd_crosscheck)

    p = sub.add_parser("list", help="plants, controllers and shipped scenarios")
    p.set_defaults(func=cmd_list)


def _model_arguments(p: argparse.ArgumentParser, plants: Iterable[str]) -> None:
    """What ``linearize`` and ``crosscheck`` share: PLANT, ``--x0``, ``--u0`` and ``--eps``."""
    p.add_argument(
        "plant",
        metavar="PLANT",
        help=f"one of: {', '.join(plants)}; an MJCF/URDF file; or a scenario file or name (its plant)",
    )
    p.add_argument("--x0", help="operating state, e.g. '0,0,0.1,0' (pi allowed: 'pi,pi,0,0')")
    p.add_argument("--u0", help="operating input, e.g. '0'")
    p.add_argument("--eps", type=float, default=1e-6, help="finite-difference step (default 1e-6)")


# ------------------------------------------------------------------ linearize
def cmd_linearize(args: argparse.Namespace) -> int:
    import numpy as np

    from shinro_ctrl.linearization import compare

    if args.plot and not args.eps_sweep:
        raise InvalidArgument("--plot goes with --eps-sweep")
    _check_step("--eps", args.eps)
    if args.plot:
        _check_output(args.plot)
    plant = _plant_argument(args.plant)  # a plant name, an MJCF/URDF model file, or a scenario (its plant)
    x0 = None if args.x0 is None else parse_vector(args.x0, what="--x0")
    u0 = None if args.u0 is None else parse_vector(args.u0, what="--u0")
    cmp = compare(plant, x0, u0, eps=args.eps)
    xe, ue = plant.operating_point(x0, u0)
    print(f"{type(plant).__name__}: continuous-time Jacobians at")
    print(f"  x0 = {dict(zip(plant.state_names, [round(float(v), 6) for v in xe], strict=True))}")
    print(f"  u0 = {dict(zip(plant.input_names, [round(float(v), 6) for v in ue], strict=True))}")
    print()
    print(side_by_side([("A exact (CasADi)", cmp.A_exact), (f"A finite diff (eps={args.eps:g})", cmp.A_fd)]))
    print()
    print(side_by_side([("B exact (CasADi)", cmp.B_exact), ("B finite diff", cmp.B_fd)]))
    print()
    print(f"max |exact - fd| = {cmp.max_abs_error:.3e}   max relative = {cmp.max_rel_error:.3e}")
    if args.eps_sweep:
        from shinro_ctrl.plots.linearization import eps_sweep, plot_eps_sweep

        xs, us = xe, ue
        if args.x0 is None and args.u0 is None:
            # At an equilibrium f(x0) = 0 and FD has no rounding error to show: sweep beside it instead.
            xs = xe + 0.1 * np.arange(1, plant.state_dim + 1) / plant.state_dim
            us = ue + 0.1
            print(f"\n(no --x0 given: the sweep uses x0 = {np.round(xs, 4).tolist()}, u0 = {np.round(us, 4).tolist()},")
            print(" off the equilibrium, where f(x0) = 0 would hide FD's rounding error)")
        sweep = eps_sweep(plant, xs, us)
        print()
        print("FD error against a complex-step reference, by step size:")
        for e, err in zip(sweep.eps[::4], sweep.fd_error[::4], strict=True):
            print(f"  eps = {e:8.1e}   max error = {err:8.2e}")
        print(f"  best eps = {sweep.best_eps:.1e}; exact (CasADi) error = {sweep.exact_error:.2e}")
        if args.plot:
            print(f"plot: {plot_eps_sweep(sweep, args.plot, title=f'{type(plant).__name__}: FD step sweep')}")
    elif args.plot:
        raise InvalidArgument("--plot goes with --eps-sweep")
    return 0


# ----------------------------------------------------------------- crosscheck
def cmd_crosscheck(args: argparse.Namespace) -> int:
    from shinro_ctrl.crosscheck import crosscheck, format_crosscheck

    _check_step("--eps", args.eps)
    if args.plot:
        _check_output(args.plot, inputs=[args.plant])
    plant = _crosscheck_plant(args.plant)
    x0 = None if args.x0 is None else parse_vector(args.x0, what="--x0")
    u0 = None if args.u0 is None else parse_vector(args.u0, what="--u0")
    result = crosscheck(plant, x0, u0, eps=args.eps)
    print(format_crosscheck(result))
    gap = model_gap_of(plant, result.x0, result.u0)
    if gap is not None:
        print()
        print(gap.format())
    if args.plot:
        from shinro_ctrl.plots.linearization import plot_crosscheck

        print(f"plot: {plot_crosscheck(result, args.plot)}")
    return 0


def model_gap_of(plant: object, x0: np.ndarray, u0: np.ndarray) -> ModelGap | None:
    """The model-gap report of a plant built from a model file at ``(x0, u0)``; None for other plants."""
    from shinro_ctrl.plants import MjcfPlant

    return plant.model_gap(x0, u0) if isinstance(plant, MjcfPlant) else None


# ----------------------------------------------------------------------- list
def cmd_list(args: argparse.Namespace) -> int:
    from shinro_ctrl.controllers import CONTROLLER_REGISTRY
    from shinro_ctrl.estimators import ESTIMATOR_REGISTRY
    from shinro_ctrl.plants import PLANT_REGISTRY
    from shinro_ctrl.resources import list_configs

    alias = {v: k for k, v in PLANT_REGISTRY.aliases.items()}
    print("plants:")
    for name, cls in PLANT_REGISTRY.shipped().items():
        doc = (cls.__doc__ or "").strip().splitlines()[0]
        print(f"  {name:22s} {alias.get(name, ''):16s} {doc}")
    print("controllers:")
    for name in CONTROLLER_REGISTRY.names(shipped=True):
        print(f"  {name}")
    print("estimators:")
    for name in ESTIMATOR_REGISTRY.names(shipped=True):
        print(f"  {name}")
    print("scenarios:")
    for name in list_configs():
        print(f"  {name}")
    return 0


def _plant_argument(name: str):
    """The PLANT argument: a plant class name or alias, an MJCF/URDF model file, or a scenario as ``run`` takes
    it (a file, or a shipped name such as ``cartpole_lqr``) whose plant, with its parameters, is used.

    Raises:
        ConfigError: neither a plant nor a scenario (naming both kinds), or an invalid scenario.
    """
    from pathlib import Path

    from shinro_ctrl.errors import ConfigError
    from shinro_ctrl.plants import is_model_file, plant_class, plant_from_name

    if not name.strip():
        raise InvalidArgument(
            "PLANT is empty (an unset shell variable?): give a plant name, a model file or a scenario"
        )
    if Path(name).is_dir() and not _is_plant_name(name):
        raise IsADirectoryError(f"'{name}' is a folder, not a plant name, model file or scenario file")
    if is_model_file(name):  # an MJCF/URDF model file: the plant is the file
        return plant_from_name(name)
    if Path(name).is_file() or name.lower().endswith(".toml"):
        return _scenario_plant(name, plant_class)
    try:
        return plant_from_name(name)
    except ConfigError as exc:
        from shinro_ctrl.resources import config_path

        try:
            config_path(name)
        except FileNotFoundError:
            raise ConfigError(f"{exc}; or give a scenario file or shipped scenario name (shinro-ctrl list)") from None
        return _scenario_plant(name, plant_class)


def _is_plant_name(name: str) -> bool:
    """``name`` is a plant class name or alias (a same-named folder in the current directory does not shadow it)."""
    from shinro_ctrl.plants import PLANT_ALIASES, PLANT_REGISTRY

    return name in PLANT_ALIASES or name in PLANT_REGISTRY.shipped()


def _scenario_plant(name: str, plant_class):
    from shinro_ctrl.config import load_scenario

    scenario = load_scenario(name)
    return plant_class(scenario.plant.type).from_config(scenario.plant.params)


def _crosscheck_plant(name: str):
    """A plant as :func:`_plant_argument`, one whose MuJoCo model maps onto its state."""
    from shinro_ctrl.plants import PLANT_ALIASES

    plant = _plant_argument(name)
    supported = {PLANT_ALIASES.get(a, a) for a in CROSSCHECK_PLANTS} | {"MjcfPlant"}
    if type(plant).__name__ not in supported:
        raise InvalidArgument(
            f"crosscheck supports {', '.join(CROSSCHECK_PLANTS)} (plants whose MuJoCo model maps onto their state); "
            f"got {type(plant).__name__}"
        )
    return plant
