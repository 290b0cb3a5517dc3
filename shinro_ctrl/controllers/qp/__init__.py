"""The QP layer under the MPC controllers.

The sparse formulation (states and inputs as variables, solved by OSQP
through the one adapter in ``controllers/_osqp.py``) and the condensed one
(inputs only, around a pre-stabilizing feedback, solved by DAQP's dual
active-set method) live here, each in a module of its own.
"""
