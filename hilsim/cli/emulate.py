"""``hilsim emulate``: an emulated Dynamixel bus on a pseudo-terminal.

Prints the device path as the first line of stdout, then what to use it with - the
``--port`` to give ``hilsim run`` and the ``[bus]`` lines of a rig file - and serves until
SIGINT/SIGTERM. Any serial program (dynamixel-sdk's own PortHandler, Dynamixel Wizard
under Wine, a terminal) can open that path. The defaults serve the demo figure as
``configs/demo.toml``'s own emulated bus has it (IDs 1-4, XM430-W350, 1 Mbps, Return
Delay Time 0): ``hilsim emulate``, then ``hilsim run configs/demo.toml --port /dev/pts/N``.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys

from drivers.clock import MonotonicClock
from drivers.dxlsim.bus import DxlBus
from drivers.dxlsim.faults import FaultSpecError, parse_fault_plan
from drivers.dxlsim.pty_server import PtyServer
from drivers.dxlsim.servo import VirtualServo
from drivers.protocol2.ids import parse_ids

HELP = "serve an emulated Dynamixel bus on a pseudo-terminal (path printed first)"
#: Adapter latency a host should count for this pty on top of ``--latency-ms`` (ms): the
#: server writes each byte when due and wakes within ~0.1-1 ms on a quiet host. The same
#: figure as ``drivers.dynamixel.link.PTY_LATENCY_MS``, which ``hilsim run`` assumes for
#: a pty when the rig gives no ``latency_timer_ms`` (not imported: the emulator does not
#: load the host's driver).
PTY_LATENCY_MS = 1.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--ids", default="1-4", help="servo IDs, e.g. 1-4 or 1,3,5 (default 1-4: the demo figure)"
    )
    p.add_argument("--model", default="XM430-W350", help="servo model (default XM430-W350)")
    p.add_argument("--baud", type=int, default=1_000_000, help="bus baud rate (default 1000000)")
    p.add_argument(
        "--rdt-us",
        type=float,
        default=0.0,
        help="Return Delay Time in µs (default 0, as the demo's servos; factory 500)",
    )
    p.add_argument(
        "--turnaround-us",
        type=float,
        default=20.0,
        help="servo processing time after the Return Delay Time (default 20)",
    )
    p.add_argument(
        "--latency-ms",
        type=float,
        default=0.0,
        help="extra USB latency-timer model on replies (default 0: the pty adds its own)",
    )
    p.add_argument("--firmware", type=int, default=None, help="firmware version to report")
    p.add_argument(
        "--faults", default="", help="fault plan, e.g. 'drop:id=2,rate=0.05;unplug:at=30'"
    )
    p.add_argument("--seed", type=int, default=0, help="fault plan seed (default 0)")
    p.add_argument("--trace", metavar="FILE", help="write every byte, timestamped, as JSON lines")


def usage_lines(path: str, args: argparse.Namespace) -> str:
    """What to give a host to use this pty: ``--port`` and a rig's ``[bus]`` lines."""
    latency = PTY_LATENCY_MS + args.latency_ms
    return "\n".join(
        (
            f"--port {path}",
            f"  e.g. hilsim run configs/demo.toml --port {path}",
            "  or in a rig file:",
            "[bus]",
            f'port = "{path}"',
            f"baud = {args.baud}",
            f"latency_timer_ms = {latency:g}",
        )
    )


def run(args: argparse.Namespace) -> int:
    try:
        ids = parse_ids(args.ids)
        plan = parse_fault_plan(args.faults, seed=args.seed)
        clock = MonotonicClock()
        t = clock.now()
        servos = [
            VirtualServo(
                args.model,
                i,
                baud=args.baud,
                return_delay_us=args.rdt_us,
                firmware=args.firmware,
                t=t,
            )
            for i in ids
        ]
        bus = DxlBus(
            servos,
            baud=args.baud,
            clock=clock,
            latency_timer_ms=args.latency_ms,
            turnaround_us=args.turnaround_us,
            faults=plan,
            trace=bool(args.trace),
        )
    except (ValueError, FaultSpecError) as exc:
        print(f"hilsim emulate: {exc}", file=sys.stderr)
        return 2
    server = PtyServer(bus)
    got = {}

    def on_signal(signum, _frame):
        got["signal"] = signum
        server.stop()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    print(server.path, flush=True)
    print(usage_lines(server.path, args), flush=True)
    print(
        f"hilsim emulate: {len(servos)} x {args.model} (IDs {args.ids}) at {args.baud} bps "
        f"on {server.path}; Ctrl-C to stop",
        file=sys.stderr,
        flush=True,
    )
    try:
        server.serve_forever()
    finally:
        server.close()
        if args.trace:
            with open(args.trace, "w") as fh:
                for r in bus.trace or ():
                    fh.write(
                        json.dumps(
                            {
                                "t_start": r.t_start - bus.t0,
                                "t_end": r.t_end - bus.t0,
                                "dir": r.direction,
                                "hex": r.data.hex(" "),
                                "note": r.note,
                            }
                        )
                        + "\n"
                    )
    print(f"hilsim emulate: stopped ({bus.stats['instructions']} packets served)", file=sys.stderr)
    return 0
