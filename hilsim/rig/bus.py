"""The servo bus of a rig: the keys of ``[bus]``, and of each ``[buses.<name>]`` table when a
figure's servos are on several buses (one process per bus, started together: ``docs/buses.md``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from drivers.dynamixel.startup import ReadMode  # the driver's: the rig names it, the bus obeys it
from drivers.protocol2.control_table import BAUD_RATES
from hilsim.rig.keys import rig_key

#: The baud rates the servos and the driver support (the driver's control table), ascending.
SUPPORTED_BAUDS: tuple[int, ...] = tuple(sorted(BAUD_RATES.values()))
#: X330 servos stop at Baud Rate index 6 (4 Mbps); X430/X540 go to index 7 (4.5 Mbps).
SERIES_MAX_BAUD = {"X330": BAUD_RATES[6]}
#: a bus name names its run directory (RUN/<bus>/): a word character, then word characters and -
BUS_NAME_RE = re.compile(r"\w[\w-]{0,31}")


@dataclass(frozen=True)
class BusConfig:
    port: str = rig_key(
        "text",
        "The serial port: a device (`/dev/ttyUSB0`, `COM3`), a pty path, or the built-in "
        "emulated bus `dxlsim://?ids=1-4&...`. The command line's `--port` overrides it.",
        example="/dev/ttyUSB0",
    )
    baud: int = rig_key(
        "integer",
        "The bus's baud rate; every servo must be set to it.",
        unit="bit/s",
        default=1_000_000,
        allowed="one of " + ", ".join(f"{b}" for b in SUPPORTED_BAUDS) + "; X330 servos: at most "
        f"{SERIES_MAX_BAUD['X330']}",
    )
    read: ReadMode = rig_key(  # noqa: RUF009
        "choice",
        "How present positions are read: `fast` = Fast Sync Read, `plain` = Sync Read, `auto` = "
        "Fast Sync Read when every servo's firmware has it.",
        default=ReadMode.AUTO,
    )
    latency_timer_ms: float | None = rig_key(
        "number",
        "The USB adapter's latency timer, when it cannot be read (the loop budgets its bus time "
        "with it).",
        unit="ms",
        default=None,
        default_doc="none: read from the adapter (hardware) or the emulator's own",
        bounds={
            "nonnegative": True,
            "at_most": 255.0,
            "why": "a USB adapter's latency timer is 0..255 ms",
        },
        example=1,
    )
    return_delay_us: float | None = rig_key(
        "number",
        "The Return Delay Time every servo on this bus should have: the start-up check refuses "
        "a longer one, and `hilsim setup` writes it.",
        unit="µs",
        default=None,
        default_doc="none: any the tick has time for (the check), 0 (`hilsim setup`)",
        bounds={
            "nonnegative": True,
            "at_most": 508.0,
            "why": "Return Delay Time is 0..254 units of 2 µs",
        },
        example=0,
    )
    health_in_tick: bool = rig_key(
        "bool",
        "X series: every servo's Torque Enable and Bus Watchdog read in the tick's own Fast Sync "
        "Read (3 more bytes a servo through indirect addresses; a torque cut seen within a "
        "tick). `false`: the tick reads positions only and the health is read between ticks, "
        "one servo at a time (each about every 80 ms), leaving the host more of each tick.",
        default=True,
        allowed="`true` | `false`",
    )
