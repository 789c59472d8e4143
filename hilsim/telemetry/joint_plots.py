"""The joints figure of a run: one row per joint, target, spring, commanded and present (deg)
against time, bad reads as a rug, limits dotted, spans where the safety filter acted shaded
(see :mod:`hilsim.telemetry.plots`)."""

from __future__ import annotations

import math
import os
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeGuard

import numpy as np

from drivers.servo_bus import ReadStatus
from hilsim.safety.limits import DEFAULT_SOFT_START_S
from hilsim.telemetry import plot_common as common
from hilsim.telemetry.reader import Run

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


LIMIT_STYLE: dict[str, Any] = {"color": "tab:red", "linestyle": ":", "linewidth": 1.3}


ACTED_STYLE: dict[str, Any] = {"facecolor": "tab:red", "alpha": 0.13, "edgecolor": "none"}


SOFT_START_STYLE: dict[str, Any] = {"facecolor": "0.5", "alpha": 0.13, "edgecolor": "none"}


#: |cmd − sim_x| above this (rad) means the safety filter changed the command (it passes the
#: spring through bit for bit otherwise; telemetry round-trips floats exactly)
ACTED_TOLERANCE_RAD = 1e-9


#: smallest y span of a joint row (deg) when its limits are unknown
MIN_SPAN_DEG = 2.0


def _number(x: object) -> TypeGuard[float]:
    """A TOML number (an int or a float, not a bool)."""
    return isinstance(x, int | float) and not isinstance(x, bool)


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
    table = data.get("safety", {})
    value = table.get("soft_start_s", DEFAULT_SOFT_START_S) if isinstance(table, dict) else None
    return float(value) if _number(value) and math.isfinite(value) and value >= 0 else None


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
        if _number(lo) and _number(hi) and math.isfinite(lo) and math.isfinite(hi) and lo < hi:
            out[table["name"]] = (float(lo), float(hi))
    return out


def safety_acted(
    cmd: np.ndarray, sim_x: np.ndarray, limits_rad: tuple[float, float] | None
) -> np.ndarray:
    """Per tick (bool, like ``cmd``): the filter changed the command, or the spring was beyond a
    limit. Ticks with a NaN command or spring (none recorded) count as not acted."""
    with np.errstate(invalid="ignore"):
        acted: np.ndarray = np.abs(cmd - sim_x) > ACTED_TOLERANCE_RAD
        if limits_rad is not None:
            acted |= (sim_x < limits_rad[0]) | (sim_x > limits_rad[1])
    return acted


def _counted(run: Run, name: str, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A decimated run's count ``name`` in the window: which rows' buckets count any (both rows
    of a bucket), and the counts (on a bucket's first row)."""
    assert run.counts is not None
    counts = run.counts[name]
    mask = counts > 0
    mask[1::2] |= mask[0::2]
    return mask[keep], counts[keep]


def _acted(
    run: Run,
    raw: dict[str, np.ndarray],
    j: int,
    lim_rad: tuple[float, float] | None,
    keep: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Joint ``j``: which rows the filter acted in, and how many ticks each stands for (a
    decimated run: counted per bucket while reading; the envelope cannot tell)."""
    if run.decimated:
        return _counted(run, f"acted_{run.joint_names[j]}", keep)
    acted = safety_acted(raw["cmd"][:, j], raw["sim_x"][:, j], lim_rad)
    return acted, acted.astype(float)


def _bad_reads(
    run: Run, status: np.ndarray, j: int, code: int, keep: np.ndarray
) -> tuple[np.ndarray, int]:
    """Joint ``j``'s rows with read status ``code``, and how many ticks had it."""
    if run.decimated:
        bad, per_row = _counted(run, f"status{code}_{run.joint_names[j]}", keep)
        return bad, int(per_row.sum())
    bad = status[:, j] == code
    return bad, int(np.count_nonzero(bad))


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


def _size(n_joints: int) -> tuple[float, float]:
    """The joints figure's width and height (in)."""
    return 12.0, 1.2 + 2.1 * n_joints


def make_ahead(n_joints: int, dpi: float = 110) -> None:
    """Make the joints figure of a run of ``n_joints`` before its data is there
    (:func:`hilsim.telemetry.plot_common.make_ahead`)."""
    common.make_ahead(*_size(n_joints), dpi, n_joints, sharex=True)


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
    return common.save(joints_figure(run, start=start, end=end, dpi=dpi), Path(path), dpi)


def joints_figure(
    run: Run, *, start: float | None = None, end: float | None = None, dpi: float = 110
) -> Figure:
    """The figure :func:`plot_joints` saves (axes in joint order)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    keep = common.window(run, start, end)
    t = run.t_sched[keep]
    names = run.joint_names
    status = run.joint("status")[keep]
    raw = {q: run.joint(q)[keep] for q in ("sim_x", "cmd")}
    traces = {q: np.degrees(run.joint(q)[keep]) for q in TRACE_STYLE}
    limits = joint_limits_deg(run)
    soft = soft_start_s(run)
    in_soft = t < (soft if soft is not None else -math.inf)
    dt = float(np.median(np.diff(run.t_sched))) if run.n_ticks > 1 else 0.0
    if run.decimated:  # two rows a bucket: the tick period from the ticks' span
        dt = common.period_s(run)
    n = len(names)
    fig, axes = common.figure_axes(*_size(n), dpi, n, sharex=True)
    # a first guess of the layout, so the tick locators see about the axes' final lengths
    common.place_column(
        fig, list(axes), left=0.8, right=1.6, top=0.25, bottom=0.85, gaps=[0.13] * (n - 1)
    )
    side: list[tuple[Any, float, float]] = []  # beside a row: (artist, axes fraction, inches)
    trace_lines = []
    any_acted = any_soft = False
    for j, (ax, name) in enumerate(zip(axes, names, strict=True)):
        lim = limits.get(name)
        lim_rad = None if lim is None else (math.radians(lim[0]), math.radians(lim[1]))
        acted, acted_n = _acted(run, raw, j, lim_rad, keep)
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
        asked = status[:, j] != ReadStatus.UNREAD  # a bus read in rotation: only asked ticks
        trace_lines = [
            ax.plot(*((t[asked], traces[q][asked, j]) if q == "present" else (t, traces[q][:, j])),
                    **style)[0]
            for q, style in TRACE_STYLE.items()
        ]  # fmt: skip
        stacked = np.concatenate([traces[q][:, j] for q in TRACE_STYLE])
        ax.set_ylim(*_y_range(stacked, lim, MIN_SPAN_DEG))
        note = ax.text(
            1.01,
            0.97,
            _safety_note(
                run,
                name,
                float(acted_n[~in_soft].sum()) * dt,
                float(acted_n[in_soft].sum()) * dt,
            ),
            transform=ax.transAxes,
            va="top",
            fontsize="small",
            color="tab:red" if spans else "0.4",
        )
        side.append((note, 0.01, 0.0))
        marks = []
        for code, (color, label) in STATUS_STYLE.items():
            bad, count = _bad_reads(run, status, j, int(code), keep)
            if count:
                # a rug along the bottom, in axes coordinates: visible however short the stretch
                marks.append(
                    ax.plot(
                        t[bad],
                        np.full(int(np.count_nonzero(bad)), 0.035),
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
            reads = ax.legend(
                handles=marks,
                loc="lower left",  # the safety note is at the top
                bbox_to_anchor=(1.005, 0.0),
                fontsize="small",
                title="reads not OK",
                title_fontsize="small",
            )
            side.append((reads, 0.005, common.legend_pad(reads)))
        else:
            reads = ax.text(
                1.01,
                0.03,
                "all reads OK",
                transform=ax.transAxes,
                va="bottom",
                fontsize="small",
                color="0.4",
            )
            side.append((reads, 0.01, 0.0))
    axes[-1].set_xlabel("time since run start (s)")
    handles = list(trace_lines)
    if limits:
        handles.append(Line2D([], [], **LIMIT_STYLE, label="joint limits (rig.toml)"))
    if any_acted:
        handles.append(Patch(**ACTED_STYLE, label="safety filter limited the command"))
    if any_soft:
        handles.append(Patch(**SOFT_START_STYLE, label="soft start (command blended)"))
    # below the plots: at the top, two rows of handles would run into the title
    legend = fig.legend(handles=handles, loc="lower center", ncols=min(len(handles), 4))
    span = f"{t[-1] - t[0]:.3g} s" if t.size else "no ticks"
    where = common.window_note(start, end)
    ticks = common.tick_count(run, common.rows_in(run, keep), start, end)
    title = common.title(
        fig,
        f"Joint positions: {run.path.name}{where} ({ticks}, {span}){common.decimation_note(run)}",
    )
    ruler = common.Ruler(fig)
    axes_w = axes[0].get_position().width * fig.get_figwidth()
    common.place_column(
        fig,
        list(axes),
        left=max(ruler.left(ax) for ax in axes),
        right=max(frac * axes_w + pad + ruler.size(a)[0] for a, frac, pad in side),
        top=ruler.size(title)[1] + common.PAD,
        bottom=ruler.below(axes[-1])
        + common.PAD
        + ruler.size(legend)[1]
        + common.legend_pad(legend),
        gaps=[common.TICK / 2 + 2 * common.PAD] * (n - 1),
    )
    return fig
