"""Bring Feetech STS/SCS and Dynamixel Protocol 1.0 servos to a rig: find, plan, write, verify.

The Protocol 1.0-framed sibling of :mod:`drivers.dynamixel.configure` (same steps, same
:class:`~drivers.dynamixel.configure.Found` and :class:`~drivers.dynamixel.configure.Change`
rows, so ``hilsim setup`` prints one table for every family):

* :func:`find`: at each baud, Feetech servos answer one broadcast Ping (each in turn, in ID
  order); Dynamixel Protocol 1.0 has no broadcast Ping, so each wanted ID is pinged alone.
  An answering servo is named by its Model Number.
* :func:`read_settings` and :func:`plan`: ID, Baud Rate, Return Delay Time, Status (Response)
  Status Level, the angle limits (widened to the joint's range, never narrowed; a wheel-mode
  0..0 becomes the whole turn), and on Feetech the Operating Mode (0: position) and Phase
  bit 4 (readings beyond 0..4095, which LeRobot clears too).
* :func:`apply`: per servo, torque off, then (Feetech) Lock := 0 so that EEPROM writes are
  kept, the Status Level first (a servo not answering writes answers from then on), the
  settings, the ID, Lock := 1; every baud last. The Dynamixel Lock (one-way until power-off)
  is never touched. :func:`verify` reads every target back at the rig's baud.

Nothing here prints.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from drivers.dynamixel.configure import Change, Found, Settings
from drivers.dynamixel.errors import CommError, CommTimeout
from drivers.p1bus.link import P1Link, StatusError
from drivers.p1bus.scan import broadcast_ping, identify
from drivers.p1bus.startup import FEETECH_MODE, PHASE_WIDE_READINGS
from drivers.p1bus.table import Family, Protocol, Reg

#: the rate each maker's servos leave the factory at (AX and Feetech 1 Mbit/s; MX 57600,
#: tried second, as the factory rate of the other)
FACTORY_BAUDS = {Protocol.FEETECH: (1_000_000,), Protocol.DXL1: (1_000_000, 57_600)}
#: Return Delay Time's unit (both makers)
RETURN_DELAY_UNIT_US = 2.0


@dataclass(frozen=True)
class P1Target:
    """What one servo should be after setup: its ID, the bus's baud, the Return Delay Time,
    and the Goal Position range (ticks) the loop will use (the limits are widened to it)."""

    id: int
    baud: int
    return_delay_us: float = 0.0
    position_ticks: tuple[int, int] | None = None


def probe_order(fam: Family, first: int | None = None) -> list[int]:
    """The family's bauds worth trying, in order: ``first`` (the rig's), the factory rates,
    the rest fastest first (a slow rate's Pings take longest)."""
    rates = sorted(set(fam.baud_codes.values()), reverse=True)
    head = [b for b in (first, *FACTORY_BAUDS[fam.protocol]) if b is not None]
    head = list(dict.fromkeys(head))
    return head + [b for b in rates if b not in head]


def baud_code(fam: Family, bps: int) -> int:
    """The Baud Rate register value for ``bps`` (ValueError naming the family if none)."""
    for code, rate in fam.baud_codes.items():
        if rate == bps:
            return code
    raise ValueError(f"{fam.name}: no Baud Rate value for {bps} bit/s")


# ---------------------------------------------------------------------- find
def find(
    link: P1Link,
    fam: Family,
    bauds: Iterable[int],
    ids: Iterable[int],
    *,
    progress: Callable[[int, list[Found]], None] | None = None,
) -> list[Found]:
    """Every servo answering at each of ``bauds``: a Feetech bus's broadcast Ping (any ID),
    else a Ping per ID of ``ids``. The link is left at the last baud."""
    wanted = sorted(set(ids))
    found: list[Found] = []
    for baud in bauds:
        try:
            link.set_baud(baud)
        except ValueError:  # a rate this port cannot set
            continue
        answering = broadcast_ping(link) if fam.protocol is Protocol.FEETECH else []
        for sid in wanted:
            if sid in answering:
                continue
            try:
                link.ping1(sid)
            except CommError:
                continue
            answering.append(sid)
        here = []
        for sid in sorted(answering):
            f = identify(link, fam, fam.protocol, baud, sid)
            name = f.model_name if f.model_number >= 0 else "model unread: answers Ping only"
            here.append(Found(sid, baud, f.model_number, name, f.firmware))
        found += here
        if progress is not None:
            progress(baud, here)
    return found


# ---------------------------------------------------------------------- read, plan
def settings_registers(fam: Family) -> list[tuple[str, Reg]]:
    """The settings :func:`plan` compares, in the order :func:`apply` writes them."""
    regs = [
        ("status_return", fam.status_return_level),
        ("return_delay", fam.return_delay),
        ("min_position", fam.min_limit),
        ("max_position", fam.max_limit),
    ]
    if fam.lock is not None:  # Feetech
        regs.append(("mode", FEETECH_MODE))
    if fam.phase is not None:
        regs.append(("phase", fam.phase))
    return regs


def read_settings(link: P1Link, fam: Family, servo_id: int, attempts: int = 3) -> Settings:
    """The family's settings of one servo; ``readable`` False when it answers Ping but not
    Read (a Dynamixel servo at Status Return Level 0)."""
    values: dict[str, int] = {}
    for key, reg in [*settings_registers(fam), ("id", fam.id), ("baud", fam.baud)]:
        for k in range(attempts):
            try:
                values[key] = link.read_reg(fam, servo_id, reg)
                break
            except (CommError, StatusError):
                if k + 1 == attempts:
                    return Settings(values, readable=False)
    try:
        torque = link.read_reg(fam, servo_id, fam.torque_enable) == 1
    except (CommError, StatusError):
        torque = False
    return Settings(values, torque)


def setting_text(fam: Family, key: str) -> Callable[[int], str]:
    if key == "return_delay":
        return lambda raw: f"{raw * RETURN_DELAY_UNIT_US:g} us ({raw})"
    if key == "mode":
        return lambda raw: "position (0)" if raw == 0 else f"not position ({raw})"
    if key == "phase":
        return lambda raw: f"0x{raw:02X}"
    if key == "baud":
        return lambda code: f"{fam.baud_codes.get(code, '?')} bit/s"
    return str


def plan(fam: Family, found: Found, settings: Settings, target: P1Target) -> list[Change]:
    """Every setting of ``found`` that differs from ``target``; ID then baud come last."""
    v = settings.values
    want: dict[str, int] = {
        "status_return": fam.status_return_all,
        "return_delay": int(target.return_delay_us // RETURN_DELAY_UNIT_US),
        "mode": 0,
    }
    lo_now, hi_now = v.get("min_position"), v.get("max_position")
    if lo_now == 0 and hi_now == 0:  # wheel mode: position mode over the whole turn
        lo_now, hi_now = 0, fam.max_tick
    if target.position_ticks is not None:
        lo, hi = target.position_ticks
        want["min_position"] = max(0, min(lo, lo if lo_now is None else lo_now))
        want["max_position"] = min(fam.max_tick, max(hi, hi if hi_now is None else hi_now))
    elif lo_now is not None and hi_now is not None:
        want["min_position"], want["max_position"] = lo_now, hi_now
    if "phase" in v:
        want["phase"] = v["phase"] & ~PHASE_WIDE_READINGS
    changes: list[Change] = []

    def add(key: str, name: str, now: int | None, wanted: int) -> None:
        if now != wanted:
            text = setting_text(fam, key)
            shown = "? (answers Ping only)" if now is None else text(now)
            changes.append(
                Change(found.id, found.baud, key, name, now, wanted, shown, text(wanted))
            )

    for key, reg in settings_registers(fam):
        if key in want:
            add(key, reg.name, v.get(key), want[key])
    add("id", fam.id.name, found.id, target.id)
    now_code = v.get("baud")
    if now_code is None or fam.baud_codes.get(now_code) != found.baud:
        now_code = next((c for c, b in fam.baud_codes.items() if b == found.baud), None)
    add("baud", fam.baud.name, now_code, baud_code(fam, target.baud))
    return changes


# ---------------------------------------------------------------------- write, verify
def apply(link: P1Link, fam: Family, changes: Sequence[Change], attempts: int = 3) -> list[str]:
    """Write ``changes`` (from :func:`plan`; several servos, several bauds): per servo,
    torque off, Lock off (Feetech), the Status Level first, the settings, the ID, Lock on;
    then every baud, last (Feetech: unlocked and relocked at the new rate). Returns what
    could not be written (one line each); the caller verifies."""
    problems: list[str] = []
    regs = dict(settings_registers(fam))
    by_servo: dict[tuple[int, int], list[Change]] = {}
    for c in changes:
        by_servo.setdefault((c.baud, c.servo), []).append(c)
    bauds: list[tuple[int, int, int]] = []  # (baud now, ID after, new baud code)
    for (baud, sid), items in sorted(by_servo.items()):
        link.set_baud(baud)
        new_id = next((c.wanted for c in items if c.key == "id"), sid)
        try:
            _write(link, fam, sid, fam.torque_enable, 0, attempts)
            if fam.lock is not None:
                _write(link, fam, sid, fam.lock, 0, attempts)
            for c in sorted(items, key=lambda c: c.key != "status_return"):
                if c.key in regs:
                    _write(link, fam, sid, regs[c.key], c.wanted, attempts)
            if new_id != sid:  # the reply may come from either ID: checked by a Ping
                _write(link, fam, sid, fam.id, new_id, 1)
                link.settle()
                link.ping1(new_id)
            if fam.lock is not None:
                _write(link, fam, new_id, fam.lock, 1, attempts)
        except (CommError, StatusError) as exc:
            problems.append(f"servo {sid}: {exc}")
            continue
        bauds += [(baud, new_id, c.wanted) for c in items if c.key == "baud"]
    for baud, sid, code in bauds:  # last: the servo hears only its new rate from here on
        link.set_baud(baud)
        try:
            if fam.lock is not None:
                _write(link, fam, sid, fam.lock, 0, attempts)
            _write(link, fam, sid, fam.baud, code, 1)
            link.settle()
            if fam.lock is not None:
                link.set_baud(fam.baud_codes[code])
                _write(link, fam, sid, fam.lock, 1, attempts)
        except (CommError, StatusError) as exc:
            problems.append(f"servo {sid}: {exc}")
        link.settle()
    return problems


def _write(link: P1Link, fam: Family, sid: int, reg: Reg, value: int, attempts: int) -> None:
    """Write one register, retried; a missing reply is not an error (a Status Level below
    "all", a changed ID or baud: the read-back checks), an error bit is."""
    for _ in range(attempts):
        try:
            link.write_reg(fam, sid, reg, value)
            return
        except CommTimeout:
            link.settle()


def verify(
    link: P1Link, fam: Family, targets: Sequence[P1Target], attempts: int = 3
) -> tuple[list[Change], list[int]]:
    """Read every target back at its baud: the settings that still differ, and the IDs
    that do not answer there."""
    left: list[Change] = []
    silent: list[int] = []
    for t in targets:
        link.set_baud(t.baud)
        for k in range(attempts):
            try:
                link.ping1(t.id)
                break
            except CommError:
                if k + 1 == attempts:
                    silent.append(t.id)
        if t.id in silent:
            continue
        found = Found(t.id, t.baud, 0, fam.name, 0)
        left += plan(fam, found, read_settings(link, fam, t.id, attempts), t)
    return left, silent
