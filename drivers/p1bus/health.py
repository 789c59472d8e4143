"""Torque, health, EEPROM writes and the exit policy on a Protocol 1.0-framed bus.

Outside the tick, each step is confirmed by reading back and retried; a servo that cannot
be confirmed is named, never skipped silently. These families have no Bus Watchdog and no
Hardware Error Status register: health comes from the status ERR bits of every reply and a
periodic read of torque, load, voltage and temperature (:func:`read_health`). ``hold``
leaves torque on with Goal Position := Present Position; if the host then dies the servos
keep holding (nothing stops them on their own). EEPROM writes go through
:func:`write_eeprom`, which unlocks and relocks a Feetech servo's Lock register.
"""

from __future__ import annotations

from collections.abc import Sequence

from drivers.dynamixel.errors import CommError, ExitNotConfirmed, PortGone
from drivers.p1bus.link import P1Link, StatusError, decode
from drivers.p1bus.table import Family, Reg
from drivers.servo_bus import (
    ExitPolicy,
    ExitReport,
    HealthPart,
    HealthProblem,
    ServoCondition,
    ServoHealth,
)

#: what an exit ``hold`` says of every servo on these buses
NO_WATCHDOG_NOTE = (
    "no Bus Watchdog on this family: the servos hold their last goal until powered off or "
    "driven again"
)


class _UnconfirmedError(Exception):
    pass


def health_block(fam: Family) -> tuple[int, int]:
    """``(addr, size)`` of one read from Torque Enable through Present Temperature."""
    start = fam.torque_enable.addr
    return start, fam.present_temperature.end - start


def read_health(link: P1Link, fam: Family, servo_id: int, part: HealthPart) -> ServoHealth:
    """Torque, the status ERR bits, load, voltage and temperature of one servo, in one read.
    ``part`` WATCHDOG (a limp joint's) and CONDITION read the same: there is no watchdog
    to read, and every read fills ``condition``."""
    addr, size = health_block(fam)
    err, data = link.read_bytes(fam, servo_id, addr, size)
    torque = bool(decode(fam, fam.torque_enable, data, addr))
    load = decode(fam, fam.present_load, data, addr)
    volts = decode(fam, fam.present_voltage, data, addr) / 10.0
    temp = decode(fam, fam.present_temperature, data, addr)
    hw = err & fam.hardware_bits
    figures = f"{temp} °C, {volts:.1f} V, load {load / 10:+.1f} %"
    cond = ServoCondition(float(temp), volts, load / 10.0)
    if hw:
        problem: HealthProblem | None = HealthProblem.HARDWARE_ERROR
        detail = f"status error bits: {fam.describe_error(hw)} ({figures})"
    elif not torque and part is not HealthPart.WATCHDOG:
        problem, detail = HealthProblem.TORQUE_OFF, f"Torque Enable reads 0 ({figures})"
    else:
        problem, detail = None, figures
    return ServoHealth(servo_id, torque, hw, None, None, problem, detail, cond)


def write_all(
    link: P1Link, fams: dict[int, Family], ids: Sequence[int], which: str, value: int, tries: int
) -> None:
    """``which`` register (a :class:`Family` field name) := ``value`` on every servo, each
    confirmed by reading back; tries all, raises the first failure with the others noted."""
    failures: list[str] = []
    for sid in ids:
        fam = fams[sid]
        try:
            _confirm(link, fam, sid, getattr(fam, which), value, tries)
        except _UnconfirmedError as exc:
            failures.append(f"servo {sid}: {exc}")
    if failures:
        raise CommError(f"{which.replace('_', ' ')} := {value}: " + "; ".join(failures))


def write_eeprom(link: P1Link, fam: Family, servo_id: int, reg: Reg, value: int) -> None:
    """Write an EEPROM register and confirm it. A Feetech servo keeps EEPROM writes only
    while unlocked: Lock := 0, write, Lock := 1 (relocked even when the write fails). The
    Dynamixel Lock (47) locks EEPROM until power-off: never touched here."""
    lock = fam.lock
    if lock is not None:
        _confirm(link, fam, servo_id, lock, 0, 2)
    try:
        _confirm(link, fam, servo_id, reg, value, 2)
    finally:
        if lock is not None:
            _confirm(link, fam, servo_id, lock, 1, 2)


def apply_exit_policy(
    link: P1Link, fams: dict[int, Family], ids: Sequence[int], policy: ExitPolicy, attempts: int
) -> ExitReport:
    """``hold``: torque must read on; Goal Position := Present Position, read back.
    ``relax``: Torque Enable := 0, read back. A servo whose step fails ``attempts`` times is
    named; the adapter gone stops at once. Raises :class:`ExitNotConfirmed` unless every
    servo is confirmed."""
    confirmed: list[int] = []
    failed: list[tuple[int, str]] = []
    notes = [NO_WATCHDOG_NOTE] if policy is ExitPolicy.HOLD else []
    try:
        link.recover()
        for sid in ids:
            fam = fams[sid]
            try:
                if policy is ExitPolicy.HOLD:
                    if not _read(link, fam, sid, fam.torque_enable, attempts):
                        raise _UnconfirmedError("torque is off: cannot hold (the servo is limp)")
                    present = _read(link, fam, sid, fam.present_position, attempts)
                    _confirm(link, fam, sid, fam.goal_position, present, attempts)
                else:
                    _confirm(link, fam, sid, fam.torque_enable, 0, attempts)
                confirmed.append(sid)
            except _UnconfirmedError as exc:
                failed.append((sid, str(exc)))
    except PortGone as exc:
        done = {s for s, _ in failed} | set(confirmed)
        failed += [(s, f"adapter gone: {exc}") for s in ids if s not in done]
        raise ExitNotConfirmed(
            ExitReport(policy, tuple(confirmed), tuple(failed), tuple(notes))
        ) from exc
    report = ExitReport(policy, tuple(confirmed), tuple(failed), tuple(notes))
    if failed:
        raise ExitNotConfirmed(report)
    return report


def _read(link: P1Link, fam: Family, sid: int, reg: Reg, attempts: int) -> int:
    last: Exception | None = None
    for _ in range(attempts):
        try:
            return link.read_reg(fam, sid, reg)
        except (CommError, StatusError) as exc:
            last = exc
    raise _UnconfirmedError(f"reading {reg.name} failed {attempts}x: {last}")


def _confirm(link: P1Link, fam: Family, sid: int, reg: Reg, value: int, attempts: int) -> None:
    """``reg := value`` and read back, up to ``attempts`` times."""
    last = ""
    for _ in range(attempts):
        try:
            link.write_reg(fam, sid, reg, value)
            got = link.read_reg(fam, sid, reg)
        except (CommError, StatusError) as exc:
            last = str(exc)
            continue
        if got == value:
            return
        last = f"wrote {value}, read back {got}"
    raise _UnconfirmedError(f"{reg.name} := {value} not confirmed after {attempts} try(s): {last}")
