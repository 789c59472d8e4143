"""``hilsim scan --port P``: which servos answer on a port, at which baud rates.

Broadcast Ping at each baud rate (unicast pings where nobody answers a broadcast).
On the emulator: ``hilsim scan --port "dxlsim://?ids=1-4"``.

``--baud`` takes bit/s as an integer (``1000000``) or with a k/M suffix as the help writes them
(``57.6k``, ``1M``, ``4.5M``); only the servos' baud rates are accepted. A bad ``--baud`` or
``--ids`` is one line on stderr and exit 2.
"""

from __future__ import annotations

import argparse
import re
import sys

HELP = "find servo IDs, models and firmware across baud rates"
DEFAULT_BAUDS = (57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)
_BAUD_RE = re.compile(r"\s*(\d+(?:\.\d+)?)\s*([kKmM]?)\s*(?:bps|bit/s)?\s*", re.IGNORECASE)


def _supported_bauds() -> tuple[int, ...]:
    from drivers.protocol2.control_table import BAUD_RATES

    return tuple(sorted(BAUD_RATES.values()))


def _short(bps: int) -> str:
    """57600 -> 57.6k, 1000000 -> 1M."""
    if bps >= 1_000_000:
        return f"{bps / 1e6:g}M"
    return f"{bps / 1e3:g}k" if bps >= 1000 else str(bps)


def parse_baud(text: str) -> int:
    """``"1M"`` -> 1000000, ``"57.6k"`` -> 57600, ``"115200"`` -> 115200.

    Raises ValueError (one line, listing the servos' rates) for anything else.
    """
    allowed = _supported_bauds()
    listed = ", ".join(f"{_short(b)} ({b})" for b in allowed)
    m = _BAUD_RE.fullmatch(text)
    if m is None:
        raise ValueError(
            f"--baud {text!r}: not a baud rate (write 1000000 or 1M); allowed: {listed}"
        )
    number, suffix = m.groups()
    scale = {"": 1, "k": 1_000, "m": 1_000_000}[suffix.lower()]
    value = round(float(number) * scale)
    if abs(float(number) * scale - value) > 1e-6 or value not in allowed:
        raise ValueError(f"--baud {text!r}: the servos do not run at that rate; allowed: {listed}")
    return value


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", required=True, help="/dev/ttyUSB0, a pty path, or dxlsim://...")
    p.add_argument(
        "--baud",
        action="append",
        metavar="BPS",
        help="baud rate to try, e.g. 1M or 1000000 (repeat for several; "
        "default: 57.6k 115.2k 1M 2M 3M 4M)",
    )
    p.add_argument("--ids", help="only these IDs, e.g. 1-8 (default 0-252)")
    p.add_argument(
        "--no-unicast", action="store_true", help="broadcast Ping only (faster when nobody answers)"
    )


def run(args: argparse.Namespace) -> int:
    from drivers.dynamixel.errors import DynamixelError
    from drivers.dynamixel.scan import scan
    from drivers.protocol2.ids import parse_ids

    try:
        ids = parse_ids(args.ids) if args.ids else None
        bauds = tuple(parse_baud(str(b)) for b in args.baud) if args.baud else DEFAULT_BAUDS
    except ValueError as exc:
        message = str(exc)
        if len(message) > 200:  # an ID list can be long: one line, not a screenful
            message = message[:200] + " …"
        print(f"hilsim scan: {message}", file=sys.stderr)
        return 2
    print(f"hilsim scan: {args.port} at {', '.join(str(b) for b in bauds)} bit/s", file=sys.stderr)
    try:
        found = scan(args.port, bauds, ids, unicast_fallback=not args.no_unicast)
    except ValueError as exc:  # a dxlsim:// URL that cannot be built: a usage error
        print(f"hilsim scan: {exc}", file=sys.stderr)
        return 2
    except DynamixelError as exc:
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
