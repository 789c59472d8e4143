"""The control table of one virtual servo: values by address, Read, Write validation, Alert.

A :class:`RegisterFile` holds the stored values (``values``, address -> int). It answers
Read spans, including registers computed on read (``dynamic``: address -> getter, filled in
by the servo); each span read is compiled once into which field's bytes land where, kept
while its Indirect Addresses stay as they were (:meth:`RegisterFile._plan`; the byte loop
:meth:`RegisterFile._read_span` is the definition). :meth:`RegisterFile.validate` checks a
Write against the field table and the present values, and returns what to store. Applying
it, with its side effects on motion and the watchdog, is the servo's job. It also keeps the
Control Table Backup (:meth:`store_backup`, :meth:`restore_eeprom`, :meth:`boot_ram`).

A Write is atomic, its fields checked in address order: Access Error (7), Data Length Error
(5), Data Range Error (4), then Data Limit Error (6). An erroneous Read returns
``(err, b"")``.

Where the e-Manual is silent, the choices are deliberate and tested: gaps in a Read span,
Indirect Data, Drive Mode bits on old firmware, the backup's contents. ``docs/dxlsim.md``
lists them (choices where the e-Manual is silent).

Addresses are named here once: from :mod:`drivers.protocol2.control_table` where the
host's driver uses the item too, else from the emulator's X-series table.
"""

from __future__ import annotations

from collections.abc import Callable
from operator import itemgetter
from typing import Any

import drivers.protocol2.control_table as ct
from drivers.protocol2.control_table import ALERT_BIT, OperatingMode, StatusError

from .model_data import X_ADDRESSES
from .models import EEPROM_END, Field, ServoModel

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
PROTOCOL_TYPE = X_ADDRESSES["protocol_type"]
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
DRIVE_MODE = ct.DRIVE_MODE.addr
STARTUP_CONFIGURATION = 60  # e-Manual XL430-W250 / XL330 tables (not on every model)
BACKUP_READY = 147  # e-Manual XL430-W250 table (not on every model)

#: Drive Mode bits that need a newer firmware (``control_table_drivemode.md``).
DRIVE_MODE_TIME_PROFILE = 0x04  # firmware 42
DRIVE_MODE_TORQUE_ON_BY_GOAL = 0x08  # the model's backup_min_firmware (45/46)
TIME_PROFILE_MIN_FIRMWARE = 42
#: Startup Configuration (60) bits.
STARTUP_TORQUE_ON = 0x01
STARTUP_RAM_RESTORE = 0x02
#: The RAM items a Control Table Backup keeps besides every EEPROM item (and the Indirect
#: Addresses), protocol2.md "Control Table Backup".
BACKUP_RAM_ITEMS = (
    "velocity_i_gain",
    "velocity_p_gain",
    "position_d_gain",
    "position_i_gain",
    "position_p_gain",
    "feedforward_2nd_gain",
    "feedforward_1st_gain",
    "profile_acceleration",
    "profile_velocity",
)

#: The goal registers: a write to one replans the motion.
GOAL_ADDRS = frozenset((GOAL_PWM, GOAL_CURRENT, GOAL_VELOCITY, GOAL_POSITION))

Updates = list[tuple[Field, int]]
#: A compiled Read span (:meth:`RegisterFile._plan`), a list: it is updated in place.
_Plan = list[Any]
_PLANS_KEPT = 64  # spans a servo keeps compiled (a show reads a few, again and again)
# Enum members looked up once (through the class it costs ~0.15 µs a time on CPython 3.11).
_OK = StatusError.NONE
_POSITION_MODE = OperatingMode.POSITION


def _getter(addrs: list[int]) -> Callable[[dict[int, int]], tuple[int, ...]] | None:
    """The values at ``addrs`` as a tuple in one call (None for no address)."""
    if not addrs:
        return None
    if len(addrs) == 1:
        one = itemgetter(addrs[0])
        return lambda values: (one(values),)
    return itemgetter(*addrs)


def _links(plan: _Plan, values: dict[int, int] | None = None) -> tuple[int, ...]:
    """A plan's Indirect Addresses: as it was built, or as they are in ``values``."""
    key: tuple[int, ...] = plan[1] if values is None else plan[0](values)
    return key[: plan[2]]


class RegisterFile:
    """The stored control table of one servo of ``model`` (``values``: address -> int)."""

    def __init__(self, model: ServoModel, firmware: int) -> None:
        self.model = model
        self.values: dict[int, int] = {}
        #: registers computed on read: address -> getter (the servo fills this in)
        self.dynamic: dict[int, Callable[[], int]] = {}
        #: the Control Table Backup (address -> value), None until one is stored
        self.backup: dict[int, int] | None = None
        #: compiled Read spans, (address, length) -> plan (see :meth:`_plan`); ``dynamic``
        #: is complete before the first read (a plan holds its getters)
        self._plans: dict[tuple[int, int], _Plan] = {}
        if model.has(BACKUP_READY):
            self.dynamic[BACKUP_READY] = lambda: int(self.backup is not None)
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
        if f is not None and f.size == length and addr not in m.indirect:  # one whole field
            getter = self.dynamic.get(addr)
            value = getter() if getter is not None else self.values[addr]
            return 0, (value & MASKS[length]).to_bytes(length, "little")
        plan = self._plans.get((addr, length))
        if plan is not None:
            check, expect, links, static, computed, stored = plan
            if computed is not None:
                if check is not None:
                    key = check(self.values)
                    if key != expect:
                        if key[:links] != expect[:links]:
                            computed = None  # an Indirect Address moved: build it again
                        else:  # only stored values changed: their bits again
                            static = 0
                            for value, (shift, mask, to) in zip(key[links:], stored, strict=True):
                                static |= (value >> shift & mask) << to
                            plan[1], plan[3] = key, static
                if computed is not None:
                    acc = static
                    for getter, shift, mask, to in computed:
                        acc |= (getter() >> shift & mask) << to
                    return 0, acc.to_bytes(length, "little")
        if length < 1:
            return StatusError.DATA_LENGTH, b""
        if addr < 0 or addr + length > m.table_end:
            return StatusError.ACCESS, b""
        if plan is None or (plan[0] is not None and _links(plan, self.values) != _links(plan)):
            if len(self._plans) >= _PLANS_KEPT:
                self._plans.clear()  # a host reading every span there is: start again
            self._plans[addr, length] = self._plan(addr, length)
        return 0, self._read_span(addr, length)

    def _read_span(self, addr: int, length: int) -> bytes:
        """A valid span's bytes, byte by byte: the definition :meth:`_plan` compiles."""
        m = self.model
        indirect = m.indirect
        end = addr + length
        out = bytearray(length)
        owner = m.byte_owner
        raws: dict[int, bytes] = {}  # each field computed once per read
        a = addr
        while a < end:
            f = owner[a]
            if f is None:
                a += 1
                continue
            if a in indirect:
                out[a - addr] = self._indirect_byte(a, raws)
                a += 1
                continue
            raw = self._raw(f, raws)
            lo, hi = a - f.addr, min(f.end, end) - f.addr
            out[a - addr : a - addr + hi - lo] = raw[lo:hi]
            a = f.addr + hi
        return bytes(out)

    def _plan(self, addr: int, length: int) -> _Plan:
        """A valid span compiled: which field's bytes land where, worked out once.

        Returns ``[check, expect, links, static, computed, stored]``. ``check(values)``
        gives the span's Indirect Addresses (the first ``links``) and the stored values it
        reads, as ``expect`` holds them when ``static`` (their bits of the result) was
        worked out: while the Indirect Addresses are the same the plan holds, so a write,
        reboot, reset or restore that moves one is seen at the next read whatever path it
        took; when only stored values changed, ``static`` is worked out again from
        ``stored``'s ``(shift, mask, to)``. ``computed`` lists ``(getter, shift, mask,
        to)`` for the fields computed on read. A value ``>> shift & mask`` lands at bit
        ``to`` of the little-endian result; gaps are the zeros left. ``computed`` is None
        where the byte loop must stay: an Indirect Data pointing at another (its stored
        byte, not a field's), or a computed field in two places (read once there).
        """
        m = self.model
        values = self.values
        indirect, owner = m.indirect, m.byte_owner
        sources: list[tuple[Field, int, int]] = []  # (field, its byte, the span's byte)
        links: list[int] = []  # the span's Indirect Addresses
        nested = False
        for i in range(length):
            a = addr + i
            f = owner[a]
            if f is None:
                continue
            if a in indirect:
                links.append(indirect[a])
                target = values[indirect[a]]
                nested = nested or target in indirect
                f = m.field_at(target)
                if f is not None:
                    sources.append((f, target - f.addr, i))
                continue
            sources.append((f, a - f.addr, i))
        pieces: list[list[int]] = []  # [field address, first byte, bytes, span byte]
        for f, byte, i in sources:
            last = pieces[-1] if pieces else None
            if last and last[0] == f.addr and last[1] + last[2] == byte and last[3] + last[2] == i:
                last[2] += 1  # the next byte of the same field, next in the span
            else:
                pieces.append([f.addr, byte, 1, i])
        dynamic = self.dynamic
        computed = [p for p in pieces if p[0] in dynamic]
        stored = [p for p in pieces if p[0] not in dynamic]
        if nested or len({p[0] for p in computed}) != len(computed):
            check = _getter(links)
            return [check, check(values) if check else None, len(links), 0, None, ()]
        check = _getter(links + [p[0] for p in stored])
        expect = check(values) if check is not None else None
        bits = tuple((8 * byte, (1 << 8 * n) - 1, 8 * i) for _, byte, n, i in stored)
        static = 0
        for p, (shift, mask, to) in zip(stored, bits, strict=True):
            static |= (values[p[0]] >> shift & mask) << to
        return [
            check,
            expect,
            len(links),
            static,
            tuple((dynamic[a], 8 * byte, (1 << 8 * n) - 1, 8 * i) for a, byte, n, i in computed),
            bits,
        ]

    def _raw(self, f: Field, raws: dict[int, bytes]) -> bytes:
        raw = raws.get(f.addr)
        if raw is None:
            getter = self.dynamic.get(f.addr)
            value = getter() if getter is not None else self.values[f.addr]
            raw = raws[f.addr] = (value & MASKS[f.size]).to_bytes(f.size, "little")
        return raw

    def indirect_target(self, data_addr: int) -> int:
        """The address Indirect Data at ``data_addr`` stands for (its Indirect Address)."""
        return self.values[self.model.indirect[data_addr]]

    def _indirect_byte(self, data_addr: int, raws: dict[int, bytes]) -> int:
        target = self.indirect_target(data_addr)
        if target in self.model.indirect:  # an Indirect Data byte: its own stored value
            return self.values[target] & 0xFF
        f = self.model.field_at(target)
        return 0 if f is None else self._raw(f, raws)[target - f.addr]

    # --- Write -----------------------------------------------------------------------------
    # long on purpose: the Write checks in the e-Manual's order
    def validate(self, addr: int, data: bytes) -> tuple[int, Updates]:  # noqa: C901
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
        if f is not None and f.size == n and addr not in m.indirect:  # the Sync Write case
            if not f.writable or (addr < EEPROM_END and regs[TORQUE_ENABLE]):
                return StatusError.ACCESS, []
            value = int.from_bytes(data, "little", signed=f.signed)
            updates = [(f, value)]
            # The two loops below for this one field, in their order, without the loops.
            if not f.accepts(value) or (addr == DRIVE_MODE and self._drive_mode_refused(value)):
                return StatusError.DATA_RANGE, []
            if addr in GOAL_ADDRS:
                if regs[BUS_WATCHDOG] == ct.WATCHDOG_TRIPPED:
                    return StatusError.DATA_RANGE, []
                if addr == GOAL_POSITION:  # within_limits() for it: no limit changes here
                    if regs[OPERATING_MODE] == _POSITION_MODE and not (
                        regs[MIN_POSITION_LIMIT] <= value <= regs[MAX_POSITION_LIMIT]
                    ):
                        return StatusError.DATA_LIMIT, []
                elif not self.within_limits(addr, value, updates):
                    return StatusError.DATA_LIMIT, []
            elif addr == BUS_WATCHDOG:
                if value != 0 and regs[BUS_WATCHDOG] == ct.WATCHDOG_TRIPPED:
                    return StatusError.DATA_RANGE, []
            elif (
                addr == TORQUE_ENABLE
                and value
                and not regs[TORQUE_ENABLE]
                and regs[HARDWARE_ERROR_STATUS] & regs[SHUTDOWN]
            ):
                return StatusError.RESULT_FAIL, []
            return _OK, updates
        if n == 0:
            return StatusError.DATA_LENGTH, []
        end = addr + n
        if addr < 0 or end > m.table_end:
            return StatusError.ACCESS, []
        err, updates = self._span_updates(addr, data)
        if err:
            return err, []
        tripped = regs[BUS_WATCHDOG] == ct.WATCHDOG_TRIPPED
        for f, value in updates:
            if not f.accepts(value) or (f.addr == DRIVE_MODE and self._drive_mode_refused(value)):
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

    def _span_updates(self, addr: int, data: bytes) -> tuple[int, Updates]:
        """The fields a Write of ``data`` at ``addr`` changes, Indirect Data resolved to the
        bytes they stand for: ``(error number, updates)`` in the order first touched."""
        m = self.model
        locked = bool(self.values[TORQUE_ENABLE])
        owner, indirect = m.byte_owner, m.indirect
        end = addr + len(data)
        # field address -> (field, its bytes so far, offsets written)
        slots: dict[int, tuple[Field, bytearray, set[int]]] = {}
        a = addr
        while a < end:
            f = owner[a]
            if f is not None and a in indirect:
                target = self.indirect_target(a)
                # an Indirect Data byte (itself by default): its own stored value
                f = owner[target] if target in indirect else m.field_at(target)
                if f is None or not f.writable or (f.eeprom and locked):
                    return StatusError.ACCESS, []
                slot = slots.setdefault(f.addr, (f, bytearray(f.size), set()))
                slot[1][target - f.addr] = data[a - addr]
                slot[2].add(target - f.addr)
                a += 1
                continue
            if f is None or not f.writable or (f.eeprom and locked):
                return StatusError.ACCESS, []
            if f.addr != a or f.end > end:
                return StatusError.DATA_LENGTH, []
            slots[f.addr] = (f, bytearray(data[a - addr : f.end - addr]), set(range(f.size)))
            a = f.end
        updates = []
        for f, raw, written in slots.values():
            if len(written) != f.size:  # part of a multi-byte item mapped: not writable alone
                return StatusError.DATA_LENGTH, []
            updates.append((f, int.from_bytes(raw, "little", signed=f.signed)))
        return StatusError.NONE, updates

    def _drive_mode_refused(self, value: int) -> bool:
        """Drive Mode bits this firmware does not have (Data Range Error)."""
        fw = self.values[FIRMWARE_VERSION]
        if value & DRIVE_MODE_TORQUE_ON_BY_GOAL and fw < self.model.backup_min_firmware:
            return True
        return bool(value & DRIVE_MODE_TIME_PROFILE and fw < TIME_PROFILE_MIN_FIRMWARE)

    # --- Control Table Backup ---------------------------------------------------------------
    def backup_fields(self) -> list[Field]:
        """What a Control Table Backup keeps: every writable EEPROM item, the gains, Profile
        Acceleration/Velocity and the Indirect Addresses."""
        m = self.model
        ram = {m.field(name).addr for name in BACKUP_RAM_ITEMS if m.has(name)}
        ram.update(m.indirect.values())
        return [f for f in m.fields if (f.eeprom and f.writable) or f.addr in ram]

    def store_backup(self) -> None:
        self.backup = {f.addr: self.values[f.addr] for f in self.backup_fields()}

    def restore_eeprom(self) -> bool:
        """The backup's EEPROM items back in place; False (nothing done) without a backup."""
        if self.backup is None:
            return False
        for a, value in self.backup.items():
            if a < EEPROM_END:
                self.values[a] = value
        return True

    def boot_ram(self) -> bool:
        """At boot, after the RAM defaults: the backup's RAM items back when Startup
        Configuration has RAM Restore. Returns True when Startup Torque On is set."""
        startup = self.values.get(STARTUP_CONFIGURATION, 0)
        if startup & STARTUP_RAM_RESTORE and self.backup is not None:
            for a, value in self.backup.items():
                if a >= EEPROM_END:
                    self.values[a] = value
        return bool(startup & STARTUP_TORQUE_ON)

    def within_limits(self, addr: int, value: int, updates: Updates) -> bool:
        """Goal registers against the limit registers as they will be after this write."""
        if len(updates) == 1 and updates[0][0].addr == addr and addr in GOAL_ADDRS:
            reg = self.values.__getitem__  # the write changes no limit: the stored values
        else:

            def reg(a: int) -> int:
                for f, v in updates:
                    if f.addr == a:
                        return v
                return self.values[a]

        if addr == GOAL_POSITION:
            if reg(OPERATING_MODE) != _POSITION_MODE:
                return True
            return reg(MIN_POSITION_LIMIT) <= value <= reg(MAX_POSITION_LIMIT)
        if addr == GOAL_VELOCITY:
            return abs(value) <= reg(VELOCITY_LIMIT)
        if addr == GOAL_CURRENT:
            return abs(value) <= reg(CURRENT_LIMIT)
        return abs(value) <= reg(PWM_LIMIT)  # Goal PWM
