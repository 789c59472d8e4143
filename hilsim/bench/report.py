"""The bench's results in one object, as JSON and as a terminal summary.

JSON shape (more keys than listed are present)::

    {"loop": {"rate_hz", "lateness_us": {"p50", "p99", "p999", "max"}, "cpu_percent", "sched",
              "cyclictest_p99_us" | null, ...},
     "loops": [<one such object per measured rate>],
     "bus": [{"ids", "baud", "read": "fast" | "plain", "achieved_hz", "model_hz",
              "return_delay_us", ...}],
     "latency": {"command_to_wire_us", "feedback_age_us", "command_to_motion_ms", ...} | null,
     "diagnosis": {"findings": [...], ...} | null,
     "verdict": [str, ...], "host": {...}, "command": str}

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


@dataclass
class LoopResult:
    """Our scheduler at one rate and cyclictest at the same interval (None: not installed)."""

    ours: SchedulerRun
    cyclictest: CyclictestRun | None
    cyclictest_installed: bool

    def as_dict(self) -> JsonDict:
        o, c = self.ours, self.cyclictest
        c_p99 = c.p99_us if c is not None else None
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

    def verdict(self) -> list[str]:
        """A few sentences answering "why does my loop only reach this rate?"."""
        out = []
        rows = [r for r in self.bus if r.timing.cycles]
        if rows:
            target = self.rig_rate_hz
            one_bus = len({(r.ids, r.baud, r.port) for r in rows}) == 1
            best = max(rows, key=lambda r: r.achieved_hz) if target or one_bus else None
            if best is not None:
                read = "Fast" if best.fast else "plain"
                if not target:
                    out.append(
                        f"This bus tops out at {best.achieved_hz:.0f} cycles/s ({read} Sync "
                        f"Read; wire-time model {best.model_hz:.0f})."
                    )
                elif best.achieved_hz < target:
                    out.append(
                        f"The bus is the limit: {best.achieved_hz:.0f} cycles/s achieved "
                        f"({read} Sync Read, model {best.model_hz:.0f}) < your {target:g} Hz."
                    )
                else:
                    out.append(
                        f"The bus keeps up: {best.achieved_hz:.0f} cycles/s achieved "
                        f"({read} Sync Read) for your {target:g} Hz loop."
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
            s = lr.ours.stats
            period_us = 1e6 / lr.ours.rate_hz
            if s.p99_us > 0.1 * period_us:
                out.append(
                    f"The scheduler is late at {lr.ours.rate_hz:g} Hz ({lr.ours.sched}): p99 "
                    f"{s.p99_us:.0f} µs of a {period_us:.0f} µs period"
                    + ("; try SCHED_FIFO (run as root)." if lr.ours.sched != "SCHED_FIFO" else ".")
                )
        return out or ["Nothing here limits the loop below its wire-time model."]

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
            }
        )
        return out

    def write_json(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.as_dict(), indent=2, ensure_ascii=False) + "\n")

    def text(self) -> str:
        """The terminal summary."""
        lines = [f"hilsim bench{' --quick' if self.quick else ''}: {self.subject}", ""]
        if self.loops:
            lines += _loop_text(self.loops)
        if self.bus:
            lines += _bus_text(self.bus)
        if self.latency is not None:
            lines += _latency_text(self.latency)
        if self.diagnosis is not None:
            lines += _diagnosis_text(self.diagnosis)
        lines += ["Verdict", *[f"  {v}" for v in self.verdict()], ""]
        if self.notes:
            lines += ["Notes", *[f"  - {n}" for n in self.notes], ""]
        if self.files:
            lines += ["Files", *[f"  {f}" for f in self.files]]
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


def _loop_text(loops: list[LoopResult]) -> list[str]:
    spin = loops[0].ours.spin_us
    lines = [
        "Loop timing: the tick scheduler alone, absolute deadlines "
        + (f"(sleep, then spin the last {spin:.0f} µs)" if spin is not None else ""),
        f"  {'':11}{'rate':>8}  {'sched':<11}{'p50':>10}{'p99':>10}{'p99.9':>10}{'max':>10}"
        f"{'overruns':>10}{'CPU':>7}",
    ]
    for lr in loops:
        o, s = lr.ours, lr.ours.stats
        lines.append(
            f"  {'ours':11}{o.rate_hz:>6g}Hz  {o.sched:<11}{_us(s.p50_us):>10}{_us(s.p99_us):>10}"
            f"{_us(s.p999_us):>10}{_us(s.max_us):>10}{s.overruns:>10}{o.cpu_percent:>6.0f}%"
        )
        c = lr.cyclictest
        if c is not None and c.output is not None:
            out = c.output
            lines.append(
                f"  {'cyclictest':11}{1e6 / c.interval_us:>6g}Hz  {c.sched:<11}"
                f"{_us(out.percentile(50)):>10}{_us(out.percentile(99)):>10}"
                f"{_us(out.percentile(99.9)):>10}{_us(out.max_us):>10}"
                f"{'':>10}{'':>7}   (v{c.version}, right after ours)"
            )
            p99 = out.percentile(99)
            if p99:
                lines.append(f"  {'':11}ours / cyclictest p99 = {s.p99_us / p99:.3g}")
        elif c is not None:
            lines.append(f"  cyclictest failed: {c.error}")
        elif not lr.cyclictest_installed:
            lines.append(f"  cyclictest not installed; for the C reference: {INSTALL_HINT}")
    return [*lines, ""]


def _bus_text(rows: list[BusRate]) -> list[str]:
    r0 = rows[0]
    where = f"emulator on the {r0.clock} clock" if r0.port.startswith("dxlsim") else r0.port
    lines = [
        f"Bus rate: Sync Write + Sync Read cycles back to back ({where}, {r0.timing.sched})",
        f"  {'servos':>6}{'baud':>10}  {'read':<6}{'achieved':>11}{'model':>11}{'ratio':>8}"
        f"{'host µs/cyc':>13}{'fails':>7}",
    ]
    for r in rows:
        lines.append(
            f"  {len(r.ids):>6}{r.baud:>10}  {'fast' if r.fast else 'plain':<6}"
            f"{_hz(r.achieved_hz):>11}{_hz(r.model_hz):>11}{r.ratio:>8.1%}"
            f"{r.host_us_per_cycle:>13.1f}{r.timing.failures:>7}"
        )
    lines.append(
        "  model: 10·bytes/baud + n_d·(RDT + turnaround) + latency timer; "
        f"RDT {r0.return_delay_us:g} µs, turnaround {r0.turnaround_us:g} µs, "
        f"latency timer {r0.latency_timer_ms:g} ms"
    )
    return [*lines, ""]


def _latency_text(lat: LatencyResult) -> list[str]:
    d = lat.as_dict()
    w, a, m = d["command_to_wire_us"], d["feedback_age_us"], d["command_to_motion_ms"]
    lines = [
        f"Latency at {lat.rate_hz:g} Hz, {len(lat.ids)} servo(s), "
        f"{'Fast' if lat.fast else 'plain'} Sync Read ({lat.method})",
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


def _diagnosis_text(d: Diagnosis) -> list[str]:
    f = d.facts
    lines = [
        f"Diagnosis of {f.port} at {f.baud} bps ({len(f.servos)} servo(s), "
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
