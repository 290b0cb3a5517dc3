"""The ``shinro-ctrl`` console script: Ctrl-C handling first, then the (heavy) command-line imports.

A Ctrl-C while the command line imports NumPy, CasADi or MuJoCo (a second or two at start-up) ends the
command with the status 130 and one line, as it does later on, never with a traceback. This module
imports nothing but the standard library until the handler is in place.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

__all__ = ["main"]

EXIT_INTERRUPTED = 130


def _interrupted(exc: BaseException | None) -> bool:
    """A KeyboardInterrupt, or an error raised because of one (inside an import or a C extension)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``shinro-ctrl`` (see :func:`shinro_ctrl.cli.main`); exits with its status."""
    try:
        from shinro_ctrl.cli import main as cli_main
    except BaseException as exc:
        if not _interrupted(exc):
            raise
        print("interrupted", file=sys.stderr)
        sys.exit(EXIT_INTERRUPTED)
    try:
        status = cli_main(argv)
    except KeyboardInterrupt:  # between the imports and the command's own handling
        print("interrupted", file=sys.stderr)
        status = EXIT_INTERRUPTED
    sys.exit(status)


if __name__ == "__main__":  # pragma: no cover
    main()
