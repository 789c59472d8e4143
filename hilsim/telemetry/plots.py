"""Figures of one run directory (PNG): joint positions, tick lateness, per-stage timing.

Matplotlib is imported inside the functions, through its object-oriented API (``Figure`` on an Agg
canvas: no pyplot, no global backend switch), so ``import hilsim.telemetry.plots`` stays cheap.

* :func:`plot_joints`  one row per joint: target, spring (sim_x), commanded and present position
  in degrees against time; reads that were not OK are drawn as a coloured rug along the bottom of
  the row (stale, error, alert) and leave a gap in the present trace. The joint's limits
  (``min_deg``/``max_deg`` from the run's copy of the rig, ``rig.toml``, joint frame) are dotted
  lines, and the spans where the safety filter acted are shaded: the command differs from the
  spring by more than rounding (:data:`ACTED_TOLERANCE_RAD`: a limit, the soft start, a walk back
  in) or the spring is beyond a limit. The y axis always shows the joint's whole range (without a
  readable rig.toml: at least :data:`MIN_SPAN_DEG`), so a quiet window is not blown up to noise.
  Beside each row: how long the filter acted, and the summary's clamp counts if it has them.
* :func:`plot_lateness` histogram of tick lateness (µs, log count) with p50/p99/p99.9/max marked,
  and lateness against time with overruns marked. A virtual-time run (``"clock": "virtual
  time"`` in summary.json) starts every tick on time by construction: the figure says so instead.
* :func:`plot_timing`  per-stage wall time (sim, safety, bus, telemetry; µs) stacked against time
  (means over time bins, with the worst tick of each bin and the tick period for reference), and
  per-stage p50/p99/max. In a virtual-time run these are the host's compute times (the bus stage
  includes the in-process emulator) and no deadline applies: labelled so, without the period line.

:func:`plot_run` writes all three into ``RUN_DIR/plots/`` (or another directory).
"""

from __future__ import annotations

import os
from pathlib import Path

from hilsim.telemetry.joint_plots import (
    ACTED_TOLERANCE_RAD,
    MIN_SPAN_DEG,
    joint_limits_deg,
    joints_figure,
    plot_joints,
    safety_acted,
    soft_start_s,
)
from hilsim.telemetry.plot_common import VIRTUAL_CLOCK, is_virtual_time
from hilsim.telemetry.reader import Run, read_run
from hilsim.telemetry.timing_plots import plot_lateness, plot_timing

__all__ = [
    "ACTED_TOLERANCE_RAD",
    "MIN_SPAN_DEG",
    "VIRTUAL_CLOCK",
    "is_virtual_time",
    "joint_limits_deg",
    "joints_figure",
    "plot_joints",
    "plot_lateness",
    "plot_run",
    "plot_timing",
    "safety_acted",
    "soft_start_s",
]


def plot_run(
    run: Run | str | os.PathLike[str],
    out_dir: str | os.PathLike[str] | None = None,
    *,
    start: float | None = None,
    end: float | None = None,
    dpi: int = 110,
) -> list[Path]:
    """Write ``joints.png``, ``lateness.png`` and ``timing.png``; return their paths.

    ``out_dir`` defaults to ``RUN_DIR/plots``; ``start``/``end`` (s since run start) limit the
    time window.
    """
    if not isinstance(run, Run):
        run = read_run(run)
    out = Path(out_dir) if out_dir is not None else run.path / "plots"
    kw = {"start": start, "end": end, "dpi": dpi}
    return [
        plot_joints(run, out / "joints.png", **kw),
        plot_lateness(run, out / "lateness.png", **kw),
        plot_timing(run, out / "timing.png", **kw),
    ]
