"""Figure plumbing shared by the plots: an Agg figure, atomic PNG/PDF/SVG output with our marker, metric formatting."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.files import GENERATOR, is_device, write_output

#: The file formats a plot is written in, by the path's suffix (what matplotlib writes, each with our marker).
PLOT_FORMATS = {".png": "png", ".pdf": "pdf", ".svg": "svg"}


def _new_figure(width: float, height: float) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    return fig


def plot_format(path: str | Path, what: str = "plot") -> str:
    """The format a plot at ``path`` is written in: ``"png"``, ``"pdf"`` or ``"svg"`` by its extension.

    A device (``/dev/null``) takes a PNG whatever its name.

    Args:
        path: The plot's file.
        what: The option or role named in the message (``"--plot"``).

    Raises:
        InvalidArgument: another extension (``.csv``, ``.jpg``) or none, naming ``what`` and the allowed ones.
    """
    suffix = Path(path).suffix.lower()
    if suffix in PLOT_FORMATS:
        return PLOT_FORMATS[suffix]
    if is_device(path):
        return "png"
    allowed = ", ".join(PLOT_FORMATS)
    got = f"'{Path(path).suffix}'" if suffix else "no extension"
    raise InvalidArgument(f"{what} '{path}': a plot is written as {allowed} (by the file's extension); got {got}")


def _metadata(fmt: str) -> dict[str, str]:
    """Our marker in each format's own metadata (see :func:`~shinro_ctrl.files.written_by_us`)."""
    if fmt == "png":
        return {"Software": GENERATOR}  # a tEXt chunk
    if fmt == "pdf":
        return {"Creator": GENERATOR, "Producer": GENERATOR}  # the document information dictionary
    return {"Creator": GENERATOR}  # SVG: <dc:creator><cc:Agent><dc:title> in its <metadata>


def save_figure(fig: Any, path: str | Path, **savefig: Any) -> Path:
    """Write ``fig`` to ``path`` as PNG, PDF or SVG by its extension, atomically, carrying our marker.

    The marker (PNG ``Software``, PDF ``Creator``, SVG ``dc:creator``) lets the next run replace the
    file; a file without it (the user's own) is never replaced, nor a symbolic link.

    Raises:
        InvalidArgument: an extension other than .png, .pdf, .svg (:func:`plot_format`), or a path
            :func:`~shinro_ctrl.files.check_replaceable` refuses.
    """
    path = Path(path)
    fmt = plot_format(path)
    meta = _metadata(fmt)
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
