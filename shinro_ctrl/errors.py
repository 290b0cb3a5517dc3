"""The exception vocabulary of shinro_ctrl.

Every error a user can cause derives from :class:`ShinroError`. Each subclass
also derives from the built-in exception a caller would naturally catch, so
``except ValueError`` keeps working for code that does not know our names.
Solver and library exceptions (scipy, OSQP, CasADi, MuJoCo) are caught at the
boundary and re-raised as one of these, with context.
"""

from __future__ import annotations

__all__ = [
    "ConcurrentUse",
    "ConfigError",
    "IdentificationError",
    "InvalidArgument",
    "MPCInfeasible",
    "NonFiniteError",
    "NotStabilizable",
    "PlanningFailed",
    "ShinroError",
    "SimulationDiverged",
    "UnknownName",
]


class ShinroError(Exception):
    """Root of every error raised on purpose by shinro_ctrl."""


class ConfigError(ShinroError, ValueError):
    """A scenario file or config dict is malformed, unknown or out of range."""


class InvalidArgument(ShinroError, ValueError):
    """An argument has the wrong shape, type or value; the message names it and says what was expected."""


class UnknownName(ShinroError, KeyError):
    """A joint, actuator, body or other named item does not exist; the message lists the valid names."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class NonFiniteError(ShinroError, FloatingPointError, ValueError):
    """A state, input or parameter contains NaN or infinity."""


class NotStabilizable(ShinroError, ValueError):
    """A linear pair (A, B) has an unstable mode that the input cannot reach."""


class MPCInfeasible(ShinroError, RuntimeError):
    """An MPC problem could not be solved (infeasible or out of iterations)."""


class SimulationDiverged(ShinroError, RuntimeError):
    """A simulation produced non-finite values or a physics-engine warning."""


class ConcurrentUse(ShinroError, RuntimeError):
    """A call entered an object that another thread is using; use one object per thread."""


class PlanningFailed(ShinroError, RuntimeError):
    """A trajectory optimization did not converge; the message names the solver status and the worst constraint."""


class IdentificationError(ShinroError, ValueError):
    """Data that cannot identify the parameters asked for (too little excitation); the message names them."""
