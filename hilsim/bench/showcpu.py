"""Where the CPU goes, for a small host: a show's CPU per second on the real clock.

``hilsim run RIG --port PTY`` in a child process, its bus a ``hilsim emulate`` pseudo-terminal
served by another process, as a USB adapter is: the emulator's CPU is that other process's,
printed apart, and the show's process (the loop, the telemetry writer, the heartbeat: every
thread, counted by the scheduler, ``/proc/PID/task/*/schedstat``) is what a host would run
beside real servos. Over a settled window of the show: CPU seconds per second of show, i.e.
the share of one core, the loop thread's part, the ticks a second kept and the lateness.

``hilsim bench`` on the built-in emulator runs it for the demo (4 joints at 250 Hz) and
scale16 (16 joints at 1 kHz), ``--quick`` too (:func:`for_bench`). A pty delivers a reply
later than a USB adapter on a real bus would (``docs/performance.md``): scale16's 1 kHz bus
does not fit through one (``hilsim run`` refuses it), so scale16 runs on the emulator in its
own process instead, the emulator's work (``WireBus.write`` and ``read``: parsing, servos,
replies; not the waits for the wire, which a real port has too) timed on the thread that does
it and taken out of the process's CPU; its line says so.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from hilsim._types import JsonDict
from hilsim.bench.cpu import REPO, emulate, sample_show
from hilsim.bench.report import EMULATED

if TYPE_CHECKING:
    import argparse

    from hilsim.bench.report import BenchReport

#: the rigs measured: (label, file under configs/, where its emulator runs)
RIGS = (("demo", "demo.toml", "pty"), ("scale16", "scale16.toml", "in-process"))
#: the child for an in-process emulator: its work timed on the thread that does it (ns,
#: calls), written to the file named by the first argument at exit, then ``hilsim``
CHILD = """import atexit, json, sys, time
from drivers.dxlsim import wire
_books, _out = [0, 0], sys.argv.pop(1)
def _timed(inner):
    def timed(*args, **kwargs):
        c = time.thread_time_ns()
        try:
            return inner(*args, **kwargs)
        finally:
            _books[0] += time.thread_time_ns() - c
            _books[1] += 1
    return timed
for _name in ("write", "read"):
    setattr(wire.WireBus, _name, _timed(getattr(wire.WireBus, _name)))
atexit.register(lambda: open(_out, "w").write(json.dumps(_books)))
from hilsim.cli import main
sys.exit(main(sys.argv[1:]))
"""
#: seconds of show before the window (start-up, soft start, the spin window's learning) and
#: measured (quick, full)
SETTLE_S = {True: 0.5, False: 1.5}
WINDOW_S = {True: 1.0, False: 5.0}
#: seconds of show after the window (the show must still be running when it closes)
TAIL_S = 0.3


@dataclass(frozen=True)
class ShowCpu:
    """One rig's show over a pty: CPU per second of show (s/s: 0.06 is 6 % of a core)."""

    rig: str
    where: str  # the emulator: "pty" (another process) or "in-process" (taken out)
    rate_hz: float
    window_s: float
    cpu_per_s: float  # the show's process, every thread (an in-process emulator's work out)
    loop_per_s: float  # its loop thread (the main thread; likewise)
    emulator_per_s: float  # the emulator's process, or its work in the show's (taken out)
    ticks_per_s: float  # ticks the show ran a second, over the whole show
    wakeups_per_tick: float  # the loop thread's voluntary context switches
    lateness_p99_us: float
    exit_code: int

    @property
    def us_per_tick(self) -> float:
        return self.cpu_per_s / self.ticks_per_s * 1e6 if self.ticks_per_s else math.nan


@dataclass
class ShowCpuResult:
    shows: list[ShowCpu]
    load: list[float]
    notes: list[str]

    def text(self) -> str:
        lines = [
            f"CPU per second of show on the real clock ({EMULATED}; the show's whole process: "
            "loop, telemetry writer, heartbeat; the emulator's CPU apart: another process on a "
            "pty, or timed and taken out in-process)"
        ]
        apart = {"pty": "emulator process", "in-process": "emulator's work taken out"}
        for s in self.shows:
            kept = f"{s.ticks_per_s:.0f} of its {s.rate_hz:g} ticks a second kept"
            lines.append(
                f"  {s.rig:<8} {s.cpu_per_s * 1e3:6.0f} ms of CPU a second = "
                f"{s.cpu_per_s:.1%} of one core (loop thread {s.loop_per_s:.1%}); "
                f"{s.us_per_tick:.0f} µs a tick, {s.wakeups_per_tick:.1f} wake-ups a tick; "
                f"{kept}; lateness p99 {s.lateness_p99_us:,.0f} µs; "
                f"{apart.get(s.where, s.where)} {s.emulator_per_s:.1%}"
                + ("" if s.exit_code == 0 else f"; exit {s.exit_code}")
            )
        w = self.shows[0].window_s if self.shows else 0.0
        load = " ".join(f"{x:.2f}" for x in self.load)
        lines.append(f"  ({w:g} s of each show measured; load {load})")
        lines += [f"  {n}" for n in self.notes]
        return "\n".join(lines) + "\n"

    def as_dict(self) -> JsonDict:
        return {
            "shows": [asdict(s) | {"us_per_tick": s.us_per_tick} for s in self.shows],
            "load": list(self.load),
            "notes": list(self.notes),
            "emulator": {
                "pty": "hilsim emulate on a pty, another process (its CPU apart)",
                "in-process": "in the show's process, its work (WireBus.write and read) timed "
                "on its thread and taken out of cpu_per_s and loop_per_s",
            },
        }


def _bus(rig: Path) -> tuple[str, int, str, float]:
    """The emulator a rig's ``dxlsim://`` bus asks for: (ids, baud, model), and its rate."""
    from drivers.dxlsim.url import DxlsimUrl
    from hilsim.rig import load_rig

    loaded = load_rig(rig)
    url = DxlsimUrl.parse(loaded.bus.port)
    ids = ",".join(str(i) for i in loaded.servo_ids)
    return ids, int(loaded.bus.baud), str(url.model), float(loaded.loop.rate_hz)


def show_once(
    rig: Path, label: str, *, window_s: float, settle_s: float, where: str = "pty"
) -> ShowCpu:
    """``hilsim run RIG`` for ``settle_s + window_s + TAIL_S`` s of show, measured over the
    window: over a ``hilsim emulate`` pty (``where="pty"``) or on the rig's own in-process
    emulator, whose work is timed and taken out (``"in-process"``)."""
    ids, baud, model, rate = _bus(rig)
    with contextlib.ExitStack() as stack:
        tmp = Path(stack.enter_context(tempfile.TemporaryDirectory()))
        out, books = tmp / "run", tmp / "emulator.json"
        length = settle_s + window_s + TAIL_S
        argv = ["run", str(rig), "--duration", f"{length:g}", "--no-plots", "--out", str(out)]
        emu = None
        if where == "pty":
            path, emu = stack.enter_context(emulate(ids, baud, model))
            cmd = [sys.executable, "-m", "hilsim", *argv, "--port", path]
        else:
            cmd = [sys.executable, "-c", CHILD, str(books), *argv]
        got = sample_show(cmd, out, label, settle_s=settle_s, window_s=window_s, emulator_pid=emu)
        summary = got.summary
        emu_ns = json.loads(books.read_text())[0] if where != "pty" else None
    dt = got.wall_s
    ticks = int(summary.get("ticks") or 0)
    shown = float(summary.get("duration_s") or length)
    ticks_per_s = ticks / shown if shown > 0 else math.nan
    late = summary.get("lateness_us") or {}
    wake = got.wakeups / (dt * ticks_per_s) if ticks_per_s else math.nan
    cpu, loop = got.cpu_s / dt, got.loop_s / dt
    if emu_ns is None:
        emulator = got.emulator_s / dt
    else:  # the show's average a tick, over the window's ticks: out of the loop thread's
        emulator = emu_ns * 1e-9 / ticks * ticks_per_s if ticks else math.nan
        cpu, loop = cpu - emulator, loop - emulator
    p99 = float(late.get("p99", math.nan))
    return ShowCpu(
        label, where, rate, window_s, cpu, loop, emulator, ticks_per_s, wake, p99, got.exit_code
    )


def measure(
    *, quick: bool = False, progress: Callable[[str], None] = lambda _s: None
) -> ShowCpuResult:
    """Each of :data:`RIGS` once over its own pty (~3 s each quick, ~9 s in full)."""
    if not hasattr(os, "openpty") or not Path("/proc/self/stat").exists():
        raise RuntimeError("needs pseudo-terminals and /proc (Linux)")
    result = ShowCpuResult([], [], [])
    for label, name, where in RIGS:
        on = "a pty" if where == "pty" else "its emulator in-process"
        progress(f"{label} on {on}: CPU per second of show ({WINDOW_S[quick]:g} s)")
        try:
            result.shows.append(
                show_once(
                    REPO / "configs" / name,
                    label,
                    window_s=WINDOW_S[quick],
                    settle_s=SETTLE_S[quick],
                    where=where,
                )
            )
        except (OSError, RuntimeError, ValueError, subprocess.SubprocessError) as exc:
            result.notes.append(f"{label}: not measured: {exc}")
    result.load = [round(x, 2) for x in os.getloadavg()]
    return result


def for_bench(
    args: argparse.Namespace, report: BenchReport, progress: Callable[[str], None]
) -> ShowCpuResult | None:
    """The measurement for ``hilsim bench``'s parsed ``args``: on the built-in emulator and
    the real clock only (a rig or a port is measured as itself); None otherwise."""
    if args.config or args.port or args.clock != "real":
        return None
    try:
        return measure(quick=bool(getattr(args, "quick", False)), progress=progress)
    except (OSError, RuntimeError) as exc:
        report.notes.append(f"CPU per second of show not measured: {exc}")
        return None


__all__ = ["ShowCpu", "ShowCpuResult", "for_bench", "measure", "show_once"]
