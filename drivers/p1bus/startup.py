"""The start-up check of a Protocol 1.0-framed bus, in each family's own terms.

Per servo, read-only: it answers Ping; its Model Number is the rig's model (a servo of
another family is named as such); firmware (reported); the Baud Rate register agrees with
the bus; Return Delay Time within what the tick allows; Status Return Level answers every
instruction (else writes go unconfirmed); position mode (limits not both 0, Feetech
Operating Mode 0) with the rig's range inside the angle limits; no status error bits;
Feetech STS Phase bit 4 clear (else positions leave 0..4095); torque (reported). Each
difference is a :class:`~drivers.dynamixel.errors.Mismatch` row, the X-series check's type, so
one :class:`~drivers.dynamixel.errors.StartupMismatch` table names them all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.dynamixel.errors import CommError, CommTimeout, Mismatch
from drivers.p1bus.link import P1Link, StatusError, decode
from drivers.p1bus.table import Family, ReadMethod, Reg, canonical, model_by_number

#: Feetech Operating Mode (addr 33): 0 is position servo mode
FEETECH_MODE = Reg("Operating Mode", 33, 1)
#: Feetech STS Phase bit 4: positions read beyond 0..4095 (LeRobot clears it)
PHASE_WIDE_READINGS = 0x10
#: a Return Delay Time unit (both makers): 2 µs
RETURN_DELAY_UNIT_S = 2e-6


@dataclass(frozen=True)
class P1Expectation:
    """What the rig expects of one servo: its ``model`` (a Protocol 1.0 name), the range
    (rad, servo frame) the loop will command, the largest Return Delay Time the tick allows."""

    id: int
    model: str
    position_range_rad: tuple[float, float] | None = None
    return_delay_us_max: float = 500.0


@dataclass(frozen=True)
class P1ServoState:
    """What the check found on one servo."""

    id: int
    model_name: str
    family: str
    firmware: int
    torque_on: bool
    return_delay_us: float
    status_return_level: int
    limits: tuple[int, int]
    position_rad: float
    lock: int | None  # Feetech Lock (1 = EEPROM locked)


@dataclass(frozen=True)
class P1StartupReport:
    """A passing check: the port, its reads, every servo as found, the notes to show."""

    port: str
    baud: int
    read_mode: ReadMethod
    servos: tuple[P1ServoState, ...]
    notes: tuple[str, ...] = ()

    @property
    def torque_on_ids(self) -> tuple[int, ...]:
        return tuple(s.id for s in self.servos if s.torque_on)

    def __str__(self) -> str:
        lines = [f"{self.port} @ {self.baud} bit/s, {len(self.servos)} servo(s), {self.read_mode}"]
        lines += [
            f"  servo {s.id}: {s.model_name} ({s.family}) fw {s.firmware}, torque "
            f"{'on' if s.torque_on else 'off'}, {s.position_rad:+.4f} rad"
            for s in self.servos
        ]
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


@dataclass(frozen=True)
class P1ServoCheck:
    state: P1ServoState | None
    rows: tuple[Mismatch, ...] = ()
    notes: tuple[str, ...] = ()
    goal_range: tuple[int, int] | None = None
    return_delay_s: float | None = None


def _fix_register(fam: Family, reg: Reg, value: str) -> str:
    unlock = f" (unlock first: Lock, addr {fam.lock.addr} := 0, then relock)" if fam.lock else ""
    return f"set {reg.name} (addr {reg.addr}) to {value}{unlock}"


# long on purpose: one servo's start-up check, each fact in turn
def check_servo(  # noqa: C901, PLR0915
    link: P1Link, fam: Family, exp: P1Expectation, attempts: int
) -> P1ServoCheck:
    """Check one servo against ``exp`` (its ``model``, ``position_range_rad``,
    ``return_delay_us_max``); read-only."""
    sid = exp.id
    rows: list[Mismatch] = []
    notes: list[str] = []

    def add(item: str, expected: str, found: str, fix: str = "") -> None:
        rows.append(Mismatch(sid, item, expected, found, fix))

    def read(reg: Reg) -> int:
        last: Exception | None = None
        for _ in range(attempts):
            try:
                return link.read_reg(fam, sid, reg)
            except (CommError, StatusError) as exc:
                last = exc
        assert last is not None
        raise last

    err = None
    last_exc: Exception | None = None
    for _ in range(attempts):
        try:
            err = link.ping1(sid)
            break
        except CommError as exc:
            last_exc = exc
    if err is None:
        silent = isinstance(last_exc, CommTimeout)
        add(
            "answers Ping",
            "yes",
            "no reply" if silent else "corrupt reply",
            f"check power, wiring, ID {sid} and the baud rate ({link.baud} bit/s): "
            "`hilsim scan` lists what answers",
        )
        return P1ServoCheck(None, tuple(rows))
    try:
        number = read(fam.model_number)
        known = model_by_number(fam.protocol, number)
        want = fam.models.get(canonical(exp.model or ""))
        if want is not None and number != want:
            found = f"{known[0]} ({known[1].name})" if known else f"model number {number}"
            add("model", f"{exp.model} (model number {want})", found, "fix the rig or the ID")
        name = known[0] if known else f"model number {number}"
        firmware = read(fam.firmware)
        baud_code = read(fam.baud)
        baud = fam.baud_codes.get(baud_code)
        if baud is not None and abs(baud - link.baud) > 0.03 * link.baud:
            codes = [c for c, b in fam.baud_codes.items() if abs(b - link.baud) <= 0.03 * link.baud]
            add(
                "Baud Rate",
                f"{link.baud} bit/s",
                f"{baud} bit/s (code {baud_code})",
                _fix_register(fam, fam.baud, str(codes[0])) if codes else "change bus.baud",
            )
        rdt = read(fam.return_delay)
        rdt_us = rdt * RETURN_DELAY_UNIT_S * 1e6
        if rdt_us > exp.return_delay_us_max:
            add(
                "Return Delay Time",
                f"<= {exp.return_delay_us_max:.0f} µs",
                f"{rdt_us:.0f} µs ({rdt})",
                _fix_register(fam, fam.return_delay, "0"),
            )
        srl = read(fam.status_return_level)
        if srl != fam.status_return_all:
            add(
                fam.status_return_level.name,
                f"{fam.status_return_all} (every instruction answered)",
                str(srl),
                _fix_register(fam, fam.status_return_level, str(fam.status_return_all)),
            )
        lo, hi = read(fam.min_limit), read(fam.max_limit)
        mode = read(FEETECH_MODE) if fam.lock is not None else 0
        goal_range = None
        if (lo == 0 and hi == 0) or mode != 0:
            add(
                "mode",
                "position (joint) mode",
                f"wheel/multi-turn (limits {lo}..{hi}, mode {mode})",
                "set the angle limits to the joint's range",
            )
        else:
            goal_range = (lo, hi)
            if exp.position_range_rad is not None:
                rlo, rhi = exp.position_range_rad
                tlo = round(rlo * fam.ticks_per_rad) + fam.center_tick
                thi = round(rhi * fam.ticks_per_rad) + fam.center_tick
                if tlo < lo or thi > hi:
                    add(
                        "angle limits",
                        f"cover ticks {tlo}..{thi} (the rig's range)",
                        f"{lo}..{hi}",
                        f"widen {fam.min_limit.name}/{fam.max_limit.name} or narrow the joint",
                    )
        if fam.phase is not None:
            phase = read(fam.phase)
            if phase & PHASE_WIDE_READINGS:
                add(
                    "Phase",
                    "bit 4 clear (readings 0..4095)",
                    f"0x{phase:02X}",
                    _fix_register(fam, fam.phase, f"0x{phase & ~PHASE_WIDE_READINGS:02X}"),
                )
        lock = read(fam.lock) if fam.lock is not None else None
        if lock == 0:
            notes.append(f"servo {sid}: EEPROM unlocked (Lock 0): a stray write would be kept")
        addr = fam.torque_enable.addr
        size = fam.present_position.end - addr
        err2, data = link.read_bytes(fam, sid, addr, size)
        torque = bool(decode(fam, fam.torque_enable, data, addr))
        tick = decode(fam, fam.present_position, data, addr)
        bits = (err | err2) & fam.hardware_bits
        if bits:
            add("status error bits", "none", fam.describe_error(bits), "let it cool, check supply")
    except (CommError, StatusError) as exc:
        add("registers", "readable", str(exc), "check wiring and power")
        return P1ServoCheck(None, tuple(rows), tuple(notes))
    if torque:
        notes.append(f"servo {sid}: torque already on")
    state = P1ServoState(
        sid,
        name,
        fam.name,
        firmware,
        torque,
        rdt_us,
        srl,
        (lo, hi),
        (tick - fam.center_tick) / fam.ticks_per_rad if math.isfinite(tick) else math.nan,
        lock,
    )
    return P1ServoCheck(state, tuple(rows), tuple(notes), goal_range, rdt * RETURN_DELAY_UNIT_S)
