"""``hilsim bench [CONFIG | --port P] [--quick] [--json FILE] [--out DIR]``.

"Why does my loop only reach 60 Hz?" in one command: the tick scheduler's lateness sleeping
only, beside cyclictest when installed (like with like), then with its spin window and
that window's CPU; the bus's achieved write+read cycle rate beside its wire-time model,
command/feedback latencies, a diagnosis of the bus with the fix for each problem and the
rate it would give, and the host's cost of one whole tick beside a bare dynamixel-sdk Sync
Write + Fast Sync Read cycle (4, 8, 16 servos; :mod:`hilsim.bench.tick`), and on the built-in
emulator the demo's and scale16's CPU per second of show (:mod:`hilsim.bench.showcpu`). One
report, in that order, then notes, files and the verdict last; the run says its expected
length first.

Without CONFIG or --port the bus side runs on the built-in emulator on the real clock (1, 4,
8 and 16 servos at 1 and 4 Mbps; 4 and 16 with ``--quick``, which also leaves the CPU over a
pty to the full run), and says so: those figures are the host's overhead only. With a rig
file it measures that rig's bus and loop rate; ``--port`` measures any port
(``/dev/ttyUSB0``, a pty, ``dxlsim://?...``).

Exit codes (:mod:`hilsim.exit_codes`): 0 measured; 2 a bad value, a rig that cannot be
loaded, or a bus that cannot be used (nothing was measured).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from drivers.clock import DEFAULT_SPIN_S
from hilsim.cli._args import add_baud, add_ids, add_port, parse_baud, parse_ids, usage_error
from hilsim.exit_codes import ExitCode

if TYPE_CHECKING:  # the bench is imported when it runs
    from hilsim.bench.report import BenchReport
    from hilsim.bench.runner import BenchPlan

HELP = "measure loop timing, bus rate and latency beside the physical limit; diagnose the bus"
#: the scheduler's spin window without a rig (µs)
_SPIN_US = round(DEFAULT_SPIN_S * 1e6, 6)
#: how long the tick cost and the CPU over a pty take (s; quick, full), measured on a 2-core
#: VM: the expected length said at the start
TICK_COST_S = {True: 3.0, False: 12.0}
PTY_CPU_S = {True: 0.0, False: 22.0}
#: the demo's and scale16's CPU per second of show over a pty (s; quick, full)
SHOW_CPU_S = {True: 6.5, False: 18.0}
#: what ``--quick`` takes on this project's 2-core VM (s), as --help and the README say
QUICK_S = 20


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", nargs="?", help="rig file (TOML); its bus, servos and rate")
    add_port(parser, help="port to measure instead (or overriding the rig's)")
    add_baud(parser, help="baud rate with --port, e.g. 1M (default: the URL's, else 1000000)")
    add_ids(parser, help="servo IDs with --port, e.g. 1-4 (default: discover)")
    parser.add_argument(
        "--quick", action="store_true", help=f"short runs (~{QUICK_S} s in all on a 2-core VM)"
    )
    parser.add_argument(
        "--json", metavar="FILE", help="write the JSON here (default OUT/bench.json)"
    )
    parser.add_argument(
        "--out", metavar="DIR", help="directory for JSON and PNGs (default runs/bench-TIME)"
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the PNGs")
    parser.add_argument(
        "--sched",
        choices=("auto", "fifo", "other"),
        default="auto",
        help="scheduling class of the timed runs: auto = SCHED_FIFO when permitted (default)",
    )
    parser.add_argument("--priority", type=int, default=80, help="SCHED_FIFO priority (80)")
    parser.add_argument(
        "--spin-us",
        type=float,
        help=f"scheduler spin window (µs; default: the rig's loop.spin_us, else {_SPIN_US:g})",
    )
    parser.add_argument("--no-cyclictest", action="store_true", help="do not run cyclictest")
    parser.add_argument("--rate", type=float, help="latency loop rate, Hz (default: rig's or 500)")
    parser.add_argument(
        "--move",
        action="store_true",
        help="on hardware, step the servos' goal by --step pulses to time command to motion",
    )
    parser.add_argument("--step", type=int, default=40, help="goal step, pulses (40)")
    parser.add_argument(
        "--clock",
        choices=("real", "virtual"),
        default="real",
        help="clock of emulated buses: virtual reproduces the wire model exactly "
        "(loop timing is skipped)",
    )
    parser.add_argument(
        "--servos", help="emulator sweep: servo counts (default 1,4,8,16; 4,16 with --quick)"
    )
    parser.add_argument("--bauds", default="1000000,4000000", help="emulator sweep: baud rates")


def build_plan(args: argparse.Namespace, argv_text: str = "hilsim bench") -> BenchPlan:
    """The :class:`~hilsim.bench.runner.BenchPlan` for parsed arguments (may load the rig)."""
    from hilsim.bench.runner import BenchPlan, BusTarget

    quick = bool(args.quick)
    pty = not (args.config or args.port or quick) and args.clock == "real"  # CPU over a pty
    shows = not (args.config or args.port) and args.clock == "real"  # CPU a second of show
    common = dict(
        host_s=TICK_COST_S[quick]
        + (PTY_CPU_S[quick] if pty else 0.0)
        + (SHOW_CPU_S[quick] if shows else 0.0),
        quick=quick,
        clock=args.clock,
        # (--quick on the emulator: 1 s, making room for the shows' CPU in its ~20 s)
        loop_duration_s=(1.0 if shows else 1.5) if quick else 10.0,
        spin_us=_SPIN_US if args.spin_us is None else args.spin_us,
        sched=args.sched,
        priority=args.priority,
        use_cyclictest=not args.no_cyclictest,
        bus_duration_s=0.3 if quick else 1.2,
        latency_duration_s=0.3 if quick else 0.6,
        move=bool(args.move),
        step_pulses=args.step,
        command=argv_text,
    )
    if args.config:
        from hilsim.rig import load_rig

        rig = load_rig(args.config, port=args.port)
        rate = float(rig.loop.rate_hz)
        read = rig.bus.read.value
        if args.spin_us is None:  # the rig's spin window, as its shows run
            common["spin_us"] = float(rig.loop.spin_us)
        return BenchPlan(
            **common,
            loop_rates_hz=(1000.0,) if rate == 1000.0 else (1000.0, rate),
            target=BusTarget(rig.bus.port, int(rig.bus.baud), tuple(rig.servo_ids), read),
            sweep=(),
            latency_rate_hz=args.rate or rate,
            subject=f"rig {args.config} on {rig.bus.port} at {rig.bus.baud} bps",
            rig_rate_hz=rate,
        )
    if args.port:
        baud = parse_baud(args.baud) if args.baud else _url_baud(args.port) or 1_000_000
        parsed = parse_ids(args.ids)
        ids = tuple(parsed) if parsed else None
        return BenchPlan(
            **common,
            target=BusTarget(args.port, baud, ids),
            sweep=(),
            latency_rate_hz=args.rate or 500.0,
            subject=f"{args.port} at {baud} bps",
        )
    servos = args.servos or ("4,16" if quick else "1,4,8,16")
    counts = [int(x) for x in servos.split(",") if x.strip()]
    bauds = [int(x) for x in args.bauds.split(",") if x.strip()]
    return BenchPlan(
        **common,
        sweep=tuple((n, b) for b in bauds for n in counts),
        latency_rate_hz=args.rate or 500.0,
        subject=f"the built-in emulator (dxlsim, {args.clock} clock)",
    )


def run(args: argparse.Namespace) -> int:
    from drivers.dynamixel.bench_session import BenchError
    from hilsim.bench.runner import run_bench
    from hilsim.rig import RigError

    t_start = time.perf_counter()
    if args.config:  # Feetech or Dynamixel Protocol 1.0 servos: their bus beside its model
        code = _p1_bench(args)
        if code is not None:
            return code
    command = "hilsim bench " + " ".join(sys.argv[2:]) if sys.argv[1:2] == ["bench"] else None
    try:
        plan = build_plan(args, command or "hilsim bench")
    except (RigError, ValueError) as exc:
        return usage_error("bench", exc)
    out = Path(args.out or f"runs/bench-{time.strftime('%Y%m%d-%H%M%S')}")

    def progress(msg: str) -> None:
        print(f"[{time.perf_counter() - t_start:5.1f} s] {msg}", file=sys.stderr, flush=True)

    try:
        report = run_bench(plan, progress)
    except BenchError as exc:  # the bus cannot be used: nothing was measured
        return usage_error("bench", exc)
    from hilsim.bench import cpu as cpu_bench  # CPU per cycle over a pty: SDK vs hilsim
    from hilsim.bench import showcpu  # CPU per second of show: the demo, scale16
    from hilsim.bench import tick as tick_bench  # host CPU of a tick: bare SDK cycle vs hilsim
    from hilsim.bench.report import _finite

    quick = bool(args.quick)  # --quick: the ticks' totals, not where their time goes
    tick_cost = tick_bench.measure_tick_cost(quick=quick, stages=not quick, progress=progress)
    report.sections.append(tick_cost.text())
    report.extra["tick_cost"] = _finite(tick_cost.as_dict())
    cpu = cpu_bench.for_bench(args, report, progress)
    if cpu is not None:
        report.sections.append(cpu.text())
        report.extra["cpu"] = _finite(cpu.as_dict())
    shows = showcpu.for_bench(args, report, progress)
    if shows is not None:
        report.sections.append(shows.text())
        report.extra["show_cpu"] = _finite(shows.as_dict())
    out.mkdir(parents=True, exist_ok=True)
    if not args.no_plots:
        progress("plotting")
        report.files += _plots(report, out)
    json_path = Path(args.json) if args.json else out / "bench.json"
    report.files.insert(0, str(json_path))
    report.notes.append(
        f"whole command: {time.perf_counter() - t_start:.1f} s wall time (expected about "
        f"{plan.expected_s():.0f} s); load average {_load()}"
    )
    report.write_json(json_path)
    print(report.text(), end="")
    return int(ExitCode.OK)


def _load() -> str:
    import os

    return " ".join(f"{x:.2f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else "n/a"


def _plots(report: BenchReport, out: Path) -> list[str]:
    from hilsim.bench import plots

    files = []
    if report.loops:
        files.append(plots.plot_lateness(report.loops[0], out / "lateness.png"))
    if report.bus:
        files.append(plots.plot_bus_rate(report.bus, out / "bus_rate.png"))
    if report.latency is not None:
        step = plots.plot_step(report.latency, out / "step.png", emulated=report.emulated)
        if step is not None:
            files.append(step)
    return [str(f) for f in files]


def _url_baud(port: str) -> int | None:
    """The ``baud=`` of a ``dxlsim://?...`` URL, if it has one."""
    if not port.startswith("dxlsim:"):
        return None
    from drivers.dxlsim.url import DxlsimUrl  # the emulator only when the port names it

    return DxlsimUrl.parse(port).baud


def _p1_bench(args: argparse.Namespace) -> int | None:
    """``hilsim bench RIG`` for a rig of the Protocol 1.0-framed families: the tick's bus
    calls timed beside the wire model (:mod:`hilsim.bench.p1rate`); None for any other rig."""
    import json

    from hilsim.rig import RigError, load_rig
    from hilsim.show.session import ShowRefusedError, p1_models, port_for

    try:
        rig = load_rig(args.config, port=args.port)
    except (RigError, ValueError) as exc:
        return usage_error("bench", exc)
    if p1_models(rig) is None:
        return None
    from hilsim.bench.p1rate import measure

    try:
        port = port_for(rig, virtual=args.clock == "virtual")
        result = measure(rig, port, cycles=500 if args.quick else 2000)
    except (ShowRefusedError, ValueError) as exc:
        return usage_error("bench", exc)
    print(result.text(), end="")
    out = Path(args.out or f"runs/bench-{time.strftime('%Y%m%d-%H%M%S')}")
    out.mkdir(parents=True, exist_ok=True)
    json_path = Path(args.json) if args.json else out / "bench.json"
    json_path.write_text(json.dumps({"p1_bus": result.as_dict()}, indent=2) + "\n")
    print(f"  json: {json_path}")
    return int(ExitCode.OK)
