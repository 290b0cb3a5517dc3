"""The input rows' active set a DAQP solve starts from, carried from one real-time-iteration solve to the next."""

from __future__ import annotations

import numpy as np

__all__ = ["InputActiveSet"]


class InputActiveSet:
    """DAQP's sense of each of the ``N m`` input rows: ``1`` active at its upper bound, ``3`` at its lower, ``0`` not.

    Held by the condensed LTV QP and the prestabilized QP of the real-time iteration: :meth:`record` keeps the
    active set of a solve, :meth:`shift` moves it one stage on (the RTI shift), and the QP copies :attr:`sense`
    into DAQP's ``sense`` before the next solve.

    Args:
        nu: Number of input rows ``N m``.
        m: Inputs per stage.
    """

    def __init__(self, nu: int, m: int):
        self.sense = np.zeros(nu, dtype=np.int32)
        self.m = m

    def shift(self) -> None:
        """One stage on: stage ``k + 1``'s rows become stage ``k``'s; the last stage starts inactive."""
        m = self.m
        self.sense[:-m] = self.sense[m:]
        self.sense[-m:] = 0

    def clear(self) -> None:
        """No row active."""
        self.sense[:] = 0

    def record(self, lam_u: np.ndarray, solved: bool) -> None:
        """The rows a solve left active, from DAQP's multipliers ``lam_u (N m,)`` (> 0 upper, < 0 lower);
        none after a failed solve."""
        self.sense[:] = 0
        if solved:
            self.sense[lam_u > 0] = 1
            self.sense[lam_u < 0] = 3
