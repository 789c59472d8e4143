"""Families and control tables of Protocol 1.0-framed servos, as data.

A :class:`Family` holds what one maker's firmware line shares: byte order, error bits, what the
Status Return Level values mean, the baud codes, which group reads exist, and the Lock register's
meaning. A :class:`ControlTable` is one model: its model number and every item (address, size,
access, EEPROM or RAM, initial value, range, sign bit). Each table's ``source`` names the page
it was read from. ``TABLES`` maps model names to tables; :func:`table_for` looks one up.

No family here has a Bus Watchdog: if the host dies, these servos hold their last goal.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import IntFlag
from typing import Any

from drivers.protocol1.encoding import (
    decode_word,
    encode_word,
    from_sign_magnitude,
    to_sign_magnitude,
)


class DxlP1Error(IntFlag):
    """Dynamixel Protocol 1.0 status ERR bits (``protocol1_packet_handler.py``)."""

    VOLTAGE = 1
    ANGLE_LIMIT = 2
    OVERHEAT = 4
    RANGE = 8
    CHECKSUM = 16
    OVERLOAD = 32
    INSTRUCTION = 64


class FeetechError(IntFlag):
    """Feetech status ERR bits (``scservo_sdk`` getRxPacketError)."""

    VOLTAGE = 1
    ANGLE_SENSOR = 2
    OVERHEAT = 4
    OVERCURRENT = 8
    OVERLOAD = 32


@dataclass(frozen=True, slots=True)
class Item:
    """One control-table item. ``sign_bit``: sign-magnitude with that sign bit (None: unsigned).
    ``lo``/``hi`` bound the raw register value; ``default`` None means set at power-up from
    the servo's state (positions, read-only measurements)."""

    name: str
    addr: int
    size: int
    access: str = "RW"  # "R" or "RW"
    eeprom: bool = False
    default: int | None = 0
    lo: int = 0
    hi: int = 0
    sign_bit: int | None = None
    big_endian: bool = False

    @property
    def end(self) -> int:
        return self.addr + self.size

    @property
    def writable(self) -> bool:
        return self.access == "RW"

    def decode(self, block: bytes | bytearray, start: int = 0) -> int:
        """The item's signed value from ``block``, a read that began at address ``start``."""
        i = self.addr - start
        raw = decode_word(block[i : i + self.size], self.big_endian)
        return raw if self.sign_bit is None else from_sign_magnitude(raw, self.sign_bit)

    def encode(self, value: int) -> bytes:
        """``value`` (signed where the item is) as the item's bytes."""
        raw = value if self.sign_bit is None else to_sign_magnitude(int(value), self.sign_bit)
        return encode_word(raw, self.size, self.big_endian)


@dataclass(frozen=True, slots=True)
class Family:
    """What one firmware line shares.

    ``srl_all``: the Status Return Level value at and above which every instruction is answered;
    below it only PING (Dynamixel level 0) or PING and READ are. ``sync_read``/``bulk_read``:
    whether the family answers SYNC READ 0x82 / BULK READ 0x92. ``lock_persist``: True when
    Lock = 1 means "EEPROM writes take effect but are not kept over a power cycle" (Feetech);
    False when it means "EEPROM cannot be written until power off" (Dynamixel).
    """

    name: str
    protocol: str  # "dynamixel-p1" or "feetech"
    big_endian: bool
    error_flags: type[IntFlag]
    srl_all: int
    srl_read: int
    baud_rates: dict[int, int]  # code -> bit/s
    sync_read: bool
    bulk_read: bool
    lock_persist: bool
    bus_watchdog: bool = False

    @property
    def read_method(self) -> str:
        """How a host reads every servo each tick: ``"sync_read"`` (Feetech STS),
        ``"bulk_read"`` (Dynamixel MX) or ``"single"`` (one READ per servo: AX, SCS); the
        values of :class:`drivers.protocol1.wire_time.ReadMethod`."""
        if self.sync_read:
            return "sync_read"
        return "bulk_read" if self.bulk_read else "single"

    def baud_code(self, baud: int) -> int:
        """The register value for ``baud`` bit/s; ValueError if the family has none."""
        for code, rate in self.baud_rates.items():
            if rate == baud:
                return code
        raise ValueError(f"{self.name}: no baud code for {baud} bit/s")


def _dxl_bauds() -> dict[int, int]:
    """Baud Rate value -> the rate it stands for. The servo runs at 2 000 000 / (value + 1)
    (e-Manual); the e-Manual's table names the standard rate each value is meant for (34:
    57 142.9 bps for 57 600, 16: 117 647.1 for 115 200), and a host at that rate is heard."""
    return {
        1: 1_000_000, 3: 500_000, 4: 400_000, 7: 250_000, 9: 200_000,
        16: 115_200, 34: 57_600, 103: 19_200, 207: 9_600,
    }  # fmt: skip


_FEETECH_BAUDS = {  # LeRobot STS_SMS_SERIES_BAUDRATE_TABLE / SCS_SERIES_BAUDRATE_TABLE
    0: 1_000_000,
    1: 500_000,
    2: 250_000,
    3: 128_000,
    4: 115_200,
    5: 57_600,
    6: 38_400,
    7: 19_200,
}

DXL_P1 = Family(
    "Dynamixel P1", "dynamixel-p1", False, DxlP1Error, 2, 1, _dxl_bauds(), False, False, False
)
DXL_MX_P1 = replace(DXL_P1, name="Dynamixel MX (P1)", bulk_read=True)
#: Feetech Response_Status_Level: 0 = answer READ and PING only, 1 = answer all.
FEETECH_STS = Family(
    "Feetech STS/SMS", "feetech", False, FeetechError, 1, 0, _FEETECH_BAUDS, True, False, True
)
FEETECH_SCS = replace(FEETECH_STS, name="Feetech SCS", big_endian=True, sync_read=False)
FAMILIES = (DXL_P1, DXL_MX_P1, FEETECH_STS, FEETECH_SCS)


@dataclass(frozen=True)
class ControlTable:
    """One model. ``resolution``: position steps per ``range_deg``; ``speed_unit_rpm``: rpm per
    unit of the speed registers; ``no_load_rpm``: top speed at nominal voltage; ``volts``:
    Present Voltage at power-up (0.1 V units)."""

    model: str
    family: Family
    model_number: int
    items: tuple[Item, ...]
    source: str
    resolution: int
    range_deg: float
    speed_unit_rpm: float
    no_load_rpm: float
    volts: int
    firmware: int
    by_name: dict[str, Item] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "by_name", {i.name: i for i in self.items})

    def item(self, name: str) -> Item:
        """The item called ``name``; KeyError naming the model if it has none."""
        try:
            return self.by_name[name]
        except KeyError:
            raise KeyError(f"{self.model} has no {name!r}") from None

    def has(self, name: str) -> bool:
        return name in self.by_name

    @property
    def last_address(self) -> int:
        return max(i.end for i in self.items) - 1

    @property
    def deg_per_step(self) -> float:
        """Degrees of one position step: 300/1024 (AX, SCS0009), 360/4096 (MX, STS3215)."""
        return self.range_deg / self.resolution

    @property
    def steps_per_rev(self) -> float:
        """Position steps in one turn of the horn."""
        return self.resolution * 360.0 / self.range_deg


def _items(big: bool, rows: list[Row]) -> tuple[Item, ...]:
    """Rows ``(name, addr, size, access, eeprom, default, lo, hi[, sign_bit])``."""
    out = []
    for row in rows:
        name, addr, size, access, eeprom, default, lo, hi, *sb = row
        out.append(
            Item(name, addr, size, access, eeprom, default, lo, hi, sb[0] if sb else None, big)
        )
    return tuple(out)


E, R = True, False  # EEPROM / RAM
#: A row of a table as written below: name, addr, size, access, eeprom, default, lo, hi[, sign].
Row = tuple[Any, ...]
_DXL_EEPROM = [
    ("Model Number", 0, 2, "R", E, None, 0, 65535),
    ("Firmware Version", 2, 1, "R", E, None, 0, 255),
    ("ID", 3, 1, "RW", E, 1, 0, 253),
    ("Baud Rate", 4, 1, "RW", E, 1, 0, 254),
    ("Return Delay Time", 5, 1, "RW", E, 250, 0, 254),
    ("CW Angle Limit", 6, 2, "RW", E, 0, 0, 1023),
    ("CCW Angle Limit", 8, 2, "RW", E, 1023, 0, 1023),
    ("Temperature Limit", 11, 1, "RW", E, 70, 0, 150),
    ("Min Voltage Limit", 12, 1, "RW", E, 60, 50, 160),
    ("Max Voltage Limit", 13, 1, "RW", E, 140, 50, 160),
    ("Max Torque", 14, 2, "RW", E, 1023, 0, 1023),
    ("Status Return Level", 16, 1, "RW", E, 2, 0, 2),
    ("Alarm LED", 17, 1, "RW", E, 36, 0, 127),
    ("Shutdown", 18, 1, "RW", E, 36, 0, 127),
]
_DXL_RAM_HEAD = [
    ("Torque Enable", 24, 1, "RW", R, 0, 0, 1),
    ("LED", 25, 1, "RW", R, 0, 0, 1),
]
_DXL_RAM_TAIL = [
    ("Goal Position", 30, 2, "RW", R, None, 0, 1023),
    ("Moving Speed", 32, 2, "RW", R, 0, 0, 2047),  # bit 10: wheel-mode direction
    ("Torque Limit", 34, 2, "RW", R, None, 0, 1023),  # power-up: Max Torque
    ("Present Position", 36, 2, "R", R, None, 0, 1023),
    ("Present Speed", 38, 2, "R", R, 0, 0, 2047, 10),
    ("Present Load", 40, 2, "R", R, 0, 0, 2047, 10),
    ("Present Voltage", 42, 1, "R", R, None, 0, 255),
    ("Present Temperature", 43, 1, "R", R, None, 0, 255),
    ("Registered", 44, 1, "R", R, 0, 0, 1),
    ("Moving", 46, 1, "R", R, 0, 0, 1),
    ("Lock", 47, 1, "RW", R, 0, 0, 1),
    ("Punch", 48, 2, "RW", R, 32, 0, 1023),
]
_AX_COMPLIANCE = [
    ("CW Compliance Margin", 26, 1, "RW", R, 1, 0, 255),
    ("CCW Compliance Margin", 27, 1, "RW", R, 1, 0, 255),
    ("CW Compliance Slope", 28, 1, "RW", R, 32, 0, 254),
    ("CCW Compliance Slope", 29, 1, "RW", R, 32, 0, 254),
]


def _with(rows: list[Row], **changes: Row) -> list[Row]:
    """``rows`` with the rows named in ``changes`` (spaces as underscores) replaced."""
    out = []
    for row in rows:
        new = changes.get(row[0].replace(" ", "_"))
        out.append(new if new is not None else row)
    return out


def _ax(model: str, number: int, temp_limit: int, rpm: float, page: str) -> ControlTable:
    rows = _with(
        _DXL_EEPROM, Temperature_Limit=("Temperature Limit", 11, 1, "RW", E, temp_limit, 0, 150)
    )
    return ControlTable(
        model, DXL_P1, number, _items(False, rows + _DXL_RAM_HEAD + _AX_COMPLIANCE + _DXL_RAM_TAIL),
        page, 1024, 300.0, 0.111, rpm, 120, 24,
    )  # fmt: skip


def _mx(
    model: str, number: int, vmax: int, rpm: float, extra: list[Row], page: str
) -> ControlTable:
    eeprom = [
        *_with(
            _DXL_EEPROM,
            Baud_Rate=("Baud Rate", 4, 1, "RW", E, 34, 0, 254),
            CW_Angle_Limit=("CW Angle Limit", 6, 2, "RW", E, 0, 0, 4095),
            CCW_Angle_Limit=("CCW Angle Limit", 8, 2, "RW", E, 4095, 0, 4095),
            Temperature_Limit=("Temperature Limit", 11, 1, "RW", E, 80, 0, 150),
            Max_Voltage_Limit=("Max Voltage Limit", 13, 1, "RW", E, vmax, 50, 250),
            Min_Voltage_Limit=("Min Voltage Limit", 12, 1, "RW", E, 60, 50, 250),
        ),
        ("Multi Turn Offset", 20, 2, "RW", E, 0, 0, 65535),
        ("Resolution Divider", 22, 1, "RW", E, 1, 1, 4),
    ]
    gains = [
        ("D Gain", 26, 1, "RW", R, 0, 0, 254),
        ("I Gain", 27, 1, "RW", R, 0, 0, 254),
        ("P Gain", 28, 1, "RW", R, 32, 0, 254),
    ]
    tail = [
        *_with(
            _DXL_RAM_TAIL,
            Goal_Position=("Goal Position", 30, 2, "RW", R, None, 0, 4095),
            Present_Position=("Present Position", 36, 2, "R", R, None, 0, 4095),
            Punch=("Punch", 48, 2, "RW", R, 0, 0, 1023),
        ),
        ("Realtime Tick", 50, 2, "R", R, 0, 0, 32767),
        *extra,
        ("Goal Acceleration", 73, 1, "RW", R, 0, 0, 254),
    ]
    return ControlTable(
        model, DXL_MX_P1, number, _items(False, eeprom + _DXL_RAM_HEAD + gains + tail),
        page, 4096, 360.0, 0.114, rpm, 120, 41,
    )  # fmt: skip


_MX_CURRENT = [
    ("Current", 68, 2, "RW", R, 2048, 0, 4095),
    ("Torque Ctrl Mode Enable", 70, 1, "RW", R, 0, 0, 1),
    ("Goal Torque", 71, 2, "RW", R, 0, 0, 2047),
]

_EMANUAL = "ROBOTIS e-Manual (github:ROBOTIS-GIT/emanual) "
AX_12A = _ax("AX-12A", 12, 70, 59.0, _EMANUAL + "docs/en/dxl/ax/ax-12a.md @07fe860b (table read)")
AX_18A = _ax("AX-18A", 18, 75, 97.0, _EMANUAL + "docs/en/dxl/ax/ax-18a.md (the AX-12A layout)")
MX_28 = _mx(
    "MX-28", 29, 160, 55.0, [], _EMANUAL + "docs/en/dxl/mx/mx-28.md (MX-64 layout less 68-71)"
)
MX_64 = _mx(
    "MX-64",
    310,
    240,
    63.0,
    _MX_CURRENT,
    _EMANUAL + "docs/en/dxl/mx/mx-64.md @01179568 (table read)",
)
MX_106 = _mx(
    "MX-106", 320, 240, 45.0, _MX_CURRENT, _EMANUAL + "docs/en/dxl/mx/mx-106.md (MX-64 layout)"
)

_FEETECH_HEAD = [
    ("Firmware Major Version", 0, 1, "R", E, None, 0, 255),
    ("Firmware Minor Version", 1, 1, "R", E, None, 0, 255),
    ("Model Number", 3, 2, "R", E, None, 0, 65535),
    ("ID", 5, 1, "RW", E, 1, 0, 253),
    ("Baud Rate", 6, 1, "RW", E, 0, 0, 7),
    ("Return Delay Time", 7, 1, "RW", E, 250, 0, 254),
    ("Response Status Level", 8, 1, "RW", E, 1, 0, 1),
    ("Min Position Limit", 9, 2, "RW", E, 0, 0, 4095),
    ("Max Position Limit", 11, 2, "RW", E, 4095, 0, 4095),
    ("Max Temperature Limit", 13, 1, "RW", E, 70, 0, 100),
    ("Max Voltage Limit", 14, 1, "RW", E, 80, 0, 254),
    ("Min Voltage Limit", 15, 1, "RW", E, 40, 0, 254),
    ("Max Torque Limit", 16, 2, "RW", E, 1000, 0, 1000),
    ("Phase", 18, 1, "RW", E, 12, 0, 254),
    ("Unloading Condition", 19, 1, "RW", E, 44, 0, 254),
    ("LED Alarm Condition", 20, 1, "RW", E, 47, 0, 254),
    ("P Coefficient", 21, 1, "RW", E, 32, 0, 254),
    ("D Coefficient", 22, 1, "RW", E, 32, 0, 254),
    ("I Coefficient", 23, 1, "RW", E, 0, 0, 254),
    ("Minimum Startup Force", 24, 2, "RW", E, 16, 0, 1000),
    ("CW Dead Zone", 26, 1, "RW", E, 1, 0, 32),
    ("CCW Dead Zone", 27, 1, "RW", E, 1, 0, 32),
]
_STS_ROWS = [
    *_FEETECH_HEAD,
    ("Protection Current", 28, 2, "RW", E, 500, 0, 511),
    ("Angular Resolution", 30, 1, "RW", E, 1, 1, 3),
    ("Homing Offset", 31, 2, "RW", E, 0, 0, 4095, 11),
    ("Operating Mode", 33, 1, "RW", E, 0, 0, 3),
    ("Protective Torque", 34, 1, "RW", E, 20, 0, 100),
    ("Protection Time", 35, 1, "RW", E, 200, 0, 254),
    ("Overload Torque", 36, 1, "RW", E, 80, 0, 100),
    ("Speed P Coefficient", 37, 1, "RW", E, 10, 0, 100),
    ("Over Current Protection Time", 38, 1, "RW", E, 200, 0, 254),
    ("Speed I Coefficient", 39, 1, "RW", E, 10, 0, 254),
    ("Torque Enable", 40, 1, "RW", R, 0, 0, 2),
    ("Acceleration", 41, 1, "RW", R, 0, 0, 254),
    ("Goal Position", 42, 2, "RW", R, None, 0, 32767, 15),
    ("Goal Time", 44, 2, "RW", R, 0, 0, 65535),
    ("Goal Speed", 46, 2, "RW", R, 0, 0, 32767, 15),
    ("Torque Limit", 48, 2, "RW", R, None, 0, 1000),  # power-up: Max Torque Limit
    ("Lock", 55, 1, "RW", R, 1, 0, 1),
    ("Present Position", 56, 2, "R", R, None, 0, 65535, 15),
    ("Present Speed", 58, 2, "R", R, 0, 0, 65535, 15),
    ("Present Load", 60, 2, "R", R, 0, 0, 65535, 10),
    ("Present Voltage", 62, 1, "R", R, None, 0, 255),
    ("Present Temperature", 63, 1, "R", R, None, 0, 255),
    ("Async Write Flag", 64, 1, "R", R, 0, 0, 1),
    ("Status", 65, 1, "R", R, 0, 0, 255),
    ("Moving", 66, 1, "R", R, 0, 0, 1),
    ("Present Current", 69, 2, "R", R, 0, 0, 65535),
]
_SCS_ROWS = [
    *_FEETECH_HEAD,
    ("Protective Torque", 37, 1, "RW", E, 20, 0, 100),
    ("Protection Time", 38, 1, "RW", E, 200, 0, 254),
    ("Torque Enable", 40, 1, "RW", R, 0, 0, 1),
    ("Goal Position", 42, 2, "RW", R, None, 0, 1023),
    ("Running Time", 44, 2, "RW", R, 0, 0, 65535),
    ("Goal Speed", 46, 2, "RW", R, 0, 0, 1000),
    ("Lock", 48, 1, "RW", R, 1, 0, 1),
    ("Present Position", 56, 2, "R", R, None, 0, 1023),
    ("Present Speed", 58, 2, "R", R, 0, 0, 65535, 15),
    ("Present Load", 60, 2, "R", R, 0, 0, 65535, 10),
    ("Present Voltage", 62, 1, "R", R, None, 0, 255),
    ("Present Temperature", 63, 1, "R", R, None, 0, 255),
    ("Async Write Flag", 64, 1, "R", R, 0, 0, 1),
    ("Status", 65, 1, "R", R, 0, 0, 255),
    ("Moving", 66, 1, "R", R, 0, 0, 1),
]
_SCS_ROWS = _with(
    _SCS_ROWS,
    Min_Position_Limit=("Min Position Limit", 9, 2, "RW", E, 0, 0, 1023),
    Max_Position_Limit=("Max Position Limit", 11, 2, "RW", E, 1023, 0, 1023),
)
_LEROBOT = "LeRobot src/lerobot/motors/feetech/tables.py @0558acc9 (from Feetech's e-manual) "
STS3215 = ControlTable(
    "STS3215", FEETECH_STS, 777, _items(False, _STS_ROWS),
    _LEROBOT + "STS_SMS_SERIES_CONTROL_TABLE; sign bits: Feetech SDK sms_sts", 4096, 360.0,
    0.0146, 45.0, 74, 3,
)  # fmt: skip
SCS0009 = ControlTable(
    "SCS0009", FEETECH_SCS, 1284, _items(True, _SCS_ROWS),
    _LEROBOT + "SCS_SERIES_CONTROL_TABLE", 1024, 300.0, 0.0146 * 4, 55.0, 50, 3,
)  # fmt: skip

TABLES: dict[str, ControlTable] = {
    t.model: t for t in (AX_12A, AX_18A, MX_28, MX_64, MX_106, STS3215, SCS0009)
}
#: Names people write for the same model.
ALIASES = {"ST3215": "STS3215", "STS-3215": "STS3215", "AX-12": "AX-12A", "AX-12+": "AX-12A"}


def table_for(model: str) -> ControlTable:
    """The table of ``model`` (case-insensitive, aliases allowed); ValueError listing the
    models there are."""
    key = model.strip().upper()
    key = ALIASES.get(key, key)
    for name, table in TABLES.items():
        if name.upper() == key:
            return table
    raise ValueError(f"unknown Protocol 1.0 servo model {model!r}; known: {', '.join(TABLES)}")


def table_for_number(model_number: int) -> ControlTable | None:
    """The table whose Model Number is ``model_number`` (what a PING/READ of address 0 or 3
    returns), or None."""
    for table in TABLES.values():
        if table.model_number == model_number:
            return table
    return None


def is_protocol1_model(model: str) -> bool:
    """True if ``model`` names one of :data:`TABLES` (or an alias)."""
    try:
        table_for(model)
    except ValueError:
        return False
    return True
