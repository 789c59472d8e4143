"""The bus flags every command shares, written once: ``--port``, ``--baud``, ``--ids``.

Values are parsed after argparse (not as its ``type=``), so a bad one is one line naming the
flag and what is allowed — ``hilsim scan: --baud '2.5M': the servos do not run at that rate;
allowed: ...`` — and exit 2, never a usage dump.
"""

from __future__ import annotations

import argparse
import re
import sys

from hilsim.exit_codes import ExitCode

PORT_HELP = "/dev/ttyUSB0, a pty path, or dxlsim://... (the emulator)"
_BAUD_RE = re.compile(r"\s*(\d+(?:\.\d+)?)\s*([kKmM]?)\s*(?:bps|bit/s)?\s*", re.IGNORECASE)
#: a message longer than this (an ID list can be long) is cut: one line, not a screenful
MAX_MESSAGE = 200


def add_port(p: argparse.ArgumentParser, *, required: bool = False, help: str = PORT_HELP) -> None:
    p.add_argument("--port", required=required, help=help)


def add_baud(
    p: argparse.ArgumentParser, *, repeat: bool = False, default: str | None = None, help: str
) -> None:
    """``--baud BPS`` (``1000000``, ``1M``, ``57.6k``); ``repeat``: may be given several times."""
    kw = {"action": "append"} if repeat else {"default": default}
    p.add_argument("--baud", metavar="BPS", help=help, **kw)


def add_ids(p: argparse.ArgumentParser, *, default: str | None = None, help: str) -> None:
    """``--ids LIST`` (``1-4``, ``1,3,5``, ``1-3,7``)."""
    p.add_argument("--ids", default=default, metavar="LIST", help=help)


def supported_bauds() -> tuple[int, ...]:
    from drivers.protocol2.control_table import BAUD_RATES

    return tuple(sorted(BAUD_RATES.values()))


def short_baud(bps: int) -> str:
    """57600 -> 57.6k, 1000000 -> 1M."""
    if bps >= 1_000_000:
        return f"{bps / 1e6:g}M"
    return f"{bps / 1e3:g}k" if bps >= 1000 else str(bps)


def parse_baud(text: str | int) -> int:
    """``"1M"`` -> 1000000, ``"57.6k"`` -> 57600, ``"115200"`` -> 115200: one of the servos'
    rates. Raises ValueError (one line, listing the servos' rates) for anything else."""
    text = str(text)
    allowed = supported_bauds()
    listed = ", ".join(f"{short_baud(b)} ({b})" for b in allowed)
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


def parse_ids(text: str | None) -> list[int] | None:
    """The ``--ids`` list, or None when the flag was not given. Raises ValueError."""
    if text is None:
        return None
    from drivers.protocol2.ids import parse_ids as parse

    try:
        return parse(text)
    except ValueError as exc:
        raise ValueError(f"--ids: {exc}") from None


def usage_error(command: str, exc: BaseException | str) -> int:
    """Say a bad value in one line on stderr; return the usage exit code (2)."""
    message = str(exc)
    if len(message) > MAX_MESSAGE:
        message = message[:MAX_MESSAGE] + " …"
    print(f"hilsim {command}: {message}", file=sys.stderr)
    return int(ExitCode.USAGE)
