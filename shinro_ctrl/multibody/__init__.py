"""Exact rigid-body dynamics of robots read from model files.

* :mod:`~shinro_ctrl.multibody.tree`: the plain description (bodies, joints,
  actuators, options) a model file is read into;
* :mod:`~shinro_ctrl.multibody.rigid_body`: :class:`RigidBodyTree`, its
  equations of motion on any scalar type (CasADi ``SX``, floats, complex);
* :mod:`~shinro_ctrl.multibody.transmission`: actuator transmissions (joint,
  fixed tendon, site), the force law and activation dynamics;
* :mod:`~shinro_ctrl.multibody.constraints`: :class:`Constraint` (joint
  couplings, connect, weld) and :class:`ConstrainedDynamics`, the exact KKT
  dynamics in the coordinates the constraints leave free;
* :mod:`~shinro_ctrl.multibody.configuration`: ball and free joints' quaternion
  configurations: ``qpos`` rates, ``integrate``/``difference`` on the manifold
  (MuJoCo's ``mj_integratePos``/``mj_differentiatePos``);
* :mod:`~shinro_ctrl.multibody.aba`: forward dynamics by the articulated-body
  algorithm (the default behind ``RigidBodyTree.forward_dynamics``).
"""

from shinro_ctrl.multibody.constraints import ConstrainedDynamics, Constraint
from shinro_ctrl.multibody.rigid_body import CASADI_OPS, FORWARD_DYNAMICS, NUMPY_OPS, Ops, RigidBodyTree, Scalar
from shinro_ctrl.multibody.transmission import Transmissions
from shinro_ctrl.multibody.tree import ActuatorInfo, BodyInfo, JointInfo, ModelTree, SiteInfo, TendonInfo

__all__ = [
    "CASADI_OPS",
    "FORWARD_DYNAMICS",
    "NUMPY_OPS",
    "ActuatorInfo",
    "BodyInfo",
    "ConstrainedDynamics",
    "Constraint",
    "JointInfo",
    "ModelTree",
    "Ops",
    "RigidBodyTree",
    "Scalar",
    "SiteInfo",
    "TendonInfo",
    "Transmissions",
]
