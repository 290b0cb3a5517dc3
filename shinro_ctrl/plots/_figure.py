"""Figure plumbing shared by the plots: an Agg figure, atomic PNG output, metric formatting."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from shinro_ctrl.files import atomic_write


def _new_figure(width: float, height: float) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    return fig


def _write_png(fig: Any, path: str | Path) -> Path:
    path = Path(path)
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110, bbox_inches="tight"), binary=True)
    return path


def _fmt_metric(v: float | None) -> str:
    if v is None or (isinstance(v, float) and math.isinf(v)):
        return "never"
    return f"{v:.3g}"
