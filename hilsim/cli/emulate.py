"""``hilsim emulate``: an emulated Dynamixel bus on a pseudo-terminal.

Prints the device path as the first line of stdout, then what to use it with - the
``--port`` to give ``hilsim run`` and the ``[bus]`` lines of a rig file - and serves until
SIGINT/SIGTERM. Any serial program (dynamixel-sdk's own PortHandler, Dynamixel Wizard
under Wine, a terminal) can open that path. The defaults serve the demo figure as
``configs/demo.toml``'s own emulated bus has it (IDs 1-4, XM430-W350, 1 Mbps, Return
Delay Time 0): ``hilsim emulate``, then ``hilsim run configs/demo.toml --port /dev/pts/N``.
Any other bus is told a ``hilsim scan`` of itself and the rig it needs, not the demo.

The servos answer only a client whose line speed is theirs (``--baud``; after a write of
Baud Rate(8) or a Factory Reset, their new rate), as on a wire: the client's speed is read
back from the pty (:func:`drivers.dxlsim.pty_server.line_speed`).
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
from types import FrameType

from drivers.dxlsim.pty_server import PtyServer
from drivers.dxlsim.url import DEFAULT_HOST_BAUD, DxlsimUrl
from drivers.p1bus.table import Protocol, protocol_of
from drivers.protocol1.control_table import TABLES as P1_TABLES
from drivers.protocol2.ids import format_ids
from drivers.protocol2.wire_time import PTY_LATENCY_MS
from hilsim.cli._args import add_baud, add_ids, parse_baud, usage_error
from hilsim.exit_codes import ExitCode

HELP = "serve an emulated Dynamixel bus on a pseudo-terminal (path printed first)"
#: What ``hilsim emulate`` serves without flags: the demo figure (IDs 1-4, Return Delay
#: Time 0) on the real clock; every other default is :class:`DxlsimUrl`'s.
BASE = DxlsimUrl(ids=(1, 2, 3, 4), rdt_us=0.0, clock="real")
#: flag destination -> DxlsimUrl field
_FIELDS = ("ids", "model", "rdt_us", "turnaround_us", "latency_ms", "firmware", "faults", "seed")


def add_arguments(p: argparse.ArgumentParser) -> None:
    keep = argparse.SUPPRESS  # a flag not given leaves BASE's value
    add_ids(p, default=keep, help="servo IDs, e.g. 1-4 or 1,3,5 (default 1-4: the demo figure)")
    p.add_argument(
        "--model",
        default=keep,
        help=f"servo model for all, and IDS:MODEL for the IDs that differ, e.g. "
        f"'XM430-W350,5-6:XL330-M288' (default {BASE.model}; the models: hilsim scan names "
        "them, the README lists them); or Protocol 1.0 servos, one protocol a bus: "
        f"{', '.join(P1_TABLES)}",
    )
    add_baud(
        p,
        default=str(DEFAULT_HOST_BAUD),
        help=f"the servos' baud rate; a client at another rate gets no reply "
        f"(default {DEFAULT_HOST_BAUD})",
    )
    p.add_argument(
        "--rdt-us",
        type=float,
        default=keep,
        help=f"Return Delay Time in µs (default {BASE.rdt_us:g}, as the demo's servos; "
        f"factory {DxlsimUrl().rdt_us:g})",
    )
    p.add_argument(
        "--turnaround-us",
        type=float,
        default=keep,
        help=f"servo processing time after the Return Delay Time (default {BASE.turnaround_us:g})",
    )
    p.add_argument(
        "--latency-ms",
        type=float,
        default=keep,
        help=f"extra USB latency-timer model on replies (default {BASE.latency_ms:g}: "
        "the pty adds its own)",
    )
    p.add_argument("--firmware", type=int, default=keep, help="firmware version to report")
    p.add_argument(
        "--faults", default=keep, help="fault plan, e.g. 'drop:id=2,rate=0.05;unplug:at=30'"
    )
    p.add_argument("--seed", type=int, default=keep, help=f"fault plan seed (default {BASE.seed})")
    p.add_argument("--trace", metavar="FILE", help="write every byte, timestamped, as JSON lines")


def url_from_args(args: argparse.Namespace) -> DxlsimUrl:
    """The bus the flags describe, as a :class:`DxlsimUrl` (``--trace FILE`` turns its
    trace on). Raises ValueError on a bad value."""
    given = {k: getattr(args, k) for k in _FIELDS if hasattr(args, k)}
    if args.trace:
        given["trace"] = True
    return BASE.replace(**given)


def demo_fits(url: DxlsimUrl, baud: int) -> bool:
    """Whether ``configs/demo.toml`` can run on this bus: its IDs, model, Return Delay Time
    and baud rate are the demo's (any other and its start-up check refuses)."""
    return (url.ids, url.model, url.rdt_us, baud) == (
        BASE.ids,
        BASE.model,
        BASE.rdt_us,
        DEFAULT_HOST_BAUD,
    )


def usage_lines(path: str, args: argparse.Namespace) -> str:
    """What to give a host to use this pty: ``--port``, a command that fits this bus (the
    demo only where it can run) and a rig's ``[bus]`` lines."""
    latency = PTY_LATENCY_MS + getattr(args, "latency_ms", BASE.latency_ms)
    url = url_from_args(args)
    if demo_fits(url, args.baud):
        example = [f"  e.g. hilsim run configs/demo.toml --port {path}"]
    else:
        ids = format_ids(url.ids)
        proto = {Protocol.DXL1: " --protocol 1.0", Protocol.FEETECH: " --protocol feetech"}
        flag = proto.get(protocol_of(url.model) or Protocol.DXL2, "")
        example = [
            f"  e.g. hilsim scan --port {path} --baud {args.baud} --ids {ids}{flag}"
            "   (what answers)",
            f'  then a rig of your own: servo_id {ids}, model = "{url.model}", baud = {args.baud}',
            f"  (configs/demo.toml expects IDs {format_ids(BASE.ids)}, {BASE.model}, "
            f"{DEFAULT_HOST_BAUD} bps, Return Delay {BASE.rdt_us:g} µs: it cannot run here)",
        ]
    return "\n".join(
        (
            f"--port {path}",
            *example,
            "  or in a rig file:",
            "[bus]",
            f'port = "{path}"',
            f"baud = {args.baud}",
            f"latency_timer_ms = {latency:g}",
        )
    )


def run(args: argparse.Namespace) -> int:
    try:
        args.baud = parse_baud(args.baud)
        url = url_from_args(args)
        bus = url.build_bus(host_baud=args.baud)
    except ValueError as exc:  # FaultSpecError is one too
        return usage_error("emulate", exc)
    server = PtyServer(bus)
    got: dict[str, int] = {}

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        got["signal"] = signum
        server.stop()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    print(server.path, flush=True)
    print(usage_lines(server.path, args), flush=True)
    print(
        f"hilsim emulate: {len(bus.servos)} servos, {url.model} ({url}) at {args.baud} bps "
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
    return int(ExitCode.OK)
