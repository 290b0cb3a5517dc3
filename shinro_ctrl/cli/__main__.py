"""``python -m shinro_ctrl.cli``: the same command as ``shinro-ctrl`` (the same entry point and Ctrl-C handling)."""

from shinro_ctrl._entry import main

main()
