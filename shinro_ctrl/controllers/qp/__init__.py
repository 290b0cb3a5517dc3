"""The QP layer under the MPC controllers.

``LinearMPC``'s two backends are objects behind one interface, one file each
(``backend_osqp.py``: the sparse QP of ``sparse.py`` solved by OSQP through the
one adapter in ``controllers/_osqp.py``; ``backend_daqp.py``: the condensed,
input-only QP of ``condensed.py`` around a pre-stabilizing feedback, solved by
DAQP's dual active-set method), named in ``dispatch.BACKENDS``; ``options.py``
holds :class:`~.options.MPCOptions` and ``solution.py`` the per-call results.
``NonlinearMPC``'s real-time iteration uses ``ltv.py`` (the condensed LTV QP),
``ltv_sparse.py`` (the sparse one, OSQP) and ``prestabilized.py`` (the QP around
its Riccati step, in the policy's prestabilized variables).
"""
