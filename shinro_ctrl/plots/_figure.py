"""Figure plumbing shared by the plots: an Agg figure, atomic PNG/PDF output with our marker, metric formatting."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from shinro_ctrl.files import GENERATOR, write_output

#: The file formats a plot is written in, by the path's suffix.
PLOT_FORMATS = {".png": "png", ".pdf": "pdf"}


def _new_figure(width: float, height: float) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    return fig


def plot_format(path: str | Path) -> str:
    """``"pdf"`` for a ``.pdf`` name, else ``"png"`` (a PNG whatever the name, as before PDF output)."""
    return PLOT_FORMATS.get(Path(path).suffix.lower(), "png")


def save_figure(fig: Any, path: str | Path, **savefig: Any) -> Path:
    """Write ``fig`` to ``path`` (PDF for a ``.pdf`` name, else PNG), atomically, carrying our marker.

    The marker (PNG ``Software``, PDF ``Creator``) lets the next run replace the
    file; a file without it (the user's own) is never replaced, nor a symbolic link.

    Raises:
        InvalidArgument: a path :func:`~shinro_ctrl.files.check_replaceable` refuses.
    """
    path = Path(path)
    fmt = plot_format(path)
    meta = {"Software": GENERATOR} if fmt == "png" else {"Creator": GENERATOR, "Producer": GENERATOR}
    write_output(
        path, lambda f: fig.savefig(f, format=fmt, metadata=meta, **savefig), binary=True, what="plot", kind=fmt.upper()
    )
    return path


def _write_png(fig: Any, path: str | Path) -> Path:
    return save_figure(fig, path, dpi=110, bbox_inches="tight")


def _fmt_metric(v: float | None) -> str:
    if v is None or (isinstance(v, float) and math.isinf(v)):
        return "never"
    return f"{v:.3g}"
