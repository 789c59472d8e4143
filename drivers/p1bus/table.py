"""The host's view of the Protocol 1.0-framed families: which models, which registers, how read.

A family is what one driver strategy serves: its registers (only those the host reads or
writes), its byte order and sign encoding, its error bits, and the best per-tick read the
wire allows:

=================  ======================  ====================================  ============
family             models                  per-tick read                         watchdog
=================  ======================  ====================================  ============
Feetech STS        STS3215                 Sync Read 0x82, a reply per servo     none
Feetech SCS        SCS0009                 single Reads in rotation              none
Dynamixel MX (P1)  MX-28, MX-64, MX-106    Bulk Read 0x92, a reply per servo     none
Dynamixel AX       AX-12A, AX-18A, AX-12W  single Reads in rotation              none
=================  ======================  ====================================  ============

The emulator's full tables (defaults, ranges, access) are :mod:`drivers.protocol1`'s; this
module holds the addresses the host uses, and a test holds the two equal; the baud codes and
the models' other names are taken from there. Sources: the
ROBOTIS e-Manual AX-12A / MX-28 (Protocol 1.0) control tables, Feetech's STS/SCS memory
tables as LeRobot's ``feetech/tables.py`` cites them, ``docs/dxlsim.md``. Data and tiny
lookups; no I/O, no SDK.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

from drivers.protocol1.control_table import ALIASES, DXL_P1, FEETECH_STS
from drivers.protocol2.control_table import MODEL_NAMES as P2_MODEL_NAMES


class Protocol(StrEnum):
    """What one bus speaks: one protocol per bus (a servo of another never answers right)."""

    DXL2 = "Dynamixel Protocol 2.0"
    DXL1 = "Dynamixel Protocol 1.0"
    FEETECH = "Feetech (Protocol 1.0 framing)"


class ReadMethod(StrEnum):
    """How the tick reads present positions on a family's bus."""

    SYNC = "sync read"  # Feetech STS 0x82: one request, one status packet per servo
    BULK = "bulk read"  # Dynamixel MX 0x92: one request, one status packet per servo
    ROTATION = "single reads in rotation"  # one READ per servo, a few servos per tick


@dataclass(frozen=True, slots=True)
class Reg:
    """One register: ``addr``, ``size`` bytes; ``sign_bit`` for a sign-magnitude value."""

    name: str
    addr: int
    size: int
    sign_bit: int | None = None

    @property
    def end(self) -> int:
        return self.addr + self.size


@dataclass(frozen=True, eq=False)  # (compared and hashed by identity: one object per family)
class Family:
    """One family's facts, as the host uses them."""

    name: str
    protocol: Protocol
    read: ReadMethod
    big_endian: bool  # SCS: big-endian words
    ticks_per_turn: float  # position ticks per 360 degrees
    max_tick: int  # the highest Goal Position
    center_tick: int  # the tick that is 0 rad
    model_number: Reg
    firmware: Reg
    id: Reg
    baud: Reg
    return_delay: Reg  # 2 µs units
    status_return_level: Reg
    status_return_all: int  # the level at which every instruction is answered
    min_limit: Reg
    max_limit: Reg
    torque_enable: Reg
    goal_position: Reg
    present_position: Reg
    present_load: Reg
    present_voltage: Reg  # 0.1 V
    present_temperature: Reg  # °C
    lock: Reg | None  # Feetech: EEPROM writable only at Lock 0 (the Dynamixel Lock is one-way)
    phase: Reg | None  # Feetech STS: the Phase byte (bit 4: readings beyond 0..4095)
    baud_codes: dict[int, int]  # register value -> bit/s
    error_bits: dict[int, str]  # status ERR bit -> meaning
    hardware_bits: int  # ERR bits that are the servo's own condition (the reading is valid)
    models: dict[str, int] = field(default_factory=dict)  # model name -> Model Number

    @property
    def ticks_per_rad(self) -> float:
        return self.ticks_per_turn / (2.0 * math.pi)

    def describe_error(self, err: int) -> str:
        """``"overheat, overload"`` for the set bits of a status ERR byte."""
        names = [text for bit, text in sorted(self.error_bits.items()) if err & bit]
        unknown = err & ~sum(self.error_bits)
        if unknown:
            names.append(f"unknown bits 0x{unknown:02X}")
        return ", ".join(names) or "none"


_DXL_ERRORS = {
    0x01: "input voltage",
    0x02: "angle limit",
    0x04: "overheating",
    0x08: "range",
    0x10: "checksum",
    0x20: "overload",
    0x40: "instruction",
}
_FEETECH_ERRORS = {
    0x01: "input voltage",
    0x02: "angle sensor",
    0x04: "overheating",
    0x08: "over-current",
    0x20: "overload",
}
_DXL_COMMON = dict(
    protocol=Protocol.DXL1,
    big_endian=False,
    model_number=Reg("Model Number", 0, 2),
    firmware=Reg("Firmware Version", 2, 1),
    id=Reg("ID", 3, 1),
    baud=Reg("Baud Rate", 4, 1),
    return_delay=Reg("Return Delay Time", 5, 1),
    status_return_level=Reg("Status Return Level", 16, 1),
    status_return_all=2,
    min_limit=Reg("CW Angle Limit", 6, 2),
    max_limit=Reg("CCW Angle Limit", 8, 2),
    torque_enable=Reg("Torque Enable", 24, 1),
    goal_position=Reg("Goal Position", 30, 2),
    present_position=Reg("Present Position", 36, 2),
    present_load=Reg("Present Load", 40, 2, sign_bit=10),
    present_voltage=Reg("Present Voltage", 42, 1),
    present_temperature=Reg("Present Temperature", 43, 1),
    lock=None,
    phase=None,
    baud_codes=DXL_P1.baud_rates,  # the standard rate each value stands for
    error_bits=_DXL_ERRORS,
    hardware_bits=0x01 | 0x04 | 0x20,
)
_FEETECH_COMMON = dict(
    protocol=Protocol.FEETECH,
    model_number=Reg("Model Number", 3, 2),
    firmware=Reg("Firmware Major", 0, 1),
    id=Reg("ID", 5, 1),
    baud=Reg("Baud Rate", 6, 1),
    return_delay=Reg("Return Delay Time", 7, 1),
    status_return_level=Reg("Response Status Level", 8, 1),
    status_return_all=1,
    min_limit=Reg("Min Position Limit", 9, 2),
    max_limit=Reg("Max Position Limit", 11, 2),
    torque_enable=Reg("Torque Enable", 40, 1),
    baud_codes=FEETECH_STS.baud_rates,
    error_bits=_FEETECH_ERRORS,
    hardware_bits=0x01 | 0x02 | 0x04 | 0x08 | 0x20,
)

STS = Family(
    name="Feetech STS",
    read=ReadMethod.SYNC,
    big_endian=False,
    ticks_per_turn=4096,
    max_tick=4095,
    center_tick=2048,
    goal_position=Reg("Goal Position", 42, 2, sign_bit=15),
    present_position=Reg("Present Position", 56, 2, sign_bit=15),
    present_load=Reg("Present Load", 60, 2, sign_bit=10),
    present_voltage=Reg("Present Voltage", 62, 1),
    present_temperature=Reg("Present Temperature", 63, 1),
    lock=Reg("Lock", 55, 1),
    phase=Reg("Phase", 18, 1),
    models={"STS3215": 777},
    **_FEETECH_COMMON,  # type: ignore[arg-type]
)
SCS = Family(
    name="Feetech SCS",
    read=ReadMethod.ROTATION,
    big_endian=True,
    ticks_per_turn=1024 * 360 / 300,  # 0..1023 over 300 degrees
    max_tick=1023,
    center_tick=512,
    goal_position=Reg("Goal Position", 42, 2),
    present_position=Reg("Present Position", 56, 2),
    present_load=Reg("Present Load", 60, 2, sign_bit=10),
    present_voltage=Reg("Present Voltage", 62, 1),
    present_temperature=Reg("Present Temperature", 63, 1),
    lock=Reg("Lock", 48, 1),
    phase=None,
    models={"SCS0009": 1284},
    **_FEETECH_COMMON,  # type: ignore[arg-type]
)
AX = Family(
    name="Dynamixel AX",
    read=ReadMethod.ROTATION,
    ticks_per_turn=1024 * 360 / 300,  # 0..1023 over 300 degrees
    max_tick=1023,
    center_tick=512,
    models={"AX-12A": 12, "AX-18A": 18, "AX-12W": 44},
    **_DXL_COMMON,  # type: ignore[arg-type]
)
MX1 = Family(
    name="Dynamixel MX (Protocol 1.0)",
    read=ReadMethod.BULK,
    ticks_per_turn=4096,
    max_tick=4095,
    center_tick=2048,
    models={"MX-28": 29, "MX-64": 310, "MX-106": 320},
    **_DXL_COMMON,  # type: ignore[arg-type]
)
FAMILIES: tuple[Family, ...] = (STS, SCS, MX1, AX)

#: model name (upper case) -> its family
_BY_MODEL: dict[str, Family] = {m: f for f in FAMILIES for m in f.models}
#: Model Number -> (name, family), per protocol (numbers are unique within one maker's range)
_BY_NUMBER: dict[tuple[Protocol, int], tuple[str, Family]] = {
    (f.protocol, n): (m, f) for f in FAMILIES for m, n in f.models.items()
}
#: the Protocol 1.0-only models a rig may name (the X series and the P2 MX are DynamixelBus's)
P1_MODELS: tuple[str, ...] = tuple(_BY_MODEL)
#: MX servos reflashed to Protocol 2.0 firmware: named with -P2; not run by this host yet
P2_MX_MODELS: tuple[str, ...] = ("MX-28-P2", "MX-64-P2", "MX-106-P2")


def canonical(model: str) -> str:
    """The model's name as the tables write it: ``"st3215"`` -> ``"STS3215"``."""
    key = model.strip().upper()
    return ALIASES.get(key, key)


def family_of(model: str) -> Family | None:
    """The Protocol 1.0 family of a model name (case-insensitive; the names people write for
    one, ``ST3215``, ``AX-12``, too), None for any other name."""
    return _BY_MODEL.get(canonical(model))


def protocol_of(model: str) -> Protocol | None:
    """The protocol a model speaks; None for an unknown name."""
    fam = family_of(model)
    if fam is not None:
        return fam.protocol
    key = model.strip().upper()
    for suffix in ("-T", "-R"):
        key = key.removesuffix(suffix)
    if key in P2_MODEL_NAMES.values() or key in P2_MX_MODELS:
        return Protocol.DXL2
    return None


def model_by_number(protocol: Protocol, number: int) -> tuple[str, Family] | None:
    """``(name, family)`` of a Model Number read on a bus of ``protocol``, None if unknown."""
    return _BY_NUMBER.get((protocol, number))


def bus_read_method(families: set[Family] | frozenset[Family]) -> ReadMethod:
    """The best per-tick read every family on one bus supports."""
    methods = {f.read for f in families}
    return methods.pop() if len(methods) == 1 else ReadMethod.ROTATION
