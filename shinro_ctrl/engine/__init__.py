"""MuJoCo engine: the one module of shinro_ctrl that imports ``mujoco``.

:class:`MujocoEngine` wraps an ``MjModel`` / ``MjData`` pair with named,
checked access to joints, actuators, bodies and sites, and turns MuJoCo's
silent failure modes into exceptions:

* an unknown name raises ``KeyError`` listing the names the model has;
* a non-finite control or state written through the engine raises
  :class:`~shinro_ctrl.errors.NonFiniteError` before it reaches ``MjData``;
* after every :meth:`MujocoEngine.step` the engine compares MuJoCo's warning
  counters with the last ones it saw (MuJoCo answers a NaN or huge
  acceleration, velocity, position or control by printing a warning and
  resetting the state) and checks that ``qpos`` / ``qvel`` are finite; either
  failure raises :class:`~shinro_ctrl.errors.SimulationDiverged` naming the
  warning and the simulation time.

MuJoCo's own warning text: left alone, MuJoCo prints each warning (``WARNING:
Nan, Inf or huge value in QACC at DOF 0. The simulation is unstable. ...``) to
stdout from C and appends it to ``MUJOCO_LOG.TXT`` in the current directory.
The first :class:`MujocoEngine` created in a process installs, once, a
process-wide handler with ``mujoco.set_mju_user_warning`` that records the
message (per thread, the last few) instead: nothing is printed and no log file
is written, and the :class:`~shinro_ctrl.errors.SimulationDiverged` raised for
that step quotes MuJoCo's text after our own description. (MuJoCo issues the
text only the first time a warning fires for an ``MjData``; the counters, and
so the exception, fire every time.) Code that installs its own handler
afterwards replaces ours; :func:`install_warning_handler` puts ours back.

:meth:`MujocoEngine.for_plant` builds the model of a plant's MuJoCo loop
(``model=``, :data:`~shinro_ctrl.engine.mjcf.MODEL_CHOICES`). ``"matched"``
(the built-in plants' default) loads the plant's MJCF asset and rewrites it
through ``MjSpec`` with the plant's parameters (point masses, lengths,
damping, gravity, timestep), so the simulated and the analytic models match
for any parameter values, and selects MuJoCo's (semi-implicit) Euler
integrator with ``mjDSBL_EULERDAMP``, so that joint damping is explicit, as in
the analytic models: the exact twin ``crosscheck`` compares. ``"realistic"``
loads a built-in plant's realistic variant, or a user's model file
(``MjcfPlant``'s default) as written: its integrator, contacts, limits,
friction loss and ``ctrlrange`` / ``forcerange`` clamps are kept, only the
timestep is the plant's. :meth:`MujocoEngine.input_ranges` maps the model's
``ctrlrange`` onto the plant's inputs and :class:`~shinro_ctrl.engine.core.ForceClamps`
reads the ``forcerange`` clamps of each step (the ``saturation_fraction`` metric).

Name lookups are resolved to addresses once, at construction: a scalar
joint read such as :meth:`MujocoEngine.get_joint_qpos` costs one dict lookup
and one array read (about 0.2 µs), and :meth:`MujocoEngine.step` adds about
1 µs of checks to ``mj_step``.

:class:`StandaloneEngine` (defined with the plants, in
:mod:`shinro_ctrl.plants.standalone`, since every plant builds one and the plants
never import this package) keeps the same ``apply / step / read / write``
contract as :class:`MujocoEngine` for the plant's own integrator.

Modules: :mod:`~shinro_ctrl.engine.core` (:class:`MujocoEngine`: set-up,
stepping, divergence checks, named joint, body and site access), :mod:`~shinro_ctrl.engine.mjcf` (loading and patching
MJCF), :mod:`~shinro_ctrl.engine.render` (offscreen rendering),
:mod:`~shinro_ctrl.engine.warnings` (MuJoCo's warning text) and
:mod:`~shinro_ctrl.engine.model_tree` (the model reader of ``MjcfPlant``).
Asset paths come from the plant's ``MjcfPatch`` or the caller, resolved by
the core :mod:`shinro_ctrl.resources` (which imports nothing else from the package).
"""

from shinro_ctrl.engine.core import ForceClamps, MujocoEngine
from shinro_ctrl.engine.mjcf import MODEL_CHOICES, TINY_INERTIA
from shinro_ctrl.engine.render import OffscreenRenderer
from shinro_ctrl.engine.warnings import _record_warning, install_warning_handler, take_warning_messages  # noqa: F401
from shinro_ctrl.plants.standalone import Engine, StandaloneEngine

__all__ = [
    "MODEL_CHOICES",
    "TINY_INERTIA",
    "Engine",
    "ForceClamps",
    "MujocoEngine",
    "OffscreenRenderer",
    "StandaloneEngine",
    "install_warning_handler",
    "take_warning_messages",
]
