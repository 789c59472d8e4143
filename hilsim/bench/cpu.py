"""Host CPU per bus cycle over a pseudo-terminal: the SDK's busy-poll beside hilsim's port.

A real port (a device path, a pty) is waited on by the process: the SDK's stock
``PortHandler`` opens it with ``timeout=0`` and ``rxPacket`` polls ``readPort()`` until
the reply is there, so it burns a core for the whole wire time; hilsim's
:class:`~drivers.dynamixel.port.PortHandler` blocks in the OS (``select``) until the bytes
the SDK asked for are readable or the packet deadline passes. This module measures the
difference where it shows, over ``hilsim emulate`` (the emulated bus served on a pty by
another process, as a USB adapter is):

* :func:`measure_cycles` - back-to-back cycles of one Sync Write of Goal Position and one
  Fast Sync Read of Present Position through the SDK's group objects, once on the bare
  SDK's port and once on hilsim's (opened by :meth:`~drivers.dynamixel.link.Link.open`, as
  a show opens it), alternating, best of ``repeats``: process CPU (``time.process_time``)
  and wall time per cycle;
* :func:`measure_demo` - ``hilsim run configs/demo.toml --port PTY`` in a child process:
  its CPU (``/proc/PID/stat``: every thread, the telemetry writer included) per tick over
  a window of the show that starts after the soft start.

``hilsim bench`` on the built-in emulator and the real clock (no rig, no ``--port``: the
figures are this host's and hilsim's, not the bus's) runs it after its other measurements
(:func:`for_bench`), prints :meth:`CpuResult.text` and puts :meth:`CpuResult.as_dict` in its
JSON under ``cpu``. ``python -m hilsim.bench.cpu`` runs it alone. Give the load
(``os.getloadavg``, in the result) beside the figures.
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

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


@dataclass
class CpuResult:
    sdk: CycleCpu
    hilsim: CycleCpu
    demo: DemoCpu | None = None
    load: list[float] = field(default_factory=list)  # 1, 5, 15-minute load when measured
    notes: list[str] = field(default_factory=list)

    @property
    def wall_change(self) -> float:
        """hilsim's wall per cycle relative to the bare SDK's (+0.02: 2 % slower)."""
        return self.hilsim.wall_us / self.sdk.wall_us - 1.0

    def text(self) -> str:
        s, h = self.sdk, self.hilsim
        lines = [
            f"CPU per cycle over a pty: bare SDK (busy-poll) {s.cpu_us:.0f} µs, hilsim "
            f"{h.cpu_us:.0f} µs; wall per cycle {s.wall_us:.0f} vs {h.wall_us:.0f} µs "
            f"({self.wall_change:+.1%})",
            f"  ({len(IDS)} servos, {BAUD} bps, Fast Sync Read, best of {s.repeats} x "
            f"{s.cycles} cycles; load {' '.join(f'{x:.2f}' for x in self.load)})",
        ]
        if self.demo is not None:
            d = self.demo
            lines.append(
                f"The demo over a pty: {d.cpu_us_per_tick:.0f} µs of CPU per tick at "
                f"{d.rate_hz:.0f} Hz ({d.cpu_us_per_tick * d.rate_hz / 1e4:.1f} % of a core; best "
                f"of {len(d.runs_us_per_tick)}, {d.window_s:g} s of show each)"
            )
        lines += [f"  {n}" for n in self.notes]
        return "\n".join(lines) + "\n"

    def as_dict(self) -> dict:
        return {
            "sdk": asdict(self.sdk),
            "hilsim": asdict(self.hilsim),
            "wall_change": self.wall_change,
            "demo": None if self.demo is None else asdict(self.demo),
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
    proc = subprocess.Popen(
        [sys.executable, "-m", "hilsim", "emulate", "--ids", ids, "--baud", str(baud)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        cwd=REPO,
    )
    try:
        path = proc.stdout.readline().strip()
        if not path.startswith("/dev/"):
            raise RuntimeError(f"hilsim emulate printed {path!r}, not a pty path")
        yield path
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
def _bare_port(path: str):
    from drivers.dynamixel.port import SdkPortHandler

    port = SdkPortHandler(path)  # the SDK's own: timeout=0, busy-polls readPort
    if not (port.openPort() and port.setBaudRate(BAUD)):
        raise RuntimeError(f"the bare SDK cannot open {path}")
    return port


def _hilsim_port(path: str):
    from drivers.dynamixel.link import Link

    return Link.open(path, baud=BAUD).port  # as a show opens it


class _Cycler:
    """One port, the SDK's group objects built once: :meth:`run` times ``cycles`` cycles."""

    def __init__(self, port) -> None:
        from drivers.dynamixel.bench_session import BenchBus
        from drivers.dynamixel.link import Link

        self.port = port
        bb = BenchBus(port, Link(port).ph, port.port_name, BAUD)
        goals = bb.read_positions(IDS)  # written back: the servos do not move (torque off)
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
    ports: dict[str, Callable] = {"bare SDK (busy-poll)": _bare_port, "hilsim": _hilsim_port}
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
        out.append(
            CycleCpu(
                port=name,
                cycles=cycles,
                repeats=repeats,
                cpu_us=cpu[0],
                wall_us=wall[0],
                cpu_us_median=cpu[len(cpu) // 2],
                wall_us_median=wall[len(wall) // 2],
                failures=sum(r[2] for r in runs),
            )
        )
    return out[0], out[1]


# ----------------------------------------------------------------------- the demo
def _cpu_s(pid: int) -> float:
    """utime + stime of process ``pid``, every thread (``/proc/PID/stat``), seconds."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def demo_once(
    path: str, *, window_s: float = 6.0, settle_s: float = 1.5
) -> tuple[float, int, int, float]:
    """One ``hilsim run configs/demo.toml --port PATH`` of ``settle_s + window_s + 1`` s
    of show. Returns (CPU µs per tick over the window, exit code, host stalls, rate Hz)."""
    with tempfile.TemporaryDirectory(prefix="hilsim-cpu-") as tmp:
        out = Path(tmp) / "run"
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "hilsim",
                "run",
                str(DEMO_RIG),
                "--port",
                path,
                "--duration",
                f"{settle_s + window_s + 1.0:g}",
                "--no-plots",
                "--out",
                str(out),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            cwd=REPO,
        )
        err = []
        try:
            for line in proc.stderr:  # "hilsim run: demo: ... -> DIR": the show starts
                err.append(line)
                if " -> " in line:
                    break
            time.sleep(settle_s)
            c0, t0 = _cpu_s(proc.pid), time.perf_counter()
            time.sleep(window_s)
            c1, t1 = _cpu_s(proc.pid), time.perf_counter()
            err.append(proc.stderr.read())
            code = proc.wait(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            proc.stderr.close()
        summary_path = out / "summary.json"
        if not summary_path.exists():
            raise RuntimeError("the demo wrote no summary:\n" + "".join(err)[-2000:])
        summary = json.loads(summary_path.read_text())
    rate = float(summary.get("rate_hz") or 0.0)
    stalls = int(((summary.get("loop") or {}).get("host_stalls") or {}).get("count", 0))
    ticks = (t1 - t0) * rate
    return (c1 - c0) / ticks * 1e6 if ticks else float("nan"), code, stalls, rate


def measure_demo(path: str, *, runs: int = 2, window_s: float = 6.0) -> DemoCpu:
    """The demo's CPU per tick over the pty at ``path``, best of ``runs``."""
    results = [demo_once(path, window_s=window_s) for _ in range(runs)]
    per_tick = [r[0] for r in results]
    return DemoCpu(
        window_s=window_s,
        rate_hz=results[0][3],
        cpu_us_per_tick=min(per_tick),
        runs_us_per_tick=per_tick,
        exit_codes=[r[1] for r in results],
        host_stalls=[r[2] for r in results],
    )


def measure(*, quick: bool = False, demo: bool = True, progress=lambda _s: None) -> CpuResult:
    """Everything above over one ``hilsim emulate`` pty (~10 s quick, ~40 s in full)."""
    if not hasattr(os, "openpty") or not Path("/proc/self/stat").exists():
        raise RuntimeError("needs pseudo-terminals and /proc (Linux)")
    with emulator() as path:
        progress(f"CPU per cycle over {path}: bare SDK vs hilsim")
        sdk_c, ours = measure_cycles(path, cycles=300 if quick else 500, repeats=3 if quick else 7)
        result = CpuResult(sdk_c, ours)
        if demo:
            progress(f"the demo over {path}: CPU per tick")
            result.demo = measure_demo(path, runs=1 if quick else 2, window_s=3.0 if quick else 6.0)
    result.load = [round(x, 2) for x in os.getloadavg()]
    return result


def for_bench(args, report, progress) -> CpuResult | None:
    """The measurement for ``hilsim bench``'s parsed ``args``, or None where it does not
    belong (a rig, a port, the virtual clock) or cannot run (then a note in ``report``)."""
    if args.config or args.port or args.clock != "real":
        return None
    try:
        return measure(quick=bool(args.quick), progress=progress)
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
    "add_to_bench",
    "emulator",
    "for_bench",
    "measure",
    "measure_cycles",
    "measure_demo",
]
