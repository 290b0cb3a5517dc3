"""``python -m shinro_ctrl.cli``: the same command as ``shinro-ctrl``."""

import sys

from shinro_ctrl.cli import main

sys.exit(main())
