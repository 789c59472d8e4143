"""The bench's figures (PNG). matplotlib is imported inside each function, never at import.

* ``lateness.png``: distribution of tick lateness, ours sleeping only (spin window 0) vs
  cyclictest, p99 of each marked;
* ``bus_rate.png``: achieved cycle rate vs servo count beside the wire model, plain and Fast,
  one panel per baud rate;
* ``step.png``: the step response the command-to-motion figures come from.

Figures measured on the built-in emulator say so in their titles (:data:`EMULATED`).
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from drivers.protocol2.control_table import TICK_BLOCK_SIZE
from drivers.protocol2.wire_time import cycle_rate_hz
from hilsim.bench.busrate import BusRate
from hilsim.bench.latency import FRACTION_63, LatencyResult
from hilsim.bench.report import EMULATED, LoopResult

if TYPE_CHECKING:
    from matplotlib.figure import Figure

PLAIN_COLOR, FAST_COLOR, BLOCK_COLOR = "#d95f02", "#1b9e77", "#7570b3"
OURS_COLOR, CT_COLOR = "#1f77b4", "#7f7f7f"


def _pyplot() -> ModuleType:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_lateness(loop: LoopResult, path: str | Path) -> Path:
    """Histogram of lateness (µs, log axis) for our scheduler and cyclictest, p99 lines."""
    plt = _pyplot()
    ours = np.maximum(loop.ours.lateness_s * 1e6, 1e-3)
    c = loop.cyclictest
    ct_vals = ct_weights = None
    if c is not None and c.output is not None and c.output.histogram:
        hist = c.output.histogram
        ct_vals = np.array([b + 0.5 for b in hist], dtype=float)  # bucket b holds [b, b+1) µs
        ct_weights = np.array(list(hist.values()), dtype=float)
    hi = max(ours.max(), ct_vals.max() if ct_vals is not None else 1.0) * 1.5
    bins = np.logspace(np.log10(max(min(ours.min(), 0.5), 1e-3)), np.log10(hi), 80)

    fig, ax = plt.subplots(figsize=(9, 4.8), layout="constrained")
    ax.hist(
        ours, bins=bins, color=OURS_COLOR, alpha=0.75, label=f"ours, sleep only ({loop.ours.sched})"
    )
    ax.axvline(loop.ours.stats.p99_us, color=OURS_COLOR, ls="--", lw=1.5)
    ax.text(
        loop.ours.stats.p99_us,
        0.97,
        f" ours p99\n {_fmt_us(loop.ours.stats.p99_us)}",
        color=OURS_COLOR,
        transform=ax.get_xaxis_transform(),
        va="top",
        fontsize=9,
    )
    if c is not None and ct_vals is not None:  # (ct_vals: c has a histogram)
        ax.hist(
            ct_vals,
            bins=bins,
            weights=ct_weights,
            histtype="step",
            lw=1.8,
            color=CT_COLOR,
            label=f"cyclictest {c.version} ({c.sched})",
        )
        p99 = c.p99_us
        if p99 is not None:
            ax.axvline(p99, color="k", ls=":", lw=1.5)
            ax.text(
                p99,
                0.80,
                f" cyclictest p99\n {_fmt_us(p99)}",
                transform=ax.get_xaxis_transform(),
                va="top",
                fontsize=9,
            )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("lateness: tick start − deadline (µs, log scale; below 1 ns shown at 1 ns)")
    ax.set_ylabel("ticks")
    n = loop.ours.stats.ticks
    ax.set_title(
        f"Tick lateness at {loop.ours.rate_hz:g} Hz, {n} ticks\nours sleeping only (spin "
        f"window 0, CPU {loop.ours.cpu_percent:.0f} % of a core) beside cyclictest"
    )
    ax.legend(loc="upper right", bbox_to_anchor=(1.0, 0.62))
    ax.grid(True, which="major", alpha=0.3)
    return _save(fig, path, plt)


def plot_bus_rate(rows: list[BusRate], path: str | Path) -> Path:
    """Achieved (markers) vs model (lines) cycle rate against servo count, per baud rate.

    The model line is drawn for every servo count between the measured ones, with the
    first row's Return Delay Time, turnaround and latency timer.
    """
    plt = _pyplot()
    from matplotlib.ticker import FuncFormatter

    bauds = sorted({r.baud for r in rows})
    fig, axes = plt.subplots(
        1, len(bauds), figsize=(5.2 * len(bauds), 4.6), layout="constrained", squeeze=False
    )
    r0 = rows[0]
    rdt, turn, lat = r0.return_delay_us * 1e-6, r0.turnaround_us * 1e-6, r0.latency_timer_ms * 1e-3
    for ax, baud in zip(axes[0], bauds, strict=True):
        ns = sorted({len(r.ids) for r in rows if r.baud == baud})
        n_line = np.arange(min(ns), max(ns) + 1)
        series = (
            (False, 4, PLAIN_COLOR, "o", "plain Sync Read"),
            (True, 4, FAST_COLOR, "s", "Fast Sync Read"),
            (True, TICK_BLOCK_SIZE, BLOCK_COLOR, "D", "Fast, tick block"),
        )
        for fast, size, color, marker, name in series:
            sel = sorted(
                (r for r in rows if r.baud == baud and r.fast == fast and r.read_bytes == size),
                key=_n,
            )
            if not sel:
                continue
            model = [
                cycle_rate_hz(
                    int(n),
                    baud,
                    fast,
                    return_delay_s=rdt,
                    turnaround_s=turn,
                    latency_s=lat,
                    read_data_bytes=size,
                )
                for n in n_line
            ]
            ax.plot(n_line, model, ls="--", color=color, lw=1.5, label=f"{name}: model")
            achieved = [r.achieved_hz for r in sel]
            ax.plot(
                [len(r.ids) for r in sel],
                achieved,
                ls="none",
                marker=marker,
                ms=7,
                color=color,
                label=f"{name}: achieved",
            )
            for r in sel:
                ax.annotate(
                    f"{r.ratio:.0%}",
                    (len(r.ids), r.achieved_hz),
                    textcoords="offset points",
                    xytext=(7, -12 if fast else 5),
                    fontsize=8,
                    color=color,
                )
        ax.set_xscale("log", base=2)
        ax.set_xticks(ns, [str(x) for x in ns])
        ax.set_xlim(min(ns) / 1.4, max(ns) * 1.6)
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(FuncFormatter(lambda y, _pos: f"{y:,.0f}"))
        ax.yaxis.set_minor_formatter(FuncFormatter(_minor_label))
        ax.tick_params(axis="y", which="minor", labelsize=7)
        ax.set_xlabel("servos on the bus")
        ax.set_ylabel("write + read cycles per second")
        ax.set_title(f"{baud / 1e6:g} Mbps" if baud >= 1e6 else f"{baud} bps")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    emulated = f"{EMULATED}\n" if r0.port.startswith("dxlsim") else ""  # its own line
    fig.suptitle(
        f"{emulated}Bus cycle rate vs wire-time model\n(RDT {r0.return_delay_us:g} µs, turnaround "
        f"{r0.turnaround_us:g} µs,\nlatency timer {r0.latency_timer_ms:g} ms; "
        "labels: achieved / model)"
    )
    return _save(fig, path, plt)


def _minor_label(y: float, _pos: int | None) -> str:
    """Label minor log ticks 2, 3, 5 × 10^k only, so the axis stays readable."""
    lead = y / 10 ** np.floor(np.log10(y))
    return f"{y:,.0f}" if round(lead) in (2, 3, 5) else ""


def plot_step(lat: LatencyResult, path: str | Path, emulated: bool = False) -> Path | None:
    """Present Position around the goal step, with the motion-start and 63 % marks
    (``emulated``: the title says the servo is the emulator's)."""
    if lat.step_tick is None:
        return None
    plt = _pyplot()
    k0 = lat.step_tick
    t0 = lat.t_tick[k0]
    ok = np.isfinite(lat.positions)
    t_ms = (lat.sample_t - t0) * 1e3
    p0 = lat.positions[k0 - 1]
    fig, ax = plt.subplots(figsize=(8, 4.4), layout="constrained")
    ax.plot(t_ms[ok], lat.positions[ok], marker="o", ms=3.5, lw=1, drawstyle="steps-post",
            label="Present Position (as read; held between samples)")  # fmt: skip
    ax.axhline(p0 + lat.step_pulses, color="k", ls="--", lw=1, label="goal after the step")
    ax.axhline(
        p0 + FRACTION_63 * lat.step_pulses, color="grey", ls=":", lw=1, label="63 % of the step"
    )
    ax.axvline(0.0, color="k", lw=0.8)
    for value, label, color in (
        (lat.motion_start_s, "starts", "#d95f02"),
        (lat.motion_63_s, "63 %", "#7570b3"),
    ):
        if value is not None:
            ms = value * 1e3
            ax.axvline(ms, color=color, ls="-.", lw=1.2, label=f"{label}: {ms:.1f} ms")
    cycle_ms = float(np.nanmedian(np.diff(lat.t_tick))) * 1e3
    after = 60.0 if lat.motion_63_s is None else max(30.0, 3 * lat.motion_63_s * 1e3)
    ax.set_xlim(-max(10.0, 1.5 * cycle_ms), after)
    ax.set_xlabel("time from the step tick's start (ms); samples at the servos' reply")
    ax.set_ylabel("position (pulses)")
    ax.set_title(
        (f"{EMULATED}\n" if emulated else "")  # its own line: the title stays in the figure
        + f"Command to motion: {lat.step_pulses:+d}-pulse goal step at {lat.rate_hz:g} Hz "
        f"(servo ID {lat.ids[0]})"
    )
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    return _save(fig, path, plt)


def _n(r: BusRate) -> int:
    return len(r.ids)


def _fmt_us(x: float) -> str:
    return f"{x:.2f} µs" if x < 10 else f"{x:.0f} µs"


def _save(fig: Figure, path: str | Path, plt: ModuleType) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
