"""``hilsim run CONFIG``: drive a rig's joints as springs following its animation.

Exit codes: 0 the show ended (exit policy applied), 2 the rig file or the servos on the bus
do not fit (nothing moved), 3 a fault stopped the show (servo and cause printed),
130/143 stopped by SIGINT/SIGTERM (exit policy applied), 1 an unexpected error.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import time
import urllib.parse
from pathlib import Path

HELP = "run a rig: springs follow the animation, streamed to the servos (or the emulator)"

EXIT_USAGE = 2


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="rig file (TOML), e.g. configs/demo.toml")
    p.add_argument("--port", help="override bus.port: /dev/ttyUSB0, a pty, or dxlsim://...")
    p.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="stop after S seconds of show (default: the animation's length)",
    )
    p.add_argument(
        "--virtual-time",
        action="store_true",
        help="run on the emulator's virtual clock: same numbers, no waiting",
    )
    p.add_argument("--out", metavar="DIR", help="run directory (default: <out_dir>/<name>-<time>)")
    p.add_argument("--no-plots", action="store_true", help="do not draw plots after the run")


def clocked_port(port: str, virtual: bool) -> str:
    """The port string with the emulator's clock chosen; hardware refuses virtual time."""
    if not port.lower().startswith("dxlsim://"):
        if virtual:
            raise ValueError(f"--virtual-time needs the emulator (a dxlsim:// port), not {port!r}")
        return port
    parts = urllib.parse.urlsplit(port)
    query = [
        (k, v)
        for k, v in urllib.parse.parse_qsl(parts.query, keep_blank_values=True)
        if k != "clock"
    ]
    if parts.netloc or parts.path.strip("/"):
        return port  # a named bus brings its own clock
    query.append(("clock", "virtual" if virtual else "real"))
    # not urlunsplit: with an empty host it writes "dxlsim:?..." and drops the "//"
    return f"{parts.scheme}://?{urllib.parse.urlencode(query, safe='-,;:=|')}"


def _status_printer(rate_hz: float):
    if not sys.stderr.isatty():
        return None
    start = time.perf_counter()

    def show(st: dict) -> None:
        wall = time.perf_counter() - start
        rate = st["tick"] / wall if wall > 0 else 0.0
        sys.stderr.write(
            f"\r  t={st['t']:7.2f} s  rate {rate:7.1f} Hz (target {rate_hz:g})  "
            f"late p99 {st.get('lateness_p99_us', float('nan')):6.0f} us  "
            f"comm errors {st['comm_errors']}  overruns {st['overruns']}   "
        )
        sys.stderr.flush()

    return show


def run(args: argparse.Namespace) -> int:

    from drivers.dynamixel.bus import DynamixelBus
    from drivers.dynamixel.errors import DynamixelError, StartupMismatch
    from hilsim.loop import HilLoop, StopFlag
    from hilsim.rig import RigError, load_rig
    from hilsim.telemetry import TelemetryWriter
    from hilsim.wiring import build_targets, bus_capacity_problem, expectations

    try:
        rig = load_rig(args.config, port=args.port)
        port = clocked_port(rig.bus.port, args.virtual_time)
        targets = build_targets(rig)
    except (RigError, ValueError) as exc:
        print(f"hilsim run: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if args.duration is not None and not args.duration > 0:
        print("hilsim run: --duration must be > 0", file=sys.stderr)
        return EXIT_USAGE
    if args.duration is None and targets.duration is None:
        print(
            "hilsim run: the animation never ends (generators only); running until "
            "Ctrl-C. Give --duration to stop by itself.",
            file=sys.stderr,
        )

    run_dir = (
        Path(args.out)
        if args.out
        else (Path(rig.telemetry.out_dir) / f"{rig.name}-{time.strftime('%Y%m%d-%H%M%S')}")
    )
    try:
        bus = DynamixelBus.open(
            port,
            baud=rig.bus.baud,
            ids=rig.servo_ids,
            read_mode=rig.bus.read.value,
            latency_timer_ms=rig.bus.latency_timer_ms,
        )
    except DynamixelError as exc:
        print(f"hilsim run: cannot open {rig.bus.port}: {exc}", file=sys.stderr)
        return 3
    stop = StopFlag()
    previous = {
        s: signal.signal(s, lambda signum, _f: stop.request(signum))
        for s in (signal.SIGINT, signal.SIGTERM)
    }
    try:
        latency_ms = bus.link.latency_timer_ms
        try:
            # A previous run's "hold" exit leaves the Bus Watchdog to trip once the host is
            # gone; we are the host again, so clear it (writing 0) before checking the rest.
            with contextlib.suppress(DynamixelError):  # an absent servo: check() names it
                bus.disarm_watchdog()
            report = bus.check(expectations(rig, latency_ms))
        except StartupMismatch as exc:
            print(
                f"hilsim run: the servos on {rig.bus.port} do not match {rig.path}:\n{exc}",
                file=sys.stderr,
            )
            return EXIT_USAGE
        except DynamixelError as exc:
            print(f"hilsim run: start-up check failed on {rig.bus.port}: {exc}", file=sys.stderr)
            return 3
        problem = bus_capacity_problem(rig, report, latency_ms)
        if problem:
            print(f"hilsim run: {rig.path}: {problem}", file=sys.stderr)
            return EXIT_USAGE
        telemetry = TelemetryWriter(
            run_dir,
            rig.joint_names,
            servo_ids=rig.servo_ids,
            flush_interval_s=rig.telemetry.flush_interval_s,
            config_text=rig.text,
            # virtual time outruns any disk: wait for the writer rather than drop rows
            overflow="block" if bus.clock.virtual else "drop",
        )
        mode = "virtual time" if bus.clock.virtual else "real time"
        print(
            f"hilsim run: {rig.name}: {len(rig.joints)} joints on {rig.bus.port} at "
            f"{rig.loop.rate_hz:g} Hz ({mode}) -> {run_dir}",
            file=sys.stderr,
        )
        loop = HilLoop(
            rig,
            bus,
            targets,
            telemetry,
            duration_s=args.duration,
            stop=stop,
            on_status=None if bus.clock.virtual else _status_printer(rig.loop.rate_hz),
        )
        wall0 = time.perf_counter()
        result = loop.run()
        wall = time.perf_counter() - wall0
        summary = telemetry.close(
            {
                "exit_code": result.exit_code,
                "exit_reason": result.reason,
                "wall_s": wall,
                "clock": mode,
                "port": rig.bus.port,
                "read_mode": bus.read_mode.value,
                "loop": result.summary,
            }
        )
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        bus.close()
    if sys.stderr.isatty():
        sys.stderr.write("\n")
    print(
        f"hilsim run: {result.reason} after {result.ticks} ticks "
        f"({result.ticks / rig.loop.rate_hz:.2f} s of show in {wall:.2f} s); "
        f"exit policy: {result.summary.get('exit_policy', '?')}",
        file=sys.stderr,
    )
    lat = summary.get("lateness_us") or {}

    def us(key: str) -> str:
        value = lat.get(key)
        return "n/a" if value is None else f"{value:.0f} us"

    print(
        f"  lateness p50 {us('p50')}, p99 {us('p99')}, max {us('max')}; "
        f"overruns {result.summary.get('overruns', 0)}; "
        f"comm errors {sum((summary.get('comm_errors') or {}).values())}",
        file=sys.stderr,
    )
    print(f"  telemetry: {run_dir}", file=sys.stderr)
    if not args.no_plots:
        from hilsim.plots import plot_run

        for path in plot_run(run_dir):
            print(f"  plot: {path}", file=sys.stderr)
    return result.exit_code
