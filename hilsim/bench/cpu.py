"""Host CPU per bus cycle over a pseudo-terminal: the SDK's busy-poll beside hilsim's port.

The SDK's stock ``PortHandler`` polls ``readPort()`` until a reply is there, burning a core for
the whole wire time; hilsim's :class:`~drivers.dynamixel.port.PortHandler` blocks in the OS
(``docs/port.md``). This module measures the difference over ``hilsim emulate`` (the emulated
bus on a pty, served by another process, as a USB adapter is):

* :func:`measure_cycles`: back-to-back Sync Write + Fast Sync Read cycles on the bare SDK's
  port and on hilsim's, alternating, best of ``repeats``: CPU and wall time;
* :func:`measure_demo`: ``hilsim run configs/demo.toml --port PTY`` in a child process: its CPU
  per tick (every thread, from ``/proc``), its wake-ups per tick and the show's lateness;
* :func:`compare_waits`: the real clock alone at 250 Hz, with the former spin window and timer
  slack (200 µs, 50 µs), the present ones, 50 µs and 0.

``hilsim bench`` on the built-in emulator and the real clock runs it last (:func:`for_bench`),
prints :meth:`CpuResult.text` and puts :meth:`CpuResult.as_dict` in its JSON under ``cpu``.
``python -m hilsim.bench.cpu`` runs it alone.
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hilsim._types import JsonDict
from hilsim.bench.report import EMULATED

if TYPE_CHECKING:
    import argparse

    import dynamixel_sdk  # (no type information: its PortHandler is Any to the checker)

    from drivers.dynamixel.port import PortHandler
    from hilsim.bench.report import BenchReport

#: The repository root (``configs/demo.toml`` lives there).
REPO = Path(__file__).resolve().parents[2]
DEMO_RIG = REPO / "configs" / "demo.toml"
IDS = (1, 2, 3, 4)
BAUD = 1_000_000


@dataclass(frozen=True)
class CycleCpu:
    """Cycles through one port: best (least) CPU and wall per cycle over the repeats (µs)."""

    port: str  # "bare SDK (busy-poll)" or "hilsim"
    cycles: int  # per repeat
    repeats: int
    cpu_us: float
    wall_us: float
    cpu_us_median: float
    wall_us_median: float
    failures: int


@dataclass(frozen=True)
class DemoCpu:
    """The demo over a pty: its process's CPU per tick over ``window_s`` of show."""

    window_s: float
    rate_hz: float
    cpu_us_per_tick: float  # best of the runs
    runs_us_per_tick: list[float]
    exit_codes: list[int]
    host_stalls: list[int]
    # of the best run: the loop's thread (the process's main thread) and all others (the
    # telemetry writer), µs per tick; voluntary context switches per tick; lateness (µs)
    loop_us_per_tick: float = math.nan
    other_us_per_tick: float = math.nan
    wakeups_per_tick: float = math.nan
    lateness_p50_us: float = math.nan
    lateness_p99_us: float = math.nan


@dataclass(frozen=True)
class WaitCpu:
    """The real clock waiting for ``ticks`` deadlines at ``rate_hz``: CPU per wait and
    lateness (µs), with a spin window and the timer slack in force."""

    spin_us: float
    slack_ns: int | None  # the thread's timer slack while it waited (None: unknown)
    ticks: int
    rate_hz: float
    cpu_us: float
    lateness_p50_us: float
    lateness_p99_us: float
    lateness_max_us: float


@dataclass
class CpuResult:
    sdk: CycleCpu
    hilsim: CycleCpu
    demo: DemoCpu | None = None
    waits: list[WaitCpu] = field(default_factory=list)
    load: list[float] = field(default_factory=list)  # 1, 5, 15-minute load when measured
    notes: list[str] = field(default_factory=list)

    @property
    def wall_change(self) -> float:
        """hilsim's wall per cycle relative to the bare SDK's (+0.02: 2 % slower)."""
        return self.hilsim.wall_us / self.sdk.wall_us - 1.0

    def text(self) -> str:
        s, h = self.sdk, self.hilsim
        lines = [
            f"CPU per cycle over a pty ({EMULATED}: hilsim emulate): bare SDK (busy-poll) "
            f"{s.cpu_us:.0f} µs, hilsim "
            f"{h.cpu_us:.0f} µs; wall per cycle {s.wall_us:.0f} vs {h.wall_us:.0f} µs "
            f"({self.wall_change:+.1%})",
            f"  ({len(IDS)} servos, {BAUD} bps, Fast Sync Read, best of {s.repeats} x "
            f"{s.cycles} cycles; load {' '.join(f'{x:.2f}' for x in self.load)})",
        ]
        if self.demo is not None:
            d = self.demo
            lines.append(
                f"The demo over a pty ({EMULATED}): {d.cpu_us_per_tick:.0f} µs of CPU per tick at "
                f"{d.rate_hz:.0f} Hz ({d.cpu_us_per_tick * d.rate_hz / 1e4:.1f} % of a core; best "
                f"of {len(d.runs_us_per_tick)}, {d.window_s:g} s of show each)"
            )
            if not math.isnan(d.loop_us_per_tick):
                lines.append(
                    f"  loop thread {d.loop_us_per_tick:.0f} µs, other threads (telemetry) "
                    f"{d.other_us_per_tick:.0f} µs; {d.wakeups_per_tick:.1f} wake-ups per tick; "
                    f"lateness p50 {d.lateness_p50_us:.1f} µs, p99 {d.lateness_p99_us:.0f} µs"
                )
        for w in self.waits:
            slack = "?" if w.slack_ns is None else f"{w.slack_ns / 1000:g} µs"
            lines.append(
                f"The clock at {w.rate_hz:.0f} Hz, spin window {w.spin_us:g} µs, timer slack "
                f"{slack}: {w.cpu_us:.0f} µs of CPU per wait, lateness p50 "
                f"{w.lateness_p50_us:.1f} µs, p99 {w.lateness_p99_us:.0f} µs, max "
                f"{w.lateness_max_us:.0f} µs ({w.ticks} ticks){'' if w.spin_us else ', bare sleep'}"
            )
        lines += [f"  {n}" for n in self.notes]
        return "\n".join(lines) + "\n"

    def as_dict(self) -> JsonDict:
        return {
            "sdk": asdict(self.sdk),
            "hilsim": asdict(self.hilsim),
            "wall_change": self.wall_change,
            "demo": None if self.demo is None else asdict(self.demo),
            "waits": [asdict(w) for w in self.waits],
            "load": list(self.load),
            "notes": list(self.notes),
            "servos": len(IDS),
            "baud": BAUD,
            "read": "fast",
        }


# ----------------------------------------------------------------------- the emulator
@contextlib.contextmanager
def emulator(ids: str = "1-4", baud: int = BAUD) -> Iterator[str]:
    """``hilsim emulate`` in a child process; yields its pty path, stops it afterwards."""
    with emulate(ids, baud) as (path, _pid):
        yield path


@contextlib.contextmanager
def emulate(ids: str, baud: int, model: str | None = None) -> Iterator[tuple[str, int]]:
    """``hilsim emulate`` in a child process; yields (its pty path, its pid)."""
    cmd = [sys.executable, "-m", "hilsim", "emulate", "--ids", ids, "--baud", str(baud)]
    proc = subprocess.Popen(
        cmd + ([] if model is None else ["--model", model]),
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        cwd=REPO,
    )
    assert proc.stdout is not None  # a pipe (stdout=PIPE)
    try:
        path = proc.stdout.readline().strip()
        if not path.startswith("/dev/"):
            raise RuntimeError(f"hilsim emulate printed {path!r}, not a pty path")
        yield path, proc.pid
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        proc.stdout.close()


# ----------------------------------------------------------------------- SDK cycles
def _bare_port(path: str) -> dynamixel_sdk.PortHandler:
    from drivers.dynamixel.port import SdkPortHandler

    port = SdkPortHandler(path)  # the SDK's own: timeout=0, busy-polls readPort
    if not (port.openPort() and port.setBaudRate(BAUD)):
        raise RuntimeError(f"the bare SDK cannot open {path}")
    return port


def _hilsim_port(path: str) -> PortHandler:
    from drivers.dynamixel.link import Link

    return Link.open(path, baud=BAUD).port  # as a show opens it


#: how long a port waits for a late reply to drain before it asks again (s)
DRAIN_S = 0.05


def first_read(bb: Any, port: Any, tries: int = 3) -> dict[int, int]:
    """The servos' positions through a port just opened, asked again (up to ``tries``) after
    draining it: on a loaded host the previous port may have given up on a reply that
    arrives now, and its bytes would spoil the first read. Raises the last BenchError."""
    from drivers.dynamixel.bench_session import BenchError

    for attempt in range(tries):
        try:
            return dict(bb.read_positions(IDS))
        except BenchError:
            if attempt == tries - 1:
                raise
            time.sleep(DRAIN_S)
            port.clearPort()
    raise AssertionError("unreachable")  # (tries >= 1)


class _Cycler:
    """One port, the SDK's group objects built once: :meth:`run` times ``cycles`` cycles."""

    def __init__(self, port: dynamixel_sdk.PortHandler) -> None:
        from drivers.dynamixel.bench_session import BenchBus
        from drivers.dynamixel.link import Link

        self.port = port
        bb = BenchBus(port, Link(port).ph, port.port_name, BAUD)
        goals = first_read(bb, port)  # written back: the servos do not move (torque off)
        self.tx, self.rx = bb.goal_writer(goals).txPacket, bb.position_reader(IDS).fastSyncRead

    def run(self, cycles: int) -> tuple[float, float, int]:
        """(CPU s, wall s, failures) of ``cycles`` back-to-back cycles, GC paused."""
        tx, rx = self.tx, self.rx
        for _ in range(20):
            tx()
            rx()
        gc_was = gc.isenabled()
        gc.disable()
        try:
            failures = 0
            c0, t0 = time.process_time(), time.perf_counter()
            for _ in range(cycles):
                if tx() or rx():
                    failures += 1
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        finally:
            if gc_was:
                gc.enable()
        return cpu, wall, failures

    def close(self) -> None:
        self.port.closePort()


def measure_cycles(path: str, *, cycles: int = 500, repeats: int = 7) -> tuple[CycleCpu, CycleCpu]:
    """The bare SDK's and hilsim's CPU and wall per cycle over the pty at ``path``,
    alternating repeat by repeat (so load drifts reach both), best of ``repeats``."""
    ports: dict[str, Callable[[str], dynamixel_sdk.PortHandler]] = {
        "bare SDK (busy-poll)": _bare_port,
        "hilsim": _hilsim_port,
    }
    samples: dict[str, list[tuple[float, float, int]]] = {k: [] for k in ports}
    for _ in range(repeats):
        for name, opener in ports.items():
            cycler = _Cycler(opener(path))
            try:
                samples[name].append(cycler.run(cycles))
            finally:
                cycler.close()
    out = []
    for name, runs in samples.items():
        cpu = sorted(r[0] / cycles * 1e6 for r in runs)
        wall = sorted(r[1] / cycles * 1e6 for r in runs)
        cpu_m, wall_m = cpu[len(cpu) // 2], wall[len(wall) // 2]
        fails = sum(r[2] for r in runs)
        out.append(CycleCpu(name, cycles, repeats, cpu[0], wall[0], cpu_m, wall_m, fails))
    return out[0], out[1]


# ----------------------------------------------------------------------- the demo
def _cpu_s(pid: int, tid: int | None = None) -> float:
    """Time on a CPU of process ``pid`` (every thread) or of its thread ``tid`` (s): the
    scheduler's own count (``schedstat``, ns), not utime/stime, which a kernel may sample
    at its tick, often 250 Hz: the demo's own rate."""
    if not Path(f"/proc/{pid}/task/{pid}/schedstat").exists():
        raise RuntimeError("this kernel has no /proc/PID/schedstat: CPU time is not measured")
    ns = 0
    for task in [str(tid)] if tid is not None else os.listdir(f"/proc/{pid}/task"):
        with contextlib.suppress(OSError, ValueError, IndexError):  # a thread that ended
            ns += int(Path(f"/proc/{pid}/task/{task}/schedstat").read_text().split()[0])
    return ns * 1e-9


def _wakeups(pid: int) -> int:
    """Voluntary context switches of process ``pid``'s main thread: sleeps and waits."""
    status = Path(f"/proc/{pid}/status").read_text()
    return int(status.split("\nvoluntary_ctxt_switches:")[1].split()[0])


@dataclass(frozen=True)
class ShowSample:
    """A ``hilsim run`` process sampled over a window of its show: seconds of wall time, of
    the process's CPU, of its main (loop) thread's, voluntary wake-ups, an emulator
    process's CPU (0 without one), its exit code and its summary."""

    wall_s: float
    cpu_s: float
    loop_s: float
    wakeups: int
    emulator_s: float
    exit_code: int
    summary: JsonDict


def sample_show(
    cmd: list[str], out: Path, label: str, *, settle_s: float, window_s: float,
    emulator_pid: int | None = None,
) -> ShowSample:  # fmt: skip
    """Start ``cmd`` (a ``hilsim run ... --out OUT``), wait for the line that says the show
    starts, let ``settle_s`` pass, then sample its CPU over ``window_s``; wait for its end and
    read ``OUT/summary.json``. Raises RuntimeError (with its last lines) if it wrote none."""
    proc = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=REPO
    )
    assert proc.stderr is not None  # a pipe (stderr=PIPE)
    err = []
    emu = emulator_pid
    try:
        for line in proc.stderr:  # "hilsim run: NAME: ... -> DIR": the show starts
            err.append(line)
            if " -> " in line:
                break
        time.sleep(settle_s)
        pid = proc.pid
        c0, m0, w0, t0 = _cpu_s(pid), _cpu_s(pid, pid), _wakeups(pid), time.perf_counter()
        e0 = _cpu_s(emu) if emu is not None else 0.0
        time.sleep(window_s)
        c1, m1, w1, t1 = _cpu_s(pid), _cpu_s(pid, pid), _wakeups(pid), time.perf_counter()
        e1 = _cpu_s(emu) if emu is not None else 0.0
        err.append(proc.stderr.read())
        code = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stderr.close()
    summary_path = out / "summary.json"
    if not summary_path.exists():
        raise RuntimeError(f"{label} wrote no summary:\n" + "".join(err)[-2000:])
    summary = json.loads(summary_path.read_text())
    return ShowSample(t1 - t0, c1 - c0, m1 - m0, w1 - w0, e1 - e0, code, summary)


def demo_once(path: str, *, window_s: float = 6.0, settle_s: float = 1.5) -> DemoCpu:
    """One ``hilsim run configs/demo.toml --port PATH`` of ``settle_s + window_s + 1`` s
    of show, measured over the window (a :class:`DemoCpu` of one run)."""
    with tempfile.TemporaryDirectory(prefix="hilsim-cpu-") as tmp:
        out = Path(tmp) / "run"
        show = ["--duration", f"{settle_s + window_s + 1.0:g}", "--no-plots", "--out", str(out)]
        cmd = [sys.executable, "-m", "hilsim", "run", str(DEMO_RIG), "--port", path, *show]
        got = sample_show(cmd, out, "the demo", settle_s=settle_s, window_s=window_s)
    summary = got.summary
    rate = float(summary.get("rate_hz") or 0.0)
    stalls = int(((summary.get("loop") or {}).get("host_stalls") or {}).get("count", 0))
    late = summary.get("lateness_us") or {}
    ticks = got.wall_s * rate or math.nan
    cpu, loop = got.cpu_s / ticks * 1e6, got.loop_s / ticks * 1e6
    p50, p99 = (float(late.get(q, math.nan)) for q in ("p50", "p99"))
    wake = got.wakeups / ticks
    code = got.exit_code
    return DemoCpu(window_s, rate, cpu, [cpu], [code], [stalls], loop, cpu - loop, wake, p50, p99)


def measure_demo(path: str, *, runs: int = 2, window_s: float = 6.0) -> DemoCpu:
    """The demo's CPU per tick over the pty at ``path``: the best of ``runs`` (the loop's
    share, wake-ups and lateness are that run's)."""
    results = [demo_once(path, window_s=window_s) for _ in range(runs)]
    return dataclasses.replace(
        min(results, key=lambda r: r.cpu_us_per_tick),
        runs_us_per_tick=[r.cpu_us_per_tick for r in results],
        exit_codes=[r.exit_codes[0] for r in results],
        host_stalls=[r.host_stalls[0] for r in results],
    )


# ----------------------------------------------------------------------- the clock
#: the spin window and timer slack of the first release (µs, ns): the comparison's "before"
FORMER_SPIN_US = 200.0
FORMER_SLACK_NS = 50_000
#: a shorter window a rig may choose (``loop.spin_us = 50``): the comparison's third line
FRUGAL_SPIN_US = 50.0


def measure_waits(
    spin_us: float, slack_ns: int | None, *, rate_hz: float = 250.0, seconds: float = 3.0
) -> WaitCpu:
    """The real clock alone: ``wait_until`` for each deadline of ``seconds`` at ``rate_hz``
    with a ``spin_us`` spin window and this thread's timer slack at ``slack_ns`` (None: as
    it is). CPU per wait (``time.thread_time``) and lateness."""
    from drivers.clock import MonotonicClock, precise_timers, timer_slack_ns

    clock = MonotonicClock(spin_us * 1e-6)
    period, n = 1.0 / rate_hz, max(1, round(seconds * rate_hz))
    late = [0.0] * n
    with contextlib.nullcontext() if slack_ns is None else precise_timers(slack_ns):
        in_force = timer_slack_ns()
        t0 = clock.now() + period
        c0 = time.thread_time()
        for k in range(n):
            t = t0 + k * period
            late[k] = clock.wait_until(t) - t
        cpu = time.thread_time() - c0
    late.sort()
    q = [late[n // 2], late[min(n - 1, int(n * 0.99))], late[-1]]
    return WaitCpu(spin_us, in_force, n, rate_hz, cpu / n * 1e6, *(x * 1e6 for x in q))


def compare_waits(*, seconds: float = 3.0, repeats: int = 2) -> list[WaitCpu]:
    """The former default (200 µs, 50 µs timer slack), the present one
    (:data:`~drivers.clock.DEFAULT_SPIN_S`, precise timers), 50 µs and none (precise timers),
    alternating, the run with the least CPU of each."""
    from drivers.clock import DEFAULT_SPIN_S, PRECISE_SLACK_NS

    setups = [(FORMER_SPIN_US, FORMER_SLACK_NS), (DEFAULT_SPIN_S * 1e6, PRECISE_SLACK_NS)]
    setups += [(FRUGAL_SPIN_US, PRECISE_SLACK_NS), (0.0, PRECISE_SLACK_NS)]  # less; a bare sleep
    runs: list[list[WaitCpu]] = [[] for _ in setups]
    for _ in range(repeats):
        for i, (spin, slack) in enumerate(setups):
            runs[i].append(measure_waits(spin, slack, seconds=seconds))
    return [min(r, key=lambda w: w.cpu_us) for r in runs]


def measure(
    *,
    quick: bool = False,
    demo: bool = True,
    waits: bool = True,
    progress: Callable[[str], None] = lambda _s: None,
) -> CpuResult:
    """Everything above over one ``hilsim emulate`` pty (~10 s quick, ~40 s in full);
    ``waits=False`` leaves out the clock's comparison of spin windows (``hilsim bench``
    measures its own spin window at the loop's rate)."""
    if not hasattr(os, "openpty") or not Path("/proc/self/stat").exists():
        raise RuntimeError("needs pseudo-terminals and /proc (Linux)")
    with emulator() as path:
        progress(f"CPU per cycle over {path}: bare SDK vs hilsim")
        sdk_c, ours = measure_cycles(path, cycles=300 if quick else 500, repeats=3 if quick else 7)
        result = CpuResult(sdk_c, ours)
        if demo:
            progress(f"the demo over {path}: CPU per tick")
            result.demo = measure_demo(path, runs=1 if quick else 2, window_s=3.0 if quick else 6.0)
    if waits:
        progress("the real clock: CPU per wait, former and present spin window")
        result.waits = compare_waits(seconds=1.5 if quick else 3.0, repeats=1 if quick else 2)
    result.load = [round(x, 2) for x in os.getloadavg()]
    return result


def for_bench(
    args: argparse.Namespace, report: BenchReport, progress: Callable[[str], None]
) -> CpuResult | None:
    """The measurement for ``hilsim bench``'s parsed ``args``, or None where it does not
    belong (a rig, a port, the virtual clock), is left to the full run (``--quick``) or
    cannot run (then a note in ``report``)."""
    if args.config or args.port or args.clock != "real":
        return None
    if getattr(args, "quick", False):  # seconds of subprocesses: the full run's
        report.notes.append("CPU per cycle over a pty: measured by the full run, not --quick")
        return None
    try:
        return measure(waits=False, progress=progress)
    except (OSError, RuntimeError, subprocess.SubprocessError) as exc:
        report.notes.append(f"CPU per cycle over a pty not measured: {exc}")
        return None


def add_to_bench(result: CpuResult, json_path: Path) -> None:
    """Print ``result`` after the bench's summary and add it to its JSON as ``cpu``."""
    print(result.text(), end="")
    data = json.loads(Path(json_path).read_text())
    data["cpu"] = result.as_dict()
    Path(json_path).write_text(json.dumps(data, indent=2, ensure_ascii=False) + "\n")


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-demo", action="store_true", help="the SDK cycles only")
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args(argv)
    result = measure(
        quick=args.quick, demo=not args.no_demo, progress=lambda s: print(s, file=sys.stderr)
    )
    print(result.text(), end="")
    if args.json:
        Path(args.json).write_text(
            json.dumps(result.as_dict(), indent=2, ensure_ascii=False) + "\n"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


__all__ = [
    "CpuResult",
    "CycleCpu",
    "DemoCpu",
    "WaitCpu",
    "add_to_bench",
    "compare_waits",
    "emulator",
    "for_bench",
    "measure",
    "measure_cycles",
    "measure_demo",
    "measure_waits",
]
