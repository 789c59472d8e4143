"""What a rig will ask of each joint, before anything moves: its tracks through the springs and
the safety filter, offline (``hilsim tracks``).

:func:`targets_at` gives every joint's target (degrees, before the spring) at chosen show
times. :func:`preview` runs the show's own parts - targets, integrator, safety filter - tick by
tick as :class:`~hilsim.show.loop.HilLoop` does, with no bus: the target, the spring's position, the
command the filter lets through and where the filter changed it. The figure starts where the
rig's ``initial_deg`` puts each joint, else at its target at t = 0 (a real show starts from the
pose the servos report, through the soft start). :func:`combine` puts the previews of a
figure's buses side by side; :func:`plot_preview` draws it;
:func:`hilsim.targets.check.check_tracks` names the limits the targets break.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hilsim._types import FloatArray
from hilsim.show.parts import Parts
from hilsim.show.stepper import Stepper, TickBuffers

if TYPE_CHECKING:  # matplotlib is imported when a preview is plotted, not before
    from matplotlib.artist import Artist

#: a command this far (rad) from the spring's position was changed by the safety filter
CLAMP_TOLERANCE_RAD = 1e-9
#: the longest preview, in ticks (a 10-minute show at 1 kHz)
MAX_PREVIEW_TICKS = 600_001
#: the safety filter's counters the preview names (the others are faults, not limits)
ACTED_KINDS = ("position", "speed", "brake", "accel")


@dataclass(frozen=True)
class Preview:
    """One dry pass over ``len(t)`` ticks. Arrays ``(ticks, joints)`` in degrees; ``clamped``
    is True where the safety filter's command differs from the spring's position after the
    soft start (its first ``soft_start_s``, when the command is blended from wherever the
    figure stands: not a limit)."""

    joints: tuple[str, ...]
    t: FloatArray
    target_deg: FloatArray
    spring_deg: FloatArray
    cmd_deg: FloatArray
    clamped: np.ndarray
    min_deg: tuple[float, ...]
    max_deg: tuple[float, ...]
    soft_start_s: float = 0.0
    #: each joint's bus, for a rig with several ``[buses.<name>]`` (empty: one bus)
    buses: tuple[str, ...] = ()
    #: per joint, how many ticks after the soft start each limit acted (position, speed,
    #: accel, brake: the safety filter's counters), and each joint's speed and acceleration
    #: limits (deg/s, deg/s²)
    acted: tuple[dict[str, int], ...] = ()
    max_speed_deg_s: tuple[float, ...] = ()
    max_accel_deg_s2: tuple[float, ...] = ()

    def limits_text(self, i: int) -> str:
        """Which limits acted on joint ``i`` after the soft start (most often first), each with
        the figure the spring asked and the key to change: "" when none did."""
        acted = self.acted[i] if self.acted else {}
        speed = acted.get("speed", 0) + acted.get("brake", 0)  # the brake is the speed's
        counts = {"position": acted.get("position", 0), "speed": speed}
        counts["accel"] = acted.get("accel", 0)
        period = float(self.t[1] - self.t[0]) if len(self.t) > 1 else 1.0
        x = self.spring_deg[self.t >= self.soft_start_s, i]
        said = []
        for kind in sorted((k for k, n in counts.items() if n), key=lambda k: -counts[k]):
            if kind == "position":
                lo, hi = self.min_deg[i], self.max_deg[i]
                under, over = lo - float(x.min(initial=lo)), float(x.max(initial=hi)) - hi
                side, by, limit = ("min", under, lo) if under >= over else ("max", over, hi)
                said.append(
                    f"position (the spring goes {by:.2g}° beyond {side}_deg {limit:g}°: keep "
                    f"the target off the limit, raise damping_ratio, or widen {side}_deg)"
                )
            elif kind == "speed" and self.max_speed_deg_s:
                v = float(np.abs(np.diff(x)).max(initial=0.0)) / period
                said.append(
                    f"speed (the spring asks up to {v:.0f}°/s of max_speed_deg_s "
                    f"{self.max_speed_deg_s[i]:g}: raise it within the servo's, or slow the "
                    "motion)"
                )
            elif kind == "accel" and self.max_accel_deg_s2:
                a = float(np.abs(np.diff(x, 2)).max(initial=0.0)) / period**2
                said.append(
                    f"accel (the spring asks up to {a:.0f}°/s² of max_accel_deg_s2 "
                    f"{self.max_accel_deg_s2[i]:g}: raise it, or lower frequency_hz)"
                )
        return "; ".join(said)


def combine(previews: Sequence[Preview], buses: Sequence[str]) -> Preview:
    """One preview of a figure on several buses: each bus's joints, bus by bus, side by side
    (the buses share the rate, the safety settings and the preview's length)."""
    first = previews[0]
    if any(len(p.t) != len(first.t) for p in previews):
        raise ValueError("the buses' previews differ in length")
    return Preview(
        joints=tuple(name for p in previews for name in p.joints),
        t=first.t,
        target_deg=np.hstack([p.target_deg for p in previews]),
        spring_deg=np.hstack([p.spring_deg for p in previews]),
        cmd_deg=np.hstack([p.cmd_deg for p in previews]),
        clamped=np.hstack([p.clamped for p in previews]),
        min_deg=tuple(v for p in previews for v in p.min_deg),
        max_deg=tuple(v for p in previews for v in p.max_deg),
        soft_start_s=first.soft_start_s,
        buses=tuple(bus for p, bus in zip(previews, buses, strict=True) for _ in p.joints),
        acted=tuple(a for p in previews for a in p.acted),
        max_speed_deg_s=tuple(v for p in previews for v in p.max_speed_deg_s),
        max_accel_deg_s2=tuple(v for p in previews for v in p.max_accel_deg_s2),
    )


def targets_at(parts: Parts, times: Sequence[float]) -> dict[str, list[float]]:
    """Each joint's target in degrees at ``times`` (show seconds), before the spring."""
    names = parts.rig.joint_names
    out: dict[str, list[float]] = {name: [] for name in names}
    n = len(names)
    pos = np.zeros(n)
    for t in times:
        parts.targets.sample(float(t), pos)
        for name, value in zip(names, pos.tolist(), strict=True):
            out[name].append(math.degrees(value))
    return out


def preview(parts: Parts, duration_s: float) -> Preview:
    """The show's first ``duration_s`` seconds, tick by tick, without a bus.

    Raises ValueError when ``duration_s`` is not a finite positive time or asks for more than
    :data:`MAX_PREVIEW_TICKS` ticks.
    """
    rig = parts.rig
    period = rig.loop.period_s
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"the preview needs a finite duration > 0 s, got {duration_s!r}")
    ticks = round(duration_s / period) + 1
    if ticks > MAX_PREVIEW_TICKS:
        raise ValueError(
            f"{duration_s:g} s at {rig.loop.rate_hz:g} Hz is {ticks} ticks; the preview takes "
            f"at most {MAX_PREVIEW_TICKS} (give a shorter --duration)"
        )
    n = len(rig.joints)
    buffers = TickBuffers.zeros(n)
    stepper = Stepper.of(parts, buffers)
    x, u = buffers.x, buffers.u
    parts.targets.sample(0.0, u, buffers.du)
    for i, jt in enumerate(rig.joints):
        x[i] = u[i] if jt.initial_rad is None else jt.initial_rad
    lo, hi = [j.min_rad for j in rig.joints], [j.max_rad for j in rig.joints]
    parts.safety.start(np.clip(x, lo, hi))
    target = np.empty((ticks, n))
    spring = np.empty((ticks, n))
    out = np.empty((ticks, n))
    soft = math.ceil(rig.safety.soft_start_s / period - 1e-9)
    before = parts.safety.counters.by_kind()
    for k in range(ticks):  # the loop's tick without the bus
        t = k * period
        if k == soft:  # the limits' counts after the soft start, as `clamped` marks them
            before = parts.safety.counters.by_kind()
        stepper.command()
        spring[k] = x
        out[k] = buffers.cmd
        first = stepper.sample(t)
        target[k] = u
        stepper.advance(t, first)
    clamped = np.abs(out - spring) > CLAMP_TOLERANCE_RAD
    clamped[:soft] = False  # the soft start's blend, not a limit
    counts = parts.safety.counters.by_kind() if ticks > soft else before
    acted = tuple(
        {kind: counts[kind][name] - before[kind][name] for kind in ACTED_KINDS}
        for name in rig.joint_names
    )
    return Preview(
        joints=tuple(rig.joint_names),
        t=np.arange(ticks, dtype=np.float64) * period,
        target_deg=np.degrees(target),
        spring_deg=np.degrees(spring),
        cmd_deg=np.degrees(out),
        clamped=clamped,
        min_deg=tuple(math.degrees(j.min_rad) for j in rig.joints),
        max_deg=tuple(math.degrees(j.max_rad) for j in rig.joints),
        soft_start_s=rig.safety.soft_start_s,
        acted=acted,
        max_speed_deg_s=tuple(math.degrees(j.max_speed_rad_s) for j in rig.joints),
        max_accel_deg_s2=tuple(math.degrees(j.max_accel_rad_s2) for j in rig.joints),
    )


def plot_preview(p: Preview, path: Path, title: str, dpi: int = 110) -> Path:
    """One panel per joint: target, spring, command, the limits, the soft start (shaded) and
    the ticks where the safety filter changed the command after it (red). Returns the PNG's
    path."""
    from hilsim.telemetry.plot_common import new_figure, save
    from hilsim.telemetry.plot_common import title as set_title

    n = len(p.joints)
    fig = new_figure(9.0, 1.2 + 1.9 * n, dpi)
    set_title(fig, title)
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    for i, (ax, name) in enumerate(zip(axes, p.joints, strict=True)):
        ax.plot(p.t, p.target_deg[:, i], color="0.6", lw=1.0, label="target")
        ax.plot(p.t, p.spring_deg[:, i], color="C0", lw=1.2, label="spring")
        ax.plot(p.t, p.cmd_deg[:, i], color="C1", lw=1.0, ls="--", label="command")
        for limit in (p.min_deg[i], p.max_deg[i]):
            ax.axhline(limit, color="k", lw=0.8, ls=":")
        if p.soft_start_s > 0:
            ax.axvspan(0, min(p.soft_start_s, p.t[-1]), color="0.9", zorder=0, label="soft start")
        hit = p.clamped[:, i]
        if hit.any():
            ax.plot(p.t[hit], p.cmd_deg[hit, i], "|", color="red", ms=6, label="safety filter")
        ax.set_ylabel(f"{p.buses[i]}: {name} (deg)" if p.buses else f"{name} (deg)")
        ax.grid(alpha=0.3)
    legend: dict[str, Artist] = {}
    for ax in axes:  # one legend for every panel's lines, on the first
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            legend.setdefault(label, handle)
    # above the first panel, outside every axes: a legend never covers the curves
    axes[0].legend(
        legend.values(),
        legend.keys(),
        loc="lower right",
        bbox_to_anchor=(1.0, 1.0),
        fontsize="small",
        ncols=5,
        frameon=False,
    )
    axes[-1].set_xlabel("show time (s)")
    height = fig.get_figheight()  # margins in inches: a figure of many joints is tall
    fig.subplots_adjust(
        left=0.1, right=0.98, top=1 - 0.85 / height, bottom=0.55 / height, hspace=0.25
    )
    return save(fig, path, dpi)
