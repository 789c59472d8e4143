"""``hilsim scan --port P``: which servos answer on a port, at which baud rates.

Broadcast Ping at each baud rate (unicast pings where nobody answers a broadcast);
``--protocol 1.0`` (Dynamixel AX/MX) or ``feetech`` (STS/SCS): a Ping per ID, each servo named
with its model and family.
On the emulator: ``hilsim scan --port "dxlsim://?ids=1-4"``.

``--baud`` takes bit/s as an integer (``1000000``) or with a k/M suffix as the help writes them
(``57.6k``, ``1M``, ``4.5M``); only the servos' baud rates are accepted. A bad ``--baud`` or
``--ids`` is one line on stderr and exit 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import TYPE_CHECKING

from hilsim.cli._args import add_baud, add_ids, add_port, parse_baud, parse_ids, usage_error
from hilsim.exit_codes import ExitCode

if TYPE_CHECKING:
    from drivers.dynamixel.scan import Found

HELP = "find servo IDs, models and firmware across baud rates"
DEFAULT_BAUDS = (57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)
PROTOCOLS = ("2.0", "1.0", "feetech")
#: what the Protocol 1.0-framed families run at (Feetech's default is 1 Mbit/s)
P1_DEFAULT_BAUDS = (1_000_000, 57_600, 115_200, 500_000)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_port(p, required=True)
    add_baud(
        p,
        repeat=True,
        help="baud rate to try, e.g. 1M or 1000000 (repeat for several; "
        "default: 57.6k 115.2k 1M 2M 3M 4M)",
    )
    add_ids(p, help="only these IDs, e.g. 1-8 (default 0-252)")
    p.add_argument(
        "--no-unicast", action="store_true", help="broadcast Ping only (faster when nobody answers)"
    )
    p.add_argument(
        "--protocol",
        choices=PROTOCOLS,
        default="2.0",
        help="2.0: Dynamixel X series (default); 1.0: Dynamixel AX/MX; feetech: STS/SCS "
        "(an SO-101 arm). 1.0 and feetech ping each ID: give --ids to be quick",
    )


def run(args: argparse.Namespace) -> int:
    from drivers.dynamixel.errors import DynamixelError
    from drivers.dynamixel.scan import scan

    try:
        ids = parse_ids(args.ids or None)
        bauds = tuple(parse_baud(b) for b in args.baud) if args.baud else DEFAULT_BAUDS
    except ValueError as exc:
        return usage_error("scan", exc)
    protocol = getattr(args, "protocol", "2.0")
    if protocol != "2.0" and not args.baud:
        bauds = P1_DEFAULT_BAUDS
    if protocol == "2.0" and (other := _emulated_protocol(args.port)) is not None:
        return usage_error(
            "scan",
            ValueError(
                f"{args.port} emulates {other[0]} servos, which do not speak Protocol 2.0: "
                f"try --protocol {other[1]}"
            ),
        )
    print(f"hilsim scan: {args.port} at {', '.join(str(b) for b in bauds)} bit/s", file=sys.stderr)
    n_ids = len(ids) if ids is not None else 253
    t0 = time.monotonic()

    def progress(baud: int, step: str, here: list[Found]) -> None:
        took = f"{time.monotonic() - t0:.1f} s"
        if step == "unicast":
            print(
                f"hilsim scan: {baud} bit/s: no answer to a broadcast Ping; pinging {n_ids} IDs "
                "one by one (--no-unicast skips this)",
                file=sys.stderr,
                flush=True,
            )
        else:
            who = f"IDs {', '.join(str(f.id) for f in here)}" if here else "none"
            print(f"hilsim scan: {baud} bit/s: {who} ({took})", file=sys.stderr, flush=True)

    try:
        if protocol != "2.0":
            from drivers.p1bus.scan import scan1
            from drivers.p1bus.table import Protocol

            proto = Protocol.FEETECH if protocol == "feetech" else Protocol.DXL1
            found: list[object] = list(scan1(args.port, bauds, ids, proto))
        else:
            found = list(
                scan(args.port, bauds, ids, unicast_fallback=not args.no_unicast, progress=progress)
            )
    except ValueError as exc:  # a dxlsim:// URL that cannot be built: a usage error
        return usage_error("scan", exc)
    except DynamixelError as exc:
        print(f"hilsim scan: {exc}", file=sys.stderr)
        return int(ExitCode.FAULT)
    for f in found:
        print(f)
    if not found and protocol == "2.0" and (hint := _feetech_hint(args.port)):
        print(f"hilsim scan: no Protocol 2.0 servo answered; {hint}", file=sys.stderr)
        return int(ExitCode.NOTHING_FOUND)
    if not found:
        print(
            "hilsim scan: no servo answered. Check power (the servos' LED blinks once at "
            "power-up), wiring, and that nothing else has the port open"
            + (
                "; Feetech (SO-101) or AX/MX servos: --protocol feetech or --protocol 1.0."
                if protocol == "2.0"
                else "."
            ),
            file=sys.stderr,
        )
        return int(ExitCode.NOTHING_FOUND)
    return int(ExitCode.OK)


def _emulated_protocol(port: str) -> tuple[str, str] | None:
    """(model, ``--protocol`` value) when ``port`` is a ``dxlsim://?model=...`` URL of
    Protocol 1.0-framed servos; None otherwise (a named bus, hardware, the X series)."""
    if not port.lower().startswith("dxlsim://"):
        return None
    from drivers.dxlsim.p1_models import bus_protocol
    from drivers.dxlsim.url import DxlsimUrl

    try:
        url = DxlsimUrl.parse(port)
        if url.name:
            return None
        proto = bus_protocol(url.model)
    except ValueError:
        return None  # the scan says what is wrong with the URL
    if proto == "2.0":
        return None
    return url.model, "feetech" if proto == "feetech" else "1.0"


def _feetech_hint(port: str) -> str:
    """When Feetech servos answer their own broadcast Ping (a quick look at their usual
    rates): which, where, and the flag to use; else empty."""
    from drivers.dynamixel.errors import DynamixelError
    from drivers.p1bus.scan import feetech_answers

    try:
        hits = feetech_answers(port, P1_DEFAULT_BAUDS)
    except (DynamixelError, ValueError, OSError):
        return ""
    if not hits:
        return ""
    where = "; ".join(f"IDs {', '.join(map(str, ids))} at {b} bit/s" for b, ids in hits)
    return f"Feetech servos answer their own Ping ({where}): try --protocol feetech"
