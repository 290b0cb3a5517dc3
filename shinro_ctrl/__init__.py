"""shinro_ctrl: a model-based control design workbench.

Plants write their dynamics once (numpy and CasADi from one definition);
exact linearizations feed LQR, linear MPC (DAQP or OSQP), nonlinear MPC,
TVLQR and IK-QP controllers, which are validated in closed loop against the
plant's own integration and against a matched MuJoCo model.

The package root holds the error vocabulary (:mod:`shinro_ctrl.errors`):
every error a user can cause derives from :class:`ShinroError`.
"""

from shinro_ctrl.errors import (
    ConcurrentUse,
    ConfigError,
    IdentificationError,
    InvalidArgument,
    MPCInfeasible,
    NonFiniteError,
    NotStabilizable,
    PlanningFailed,
    ShinroError,
    SimulationDiverged,
    UnknownName,
)

__version__ = "0.1.0"

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
    "__version__",
]
