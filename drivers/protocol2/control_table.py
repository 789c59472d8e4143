"""The host-side view of the X-series control table: the addresses the driver uses, as data.

Only what the driver reads or writes is here (Protocol 2.0, X series; identical addresses
on X330/X430/X540). Values are little endian, two's complement when ``signed``. This
module is data and tiny lookups; it imports neither ``dynamixel_sdk`` nor the emulator,
so the driver stands without :mod:`drivers.dxlsim`.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, IntFlag


@dataclass(frozen=True, slots=True)
class Item:
    """One control-table item: ``addr`` and ``size`` in bytes (1, 2 or 4)."""

    name: str
    addr: int
    size: int
    signed: bool = False

    @property
    def end(self) -> int:
        """First address after the item."""
        return self.addr + self.size

    def decode(self, block: bytes | bytearray, start: int = 0) -> int:
        """The item's value from ``block``, a read that began at address ``start``."""
        i = self.addr - start
        return int.from_bytes(block[i : i + self.size], "little", signed=self.signed)

    def encode(self, value: int) -> bytes:
        """``value`` as the item's little-endian bytes (wraps like the wire does)."""
        return (int(value) & ((1 << (8 * self.size)) - 1)).to_bytes(self.size, "little")


MODEL_NUMBER = Item("Model Number", 0, 2)
FIRMWARE_VERSION = Item("Firmware Version", 6, 1)
ID = Item("ID", 7, 1)
BAUD_RATE = Item("Baud Rate", 8, 1)
RETURN_DELAY_TIME = Item("Return Delay Time", 9, 1)  # unit 2 µs
DRIVE_MODE = Item("Drive Mode", 10, 1)
OPERATING_MODE = Item("Operating Mode", 11, 1)
HOMING_OFFSET = Item("Homing Offset", 20, 4, signed=True)
VELOCITY_LIMIT = Item("Velocity Limit", 44, 4)
MAX_POSITION_LIMIT = Item("Max Position Limit", 48, 4)
MIN_POSITION_LIMIT = Item("Min Position Limit", 52, 4)
SHUTDOWN = Item("Shutdown", 63, 1)
TORQUE_ENABLE = Item("Torque Enable", 64, 1)
LED = Item("LED", 65, 1)
STATUS_RETURN_LEVEL = Item("Status Return Level", 68, 1)
HARDWARE_ERROR_STATUS = Item("Hardware Error Status", 70, 1)
BUS_WATCHDOG = Item("Bus Watchdog", 98, 1, signed=True)  # reads -1 once tripped
GOAL_POSITION = Item("Goal Position", 116, 4, signed=True)
PRESENT_VELOCITY = Item("Present Velocity", 128, 4, signed=True)
PRESENT_POSITION = Item("Present Position", 132, 4, signed=True)
PRESENT_LOAD = Item("Present Load", 126, 2, signed=True)  # current (mA units) on XM, 0.1 % on XL
PRESENT_INPUT_VOLTAGE = Item("Present Input Voltage", 144, 2)  # 0.1 V
PRESENT_TEMPERATURE = Item("Present Temperature", 146, 1)  # °C
#: Indirect Address n (2 bytes) holds the address that Indirect Data n (1 byte) stands for;
#: two blocks of 28, n = 1..28 and 29..56 (e-Manual X-series control tables).
INDIRECT_ADDRESS_1 = Item("Indirect Address 1", 168, 2)
INDIRECT_DATA_1 = Item("Indirect Data 1", 224, 1)
INDIRECT_ADDRESS_29 = Item("Indirect Address 29", 578, 2)
INDIRECT_DATA_29 = Item("Indirect Data 29", 634, 1)
INDIRECT_COUNT = 56


def indirect_address(n: int) -> Item:
    """Indirect Address ``n`` (1..56): 168, 170, ... 222, then 578, 580, ... 632."""
    first = _indirect_block(n)
    base = INDIRECT_ADDRESS_1 if first == 1 else INDIRECT_ADDRESS_29
    return Item(f"Indirect Address {n}", base.addr + 2 * (n - first), 2)


def indirect_data(n: int) -> Item:
    """Indirect Data ``n`` (1..56): 224, 225, ... 251, then 634, 635, ... 661."""
    first = _indirect_block(n)
    base = INDIRECT_DATA_1 if first == 1 else INDIRECT_DATA_29
    return Item(f"Indirect Data {n}", base.addr + n - first, 1)


def _indirect_block(n: int) -> int:
    if not 1 <= n <= INDIRECT_COUNT:
        raise ValueError(f"indirect index must be 1..{INDIRECT_COUNT}, got {n}")
    return 1 if n <= INDIRECT_COUNT // 2 else INDIRECT_COUNT // 2 + 1


#: X330 servos have 20 indirect pairs: Indirect Address 1-20 at 168-206, Indirect Data 1-20
#: at 208-227 (e-Manual XL330/XC330 control tables); the others' Indirect Data 1 is at 224.
X330_INDIRECT_DATA_1 = 208


def indirect_data_1(model: str) -> int:
    """Address of Indirect Data 1 on ``model`` (a model name)."""
    return X330_INDIRECT_DATA_1 if series(model) == "X330" else INDIRECT_DATA_1.addr


#: What the tick's one read returns through Indirect Data 1..7 once the start-up check has
#: written Indirect Address 1..7: Present Position, then a byte each of Torque Enable, Bus
#: Watchdog and Status Return Level. The last reads 2 while the block is set (the start-up
#: check requires 2) and 0 once a brownout or reboot has put the Indirect Addresses back at
#: their defaults (each Indirect Data then reads its own 0). Hardware Error Status is not
#: in it: every reply's Alert bit (ERR 0x80) already says it is not 0.
TICK_BLOCK = (PRESENT_POSITION, TORQUE_ENABLE, BUS_WATCHDOG, STATUS_RETURN_LEVEL)
TICK_BLOCK_SIZE = sum(item.size for item in TICK_BLOCK)


def tick_block_targets() -> bytes:
    """Indirect Address 1..7 as one 14-byte write: each byte's address, little-endian."""
    addrs = [item.addr + b for item in TICK_BLOCK for b in range(item.size)]
    return b"".join(a.to_bytes(2, "little") for a in addrs)


#: One Read from address 0 of this many bytes covers every item the start-up check needs
#: (EEPROM, Torque Enable, Status Return Level, Hardware Error, Bus Watchdog, Goal and
#: Present Position). Gaps read as 0.
STARTUP_BLOCK = Item("start-up block", 0, PRESENT_POSITION.end)
#: What a periodic health read covers (Torque Enable .. Hardware Error Status, 7 bytes: it
#: must fit in the spare part of a tick behind a 1 ms USB latency timer)
HEALTH_BLOCK = Item(
    "health block", TORQUE_ENABLE.addr, HARDWARE_ERROR_STATUS.end - TORQUE_ENABLE.addr
)
#: ... and up to the Bus Watchdog (35 bytes), read after a bus silence or to name a cause
HEALTH_WATCHDOG_BLOCK = Item(
    "health block with watchdog", TORQUE_ENABLE.addr, BUS_WATCHDOG.end - TORQUE_ENABLE.addr
)
#: Present Load .. Present Temperature (21 bytes): what a hardware-error stop records, and
#: the periodic condition read (temperature, voltage, load)
CONDITION_BLOCK = Item(
    "condition block", PRESENT_LOAD.addr, PRESENT_TEMPERATURE.end - PRESENT_LOAD.addr
)

#: Addresses below this are EEPROM: writes are refused (Access Error) while torque is on.
EEPROM_END = 64
#: Return Delay Time unit, s.
RETURN_DELAY_UNIT_S = 2e-6
#: Bus Watchdog unit, s; 1..127 arms it, 0 disarms and clears a trip, -1 reads "tripped".
WATCHDOG_UNIT_S = 0.020
WATCHDOG_MAX_UNITS = 127
WATCHDOG_TRIPPED = -1
#: Goal Position range in Extended Position / Current-based Position Control Mode, ticks.
EXTENDED_GOAL_LIMIT = 1_048_575
#: Status Return Level (68): 0 answers Ping only, 1 Ping and Read, 2 everything.
STATUS_RETURN_ALL = 2

#: Baud Rate (addr 8) index -> bit/s. X330 accepts indices 0..6, X430/X540 0..7.
BAUD_RATES: dict[int, int] = {
    0: 9_600,
    1: 57_600,
    2: 115_200,
    3: 1_000_000,
    4: 2_000_000,
    5: 3_000_000,
    6: 4_000_000,
    7: 4_500_000,
}
BAUD_INDEX: dict[int, int] = {bps: i for i, bps in BAUD_RATES.items()}


def check_unicast_id(servo_id: int) -> None:
    """ValueError unless ``servo_id`` can be addressed alone (0..252; 254 is broadcast)."""
    if not 0 <= servo_id <= 252:
        raise ValueError(f"servo ID must be 0..252, got {servo_id}")


class OperatingMode(IntEnum):
    """Operating Mode (addr 11)."""

    CURRENT = 0
    VELOCITY = 1
    POSITION = 3
    EXTENDED_POSITION = 4
    CURRENT_BASED_POSITION = 5
    PWM = 16


#: Modes in which Goal Position is obeyed.
POSITION_MODES = frozenset(
    {
        OperatingMode.POSITION,
        OperatingMode.EXTENDED_POSITION,
        OperatingMode.CURRENT_BASED_POSITION,
    }
)


class HardwareError(IntFlag):
    """Bits of Hardware Error Status (addr 70); latched until Reboot."""

    INPUT_VOLTAGE = 0x01
    OVERHEATING = 0x04
    MOTOR_ENCODER = 0x08
    ELECTRICAL_SHOCK = 0x10
    OVERLOAD = 0x20


def describe_hardware_error(bits: int) -> str:
    """``0x24`` -> ``"overheating, overload"``; unknown bits are shown in hex."""
    names = [name.lower() for name, f in HardwareError.__members__.items() if bits & f]
    rest = bits & ~sum(HardwareError)
    if rest:
        names.append(f"0x{rest:02X}")
    return ", ".join(names) or "none"


#: Status packet ERR byte: bit 7 is the Alert bit (Hardware Error Status is non-zero).
ALERT_BIT = 0x80
ERROR_NUMBER_MASK = 0x7F


class StatusError(IntEnum):
    """The error number in bits 0-6 of a status packet's ERR byte."""

    NONE = 0
    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


_ERROR_TEXT = {
    StatusError.NONE: "no error",
    StatusError.RESULT_FAIL: "Result Fail",
    StatusError.INSTRUCTION: "Instruction Error",
    StatusError.CRC: "CRC Error",
    StatusError.DATA_RANGE: "Data Range Error",
    StatusError.DATA_LENGTH: "Data Length Error",
    StatusError.DATA_LIMIT: "Data Limit Error",
    StatusError.ACCESS: "Access Error",
}


def error_name(number: int) -> str:
    """Readable name of a status error number (bits 0-6 of ERR)."""
    try:
        return _ERROR_TEXT[StatusError(number)]
    except ValueError:
        return f"unknown error {number}"


#: Model Number (addr 0) -> model name.
MODEL_NAMES: dict[int, str] = {
    1000: "XH430-W350",
    1010: "XH430-W210",
    1020: "XM430-W350",
    1030: "XM430-W210",
    1040: "XH430-V350",
    1050: "XH430-V210",
    1060: "XL430-W250",
    1070: "XC430-W150",
    1080: "XC430-W240",
    1090: "2XL430-W250",
    1120: "XM540-W270",
    1130: "XM540-W150",
    1190: "XL330-M077",
    1200: "XL330-M288",
    1210: "XC330-T181",
    1220: "XC330-T288",
    1230: "XC330-M181",
    1240: "XC330-M288",
}
MODEL_NUMBERS: dict[str, int] = {name: number for number, name in MODEL_NAMES.items()}

#: No-load speed (rpm) at the recommended voltage, per model: the e-Manual's figure
#: (``github:ROBOTIS-GIT/emanual`` ``_data/dxl_x_info.yml``), as the emulator's
#: :data:`drivers.dxlsim.model_data.MODEL_DATA` has it (a test holds the two equal). A
#: command faster than this cannot be followed, even unloaded.
NO_LOAD_SPEED_RPM: dict[str, float] = {
    "XM430-W350": 46.0,
    "XM430-W210": 77.0,
    "XH430-W350": 30.0,
    "XH430-W210": 50.0,
    "XH430-V350": 31.0,
    "XH430-V210": 52.0,
    "XL430-W250": 57.0,
    "2XL430-W250": 57.0,
    "XC430-W150": 106.0,
    "XC430-W240": 70.0,
    "XM540-W270": 30.0,
    "XM540-W150": 53.0,
    "XL330-M288": 103.0,
    "XL330-M077": 383.0,
    "XC330-M181": 129.0,
    "XC330-M288": 81.0,
    "XC330-T181": 104.0,
    "XC330-T288": 65.0,
}

#: What Present Load (126) holds per model: the current in this many mA per unit (signed),
#: or None where it is Present Load proper (0.1 % of the maximum torque, signed); the
#: e-Manual's figures, as the emulator's MODEL_DATA has them (a test holds the two equal)
LOAD_REGISTER_MA: dict[str, float | None] = {
    "XM430-W350": 2.69,
    "XM430-W210": 2.69,
    "XH430-W350": 2.69,
    "XH430-W210": 2.69,
    "XH430-V350": 1.34,
    "XH430-V210": 1.34,
    "XL430-W250": None,
    "2XL430-W250": None,
    "XC430-W150": None,
    "XC430-W240": None,
    "XM540-W270": 2.69,
    "XM540-W150": 2.69,
    "XL330-M288": 1.0,
    "XL330-M077": 1.0,
    "XC330-M181": 1.0,
    "XC330-M288": 1.0,
    "XC330-T181": 1.0,
    "XC330-T288": 1.0,
}


def no_load_speed_deg_s(name: str) -> float | None:
    """A model's no-load speed in °/s (``"XM430-W350"`` -> 276.0), None if unknown."""
    try:
        rpm = NO_LOAD_SPEED_RPM.get(MODEL_NAMES[model_number(name)])
    except ValueError:
        return None
    return None if rpm is None else rpm * 6.0


#: Lowest firmware (addr 6) with Fast Sync/Bulk Read, by series (name prefix).
FAST_READ_MIN_FIRMWARE: dict[str, int] = {"X330": 46, "X430": 45, "X540": 45}


def model_name(number: int) -> str:
    """``1020`` -> ``"XM430-W350"``; unknown numbers -> ``"unknown model 1234"``."""
    return MODEL_NAMES.get(number, f"unknown model {number}")


def model_number(name: str) -> int:
    """``"xm430-w350"`` (case-insensitive, ``-T``/``-R`` suffix allowed) -> ``1020``.

    Raises ValueError listing the known models.
    """
    key = name.strip().upper()
    for suffix in ("-T", "-R"):
        if key.endswith(suffix) and key[: -len(suffix)] in MODEL_NUMBERS:
            key = key[: -len(suffix)]
    try:
        return MODEL_NUMBERS[key]
    except KeyError:
        known = ", ".join(f"{n} ({m})" for m, n in MODEL_NAMES.items())
        raise ValueError(f"unknown servo model {name!r}; known: {known}") from None


def series(name: str) -> str:
    """``"XM430-W350"`` -> ``"X430"`` (``"2XL430-W250"`` too): the family that sets firmware
    features."""
    core = name.lstrip("0123456789")
    return "X" + core[2:5] if len(core) >= 5 and core.startswith("X") else name


def fast_read_min_firmware(number: int) -> int | None:
    """Lowest firmware with Fast Sync Read for this Model Number, None if unknown."""
    name = MODEL_NAMES.get(number)
    return None if name is None else FAST_READ_MIN_FIRMWARE.get(series(name))


def supports_fast_read(number: int, firmware: int) -> bool:
    """True when a servo of this Model Number and firmware answers Fast Sync Read."""
    least = fast_read_min_firmware(number)
    return least is not None and firmware >= least
