"""A controller regression test as a user writes it (run with ``pytest examples/test_my_controller.py``).

``run_scenario`` is a fixture that shinro_ctrl installs as a pytest plugin;
``assert_matches_baseline`` fails with a table of every metric that moved.
Record or refresh the baseline after a deliberate change with
``SHINRO_UPDATE_BASELINES=1 pytest examples/test_my_controller.py``.
"""

from __future__ import annotations

from pathlib import Path

from shinro_ctrl.testing import assert_matches_baseline

HERE = Path(__file__).parent
SCENARIO = {
    "plant": {"type": "CartPole", "dt": 0.01},
    "controller": {"type": "LQR", "Q": [10, 1, 100, 1], "R": [0.1]},
    "sim": {"duration": 3.0, "initial_state": [0.0, 0.0, 0.2, 0.0]},
}


def test_cartpole_gains_still_balance(run_scenario):
    result = run_scenario(SCENARIO)
    assert result.metrics["settling_time"] < 3.0
    assert_matches_baseline(result, HERE / "my_cartpole.baseline.json", {"rms_error": {"rel": 1e-3}})
