"""The timing figures of a run: tick lateness, and host time per tick by stage
(see :mod:`hilsim.telemetry.plots`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hilsim.telemetry import plot_common as common
from hilsim.telemetry.format import STAGES
from hilsim.telemetry.reader import Run

if TYPE_CHECKING:
    from matplotlib.figure import Figure

STAGE_COLORS = {"sim": "tab:blue", "safety": "tab:orange", "bus": "tab:green", "telemetry": "0.5"}

#: the figures' sizes (in): lateness (a virtual-time run's: a note), time per stage
LATENESS_SIZE, VIRTUAL_LATENESS_SIZE, TIMING_SIZE = (11.0, 8.0), (11.0, 3.0), (11.0, 7.5)


def make_ahead(virtual: bool, dpi: float = 110) -> None:
    """Make the lateness and timing figures of a run before its data is there
    (:func:`hilsim.telemetry.plot_common.make_ahead`); ``virtual``: a virtual-time run's."""
    if virtual:
        common.make_ahead(*VIRTUAL_LATENESS_SIZE, dpi, 1)
    else:
        common.make_ahead(*LATENESS_SIZE, dpi, 2)
    common.make_ahead(*TIMING_SIZE, dpi, 2, minor_y=(1,))  # the bars' axis: log, as a rule


def _percentiles(run: Run, name: str, values: np.ndarray, qs: list[float]) -> list[float]:
    """Percentiles of a column: from the rows, or a decimated run's histogram (whole run)."""
    env = run.envelope
    if run.decimated and env is not None:
        return [env.percentile(name, q) if q < 100.0 else float(np.nanmax(values)) for q in qs]
    return [float(v) for v in np.percentile(values, qs)]


def _lateness_marks(run: Run, lat: np.ndarray) -> list[tuple[str, float, str]]:
    p50, p99, p999 = _percentiles(run, "lateness_us", lat, [50.0, 99.0, 99.9])
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
    keep = common.window(run, start, end)
    t = run.t_sched[keep]
    if common.is_virtual_time(run):
        fig, (ax,) = common.figure_axes(*VIRTUAL_LATENESS_SIZE, dpi, 1)
        where = common.window_note(start, end)
        ticks = common.tick_count(run, common.rows_in(run, keep), start, end)
        title = common.title(fig, f"Tick lateness: {run.path.name}{where} ({ticks})")
        top = common.Ruler(fig).size(title)[1] + common.PAD
        common.place_column(fig, [ax], left=0.0, right=0.0, top=top, bottom=0.0)
        ax.set_axis_off()
        note = (
            "Virtual-time run: the clock jumps to every deadline, so each tick starts exactly on "
            "time by construction.\nLateness was not measured; run on the real clock (without "
            "--virtual-time) to see it."
        )
        ax.text(0.5, 0.5, note, transform=ax.transAxes, ha="center", va="center",
                fontsize="large")  # fmt: skip
        return common.save(fig, Path(path), dpi)
    lat_all = run.lateness_us[keep]
    lat = lat_all[np.isfinite(lat_all)]
    overrun = run.overrun[keep]
    fig, (ax_h, ax_t) = common.figure_axes(*LATENESS_SIZE, dpi, 2)
    n_over = int(np.count_nonzero(overrun))
    n_rows = lat.size
    if run.decimated and run.counts is not None:  # counted while reading
        counts = run.counts["overrun"]
        overrun = np.zeros(counts.size, dtype=bool)
        overrun[1::2] = counts[0::2] > 0  # marked at the bucket's largest lateness
        overrun, n_over = overrun[keep], int(counts[keep].sum())
        n_rows = common.rows_in(run, keep)
    title = common.title(
        fig,
        f"Tick lateness: {run.path.name}{common.window_note(start, end)} "
        f"({common.tick_count(run, n_rows, start, end)}, "
        f"{n_over} overrun{'s' if n_over != 1 else ''}){common.decimation_note(run)}",
    )
    log_x = _use_log_axis(lat)
    if run.decimated and lat.size:
        log_x = _decimated_hist(ax_h, run)
        for name, value, color in _lateness_marks(run, lat):
            ax_h.axvline(
                value, color=color, linestyle="--", linewidth=1.2, label=f"{name} = {value:,.1f} µs"
            )
        ax_h.legend(loc="upper right", title="lateness (whole run)")
    elif lat.size == 0:
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
        common.log_axis(ax_h.yaxis)
        if log_x:
            common.log_axis(ax_h.xaxis)
        for name, value, color in _lateness_marks(run, lat):
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
        common.log_axis(ax_t.yaxis)
    ax_t.set_xlabel("time since run start (s)")
    ax_t.set_ylabel(f"lateness (µs){scale}")
    ax_t.grid(True, alpha=0.3)
    legend = ax_t.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), ncols=2, frameon=False,
                         fontsize="small")  # fmt: skip
    _place_pair(fig, (ax_h, ax_t), title, 0.0, _above(fig, legend))
    return common.save(fig, Path(path), dpi)


def _decimated_hist(ax: Any, run: Run) -> bool:
    """A decimated run's lateness histogram (its log bins, the whole run); True: log x."""
    from hilsim.telemetry.envelope import EDGES

    assert run.envelope is not None
    h = run.envelope.hist["lateness_us"]
    nz = np.flatnonzero(h)
    lo, hi = int(nz[0]), int(nz[-1])
    left = EDGES[lo - 1] if lo > 0 else EDGES[0] / 10.0
    ax.stairs(h[lo : hi + 1], np.concatenate([[left], EDGES[lo : hi + 1]]), fill=True,
              color="tab:blue", alpha=0.8)  # fmt: skip
    ax.set_xscale("log")
    ax.set_yscale("log")
    common.log_axis(ax.yaxis)
    common.log_axis(ax.xaxis)
    return True


def _above(fig: Figure, legend: Any) -> float:
    """Inches a legend anchored on top of its axes takes above them."""
    return common.Ruler(fig).size(legend)[1] + common.legend_pad(legend)


def _place_pair(
    fig: Figure, axes: tuple[Any, Any], title: Any, above_upper: float, above_lower: float
) -> None:
    """Two axes in a column, 3:2, below the figure's title; ``above_*``: inches of legend or
    title above each."""
    ratios = [3.0, 2.0]
    # a first guess, so the tick locators see about the axes' final lengths
    common.place_column(fig, list(axes), left=0.8, right=0.1, top=0.3, bottom=0.5, gaps=[0.9],
                        ratios=ratios)  # fmt: skip
    ruler = common.Ruler(fig)
    upper, lower = axes
    common.place_column(
        fig,
        list(axes),
        left=max(ruler.left(ax) for ax in axes),
        right=0.02,  # a tick label at the right end may stick out by half its width
        top=ruler.size(title)[1] + common.PAD + above_upper + ruler.offset(upper.yaxis),
        bottom=ruler.below(lower),
        gaps=[ruler.below(upper) + 2 * common.PAD + above_lower + ruler.offset(lower.yaxis)],
        ratios=ratios,
    )


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


def _binned_counted(
    run: Run, keep: np.ndarray, n_bins: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_binned` of a decimated run: exact means from the stage sums counted while
    reading; the worst tick from each bucket's largest stage total."""
    from hilsim.telemetry.envelope import STAGE_TOTAL

    assert run.counts is not None
    first = np.zeros(run.n_ticks, dtype=bool)
    first[0::2] = True
    pick = keep & first  # a bucket's counts are on its first row
    t = run.t_sched[pick]
    sums = np.column_stack([run.counts[f"sum_t_{s}_us"][pick] for s in STAGES])
    n = np.column_stack([run.counts[f"n_t_{s}_us"][pick] for s in STAGES])
    total = np.fmax(run.columns[STAGE_TOTAL][0::2], run.columns[STAGE_TOTAL][1::2])
    total = total[pick[0::2]]
    starts = np.linspace(0, t.size, min(n_bins, t.size) + 1).astype(int)[:-1]
    counts = np.diff(np.append(starts, t.size))
    centers = np.add.reduceat(t, starts) / counts
    s_sum, n_sum = np.add.reduceat(sums, starts, axis=0), np.add.reduceat(n, starts, axis=0)
    means = np.divide(s_sum, n_sum, out=np.zeros_like(s_sum), where=n_sum > 0)
    return centers, means, np.fmax.reduceat(total, starts)


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
    keep = common.window(run, start, end)
    t = run.t_sched[keep]
    stages = np.column_stack([run.stage_us(s)[keep] for s in STAGES]).reshape(-1, len(STAGES))
    virtual = common.is_virtual_time(run)
    fig, (ax_s, ax_b) = common.figure_axes(*TIMING_SIZE, dpi, 2)
    title = common.title(
        fig,
        f"Time per tick by stage: {run.path.name}{common.window_note(start, end)} "
        f"({common.tick_count(run, common.rows_in(run, keep), start, end)})"
        + common.decimation_note(run)
        + (
            "\nvirtual-time run: the host's compute time per stage ('bus' includes the "
            "in-process emulator, not wire time); no deadline applied"
            if virtual
            else ""
        ),
    )
    if t.size == 0 or not np.isfinite(stages).any():
        ax_b.remove()
        ax_s.set_axis_off()
        top = common.Ruler(fig).size(title)[1] + common.PAD
        common.place_column(fig, [ax_s], left=0.0, right=0.0, top=top, bottom=0.0)
        ax_s.text(0.5, 0.5, "no per-stage timing in this run\n(every t_<stage>_us column is nan)",
                  transform=ax_s.transAxes, ha="center", va="center", fontsize="large")  # fmt: skip
        return common.save(fig, Path(path), dpi)
    if run.decimated:
        centers, means, worst = _binned_counted(run, keep, n_bins)
    else:
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
    legend = ax_s.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncols=3, frameon=False,
                         fontsize="small")  # fmt: skip

    x = np.arange(len(STAGES))
    width = 0.26
    finite_cols = [stages[np.isfinite(stages[:, s]), s] for s in range(len(STAGES))]
    tops = []
    for k, (label, q, color) in enumerate(
        [("p50", 50.0, "#9ecae1"), ("p99", 99.0, "#4292c6"), ("max", 100.0, "#08306b")]
    ):
        vals = [
            _percentiles(run, f"t_{stage}_us", c, [q])[0] if c.size else np.nan
            for stage, c in zip(STAGES, finite_cols, strict=True)
        ]
        tops += vals
        bars = ax_b.bar(x + (k - 1) * width, vals, width, label=label, color=color)
        ax_b.bar_label(bars, fmt="%.0f", fontsize="x-small", padding=1)
    positive = [v for v in tops if np.isfinite(v) and v > 0]
    if positive and max(positive) > 30 * min(positive):
        ax_b.set_yscale("log")  # small stages would be invisible next to the bus
        common.log_axis(ax_b.yaxis)
        ax_b.set_ylabel("wall time per tick (µs, log)")
    else:
        ax_b.set_ylabel("wall time per tick (µs)")
    ax_b.set_xticks(x, list(STAGES))
    # y given: matplotlib then does not measure the (absent) top ticks to lift the title over them
    ax_b.set_title("per stage over the whole window", fontsize="medium", y=1.0)
    ax_b.legend(loc="upper left")
    ax_b.grid(True, axis="y", alpha=0.3)
    ax_b.margins(y=0.2)
    title_b = common.Ruler(fig).size(ax_b.title)[1] + common.TITLE_PAD
    _place_pair(fig, (ax_s, ax_b), title, _above(fig, legend), title_b)
    return common.save(fig, Path(path), dpi)
