"""What the run's figures share: a figure on the Agg canvas (no pyplot), saving, the time
window, and whether the run was in virtual time. Matplotlib is imported inside the functions."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hilsim.telemetry.reader import Run

if TYPE_CHECKING:
    from matplotlib.figure import Figure


#: summary.json's "clock" for a run on the emulator's virtual clock
VIRTUAL_CLOCK = "virtual time"


def new_figure(width: float, height: float) -> Figure:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save(fig: Figure, path: Path, dpi: int) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path


def window(run: Run, start: float | None, end: float | None) -> np.ndarray:
    t = run.t_sched
    keep = np.ones(t.shape, dtype=bool)
    if start is not None:
        keep &= t >= start
    if end is not None:
        keep &= t <= end
    return keep


def window_note(start: float | None, end: float | None) -> str:
    if start is None and end is None:
        return ""
    lo = "start" if start is None else f"{start:g} s"
    hi = "end" if end is None else f"{end:g} s"
    return f", {lo} to {hi}"


def is_virtual_time(run: Run) -> bool:
    """True when the run's summary says it ran on the virtual clock."""
    return isinstance(run.summary, dict) and run.summary.get("clock") == VIRTUAL_CLOCK
