"""The control table of one virtual servo: values by address, Read, Write validation, Alert.

A :class:`RegisterFile` holds the stored values (``values``, address -> int) and answers
Read spans, including the registers computed on read (``dynamic``: address -> getter,
filled in by the servo). :meth:`RegisterFile.validate` checks a Write against the field
table and the present values and returns what to store; applying it (and its side
effects on motion and the watchdog) is the servo's job.

Choices where the e-Manual is silent or ambiguous (all deliberate, all tested):

- Read of a span with gaps returns 0 for the undefined bytes (as a real X-series
  returns reserved data); a read reaching past the last field (addr 146) is an Access
  Error; a read may start or end inside a field (its bytes are sliced). Length 0 is a
  Data Length Error. An erroneous read returns ``(err, b"")``.
- Write: atomic; checks per field in address order: undefined/read-only/EEPROM with
  torque on -> Access Error 7, partial multi-byte field -> Data Length Error 5, own
  range -> Data Range Error 4 (also every goal register while the Bus Watchdog is
  tripped, and a non-zero Bus Watchdog value while tripped), cross-field limits ->
  Data Limit Error 6. Profile Velocity above Velocity Limit is accepted and capped at
  use. Torque Enable 1 while ``Hardware Error Status & Shutdown`` is non-zero is
  refused with Result Fail 1 (the errors that cut torque keep it off until Reboot).

Addresses are named here once: from :mod:`drivers.protocol2.control_table` where the
host's driver uses the item too, else from the emulator's X-series table.
"""

from __future__ import annotations

from collections.abc import Callable

import drivers.protocol2.control_table as ct
from drivers.protocol2.control_table import ALERT_BIT, OperatingMode, StatusError

from .models import EEPROM_END, X_ADDRESSES, Field, ServoModel

ALERT = ALERT_BIT  # bit 7 of the ERR byte: Hardware Error Status is not 0
MASKS = {1: 0xFF, 2: 0xFFFF, 4: 0xFFFFFFFF}

# --- addresses (X series) -----------------------------------------------------------------
MODEL_NUMBER = ct.MODEL_NUMBER.addr
FIRMWARE_VERSION = ct.FIRMWARE_VERSION.addr
ID = ct.ID.addr
BAUD_RATE = ct.BAUD_RATE.addr
RETURN_DELAY_TIME = ct.RETURN_DELAY_TIME.addr
OPERATING_MODE = ct.OPERATING_MODE.addr
SECONDARY_ID = X_ADDRESSES["secondary_id"]
HOMING_OFFSET = ct.HOMING_OFFSET.addr
MOVING_THRESHOLD = X_ADDRESSES["moving_threshold"]
TEMPERATURE_LIMIT = X_ADDRESSES["temperature_limit"]
MAX_VOLTAGE_LIMIT = X_ADDRESSES["max_voltage_limit"]
MIN_VOLTAGE_LIMIT = X_ADDRESSES["min_voltage_limit"]
PWM_LIMIT = X_ADDRESSES["pwm_limit"]
CURRENT_LIMIT = X_ADDRESSES["current_limit"]
VELOCITY_LIMIT = ct.VELOCITY_LIMIT.addr
MAX_POSITION_LIMIT = ct.MAX_POSITION_LIMIT.addr
MIN_POSITION_LIMIT = ct.MIN_POSITION_LIMIT.addr
SHUTDOWN = ct.SHUTDOWN.addr
TORQUE_ENABLE = ct.TORQUE_ENABLE.addr
STATUS_RETURN_LEVEL = ct.STATUS_RETURN_LEVEL.addr
REGISTERED_INSTRUCTION = X_ADDRESSES["registered_instruction"]
HARDWARE_ERROR_STATUS = ct.HARDWARE_ERROR_STATUS.addr
BUS_WATCHDOG = ct.BUS_WATCHDOG.addr
GOAL_PWM = X_ADDRESSES["goal_pwm"]
GOAL_CURRENT = X_ADDRESSES["goal_current"]
GOAL_VELOCITY = X_ADDRESSES["goal_velocity"]
PROFILE_ACCELERATION = X_ADDRESSES["profile_acceleration"]
PROFILE_VELOCITY = X_ADDRESSES["profile_velocity"]
GOAL_POSITION = ct.GOAL_POSITION.addr
REALTIME_TICK = X_ADDRESSES["realtime_tick"]
MOVING = X_ADDRESSES["moving"]
MOVING_STATUS = X_ADDRESSES["moving_status"]
PRESENT_PWM = X_ADDRESSES["present_pwm"]
PRESENT_CURRENT = ct.PRESENT_LOAD.addr  # Present Current on XM, Present Load on XL
PRESENT_VELOCITY = ct.PRESENT_VELOCITY.addr
PRESENT_POSITION = ct.PRESENT_POSITION.addr
VELOCITY_TRAJECTORY = X_ADDRESSES["velocity_trajectory"]
POSITION_TRAJECTORY = X_ADDRESSES["position_trajectory"]
PRESENT_INPUT_VOLTAGE = ct.PRESENT_INPUT_VOLTAGE.addr
PRESENT_TEMPERATURE = ct.PRESENT_TEMPERATURE.addr

#: The goal registers: a write to one replans the motion.
GOAL_ADDRS = frozenset((GOAL_PWM, GOAL_CURRENT, GOAL_VELOCITY, GOAL_POSITION))

Updates = list[tuple[Field, int]]


class RegisterFile:
    """The stored control table of one servo of ``model`` (``values``: address -> int)."""

    def __init__(self, model: ServoModel, firmware: int) -> None:
        self.model = model
        self.values: dict[int, int] = {}
        #: registers computed on read: address -> getter (the servo fills this in)
        self.dynamic: dict[int, Callable[[], int]] = {}
        self.reset_eeprom(keep=())
        self.values[FIRMWARE_VERSION] = firmware
        self.reset_ram()

    @property
    def alert(self) -> int:
        """The Alert bit of an error byte: :data:`ALERT` while Hardware Error Status is set."""
        return ALERT if self.values[HARDWARE_ERROR_STATUS] else 0

    def reset_eeprom(self, keep: tuple[int, ...]) -> None:
        """EEPROM fields to their defaults, but those at ``keep`` and the firmware version."""
        for f in self.model.fields:
            if f.addr < EEPROM_END and f.addr not in keep and f.addr != FIRMWARE_VERSION:
                self.values[f.addr] = f.default

    def reset_ram(self) -> None:
        for f in self.model.fields:
            if f.addr >= EEPROM_END:
                self.values[f.addr] = f.default

    # --- Read ------------------------------------------------------------------------------
    def read(self, addr: int, length: int) -> tuple[int, bytes]:
        """``length`` bytes from ``addr``: ``(error number, data)``, data ``b""`` on error.

        Gaps read as 0; a span past the table end is an Access Error; length < 1 a Data
        Length Error. A span may start or end inside a field (its bytes are sliced).
        """
        m = self.model
        f = m.by_addr.get(addr)
        if f is not None and f.size == length:  # the common case: one whole field
            getter = self.dynamic.get(addr)
            value = getter() if getter is not None else self.values[addr]
            return 0, (value & MASKS[length]).to_bytes(length, "little")
        if length < 1:
            return StatusError.DATA_LENGTH, b""
        end = addr + length
        if addr < 0 or end > m.table_end:
            return StatusError.ACCESS, b""
        out = bytearray(length)
        owner = m.byte_owner
        a = addr
        while a < end:
            f = owner[a]
            if f is None:
                a += 1
                continue
            getter = self.dynamic.get(f.addr)
            value = getter() if getter is not None else self.values[f.addr]
            raw = (value & MASKS[f.size]).to_bytes(f.size, "little")
            lo, hi = a - f.addr, min(f.end, end) - f.addr
            out[a - addr : a - addr + hi - lo] = raw[lo:hi]
            a = f.addr + hi
        return 0, bytes(out)

    # --- Write -----------------------------------------------------------------------------
    def validate(self, addr: int, data: bytes) -> tuple[int, Updates]:
        """Check a Write of ``data`` at ``addr``: ``(error number, [(field, value), ...])``.

        Per field in address order: undefined/read-only/EEPROM with torque on -> Access
        Error, partial multi-byte field -> Data Length Error, own range (and every goal
        while the Bus Watchdog is tripped) -> Data Range Error, cross-field limits -> Data
        Limit Error; Torque Enable 1 with a Shutdown error latched -> Result Fail.
        """
        m = self.model
        regs = self.values
        n = len(data)
        f = m.by_addr.get(addr)
        if f is not None and f.size == n:  # one whole field: the Sync Write case
            if not f.writable or (addr < EEPROM_END and regs[TORQUE_ENABLE]):
                return StatusError.ACCESS, []
            updates = [(f, int.from_bytes(data, "little", signed=f.signed))]
        else:
            if n == 0:
                return StatusError.DATA_LENGTH, []
            end = addr + n
            if addr < 0 or end > m.table_end:
                return StatusError.ACCESS, []
            updates = []
            owner = m.byte_owner
            a = addr
            while a < end:
                f = owner[a]
                if f is None or not f.writable or (f.addr < EEPROM_END and regs[TORQUE_ENABLE]):
                    return StatusError.ACCESS, []
                if f.addr != a or f.end > end:
                    return StatusError.DATA_LENGTH, []
                value = int.from_bytes(data[a - addr : f.end - addr], "little", signed=f.signed)
                updates.append((f, value))
                a = f.end
        tripped = regs[BUS_WATCHDOG] == ct.WATCHDOG_TRIPPED
        for f, value in updates:
            if not f.accepts(value):
                return StatusError.DATA_RANGE, []
            if tripped and (f.addr in GOAL_ADDRS or (f.addr == BUS_WATCHDOG and value != 0)):
                return StatusError.DATA_RANGE, []
        for f, value in updates:
            if f.addr in GOAL_ADDRS and not self.within_limits(f.addr, value, updates):
                return StatusError.DATA_LIMIT, []
            if (
                f.addr == TORQUE_ENABLE
                and value
                and not regs[TORQUE_ENABLE]
                and regs[HARDWARE_ERROR_STATUS] & regs[SHUTDOWN]
            ):
                return StatusError.RESULT_FAIL, []
        return StatusError.NONE, updates

    def within_limits(self, addr: int, value: int, updates: Updates) -> bool:
        """Goal registers against the limit registers as they will be after this write."""

        def reg(a: int) -> int:
            for f, v in updates:
                if f.addr == a:
                    return v
            return self.values[a]

        if addr == GOAL_POSITION:
            return reg(OPERATING_MODE) != OperatingMode.POSITION or reg(
                MIN_POSITION_LIMIT
            ) <= value <= reg(MAX_POSITION_LIMIT)
        if addr == GOAL_VELOCITY:
            return abs(value) <= reg(VELOCITY_LIMIT)
        if addr == GOAL_CURRENT:
            return abs(value) <= reg(CURRENT_LIMIT)
        return abs(value) <= reg(PWM_LIMIT)  # Goal PWM
