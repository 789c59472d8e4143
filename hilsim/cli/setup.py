"""``hilsim setup RIG [--port P] [--yes] [--id OLD:NEW ...]``: servos to what the rig expects.

Finds the rig's servos at any baud (the family's baud table, the rig's rate first; each
baud is said as it is tried), reads each one, and prints ONE table - servo, register, now,
wanted - of what differs: ID, Return Delay Time, Operating Mode, position limits, Shutdown,
Status Return Level, baud (Feetech STS/SCS and Dynamixel Protocol 1.0 servos: their own
registers, :mod:`hilsim.show.p1_setup`; a Feetech servo's Lock opened for the EEPROM writes and
closed after). Writes only with ``--yes`` (torque off first; the baud last), then
reads every value back at the rig's baud and says what it found. On a ``dxlsim://`` port
the emulator lives in this process: the changes last until it exits (``hilsim emulate``
keeps its servos' state while it runs).

Exit 0: nothing to do, a dry run, or every value read back as wanted; 2: a usage error or a
servo of the rig found nowhere; 3: a value did not read back as written.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

from hilsim.cli._args import add_port, usage_error
from hilsim.exit_codes import ExitCode

if TYPE_CHECKING:
    from hilsim.show.p1_setup import P1ServoSetup
    from hilsim.show.servo_setup import ServoSetup, SetupPlan

    AnySetup = ServoSetup | P1ServoSetup

HELP = "set the rig's servos up: IDs, baud, Return Delay, mode, limits (writes with --yes)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("rig", help="the rig file (TOML)")
    add_port(p, help="the port (overrides the rig's bus.port): /dev/ttyUSB0, a pty, dxlsim://")
    p.add_argument("--yes", action="store_true", help="write the changes (default: only show)")
    p.add_argument(
        "--id",
        action="append",
        default=[],
        metavar="OLD:NEW",
        help="the servo now at ID OLD becomes the rig's ID NEW (repeat for several)",
    )
    p.add_argument("--bus", help="which of the rig's [buses.<name>] (a rig with several)")


def _say(msg: str) -> None:
    print(f"hilsim setup: {msg}", file=sys.stderr, flush=True)


def parse_renames(items: list[str]) -> dict[int, int]:
    """``["7:1", "8:2"]`` -> ``{7: 1, 8: 2}``; ValueError naming the bad item."""
    out: dict[int, int] = {}
    for item in items:
        old, sep, new = item.partition(":")
        try:
            a, b = int(old), int(new)
        except ValueError:
            a = b = -1
        if not sep or not (0 <= a <= 252 and 0 <= b <= 252):
            raise ValueError(f"--id {item!r}: give OLD:NEW, two IDs 0..252 (e.g. --id 1:3)")
        if a in out:
            raise ValueError(f"--id {item!r}: ID {a} is renamed twice")
        out[a] = b
    return out


def _table(rows: Sequence[tuple[str, ...]]) -> str:
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    lines = []
    for k, row in enumerate(rows):
        lines.append("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip())
        if k == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from drivers.dynamixel.errors import DynamixelError
    from drivers.dynamixel.link import Link
    from hilsim.rig import RigError, load_rig
    from hilsim.show.servo_setup import ServoSetup
    from hilsim.show.session import p1_models, port_for, real_clock

    try:
        renames = parse_renames(args.id)
        rig = load_rig(args.rig, port=args.port, bus=args.bus)
    except (RigError, ValueError, OSError) as exc:
        return usage_error("setup", exc)
    emulated = rig.bus.port.lower().startswith("dxlsim://")
    port = port_for(rig, virtual=emulated)
    if emulated:
        _say("an emulated bus in this process: its servos keep the changes until setup exits")
    p1 = p1_models(rig) is not None  # Feetech or Dynamixel Protocol 1.0
    opener = Link
    if p1:
        from drivers.p1bus.link import P1Link

        opener = P1Link
    try:
        link = opener.open(
            port,
            baud=rig.bus.baud,
            clock=None if emulated else real_clock(rig),
            latency_timer_ms=rig.bus.latency_timer_ms,
        )
    except (DynamixelError, ValueError) as exc:
        return usage_error("setup", exc)
    try:
        setup: AnySetup
        if p1:
            from drivers.p1bus.link import P1Link
            from hilsim.show.p1_setup import P1ServoSetup

            assert isinstance(link, P1Link)
            setup = P1ServoSetup(rig, link, renames)
        else:
            setup = ServoSetup(rig, link, renames)
        return _setup(setup, args.yes)
    except (DynamixelError, ValueError) as exc:
        _say(f"{exc} (nothing more written)")
        return int(ExitCode.FAULT)
    finally:
        link.close()


def _missing_code(setup: AnySetup, the_plan: SetupPlan) -> int:
    """Exit 2 when a rig servo answered nowhere, unless ``--id`` renames servos connected one
    at a time (then the others are expected to be absent) and one was found."""
    if the_plan.missing and not (setup.renaming and the_plan.found):
        return int(ExitCode.USAGE)
    return int(ExitCode.OK)


def _setup(setup: AnySetup, yes: bool) -> int:
    from drivers.dynamixel.configure import Found

    names = setup.names
    _say(f"looking for servos {sorted(setup.targets)} on {setup.rig.bus.port}")

    def progress(baud: int, here: list[Found]) -> None:
        ids = ", ".join(f"{f.id} ({f.model_name})" for f in here) or "none"
        _say(f"  {baud:>7} bit/s: {ids}")

    found = setup.find(progress)
    the_plan = setup.plan(found)
    for f in the_plan.others:
        _say(f"ID {f.id} at {f.baud} bit/s ({f.model_name}) is not one of the rig's: left alone")
    for line in the_plan.models:
        _say(f"{line}: set the joint's model in the rig (setup cannot change a servo's model)")
    if the_plan.missing:
        _say(
            "not found at any baud: servo(s) "
            + ", ".join(
                f"{sid} ({names.get(setup.targets[sid].id, '?')})" for sid in the_plan.missing
            )
            + " (check power and wiring; --id OLD:NEW renames a servo found at another ID; "
            "servos sharing an ID, as factory ones do, answer as noise: connect them one at a "
            "time)"
        )
    if not the_plan.changes:
        _say("every servo found is as the rig expects: nothing to write")
        return _missing_code(setup, the_plan)
    rows = [("servo", "register", "now", "wanted")]
    for c in the_plan.changes:
        who = f"{c.servo} ({names.get(setup.targets[c.servo].id, '?')}) @ {c.baud}"
        rows.append((who, c.name, c.now_text, c.wanted_text))
    print(_table(rows), flush=True)
    if not yes:
        _say(
            f"nothing written: {len(the_plan.changes)} change(s); run again with --yes to write "
            "them (torque is turned off first: support the figure)"
        )
        return _missing_code(setup, the_plan)
    problems, left, silent = setup.write(the_plan)
    for line in problems:
        _say(f"write failed: {line}")
    baud = setup.rig.bus.baud
    if silent:
        _say(f"read back at {baud} bit/s: servo(s) {silent} do not answer there")
    back = [("servo", "register", "read back")] + [
        (f"{sid} ({names.get(sid, '?')})", reg, value)
        for sid, reg, value in setup.read_back(the_plan)
    ]
    print(f"read back at {baud} bit/s:", flush=True)
    print(_table(back), flush=True)
    if left:
        for c in left:
            _say(f"servo {c.servo}: {c.name} reads {c.now_text}, wanted {c.wanted_text}")
        return int(ExitCode.FAULT)
    if silent or problems:
        return int(ExitCode.FAULT)
    _say(f"done: {len(the_plan.found)} servo(s) read back as the rig expects at {baud} bit/s")
    return _missing_code(setup, the_plan)
