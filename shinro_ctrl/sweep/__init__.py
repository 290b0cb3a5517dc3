"""Robustness sweeps: one nominal controller evaluated on many perturbed plants.

The controller is designed once, on the plant the scenario describes (the
*nominal* plant). Each sample then rebuilds the plant (and, for a MuJoCo loop,
its engine via :meth:`MujocoEngine.for_plant`) from the ``[plant]`` table with
some parameters changed, and runs the scenario's closed loop with the nominal
controller. The parameters are drawn up-front in the calling process (uniform
Monte-Carlo from a seeded ``numpy`` generator, or a full grid), so the table
depends only on the scenario, the ranges, ``samples``/``grid`` and ``seed``:
never on the worker count or the executor.

Stability rule (per sample): **stable** iff the run completed without raising,
every state stayed finite, and the final tracking error
``metrics["final_error"]`` (the norm over the tracked states at the last step)
is below ``stable_tol``, by default ``10 × [sim] settle_tol``. A sample that
raises (``SimulationDiverged``, ``MPCInfeasible``, ``NonFiniteError``, any
``ShinroError``, an invalid parameter such as a negative mass, a numeric
overflow) is recorded with its message and marked unstable; it never aborts
the sweep. A diverging MuJoCo sample prints nothing: the engine records
MuJoCo's warning text instead of letting the C library print it (see
:mod:`shinro_ctrl.engine`), and the ``SimulationDiverged`` message, which
quotes it, goes in the table.

Executors (``method``):

* ``"serial"``: in this process, one sample after another.
* ``"pool"``: a local :class:`~concurrent.futures.ProcessPoolExecutor`
  (``forkserver`` processes); the scenario document and chunks of parameter
  rows are sent, each worker rebuilds and caches the nominal sim.
* ``"dask"``: the same chunks on a Dask cluster (``scheduler`` = the address
  of a ``dask.distributed`` scheduler; needs the ``distributed`` extra).
* ``"batch"``: the vectorized rollout of :mod:`shinro_ctrl.sweep.batch`: every
  instance advances in one numpy evaluation of the plant's dynamics per step
  (standalone loop, LQR, constant reference, no measurement noise, a plant
  whose constructor parameters are its dynamics parameters).
* ``"auto"`` (default): ``dask`` when a scheduler is given, else ``batch``
  when it applies, else ``pool`` (``serial`` for one worker).

Determinism: the table (:meth:`SweepResult.table`, ``sweep.csv`` and the
``rows`` of ``sweep.json``) holds only what the seed decides: the parameters,
the metrics of :data:`TABLE_METRICS`, the verdict and the error text. The
same scenario, ranges and seed give the same table, byte for byte, whatever
the executor or worker count (the batch rollout agrees to rounding). Wall-clock
measurements are kept out of it: each sample's ``solve_time_median_s`` (see
:data:`WALL_CLOCK_METRICS`) is in :attr:`SweepRow.timing`, and in
``sweep.json`` under ``"timings"`` (``"per_sample"``, by index), beside the
sweep's own ``elapsed_s``.

Output (``out``): ``sweep.csv``, ``sweep.json`` and ``sweep.png``, written
atomically.

Modules: :mod:`~shinro_ctrl.sweep.spec` (ranges, keys, samples),
:mod:`~shinro_ctrl.sweep.executors` (the per-sample sim and the executors),
:mod:`~shinro_ctrl.sweep.result` (the table and its plot) and
:mod:`~shinro_ctrl.sweep.run` (:func:`run_sweep`).
"""

from shinro_ctrl.sweep.executors import perturbed_sim
from shinro_ctrl.sweep.result import SweepResult, SweepRow
from shinro_ctrl.sweep.run import run_sweep
from shinro_ctrl.sweep.spec import (
    METHODS,
    TABLE_METRICS,
    WALL_CLOCK_METRICS,
    draw_samples,
    parse_param,
    parse_params,
    sweep_keys,
)

__all__ = [
    "METHODS",
    "TABLE_METRICS",
    "WALL_CLOCK_METRICS",
    "SweepResult",
    "SweepRow",
    "draw_samples",
    "parse_param",
    "parse_params",
    "perturbed_sim",
    "run_sweep",
    "sweep_keys",
]
