"""One emulated Protocol 1.0-family servo: Dynamixel AX/MX (P1 firmware), Feetech STS/SCS.

The register model is the model's :class:`~drivers.protocol1.control_table.ControlTable`
(address, size, access, EEPROM or RAM, range, sign bit, byte order): a byte image, written
and read as the wire does. What each family does differently is in :class:`Family`:

* **Dynamixel P1**: a write is atomic; a read-only or undefined byte, or a value outside its
  item's range, is a Range Error (bit 3) and nothing is written; a goal outside the angle
  limits sets Angle Limit Error (bit 1) and is clamped. Lock = 1 keeps EEPROM from being
  written (silently) until power is cycled (e-Manual: "the power must be turned off").
* **Feetech**: no error bit for a bad write: read-only and undefined bytes are skipped. While
  Lock = 1 (its power-up value) an EEPROM write takes effect but is not kept over a power
  cycle; with Lock = 0 it is. A goal write turns torque on, as Feetech's own examples rely on.
  Torque Enable 128 makes the present position read 2048 (Homing Offset is set to match).

The horn: velocity-limited moves at the speed register (0 = the no-load speed) with the
family's acceleration register (STS Acceleration x 100 step/s², MX Goal Acceleration
x 8.583 °/s², AX none), stepped on a 1 ms grid; nothing moves while torque is off. Temperature
and voltage are constant unless a fault says otherwise. What is not modelled: ``docs/dxlsim.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from drivers.protocol1.control_table import ControlTable, DxlP1Error, Item, table_for
from drivers.protocol1.encoding import decode_word, encode_word, from_sign_magnitude

#: Motion grid (s): a move is integrated in steps of at most this.
STEP_S = 1e-3
AMBIENT_C = 30
#: MX Goal Acceleration unit (°/s²), e-Manual.
MX_ACCEL_UNIT_DEG = 8.583
#: STS Acceleration unit (step/s²).
STS_ACCEL_UNIT = 100.0


class P1Servo:
    """One servo of ``table`` (a model name or table) on ``servo_id``."""

    def __init__(
        self,
        table: ControlTable | str,
        servo_id: int,
        *,
        baud: int = 1_000_000,
        return_delay_us: float = 500.0,
        firmware: int | None = None,
        t: float = 0.0,
    ) -> None:
        self.table = table_for(table) if isinstance(table, str) else table
        self.family = self.table.family
        self.dxl = self.family.protocol == "dynamixel-p1"
        self._items = self.table.by_name
        # name -> (addr, end, byte order): the registers' hot path without Item lookups
        self._slots: dict[str, tuple[int, int, Literal["little", "big"]]] = {
            i.name: (i.addr, i.end, "big" if i.big_endian else "little") for i in self.table.items
        }
        # goal (actual frame), vmax, amax, Homing Offset: cached until a write
        self._plan: tuple[float, float, float, int] | None = None
        # vmax, amax, Homing Offset, the position limits: cached until a write of anything
        # but Goal Position (a Sync Write of goals keeps them)
        self._limits: tuple[float, float, int, int, int] | None = None
        # (addr, length) of a write -> what it touches (_Span), worked out once
        self._spans: dict[tuple[int, int], _Span] = {}
        pp, ps = self._items["Present Position"], self._items["Present Speed"]
        self._present_pos = (pp.addr, pp.end, self._slots[pp.name][2], pp.sign_bit or 0)
        self._present_speed = (ps.addr, ps.end, self._slots[ps.name][2], ps.sign_bit or 0)
        self._torque_addr = self._items["Torque Enable"].addr
        self._id_addr = self._items["ID"].addr
        self._rdt_addr = self._items["Return Delay Time"].addr
        self._srl_addr = self._items[
            "Status Return Level" if self.dxl else "Response Status Level"
        ].addr
        self._moving_addr = self._items["Moving"].addr
        self._status_addr = self._items["Status"].addr if self.table.has("Status") else None
        self._rpm_per_step_s = (
            60.0
            / (self.table.resolution * 360.0 / self.table.range_deg)
            / self.table.speed_unit_rpm
        )
        self._size = self.table.last_address + 1
        self._owner: list[Item | None] = [None] * self._size
        for item in self.table.items:
            for a in range(item.addr, item.end):
                self._owner[a] = item
        if not 0 <= servo_id <= 253:
            raise ValueError(f"servo ID must be 0..253, got {servo_id}")
        if return_delay_us < 0 or return_delay_us > 508 or return_delay_us % 2:
            raise ValueError(
                f"return_delay_us must be a multiple of 2 in 0..508: {return_delay_us}"
            )
        self._baud = int(baud)
        # The servo's flash: factory EEPROM with the ID, baud and Return Delay it was set to.
        self._flash = bytearray(self._size)
        self._defaults(self._flash, eeprom=True)
        self._put(self._flash, "Model Number", self.table.model_number)
        fw = self.table.firmware if firmware is None else int(firmware)
        if self.dxl:
            self._put(self._flash, "Firmware Version", fw)
        else:
            self._put(self._flash, "Firmware Major Version", fw)
        self._put(self._flash, "ID", servo_id)
        self._put(self._flash, "Baud Rate", self._baud_code(self._baud))
        self._put(self._flash, "Return Delay Time", int(return_delay_us) // 2)
        self._mem = bytearray(self._size)
        self._now = t
        self._pos = float(self.table.resolution // 2)  # the horn, actual frame (steps)
        self._vel = 0.0  # steps/s
        self._alarm = 0  # latched status error bits (faults)
        self._registered: tuple[int, bytes] | None = None
        self._power_up()

    # --- registers ------------------------------------------------------------------------
    def _defaults(self, mem: bytearray, *, eeprom: bool) -> None:
        for item in self.table.items:
            if item.eeprom == eeprom and item.default is not None:
                mem[item.addr : item.end] = encode_word(item.default, item.size, item.big_endian)

    def _put(self, mem: bytearray, name: str, raw: int) -> None:
        item = self._items[name]
        mem[item.addr : item.end] = encode_word(raw, item.size, item.big_endian)

    def raw(self, name: str) -> int:
        """The unsigned register value of item ``name``."""
        a, e, order = self._slots[name]
        return int.from_bytes(self._mem[a:e], order)

    def value(self, name: str) -> int:
        """Item ``name`` as a number (sign-magnitude items signed)."""
        item = self._items[name]
        raw = self.raw(name)
        return raw if item.sign_bit is None else from_sign_magnitude(raw, item.sign_bit)

    def set_value(self, name: str, value: int) -> None:
        """Set item ``name`` directly (a test's or a fault's hand, not the wire)."""
        item = self._items[name]
        self._mem[item.addr : item.end] = item.encode(value)
        self._plan = self._limits = None

    def _baud_code(self, baud: int) -> int:
        if self.dxl:
            for code, rate in self.family.baud_rates.items():
                if rate == baud:
                    return code
            code = round(2_000_000 / baud) - 1
            if code < 0 or code > 254 or abs(2_000_000 / (code + 1) - baud) > 0.03 * baud:
                raise ValueError(f"{self.table.model}: no Baud Rate value gives {baud} bps")
            return code
        try:
            return self.family.baud_code(baud)
        except ValueError:
            rates = ", ".join(map(str, self.family.baud_rates.values()))
            raise ValueError(f"{self.table.model}: {baud} bps is not one of {rates}") from None

    def _code_baud(self, code: int) -> int:
        if self.dxl:  # the standard rate the value stands for, else 2 000 000 / (value + 1)
            return self.family.baud_rates.get(code) or round(2_000_000 / (code + 1))
        return self.family.baud_rates.get(code, 0)

    def _power_up(self) -> None:
        """Power on: EEPROM from flash, RAM at its initial values, goal where the horn is."""
        self._plan = self._limits = None
        self._mem[:] = self._flash
        self._defaults(self._mem, eeprom=False)
        if self.table.has("Torque Limit"):  # its power-up value is the EEPROM maximum
            max_torque = self.raw("Max Torque" if self.dxl else "Max Torque Limit")
            self._put(self._mem, "Torque Limit", max_torque)
        self._put(self._mem, "Present Voltage", self.table.volts)
        self._put(self._mem, "Present Temperature", AMBIENT_C)
        self._vel = 0.0
        self._alarm = 0
        self._registered = None
        self._hold()
        self._refresh()

    # --- what the bus needs ---------------------------------------------------------------
    @property
    def id(self) -> int:
        return self._mem[self._id_addr]

    @property
    def model_name(self) -> str:
        return self.table.model

    @property
    def baud(self) -> int:
        return self._baud

    @property
    def listening_baud(self) -> int:
        return self._baud

    @property
    def return_delay_s(self) -> float:
        return self._mem[self._rdt_addr] * 2e-6

    @property
    def status_return_level(self) -> int:
        return self._mem[self._srl_addr]

    @property
    def torque_enabled(self) -> bool:
        return self.raw("Torque Enable") == 1

    @property
    def position(self) -> float:
        """The horn, in position steps of the actual frame."""
        return self._pos

    def replies_to(self, inst: int) -> bool:
        """Whether Status Return Level lets this servo answer ``inst`` (PING always)."""
        level = self.status_return_level
        if inst == 0x01:
            return True
        if inst == 0x02:
            return level >= self.family.srl_read
        return level >= self.family.srl_all

    def status(self, err: int = 0) -> int:
        """The ERR byte: ``err`` with the latched alarm bits."""
        return (err | self._alarm) & 0x7F

    def touch(self, t: float) -> None:
        """Bring the horn and the present registers to ``t``."""
        if t <= self._now:
            return
        if self._vel == 0.0:  # at rest: nothing changes unless a goal is still ahead
            plan = self._plan if self._plan is not None else self._make_plan()
            if plan[0] == self._pos or self._mem[self._torque_addr] != 1:
                self._now = t
                return
        self._advance(t)
        self._refresh()

    def ping(self, t: float) -> tuple[int, bytes]:
        self.touch(t)
        return self.status(), b""

    def read(self, addr: int, length: int, t: float) -> tuple[int, bytes]:
        """``(ERR, data)``; gaps read 0. Past the table or length 0: Range Error (Dynamixel;
        no data) or zeros (Feetech)."""
        self.touch(t)
        end = addr + length
        if length == 0 or end > self._size:
            if self.dxl:
                return self.status(DxlP1Error.RANGE), b""
            data = bytes(self._mem[addr : min(end, self._size)])
            return self.status(), data + bytes(length - len(data))
        return self.status(), bytes(self._mem[addr:end])

    def write(self, addr: int, data: bytes, t: float) -> int:
        """Write ``data`` at ``addr``; returns the ERR byte."""
        self.touch(t)
        err = 0
        span = self._spans.get((addr, len(data))) or self._span(addr, len(data))
        mem = self._mem
        if self.dxl:
            err = self._dxl_check(addr, data)
            if err & DxlP1Error.RANGE:
                return self.status(err)
            if span.eeprom and self.raw("Lock"):
                return self.status(err)  # locked: EEPROM unchanged, no error bit
        old_torque = mem[self._torque_addr]
        if (
            span.names == _GOAL_ONLY
            and mem[addr : addr + len(data)] == data
            and (self.dxl or old_torque == 1)
            and self._plan is not None
        ):
            return self.status(err)  # the goal it holds (and torque on): nothing changes
        if span.whole:  # every byte writable, no Lock among them
            mem[addr : addr + len(data)] = data
        else:
            for i in span.keep:  # Feetech skips the others (Dynamixel refused them above)
                if self.dxl and span.lock == addr + i and mem[addr + i]:
                    continue  # Dynamixel: only a power cycle clears Lock
                mem[addr + i] = data[i]
        self._after_write(old_torque, span)
        return self.status(err)

    def _span(self, addr: int, length: int) -> _Span:
        """What a write of ``length`` bytes at ``addr`` touches (kept for the next one)."""
        span = range(addr, addr + length)
        owners = [self._owner[a] if a < self._size else None for a in span]
        keep = tuple(i for i, item in enumerate(owners) if item is not None and item.writable)
        names = frozenset(item.name for item in owners if item is not None)
        lock = next((a for a, i in zip(span, owners, strict=True) if i and i.name == "Lock"), None)
        found = self._spans[(addr, length)] = _Span(
            keep,
            len(keep) == length and lock is None,
            names,
            tuple(a for a in span if self._eeprom(a)),
            lock,
        )
        return found

    def _eeprom(self, a: int) -> bool:
        item = self._owner[a] if a < self._size else None
        return item is not None and item.eeprom

    def _dxl_check(self, addr: int, data: bytes) -> int:
        """Dynamixel: Range Error for a byte no writable item owns or an item's value out of
        range; Angle Limit Error for a goal outside the limits (the goal is then clamped)."""
        err = 0
        trial = bytearray(self._mem)
        for i in range(len(data)):
            a = addr + i
            item = self._owner[a] if a < self._size else None
            if item is None or not item.writable:
                return DxlP1Error.RANGE
            trial[a] = data[i]
        for item in {self._owner[a] for a in range(addr, addr + len(data))}:
            assert item is not None
            raw = decode_word(trial[item.addr : item.end], item.big_endian)
            if not item.lo <= raw <= item.hi:
                return DxlP1Error.RANGE
            if item.name == "Goal Position":
                lo, hi = self.raw("CW Angle Limit"), self.raw("CCW Angle Limit")
                if (lo or hi) and not lo <= raw <= hi:
                    err |= DxlP1Error.ANGLE_LIMIT
        return err

    def _after_write(self, old_torque: int, span: _Span) -> None:
        names = span.names
        self._plan = None
        if names != _GOAL_ONLY:
            self._limits = None
        if "Baud Rate" in names:
            self._baud = self._code_baud(self.raw("Baud Rate"))
        eeprom = span.eeprom
        if eeprom and (self.dxl or not self.raw("Lock")):
            for a in eeprom:  # kept over a power cycle
                self._flash[a] = self._mem[a]
        if "Torque Enable" in names:
            te = self.raw("Torque Enable")
            if te == 128 and not self.dxl and self.table.has("Homing Offset"):
                # "set the present position as the middle": Present Position reads 2048
                offset = round(self._pos) - self.table.resolution // 2
                self.set_value("Homing Offset", offset)
                if not self.raw("Lock"):
                    item = self._items["Homing Offset"]
                    self._flash[item.addr : item.end] = self._mem[item.addr : item.end]
                self._put(self._mem, "Torque Enable", old_torque)
            elif te == 1 and old_torque != 1:
                self._hold()
            elif te != 1:
                self._vel = 0.0
        elif "Goal Position" in names and not self.dxl and self.raw("Torque Enable") != 1:
            self._put(self._mem, "Torque Enable", 1)  # a Feetech goal turns torque on
        self._refresh()

    def _hold(self) -> None:
        """Goal Position := where the horn is (power-up, torque on)."""
        self.set_value("Goal Position", round(self._pos) - self._offset())

    def _offset(self) -> int:
        return self.value("Homing Offset") if self.table.has("Homing Offset") else 0

    # --- instructions beyond read/write ---------------------------------------------------
    def reg_write(self, addr: int, data: bytes, t: float) -> int:
        self.touch(t)
        self._registered = (addr, bytes(data))
        if self.table.has("Registered"):
            self._put(self._mem, "Registered", 1)
        return self.status()

    def action(self, t: float) -> int:
        if self._registered is None:
            return self.status(DxlP1Error.INSTRUCTION if self.dxl else 0)
        addr, data = self._registered
        self._registered = None
        if self.table.has("Registered"):
            self._put(self._mem, "Registered", 0)
        return self.write(addr, data, t)

    def factory_reset(self, t: float) -> int:
        """RESET: EEPROM to factory values (ID 1; the baud rate is kept, so the emulated
        bus stays reachable), then a power cycle."""
        self.touch(t)
        keep = self.raw("Baud Rate")
        self._flash = bytearray(self._size)
        self._defaults(self._flash, eeprom=True)
        for name in ("Model Number", "Firmware Version", "Firmware Major Version"):
            if self.table.has(name):
                item = self._items[name]
                self._flash[item.addr : item.end] = self._mem[item.addr : item.end]
        self._put(self._flash, "Baud Rate", keep)
        self._power_up()
        return self.status()

    # --- faults ---------------------------------------------------------------------------
    def inject_hardware_error(self, bits: int, t: float) -> None:
        """Latch status error ``bits`` (the family's); overheating raises the temperature past
        its limit; bits the servo's shutdown mask names cut torque."""
        self.touch(t)
        self._alarm |= bits & 0x7F
        if bits & 4:  # overheating, both families
            limit = self.raw("Temperature Limit" if self.dxl else "Max Temperature Limit")
            self._put(self._mem, "Present Temperature", limit + 1)
        mask = self.raw("Shutdown" if self.dxl else "Unloading Condition")
        if bits & mask:
            self.cut_torque(t)

    def cut_torque(self, t: float) -> None:
        self.touch(t)
        self._put(self._mem, "Torque Enable", 0)
        self._vel = 0.0
        self._refresh()

    def trip_watchdog(self, t: float) -> None:
        """These families have no Bus Watchdog; the bus refuses the fault before it runs."""
        raise ValueError(f"{self.table.model} has no Bus Watchdog")

    def brownout(self, t: float) -> None:
        """Power returns at ``t``: RAM to its initial values, EEPROM from flash."""
        self._now = max(self._now, t)
        self._power_up()

    # --- the horn -------------------------------------------------------------------------
    def _steps_per_rev(self) -> float:
        return self.table.resolution * 360.0 / self.table.range_deg

    def _vmax(self) -> float:
        """Top speed for this move (steps/s)."""
        top = self.table.no_load_rpm / 60.0 * self._steps_per_rev()
        raw = self.raw("Moving Speed") & 0x3FF if self.dxl else abs(self.value("Goal Speed"))
        if raw == 0:
            return top
        if self.dxl:
            return min(top, raw * self.table.speed_unit_rpm / 60.0 * self._steps_per_rev())
        return min(top, raw * self.table.speed_unit_rpm / 60.0 * self._steps_per_rev())

    def _amax(self) -> float:
        """Acceleration limit (steps/s²); inf when the family or the register says none."""
        if self.table.has("Acceleration"):
            raw = self.raw("Acceleration")
            return raw * STS_ACCEL_UNIT if raw else math.inf
        if self.table.has("Goal Acceleration"):
            raw = self.raw("Goal Acceleration")
            return raw * MX_ACCEL_UNIT_DEG * self._steps_per_rev() / 360.0 if raw else math.inf
        return math.inf

    def _make_plan(self) -> tuple[float, float, float, int]:
        """The move's goal (actual frame), top speed, acceleration and the Homing Offset,
        cached until a write."""
        vmax, amax, offset, lo, hi = self._limits or self._make_limits()
        goal = self.value("Goal Position")
        if lo or hi:  # clamped to the position limits
            goal = min(max(goal, lo), hi)
        self._plan = (float(goal + offset), vmax, amax, offset)
        return self._plan

    def _make_limits(self) -> tuple[float, float, int, int, int]:
        """Top speed, acceleration, Homing Offset and the position limits (0, 0: none),
        cached until a write of anything but Goal Position."""
        if self.dxl:
            lo, hi = self.raw("CW Angle Limit"), self.raw("CCW Angle Limit")
        else:
            lo, hi = self.raw("Min Position Limit"), self.raw("Max Position Limit")
        self._limits = (self._vmax(), self._amax(), self._offset(), lo, hi)
        return self._limits

    def _advance(self, t: float) -> None:
        """Move the horn from ``_now`` to ``t``: time-optimal towards the goal under the speed
        and acceleration limits (accelerate, cruise, brake), planned piece by piece exactly."""
        if self.raw("Torque Enable") != 1:
            self._vel = 0.0
            self._now = t
            return
        goal, vmax, amax, _ = self._plan if self._plan is not None else self._make_plan()
        pos, vel, left = self._pos, self._vel, t - self._now
        for _ in range(8):  # at most: stop, turn, accelerate, cruise, brake
            d = goal - pos
            if left <= 0.0 or (vel == 0.0 and abs(d) < 1e-9):
                break
            sgn = 1.0 if d > 0 or (d == 0 and vel < 0) else -1.0
            dist, v = abs(d), vel * sgn  # in the goal's direction
            dur, acc, last = _segment(dist, v, vmax, amax)
            h = min(dur, left)
            if math.isinf(amax):
                pos, vel = pos + sgn * vmax * h, sgn * vmax
            else:
                pos += sgn * (v * h + 0.5 * acc * h * h)
                vel = sgn * (v + acc * h)
            left -= h
            if last and h >= dur:
                pos, vel = goal, 0.0
        self._pos, self._vel, self._now = pos, vel, t

    def _refresh(self) -> None:
        """Present Position/Speed, Moving (and Feetech's Status) from the horn. Bytes are put
        straight into the image: this runs for every servo a packet reaches."""
        goal, _, _, offset = self._plan if self._plan is not None else self._make_plan()
        mem, pos, vel = self._mem, self._pos, self._vel
        a, e, order, sign = self._present_pos
        present = round(pos) - offset
        mem[a:e] = (-present | 1 << sign if present < 0 and sign else present & 0xFFFF).to_bytes(
            e - a, order
        )
        a, e, order, sign = self._present_speed
        if self.dxl:
            raw = min(1023, round(abs(vel) * self._rpm_per_step_s))
            raw |= 1024 if vel < 0 and raw else 0
        else:
            raw = round(vel)
            raw = (-raw | 1 << sign) if raw < 0 else raw
        mem[a:e] = raw.to_bytes(e - a, order)
        moving = vel != 0.0 or (mem[self._torque_addr] == 1 and abs(goal - pos) >= 0.5)
        mem[self._moving_addr] = moving
        if self._status_addr is not None:  # Feetech: the latched error bits
            mem[self._status_addr] = self._alarm

    def __repr__(self) -> str:
        return (
            f"P1Servo({self.table.model!r}, id={self.id}, t={self._now:.6f}, pos={self._pos:.1f})"
        )


#: The names a Sync Write of goals touches: the move's limits stay as they were.
_GOAL_ONLY = frozenset({"Goal Position"})


@dataclass(frozen=True, slots=True)
class _Span:
    """What a write of some bytes at some address touches: the offsets of the writable
    bytes, whether that is all of them (and no Lock), the items' names, the EEPROM
    addresses, the Lock register's address if among them."""

    keep: tuple[int, ...]
    whole: bool
    names: frozenset[str]
    eeprom: tuple[int, ...]
    lock: int | None


def _segment(dist: float, v: float, vmax: float, a: float) -> tuple[float, float, bool]:
    """The next piece of a time-optimal move ``dist`` (>= 0) ahead at speed ``v`` (signed,
    towards the goal): ``(duration, acceleration, ends_at_the_goal)``."""
    eps = 1e-9
    if math.isinf(a):
        return dist / vmax, 0.0, True
    if v < -eps:  # moving away: stop first
        return -v / a, a, False
    if v * v / (2.0 * a) > dist + eps:  # cannot stop in time: brake through the goal
        return v / a, -a, False
    if v > vmax + eps:  # faster than this move allows: slow down to it
        return (v - vmax) / a, -a, False
    peak = min(vmax, math.sqrt(a * dist + v * v / 2.0))
    if v < peak - eps:
        return (peak - v) / a, a, False
    cruise = dist - v * v / (2.0 * a)
    if cruise > eps and v > eps:
        return cruise / v, 0.0, False
    return (v / a if v > eps else 0.0), -a, True
