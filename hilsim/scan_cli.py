"""``hilsim scan --port P``: which servos answer on a port, at which baud rates.

Broadcast Ping at each baud rate (unicast pings where nobody answers a broadcast).
On the emulator: ``hilsim scan --port "dxlsim://?ids=1-4"``.
"""

from __future__ import annotations

import argparse
import sys

HELP = "find servo IDs, models and firmware across baud rates"
DEFAULT_BAUDS = (57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", required=True, help="/dev/ttyUSB0, a pty path, or dxlsim://...")
    p.add_argument(
        "--baud",
        type=int,
        action="append",
        metavar="BPS",
        help="baud rate to try (repeat for several; default: 57600 115200 1M 2M 3M 4M)",
    )
    p.add_argument("--ids", help="only these IDs, e.g. 1-8 (default 0-252)")
    p.add_argument(
        "--no-unicast", action="store_true", help="broadcast Ping only (faster when nobody answers)"
    )


def run(args: argparse.Namespace) -> int:
    from drivers.dxlsim.ids import parse_ids
    from drivers.dynamixel.errors import DynamixelError
    from drivers.dynamixel.scan import scan

    try:
        ids = parse_ids(args.ids) if args.ids else None
    except ValueError as exc:
        print(f"hilsim scan: {exc}", file=sys.stderr)
        return 2
    bauds = tuple(args.baud) if args.baud else DEFAULT_BAUDS
    print(f"hilsim scan: {args.port} at {', '.join(str(b) for b in bauds)} bit/s", file=sys.stderr)
    try:
        found = scan(args.port, bauds, ids, unicast_fallback=not args.no_unicast)
    except (DynamixelError, ValueError) as exc:
        print(f"hilsim scan: {exc}", file=sys.stderr)
        return 3
    for f in found:
        print(f)
    if not found:
        print(
            "hilsim scan: no servo answered. Check power (the servos' LED blinks once at "
            "power-up), wiring, and that nothing else has the port open.",
            file=sys.stderr,
        )
        return 1
    return 0
