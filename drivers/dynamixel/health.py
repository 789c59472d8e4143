"""Servo state outside the tick, over a :class:`~drivers.dynamixel.link.Link`: health
reads, torque and the Bus Watchdog (arming on every servo, clearing old trips, recovering
from one) and the exit policy.

:class:`~drivers.dynamixel.bus.DynamixelBus` calls these with its link, its servo IDs and
the watchdog period it armed (``watchdog_units``, 20 ms units; None when not armed).
Each step is tried up to ``attempts`` times. The recovery and exit steps are confirmed by
reading them back; a servo that cannot be confirmed is named, never skipped silently.

Imports neither ``dynamixel_sdk`` nor the bus.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from typing import TYPE_CHECKING

from drivers.dynamixel.errors import (
    CommError,
    DynamixelError,
    ExitNotConfirmed,
    PortGone,
    ServoError,
)
from drivers.dynamixel.startup import retry
from drivers.protocol2 import control_table as ct
from drivers.protocol2.control_table import Item
from drivers.servo_bus import (
    ExitPolicy,
    ExitReport,
    HealthPart,
    HealthProblem,
    ServoCondition,
    ServoHealth,
)

if TYPE_CHECKING:
    from drivers.dynamixel.link import Link

#: Watchdog period a ``hold`` exit arms when the bus never armed one (s).
DEFAULT_EXIT_WATCHDOG_S = 0.1


class _UnconfirmedError(Exception):
    """One exit or recovery step could not be confirmed on one servo (internal)."""


# ----------------------------------------------------------------------- health
def read_condition(link: Link, servo_id: int, model: str | None) -> ServoCondition:
    """Temperature, input voltage and load of one servo in one read of Present Load ..
    Present Temperature. ``model`` says what register 126 holds (see
    :data:`~drivers.protocol2.control_table.LOAD_REGISTER_MA`): a current on most
    models, Present Load on a few; an unknown model leaves both NaN rather than guess."""
    item = ct.CONDITION_BLOCK
    block = link.read(servo_id, item.addr, item.size)
    raw = ct.PRESENT_LOAD.decode(block, item.addr)
    nan = float("nan")
    load = current = nan
    if model in ct.LOAD_REGISTER_MA:
        unit_ma = ct.LOAD_REGISTER_MA[model]
        if unit_ma is None:
            load = raw / 10.0
        else:
            current = raw * unit_ma * 1e-3
    return ServoCondition(
        float(ct.PRESENT_TEMPERATURE.decode(block, item.addr)),
        ct.PRESENT_INPUT_VOLTAGE.decode(block, item.addr) / 10.0,
        load,
        current,
    )


def read_health(
    link: Link,
    servo_id: int,
    part: HealthPart,
    watchdog_units: int | None,
    model: str | None = None,
) -> ServoHealth:
    """Read ``part`` of one servo's health and name what is wrong, if anything (see
    :meth:`~drivers.servo_bus.ServoBus.read_health`)."""
    if part is HealthPart.CONDITION:
        return ServoHealth(
            servo_id, None, None, None, None, condition=read_condition(link, servo_id, model)
        )
    torque = hw = wd = None
    if part is HealthPart.WATCHDOG:
        wd = link.read_item(servo_id, ct.BUS_WATCHDOG)
    else:
        item = ct.HEALTH_WATCHDOG_BLOCK if part is HealthPart.ALL else ct.HEALTH_BLOCK
        block = link.read(servo_id, item.addr, item.size)
        torque = ct.TORQUE_ENABLE.decode(block, item.addr) == 1
        hw = ct.HARDWARE_ERROR_STATUS.decode(block, item.addr)
        if part is HealthPart.ALL:
            wd = ct.BUS_WATCHDOG.decode(block, item.addr)
        elif not torque or hw:  # something is wrong: the watchdog names the cause
            wd = link.read_item(servo_id, ct.BUS_WATCHDOG)
    return judge(link, servo_id, torque, hw, wd, watchdog_units)


def judge(
    link: Link,
    servo_id: int,
    torque: bool | None,
    hw: int | None,
    wd: int | None,
    watchdog_units: int | None,
) -> ServoHealth:
    """What is wrong with a servo whose Torque Enable, Hardware Error Status and Bus
    Watchdog read ``torque``, ``hw``, ``wd`` (None: not read), if anything; a problem's
    detail reads its temperature, voltage and load (best effort)."""
    tripped = None if wd is None else wd == ct.WATCHDOG_TRIPPED
    armed = None if wd is None else wd > 0
    expected = watchdog_units
    problem, detail = None, ""
    if hw:
        problem = HealthProblem.HARDWARE_ERROR
        detail = (
            f"Hardware Error Status 0x{hw:02X} ({ct.describe_hardware_error(hw)})"
            f"{condition(link, servo_id)}; remove the cause, then reboot the servo"
        )
    elif torque is False and expected and wd == 0:
        problem = HealthProblem.RESET
        detail = (
            f"torque off and Bus Watchdog 0 although it was armed ({expected} x 20 ms): "
            "the servo restarted (brownout or reboot) and its RAM is back to defaults"
            f"{condition(link, servo_id)}"
        )
    elif tripped:
        problem = HealthProblem.WATCHDOG_TRIPPED
        detail = "Bus Watchdog reads -1: the servo stopped itself and refuses goals"
    elif torque is False:
        problem = HealthProblem.TORQUE_OFF
        detail = "Torque Enable reads 0: the servo is limp"
    return ServoHealth(servo_id, torque, hw, tripped, armed, problem, detail)


def condition(link: Link, servo_id: int) -> str:
    """Temperature, input voltage and load of one servo, as text (best effort: "" when
    it does not answer)."""
    block_item = ct.CONDITION_BLOCK
    try:
        block = link.read(servo_id, block_item.addr, block_item.size)
    except (CommError, ServoError):
        return ""
    start = block_item.addr
    return (
        f"; {ct.PRESENT_TEMPERATURE.decode(block, start)} °C, "
        f"{ct.PRESENT_INPUT_VOLTAGE.decode(block, start) / 10:.1f} V, "
        f"load {ct.PRESENT_LOAD.decode(block, start)}"
    )


# ----------------------------------------------------------------------- torque, watchdog
def write_all(
    link: Link, ids: Sequence[int], item: Item, value: int, attempts: int, what: str
) -> None:
    """Write ``item := value`` on every servo (each tried ``attempts`` times); raise the
    first failure after trying all, the others noted on it (``what`` names the step)."""
    link.recover()
    failures: list[DynamixelError] = []
    for sid in ids:
        try:
            retry(attempts, partial(link.write_item, sid, item, value), settle=link.settle)
        except (CommError, ServoError) as exc:
            failures.append(exc)
    if failures:
        first = failures[0]
        if len(failures) > 1:
            first.add_note(f"{what} also failed on: " + "; ".join(map(str, failures[1:])))
        raise first


def clear_watchdog_trips(link: Link, ids: Sequence[int], attempts: int) -> tuple[int, ...]:
    """Disarm every servo's Bus Watchdog and return the IDs whose watchdog had tripped.
    Servos that do not answer are skipped (see
    :meth:`~drivers.dynamixel.bus.DynamixelBus.clear_watchdog_trips`)."""
    link.recover()
    tripped = []
    for sid in ids:
        try:
            value = retry(
                attempts, partial(link.read_item, sid, ct.BUS_WATCHDOG), settle=link.settle
            )
            if value != 0:
                retry(
                    attempts,
                    partial(link.write_item, sid, ct.BUS_WATCHDOG, 0),
                    settle=link.settle,
                )
        except (CommError, ServoError):
            continue
        if value == ct.WATCHDOG_TRIPPED:
            tripped.append(sid)
    return tuple(tripped)


def recover_watchdog(
    link: Link, servo_id: int, tick: int, watchdog_units: int | None, attempts: int
) -> None:
    """Clear one servo's tripped Bus Watchdog, set its Goal Position to ``tick`` and arm
    the watchdog again (``watchdog_units``, when armed), each step read back; raises
    :class:`DynamixelError` naming the step that could not be confirmed."""
    link.recover()
    try:  # inside a tick: a failed try is retried at once (no settle)
        _confirm(link, servo_id, ct.BUS_WATCHDOG, 0, attempts, settle=False)
        _confirm(link, servo_id, ct.GOAL_POSITION, tick, attempts, settle=False)
        if watchdog_units:
            _confirm(link, servo_id, ct.BUS_WATCHDOG, watchdog_units, attempts, settle=False)
    except _UnconfirmedError as exc:
        raise DynamixelError(
            f"servo {servo_id}: cannot recover from the Bus Watchdog trip: {exc}"
        ) from None


# ----------------------------------------------------------------------- exit
def apply_exit_policy(
    link: Link,
    ids: Sequence[int],
    policy: ExitPolicy,
    attempts: int,
    watchdog_units: int | None,
) -> ExitReport:
    """``hold``: torque must be on; a tripped watchdog is cleared, Goal Position :=
    Present Position, then the watchdog armed (``watchdog_units``, else
    :data:`DEFAULT_EXIT_WATCHDOG_S`); each read back. ``relax``: Torque Enable := 0, read
    back. A servo whose step fails ``attempts`` times is skipped and named; the adapter
    gone stops at once. Raises :class:`ExitNotConfirmed` unless every servo is confirmed."""
    confirmed: list[int] = []
    failed: list[tuple[int, str]] = []
    notes: list[str] = []
    try:
        link.recover()
        for sid in ids:
            try:
                if policy is ExitPolicy.HOLD:
                    _hold_one(link, sid, attempts, watchdog_units, notes)
                else:
                    _confirm(link, sid, ct.TORQUE_ENABLE, 0, attempts)
                confirmed.append(sid)
            except _UnconfirmedError as exc:
                failed.append((sid, str(exc)))
    except PortGone as exc:
        done = {s for s, _ in failed} | set(confirmed)
        failed += [(s, f"adapter gone: {exc}") for s in ids if s not in done]
        report = ExitReport(policy, tuple(confirmed), tuple(failed), tuple(notes))
        raise ExitNotConfirmed(report) from exc
    report = ExitReport(policy, tuple(confirmed), tuple(failed), tuple(notes))
    if failed:
        raise ExitNotConfirmed(report)
    return report


def _hold_one(
    link: Link, sid: int, attempts: int, watchdog_units: int | None, notes: list[str]
) -> None:
    if not _read(link, sid, ct.TORQUE_ENABLE, attempts):
        raise _UnconfirmedError("torque is off: cannot hold (the servo is limp)")
    if _read(link, sid, ct.BUS_WATCHDOG, attempts) == ct.WATCHDOG_TRIPPED:
        # The servo had stopped itself (the host was silent longer than the watchdog
        # period); holding needs the trip cleared: say so, never silently.
        _confirm(link, sid, ct.BUS_WATCHDOG, 0, attempts)
        notes.append(
            f"servo {sid}: its Bus Watchdog had tripped (it had stopped itself); cleared to hold it"
        )
    present = _read(link, sid, ct.PRESENT_POSITION, attempts)
    _confirm(link, sid, ct.GOAL_POSITION, present, attempts)
    units = watchdog_units or round(DEFAULT_EXIT_WATCHDOG_S / ct.WATCHDOG_UNIT_S)
    _confirm(link, sid, ct.BUS_WATCHDOG, units, attempts)


def _read(link: Link, sid: int, item: Item, attempts: int, settle: bool = True) -> int:
    """``item`` of servo ``sid``, tried ``attempts`` times; ``settle``: wait a failed try's
    late reply out before the next (:meth:`Link.settle`; never inside a tick)."""
    last: Exception | None = None
    for k in range(attempts):
        try:
            return link.read_item(sid, item)
        except (CommError, ServoError) as exc:
            last = exc
            if settle and k + 1 < attempts:
                link.settle()
    raise _UnconfirmedError(f"reading {item.name} failed {attempts}x: {last}")


def _confirm(
    link: Link, sid: int, item: Item, value: int, attempts: int, settle: bool = True
) -> None:
    """Write ``item := value`` and read it back, up to ``attempts`` tries (``settle``: as
    :func:`_read`). After a try that failed on the wire the write may have taken (its
    status packet late or lost), so the next try reads first and writes only if the value
    is not there: on a noisy line a try then needs one clean reply, not two."""
    last = ""
    write = True
    for k in range(attempts):
        try:
            if not write and link.read_item(sid, item) == value:
                return
            link.write_item(sid, item, value)
            got = link.read_item(sid, item)
        except (CommError, ServoError) as exc:
            last = str(exc)
            write = False
            if settle and k + 1 < attempts:
                link.settle()
            continue
        if got == value:
            return
        last = f"wrote {value}, read back {got}"
    raise _UnconfirmedError(
        f"{item.name} := {value} not confirmed after {attempts} attempt(s): {last}"
    )
