"""The bench's results in one object, as JSON and as a terminal summary.

JSON shape (more keys than listed are present)::

    {"loop": {"rate_hz", "lateness_us": {"p50", "p99", "p999", "max"}, "cpu_percent", "sched",
              "cyclictest_p99_us" | null, ...},
     "loops": [<one such object per measured rate>],
     "bus": [{"ids", "baud", "read": "fast" | "plain", "read_bytes": 4 | 7, "achieved_hz",
              "model_hz", "return_delay_us", ...}],
     "latency": {"command_to_wire_us", "feedback_age_us", "command_to_motion_ms", ...} | null,
     "diagnosis": {"findings": [...], ...} | null,
     "verdict": [str, ...], "host": {...}, "command": str, "emulated": bool}

``loop`` is the sleep-only loop (spin window 0), the one compared with cyclictest (which
sleeps too); ``loop.spin`` is the same loop with the spin window, its lateness and CPU
apart. The terminal summary is one report in a fixed order: loop timing, the spin window,
bus rate, latency, diagnosis, the host-cost sections, notes, files, and the verdict last.
Non-finite numbers become null (JSON has no NaN).
"""

from __future__ import annotations

import json
import math
import os
import platform
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hilsim._types import JsonDict
from hilsim.bench.busrate import BusRate
from hilsim.bench.cyclictest import INSTALL_HINT, CyclictestRun
from hilsim.bench.diagnose import Diagnosis
from hilsim.bench.latency import LatencyResult
from hilsim.bench.sched import SchedulerRun

#: what a figure measured on the built-in emulator can tell: the host's own cost, never a
#: servo's or an adapter's (the emulator is checked against its own wire-time model)
EMULATED = "emulated: host overhead only"


@dataclass
class LoopResult:
    """Our scheduler at one rate, sleeping only (``ours``: spin window 0, like cyclictest),
    cyclictest at the same interval (None: not run or not installed) and, apart, the same
    loop with the spin window (``spin``; None when the window is 0)."""

    ours: SchedulerRun
    cyclictest: CyclictestRun | None
    cyclictest_installed: bool
    spin: SchedulerRun | None = None

    def as_dict(self) -> JsonDict:
        o, c, w = self.ours, self.cyclictest, self.spin
        c_p99 = c.p99_us if c is not None else None
        spin = None
        if w is not None:
            spin = {
                "spin_us": w.spin_us,
                "lateness_us": w.stats.as_dict(),
                "overruns": w.stats.overruns,
                "cpu_percent": w.cpu_percent,
                "sched": w.sched,
            }
        return {
            "rate_hz": o.rate_hz,
            "ticks": o.stats.ticks,
            "lateness_us": o.stats.as_dict(),
            "lateness_mean_us": o.stats.mean_us,
            "overruns": o.stats.overruns,
            "cpu_percent": o.cpu_percent,
            "sched": o.sched,
            "priority": o.priority,
            "memory_locked": o.memory_locked,
            "spin_us": o.spin_us,
            "cyclictest_p99_us": c_p99,
            "p99_ratio": o.stats.p99_us / c_p99 if c_p99 else None,
            "cyclictest": None if c is None else {**c.as_dict(), "when": "right after ours"},
            "cyclictest_install": None if self.cyclictest_installed else INSTALL_HINT,
            "spin": spin,
        }


@dataclass
class BenchReport:
    command: str
    quick: bool
    subject: str  # what was measured: "emulator" or the port / rig
    rig_rate_hz: float | None = None
    loops: list[LoopResult] = field(default_factory=list)
    bus: list[BusRate] = field(default_factory=list)
    latency: LatencyResult | None = None
    diagnosis: Diagnosis | None = None
    notes: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)
    #: the bus side ran on the built-in emulator (its figures are labelled :data:`EMULATED`)
    emulated: bool = False
    #: more sections' text (tick cost, CPU over a pty), printed before the notes, and their
    #: JSON by key
    sections: list[str] = field(default_factory=list)
    extra: dict[str, JsonDict] = field(default_factory=dict)

    def verdict(self) -> list[str]:
        """A few sentences answering "why does my loop only reach this rate?"."""
        out: list[str] = []
        beside: list[str] = []  # not a limit: the like-for-like comparison's outcome
        rows = [r for r in self.bus if r.timing.cycles]
        if rows:
            target = self.rig_rate_hz
            one_bus = len({(r.ids, r.baud, r.port) for r in rows}) == 1
            best = max(_as_run(rows), key=lambda r: r.achieved_hz) if target or one_bus else None
            if best is not None:
                read = (
                    ("Fast" if best.fast else "plain")
                    + " Sync Read"
                    + (f" of the {best.read_bytes} B tick block" if best.read_bytes != 4 else "")
                )
                if not target:
                    out.append(
                        f"This bus tops out at {best.achieved_hz:.0f} cycles/s ({read}; "
                        f"wire-time model {best.model_hz:.0f})."
                    )
                elif best.achieved_hz < target:
                    out.append(
                        f"The bus is the limit: {best.achieved_hz:.0f} cycles/s achieved "
                        f"({read}, model {best.model_hz:.0f}) < your {target:g} Hz."
                    )
                else:
                    out.append(
                        f"The bus keeps up: {best.achieved_hz:.0f} cycles/s achieved "
                        f"({read}) for your {target:g} Hz loop."
                    )
            worst = min(rows, key=lambda r: r.ratio)
            if worst.ratio < 0.8:
                out.append(
                    f"Host time per cycle matters at {worst.baud} bps with {len(worst.ids)} "
                    f"servo(s): +{worst.host_us_per_cycle:.0f} µs per cycle beyond the wire "
                    f"({worst.ratio:.0%} of the model)."
                )
        if self.diagnosis is not None and self.diagnosis.findings:
            d = self.diagnosis
            names = ", ".join(f.check.replace("_", " ") for f in d.findings)
            out.append(
                f"Fixable: {names}; model {_hz(d.current_hz)} now, {_hz(d.all_fixed_hz)} with "
                "every fix."
            )
        for lr in self.loops:
            run = lr.spin or lr.ours  # the loop as a show runs it
            s = run.stats
            period_us = 1e6 / run.rate_hz
            if s.p99_us > 0.1 * period_us:
                out.append(
                    f"The scheduler is late at {run.rate_hz:g} Hz ({run.sched}): p99 "
                    f"{s.p99_us:.0f} µs of a {period_us:.0f} µs period"
                    + ("; try SCHED_FIFO (run as root)." if run.sched != "SCHED_FIFO" else ".")
                )
            c_p99 = lr.cyclictest.p99_us if lr.cyclictest is not None else None
            if c_p99:
                beside.append(
                    f"Sleeping as cyclictest does, the loop wakes with p99 "
                    f"{_us(lr.ours.stats.p99_us)} against cyclictest's {_us(c_p99)} at "
                    f"{lr.ours.rate_hz:g} Hz ({lr.ours.stats.p99_us / c_p99:.2g}×)."
                )
        return (out or ["Nothing here limits the loop below its wire-time model."]) + beside

    def as_dict(self) -> JsonDict:
        loops = [lr.as_dict() for lr in self.loops]
        out: JsonDict = _finite(
            {
                "command": self.command,
                "quick": self.quick,
                "subject": self.subject,
                "host": host_info(),
                "loop": loops[0] if loops else None,
                "loops": loops,
                "bus": [r.as_dict() for r in self.bus],
                "latency": None if self.latency is None else self.latency.as_dict(),
                "diagnosis": None if self.diagnosis is None else self.diagnosis.as_dict(),
                "verdict": self.verdict(),
                "notes": list(self.notes),
                "files": list(self.files),
                "emulated": self.emulated,
                **self.extra,
            }
        )
        return out

    def write_json(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.as_dict(), indent=2, ensure_ascii=False) + "\n")

    def text(self) -> str:
        """The terminal summary: one report, in a fixed order, the verdict last."""
        lines = [f"hilsim bench{' --quick' if self.quick else ''}: {self.subject}"]
        if self.emulated:
            lines.append(
                f"  (bus figures {EMULATED}: the emulator checked against its own wire-time "
                "model; run it on your port for your servos' figures)"
            )
        lines.append("")
        if self.loops:
            lines += _loop_text(self.loops)
            lines += _spin_text(self.loops)
        emulated = f"{EMULATED}; " if self.emulated else ""
        if self.bus:
            lines += _bus_text(self.bus, emulated)
        if self.latency is not None:
            lines += _latency_text(self.latency, emulated)
        if self.diagnosis is not None:
            lines += _diagnosis_text(self.diagnosis, emulated)
        for section in self.sections:
            lines += [*section.rstrip("\n").splitlines(), ""]
        if self.notes:
            lines += ["Notes", *[f"  - {n}" for n in self.notes], ""]
        if self.files:
            lines += ["Files", *[f"  {f}" for f in self.files], ""]
        lines += ["Verdict", *[f"  {v}" for v in self.verdict()]]
        return "\n".join(lines).rstrip() + "\n"


def host_info() -> JsonDict:
    return {
        "node": platform.node(),
        "cpus": os.cpu_count(),
        "kernel": platform.release(),
        "python": platform.python_version(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }


# ------------------------------------------------------------------------------ text
def _hz(x: float | None) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:,.0f} Hz"


def _us(x: float | None) -> str:
    if x is None or not math.isfinite(x):
        return "n/a"
    return f"{x:.2f} µs" if x < 10 else f"{x:,.0f} µs"


_LOOP_HEAD = (
    f"  {'':18}{'rate':>8}  {'sched':<11}{'p50':>10}{'p99':>10}{'p99.9':>10}{'max':>10}"
    f"{'overruns':>10}{'CPU':>7}"
)


def _run_row(name: str, o: SchedulerRun) -> str:
    s = o.stats
    return (
        f"  {name:18}{o.rate_hz:>6g}Hz  {o.sched:<11}{_us(s.p50_us):>10}{_us(s.p99_us):>10}"
        f"{_us(s.p999_us):>10}{_us(s.max_us):>10}{s.overruns:>10}{o.cpu_percent:>6.0f}%"
    )


def _loop_text(loops: list[LoopResult]) -> list[str]:
    """Like with like: our loop sleeping to each absolute deadline (no spin) beside
    cyclictest, which sleeps to its deadlines too."""
    lines = [
        "Loop timing: the tick scheduler alone, sleeping to absolute deadlines (spin window 0), "
        "beside cyclictest (which sleeps too)",
        _LOOP_HEAD,
    ]
    for lr in loops:
        s = lr.ours.stats
        lines.append(_run_row("ours, sleep only", lr.ours))
        c = lr.cyclictest
        if c is not None and c.output is not None:
            out = c.output
            lines.append(
                f"  {'cyclictest':18}{1e6 / c.interval_us:>6g}Hz  {c.sched:<11}"
                f"{_us(out.percentile(50)):>10}{_us(out.percentile(99)):>10}"
                f"{_us(out.percentile(99.9)):>10}{_us(out.max_us):>10}"
                f"{'':>10}{'':>7}   (v{c.version}, right after ours)"
            )
            p99 = out.percentile(99)
            if p99:
                lines.append(
                    f"  {'':18}sleep vs sleep: ours / cyclictest p99 = {s.p99_us / p99:.3g}"
                )
        elif c is not None:
            lines.append(f"  cyclictest failed: {c.error}")
        elif not lr.cyclictest_installed:
            lines.append(f"  cyclictest not installed; for the C reference: {INSTALL_HINT}")
    return [*lines, ""]


def _spin_text(loops: list[LoopResult]) -> list[str]:
    """The spin window apart: what it buys in lateness and what it costs in CPU."""
    spun = [lr for lr in loops if lr.spin is not None]
    if not spun:
        return []
    w0 = spun[0].spin
    assert w0 is not None  # (filtered above)
    lines = [
        f"Spin window: the same loop sleeping, then spinning at most the last "
        f"{w0.spin_us or 0:g} µs of each wait (loop.spin_us; less where this host's wake-ups "
        "are sooner, learned): its lateness and its CPU, not comparable with cyclictest",
        _LOOP_HEAD,
    ]
    for lr in spun:
        w = lr.spin
        assert w is not None
        lines.append(_run_row(f"ours, spin {w.spin_us or 0:g} µs", w))
        lines.append(
            f"  {'':18}p99 {_us(lr.ours.stats.p99_us)} -> {_us(w.stats.p99_us)} for "
            f"{w.cpu_percent - lr.ours.cpu_percent:+.0f} % of a core"
        )
    return [*lines, ""]


def _as_run(rows: list[BusRate]) -> list[BusRate]:
    """The rows whose read is the one hilsim's tick makes: a Fast read of positions alone
    is left out where the same bus has a tick block row (the X series reads the block)."""
    blocks = {(r.ids, r.baud, r.port) for r in rows if r.read_bytes != 4}
    return [
        r for r in rows if not (r.fast and r.read_bytes == 4 and (r.ids, r.baud, r.port) in blocks)
    ]


def _bus_text(rows: list[BusRate], emulated: str = "") -> list[str]:
    r0 = rows[0]
    where = f"emulator on the {r0.clock} clock" if r0.port.startswith("dxlsim") else r0.port
    lines = [
        f"Bus rate: Sync Write + Sync Read cycles back to back ({emulated}{where}, "
        f"{r0.timing.sched})",
        f"  {'servos':>6}{'baud':>10}  {'read':<6}{'carries':<16}{'achieved':>11}{'model':>11}"
        f"{'ratio':>8}{'host µs/cyc':>13}{'fails':>7}",
    ]
    for r in rows:
        carries = f"{r.carries} {r.read_bytes} B"
        lines.append(
            f"  {len(r.ids):>6}{r.baud:>10}  {'fast' if r.fast else 'plain':<6}{carries:<16}"
            f"{_hz(r.achieved_hz):>11}{_hz(r.model_hz):>11}{r.ratio:>8.1%}"
            f"{r.host_us_per_cycle:>13.1f}{r.timing.failures:>7}"
        )
    if any(r.read_bytes != 4 for r in rows):
        lines.append(
            "  carries: position = Present Position, the SDK's own cycle; tick block = what "
            "hilsim's X-series tick reads: Present Position, Torque Enable, Bus Watchdog and "
            "Status Return Level through Indirect Data 1-7 (every servo's health every tick)"
        )
    lines.append(
        "  model: 10·bytes/baud + n_d·(RDT + turnaround) + latency timer; "
        f"RDT {r0.return_delay_us:g} µs, turnaround {r0.turnaround_us:g} µs, "
        f"latency timer {r0.latency_timer_ms:g} ms"
    )
    return [*lines, ""]


def _latency_text(lat: LatencyResult, emulated: str = "") -> list[str]:
    d = lat.as_dict()
    w, a, m = d["command_to_wire_us"], d["feedback_age_us"], d["command_to_motion_ms"]
    lines = [
        f"Latency at {lat.rate_hz:g} Hz, {len(lat.ids)} servo(s), "
        f"{'Fast' if lat.fast else 'plain'} Sync Read ({emulated}{lat.method})",
        f"  command -> wire     p50 {_us(w['p50'])}, p99 {_us(w['p99'])}, max {_us(w['max'])}"
        "   (tick start -> last goal byte on the wire)",
        f"  feedback age       p50 {_us(a['p50'])}, p99 {_us(a['p99'])}, max {_us(a['max'])}"
        "   (reply's first byte -> host has it)",
    ]
    if m["start"] is not None:
        reach = "not reached" if m["reach_63"] is None else f"{m['reach_63']:.1f} ms"
        lines.append(
            f"  command -> motion   starts {m['start']:.1f} ms, 63 % at {reach} "
            f"(step {m['step_pulses']} pulses; resolution {m['resolution']:.1f} ms)"
        )
    else:
        lines.append("  command -> motion   not measured (pass --move to step the servos)")
    if lat.overruns or lat.failures:
        lines.append(f"  {lat.overruns} overrun(s), {lat.failures} failed cycle(s)")
    if lat.note:
        lines.append(f"  note: {lat.note}")
    return [*lines, ""]


def _diagnosis_text(d: Diagnosis, emulated: str = "") -> list[str]:
    f = d.facts
    lines = [
        f"Diagnosis of {f.port} at {f.baud} bps ({emulated}{len(f.servos)} servo(s), "
        f"{'Fast' if f.fast_read else 'plain'} Sync Read; model {_hz(d.current_hz)})"
    ]
    if f.read_time_ms is not None:
        lines.append(
            f"  single read: {f.read_time_ms:.2f} ms measured, {f.read_model_ms:.2f} ms on the "
            f"wire; latency timer {f.latency_timer_ms:.1f} ms ({f.latency_source})"
        )
    if not d.findings:
        lines.append("  no findings: latency timer, Return Delay Time, baud rate and firmware OK")
    for x in d.findings:
        gain = (
            "" if x.predicted_hz is None else f"  ->  {_hz(x.current_hz)} -> {_hz(x.predicted_hz)}"
        )
        lines.append(_wrap(f"* {x.check.replace('_', ' ')}: {x.problem}{gain}", 2, 4))
        lines.append(_wrap(f"fix: {x.fix}", 6, 11))
        for name, hz in x.alternatives.items():
            lines.append(f"      (at {name} bps: {_hz(hz)})")
    if d.findings and math.isfinite(d.all_fixed_hz):
        lines.append(f"  with every fix: {_hz(d.all_fixed_hz)} (wire-time model)")
    return [*lines, ""]


def _wrap(text: str, indent: int, hang: int) -> str:
    return textwrap.fill(
        text,
        width=100,
        initial_indent=" " * indent,
        subsequent_indent=" " * hang,
        break_on_hyphens=False,
    )


def _finite(obj: Any) -> Any:
    """Replace NaN/inf by None, recursively (JSON has no NaN); tuples become lists."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    return obj
