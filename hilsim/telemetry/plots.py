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

import math
import os
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.servo_bus import ReadStatus
from hilsim.telemetry.format import STAGES
from hilsim.telemetry.reader import Run, read_run

if TYPE_CHECKING:
    from matplotlib.figure import Figure

#: colours of the traces and of the non-OK read rugs
TRACE_STYLE: dict[str, dict[str, Any]] = {
    # present underneath, wide and pale, so the thin commanded line stays visible on top of it
    "present": {
        "color": "tab:green",
        "linewidth": 4.0,
        "alpha": 0.45,
        "solid_capstyle": "butt",
        "label": "present (read back)",
    },
    "target": {"color": "0.25", "linestyle": "--", "linewidth": 1.1, "label": "target"},
    "sim_x": {"color": "tab:blue", "linewidth": 1.1, "label": "spring (sim)"},
    "cmd": {"color": "tab:orange", "linewidth": 1.1, "label": "commanded (after safety)"},
}
STATUS_STYLE: dict[ReadStatus, tuple[str, str]] = {
    ReadStatus.STALE: ("tab:red", "stale read"),
    ReadStatus.ERROR: ("tab:purple", "error reply"),
    ReadStatus.ALERT: ("black", "alert bit"),
}
STAGE_COLORS = {"sim": "tab:blue", "safety": "tab:orange", "bus": "tab:green", "telemetry": "0.5"}
LIMIT_STYLE: dict[str, Any] = {"color": "tab:red", "linestyle": ":", "linewidth": 1.3}
ACTED_STYLE: dict[str, Any] = {"facecolor": "tab:red", "alpha": 0.13, "edgecolor": "none"}
SOFT_START_STYLE: dict[str, Any] = {"facecolor": "0.5", "alpha": 0.13, "edgecolor": "none"}
#: |cmd − sim_x| above this (rad) means the safety filter changed the command (it passes the
#: spring through bit for bit otherwise; telemetry round-trips floats exactly)
ACTED_TOLERANCE_RAD = 1e-9
#: smallest y span of a joint row (deg) when its limits are unknown
MIN_SPAN_DEG = 2.0
#: summary.json's "clock" for a run on the emulator's virtual clock
VIRTUAL_CLOCK = "virtual time"


def _rig_copy(run: Run) -> dict[str, Any]:
    """The run's ``rig.toml`` copy, parsed; {} when there is none or it does not parse."""
    if not run.config_text:
        return {}
    try:
        return tomllib.loads(run.config_text)
    except (tomllib.TOMLDecodeError, ValueError):
        return {}


def soft_start_s(run: Run) -> float | None:
    """The run's soft start (s) from its ``rig.toml`` copy (the rig default when the key is
    absent); None when there is no readable rig copy or the value is not a number >= 0."""
    data = _rig_copy(run)
    if not isinstance(data.get("joints"), list):  # not a rig file: its defaults do not apply
        return None
    from hilsim.rig import SafetyConfig

    table = data.get("safety", {})
    value = (
        table.get("soft_start_s", SafetyConfig.soft_start_s) if isinstance(table, dict) else None
    )
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    return float(value) if ok and math.isfinite(value) and value >= 0 else None


def joint_limits_deg(run: Run) -> dict[str, tuple[float, float]]:
    """``{joint: (min_deg, max_deg)}`` from the run's ``rig.toml`` copy (joint frame, degrees).

    Tolerant: no copy, TOML that does not parse, or a joint without two finite numbers with
    min < max gives no entry for it (the plot then draws no limits for that joint).
    """
    joints = _rig_copy(run).get("joints")
    out: dict[str, tuple[float, float]] = {}
    if not isinstance(joints, list):
        return out
    for table in joints:
        if not isinstance(table, dict) or not isinstance(table.get("name"), str):
            continue
        lo, hi = table.get("min_deg"), table.get("max_deg")
        ok = all(isinstance(x, int | float) and not isinstance(x, bool) for x in (lo, hi))
        if ok and math.isfinite(lo) and math.isfinite(hi) and lo < hi:
            out[table["name"]] = (float(lo), float(hi))
    return out


def is_virtual_time(run: Run) -> bool:
    """True when the run's summary says it ran on the virtual clock."""
    return isinstance(run.summary, dict) and run.summary.get("clock") == VIRTUAL_CLOCK


def safety_acted(
    cmd: np.ndarray, sim_x: np.ndarray, limits_rad: tuple[float, float] | None
) -> np.ndarray:
    """Per tick (bool, like ``cmd``): the filter changed the command, or the spring was beyond a
    limit. Ticks with a NaN command or spring (none recorded) count as not acted."""
    with np.errstate(invalid="ignore"):
        acted = np.abs(cmd - sim_x) > ACTED_TOLERANCE_RAD
        if limits_rad is not None:
            acted |= (sim_x < limits_rad[0]) | (sim_x > limits_rad[1])
    return acted


def _spans(t: np.ndarray, mask: np.ndarray, dt: float) -> list[tuple[float, float]]:
    """(start, width) of each run of True in ``mask``; a tick covers [t, t + dt)."""
    if not mask.any():
        return []
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(float(t[a]), float(t[b] - t[a] + dt)) for a, b in zip(starts, ends, strict=True)]


def _y_range(
    values: np.ndarray, limits: tuple[float, float] | None, min_span: float
) -> tuple[float, float]:
    """The joint row's y limits: the data and the joint's limits, at least ``min_span`` tall,
    with room for the rug at the bottom."""
    finite = values[np.isfinite(values)]
    lo = float(finite.min()) if finite.size else math.inf
    hi = float(finite.max()) if finite.size else -math.inf
    if limits is not None:
        lo, hi = min(lo, limits[0]), max(hi, limits[1])
    if not (math.isfinite(lo) and math.isfinite(hi)):
        lo, hi = -0.5 * min_span, 0.5 * min_span
    if hi - lo < min_span:
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 0.5 * min_span, mid + 0.5 * min_span
    pad = 0.06 * (hi - lo)
    return lo - 2.3 * pad, hi + pad


def _safety_note(run: Run, name: str, acted_s: float, soft_s: float) -> str:
    """Beside a joint row: how long the filter acted, and the summary's counts if any."""
    lines = [f"safety limited {acted_s:.2f} s" if acted_s > 0 else "safety never limited"]
    if soft_s > 0:
        lines.append(f"soft start blended {soft_s:.2f} s")
    limits = run.summary.get("safety_limits") if isinstance(run.summary, dict) else None
    if isinstance(limits, dict):
        counts = [
            f"{kind} {per.get(name)}"
            for kind, per in limits.items()
            if isinstance(per, dict) and isinstance(per.get(name), int) and per.get(name)
        ]
        if counts:  # clamp counts from the summary, two a line (the margin is narrow)
            lines.append("run total, ticks:")
            lines += [", ".join(counts[i : i + 2]) for i in range(0, len(counts), 2)]
    return "\n".join(lines)


def _new_figure(width: float, height: float) -> Figure:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: Path, dpi: int) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path


def _window(run: Run, start: float | None, end: float | None) -> np.ndarray:
    t = run.t_sched
    keep = np.ones(t.shape, dtype=bool)
    if start is not None:
        keep &= t >= start
    if end is not None:
        keep &= t <= end
    return keep


def _window_note(start: float | None, end: float | None) -> str:
    if start is None and end is None:
        return ""
    lo = "start" if start is None else f"{start:g} s"
    hi = "end" if end is None else f"{end:g} s"
    return f", {lo} to {hi}"


def plot_joints(
    run: Run,
    path: str | os.PathLike[str],
    *,
    start: float | None = None,
    end: float | None = None,
    dpi: int = 110,
) -> Path:
    """One row per joint: target, spring, commanded, present (deg) vs time (s); bad reads marked,
    limits drawn, spans where the safety filter acted shaded (module docstring)."""
    return _save(joints_figure(run, start=start, end=end), Path(path), dpi)


def joints_figure(run: Run, *, start: float | None = None, end: float | None = None) -> Figure:
    """The figure :func:`plot_joints` saves (axes in joint order)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    keep = _window(run, start, end)
    t = run.t_sched[keep]
    names = run.joint_names
    status = run.joint("status")[keep]
    raw = {q: run.joint(q)[keep] for q in ("sim_x", "cmd")}
    traces = {q: np.degrees(run.joint(q)[keep]) for q in TRACE_STYLE}
    limits = joint_limits_deg(run)
    soft = soft_start_s(run)
    in_soft = t < (soft if soft is not None else -math.inf)
    dt = float(np.median(np.diff(run.t_sched))) if run.n_ticks > 1 else 0.0
    n = len(names)
    fig = _new_figure(12.0, 1.2 + 2.1 * n)
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    trace_lines = []
    any_acted = any_soft = False
    for j, (ax, name) in enumerate(zip(axes, names, strict=True)):
        lim = limits.get(name)
        lim_rad = None if lim is None else (math.radians(lim[0]), math.radians(lim[1]))
        acted = safety_acted(raw["cmd"][:, j], raw["sim_x"][:, j], lim_rad)
        spans = _spans(t, acted & ~in_soft, dt)
        soft_spans = _spans(t, acted & in_soft, dt)
        for sp, style in ((spans, ACTED_STYLE), (soft_spans, SOFT_START_STYLE)):
            if sp:
                ax.broken_barh(sp, (0.0, 1.0), transform=ax.get_xaxis_transform(), **style)
        any_acted |= bool(spans)
        any_soft |= bool(soft_spans)
        if lim is not None:
            for edge in lim:
                ax.axhline(edge, **LIMIT_STYLE)
        trace_lines = [ax.plot(t, traces[q][:, j], **style)[0] for q, style in TRACE_STYLE.items()]
        stacked = np.concatenate([traces[q][:, j] for q in TRACE_STYLE])
        ax.set_ylim(*_y_range(stacked, lim, MIN_SPAN_DEG))
        ax.text(
            1.01,
            0.97,
            _safety_note(
                run,
                name,
                float(np.count_nonzero(acted & ~in_soft)) * dt,
                float(np.count_nonzero(acted & in_soft)) * dt,
            ),
            transform=ax.transAxes,
            va="top",
            fontsize="small",
            color="tab:red" if spans else "0.4",
        )
        marks = []
        for code, (color, label) in STATUS_STYLE.items():
            bad = status[:, j] == code
            count = int(np.count_nonzero(bad))
            if count:
                # a rug along the bottom, in axes coordinates: visible however short the stretch
                marks.append(
                    ax.plot(
                        t[bad],
                        np.full(count, 0.035),
                        linestyle="none",
                        marker="|",
                        markersize=10,
                        markeredgewidth=1.5,
                        color=color,
                        transform=ax.get_xaxis_transform(),
                        label=f"{label} ×{count}",
                    )[0]
                )
        ax.margins(x=0.01)  # y: _y_range leaves the bottom band to the rug
        ax.set_ylabel(f"{name}\nangle (deg)")
        ax.grid(True, alpha=0.3)
        if marks:
            ax.legend(
                handles=marks,
                loc="lower left",  # the safety note is at the top
                bbox_to_anchor=(1.005, 0.0),
                fontsize="small",
                title="reads not OK",
                title_fontsize="small",
            )
        else:
            ax.text(
                1.01,
                0.03,
                "all reads OK",
                transform=ax.transAxes,
                va="bottom",
                fontsize="small",
                color="0.4",
            )
    axes[-1].set_xlabel("time since run start (s)")
    handles = list(trace_lines)
    if limits:
        handles.append(Line2D([], [], **LIMIT_STYLE, label="joint limits (rig.toml)"))
    if any_acted:
        handles.append(Patch(**ACTED_STYLE, label="safety filter limited the command"))
    if any_soft:
        handles.append(Patch(**SOFT_START_STYLE, label="soft start (command blended)"))
    # below the plots: at the top, two rows of handles would run into the title
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 4))
    span = f"{t[-1] - t[0]:.3g} s" if t.size else "no ticks"
    fig.suptitle(
        f"Joint positions: {run.path.name}{_window_note(start, end)} ({t.size} ticks, {span})",
        x=0.01,
        ha="left",
    )
    return fig


def _lateness_marks(lat: np.ndarray) -> list[tuple[str, float, str]]:
    p50, p99, p999 = np.percentile(lat, [50.0, 99.0, 99.9])
    return [
        ("p50", float(p50), "tab:green"),
        ("p99", float(p99), "tab:orange"),
        ("p99.9", float(p999), "tab:red"),
        ("max", float(lat.max()), "black"),
    ]


def _use_log_axis(lat: np.ndarray) -> bool:
    """A log lateness axis when all values are positive and the tail is far from the body."""
    if lat.size == 0 or float(lat.min()) <= 0.0:
        return False
    return float(lat.max()) > 20.0 * float(np.median(lat))


def plot_lateness(
    run: Run,
    path: str | os.PathLike[str],
    *,
    start: float | None = None,
    end: float | None = None,
    dpi: int = 110,
) -> Path:
    """Histogram of tick lateness (µs, log count) with p50/p99/p99.9/max marked; lateness vs time
    with overruns marked. The lateness axis is logarithmic when the tail is > 20× the median."""
    keep = _window(run, start, end)
    t = run.t_sched[keep]
    if is_virtual_time(run):
        fig = _new_figure(11.0, 3.0)
        fig.suptitle(f"Tick lateness: {run.path.name}{_window_note(start, end)} ({t.size} ticks)",
                     x=0.01, ha="left")  # fmt: skip
        ax = fig.subplots()
        ax.set_axis_off()
        note = (
            "Virtual-time run: the clock jumps to every deadline, so each tick starts exactly on "
            "time by construction.\nLateness was not measured; run on the real clock (without "
            "--virtual-time) to see it."
        )
        ax.text(0.5, 0.5, note, transform=ax.transAxes, ha="center", va="center",
                fontsize="large")  # fmt: skip
        return _save(fig, Path(path), dpi)
    lat_all = run.lateness_us[keep]
    lat = lat_all[np.isfinite(lat_all)]
    overrun = run.overrun[keep]
    fig = _new_figure(11.0, 8.0)
    ax_h, ax_t = fig.subplots(2, 1, height_ratios=[3, 2])
    n_over = int(np.count_nonzero(overrun))
    fig.suptitle(
        f"Tick lateness: {run.path.name}{_window_note(start, end)} ({lat.size} ticks, "
        f"{n_over} overrun{'s' if n_over != 1 else ''})",
        x=0.01,
        ha="left",
    )
    log_x = _use_log_axis(lat)
    if lat.size == 0:
        ax_h.text(0.5, 0.5, "no lateness data", transform=ax_h.transAxes, ha="center")
    else:
        lo, hi = float(lat.min()), float(lat.max())
        if log_x:
            bins = np.geomspace(lo, hi * 1.0001, 121)
            ax_h.set_xscale("log")
        else:
            if hi - lo < 1e-9:  # e.g. a virtual clock: every tick exactly on time
                ax_h.text(0.02, 0.95, f"every tick: {lo:,.3f} µs", transform=ax_h.transAxes,
                          va="top", fontsize="large")  # fmt: skip
                lo, hi = lo - 0.5, hi + 0.5
            bins = np.linspace(lo, hi, 121)
        ax_h.hist(lat, bins=bins, color="tab:blue", alpha=0.8, log=True)
        for name, value, color in _lateness_marks(lat):
            ax_h.axvline(
                value, color=color, linestyle="--", linewidth=1.2, label=f"{name} = {value:,.1f} µs"
            )
        ax_h.legend(loc="upper right", title="lateness")
    scale = " (log scale)" if log_x else ""
    ax_h.set_xlabel(f"lateness: tick start − scheduled time (µs){scale}")
    ax_h.set_ylabel("ticks (log scale)")
    ax_h.grid(True, which="both" if log_x else "major", alpha=0.25)

    ax_t.plot(
        t, lat_all, linestyle="none", marker=".", markersize=2, color="tab:blue", label="one tick"
    )
    if n_over:
        ax_t.plot(t[overrun], lat_all[overrun], linestyle="none", marker="x", markersize=6,
                  color="tab:red", label=f"overrun ×{n_over}")  # fmt: skip
    if log_x:
        ax_t.set_yscale("log")
    ax_t.set_xlabel("time since run start (s)")
    ax_t.set_ylabel(f"lateness (µs){scale}")
    ax_t.grid(True, alpha=0.3)
    ax_t.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), ncols=2, frameon=False,
                fontsize="small")  # fmt: skip
    return _save(fig, Path(path), dpi)


def _binned(
    t: np.ndarray, values: np.ndarray, n_bins: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split ticks into ``n_bins`` equal runs: bin centre times, per-stage NaN-mean ``(bins, k)``,
    and the largest per-tick stage total in each bin ``(bins,)``."""
    starts = np.linspace(0, t.size, min(n_bins, t.size) + 1).astype(int)[:-1]
    counts = np.diff(np.append(starts, t.size))
    centers = np.add.reduceat(t, starts) / counts
    finite = np.isfinite(values)
    sums = np.add.reduceat(np.where(finite, values, 0.0), starts, axis=0)
    n = np.add.reduceat(finite.astype(np.int64), starts, axis=0)
    means = np.divide(sums, n, out=np.zeros_like(sums), where=n > 0)
    worst = np.fmax.reduceat(np.nansum(values, axis=1), starts)
    return centers, means, worst


def plot_timing(
    run: Run,
    path: str | os.PathLike[str],
    *,
    start: float | None = None,
    end: float | None = None,
    dpi: int = 110,
    n_bins: int = 400,
) -> Path:
    """Per-stage wall time (µs): stacked bin means vs time, and per-stage p50/p99/max bars."""
    keep = _window(run, start, end)
    t = run.t_sched[keep]
    stages = np.column_stack([run.stage_us(s)[keep] for s in STAGES]).reshape(-1, len(STAGES))
    virtual = is_virtual_time(run)
    fig = _new_figure(11.0, 7.5)
    ax_s, ax_b = fig.subplots(2, 1, height_ratios=[3, 2])
    fig.suptitle(
        f"Time per tick by stage: {run.path.name}{_window_note(start, end)} ({t.size} ticks)"
        + (
            "\nvirtual-time run: the host's compute time per stage ('bus' includes the "
            "in-process emulator, not wire time); no deadline applied"
            if virtual
            else ""
        ),
        x=0.01,
        ha="left",
    )
    if t.size == 0 or not np.isfinite(stages).any():
        ax_b.remove()
        ax_s.set_axis_off()
        ax_s.text(0.5, 0.5, "no per-stage timing in this run\n(every t_<stage>_us column is nan)",
                  transform=ax_s.transAxes, ha="center", va="center", fontsize="large")  # fmt: skip
        return _save(fig, Path(path), dpi)
    centers, means, worst = _binned(t, stages, n_bins)
    ax_s.stackplot(centers, means.T, labels=[f"{s} (mean)" for s in STAGES],
                   colors=[STAGE_COLORS[s] for s in STAGES], alpha=0.85)  # fmt: skip
    ax_s.plot(centers, worst, color="black", linewidth=0.8, label="all stages, worst tick")
    top = float(np.nanmax(worst))
    if t.size > 1 and not virtual:
        period_us = float(np.median(np.diff(t))) * 1e6
        top = max(top, period_us)
        ax_s.axhline(period_us, color="tab:red", linestyle="--", linewidth=1.0,
                     label=f"tick period {period_us:,.0f} µs")  # fmt: skip
    bin_s = (t[-1] - t[0]) / max(1, centers.size)
    ax_s.set_xlabel(f"time since run start (s); one point per {bin_s * 1e3:.3g} ms of ticks")
    ax_s.set_ylabel("wall time per tick (µs)")
    ax_s.set_ylim(0, top * 1.08 if top > 0 else 1.0)
    ax_s.grid(True, alpha=0.3)
    ax_s.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncols=3, frameon=False,
                fontsize="small")  # fmt: skip

    x = np.arange(len(STAGES))
    width = 0.26
    finite_cols = [stages[np.isfinite(stages[:, s]), s] for s in range(len(STAGES))]
    tops = []
    for k, (label, q, color) in enumerate(
        [("p50", 50.0, "#9ecae1"), ("p99", 99.0, "#4292c6"), ("max", 100.0, "#08306b")]
    ):
        vals = [float(np.percentile(c, q)) if c.size else np.nan for c in finite_cols]
        tops += vals
        bars = ax_b.bar(x + (k - 1) * width, vals, width, label=label, color=color)
        ax_b.bar_label(bars, fmt="%.0f", fontsize="x-small", padding=1)
    positive = [v for v in tops if np.isfinite(v) and v > 0]
    if positive and max(positive) > 30 * min(positive):
        ax_b.set_yscale("log")  # small stages would be invisible next to the bus
        ax_b.set_ylabel("wall time per tick (µs, log)")
    else:
        ax_b.set_ylabel("wall time per tick (µs)")
    ax_b.set_xticks(x, list(STAGES))
    ax_b.set_title("per stage over the whole window", fontsize="medium")
    ax_b.legend(loc="upper left")
    ax_b.grid(True, axis="y", alpha=0.3)
    ax_b.margins(y=0.2)
    return _save(fig, Path(path), dpi)


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
