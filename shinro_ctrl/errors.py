"""The exception vocabulary of shinro_ctrl.

Every error a user can cause derives from :class:`ShinroError`. Each subclass
also derives from the built-in exception a caller would naturally catch, so
``except ValueError`` keeps working for code that does not know our names.
Solver and library exceptions (scipy, OSQP, CasADi, MuJoCo) are caught at the
boundary and re-raised as one of these, with context.
"""

from __future__ import annotations

__all__ = [
    "ConfigError",
    "MPCInfeasible",
    "NonFiniteError",
    "NotStabilizable",
    "ShinroError",
    "SimulationDiverged",
]


class ShinroError(Exception):
    """Root of every error raised on purpose by shinro_ctrl."""


class ConfigError(ShinroError, ValueError):
    """A scenario file or config dict is malformed, unknown or out of range."""


class NonFiniteError(ShinroError, FloatingPointError, ValueError):
    """A state, input or parameter contains NaN or infinity."""


class NotStabilizable(ShinroError, ValueError):
    """A linear pair (A, B) has an unstable mode that the input cannot reach."""


class MPCInfeasible(ShinroError, RuntimeError):
    """An MPC problem could not be solved (infeasible or out of iterations)."""


class SimulationDiverged(ShinroError, RuntimeError):
    """A simulation produced non-finite values or a physics-engine warning."""
