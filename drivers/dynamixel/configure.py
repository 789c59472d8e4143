"""Bring servos to what a rig expects: find them at any baud, plan, write, read back.

A servo family is a small table (:class:`Family`): which register holds each setting, how
its raw value reads, the baud table, and a Lock register for families that have one (written
0 before EEPROM writes and 1 after). :data:`X_SERIES` is the Dynamixel X-series on Protocol
2.0; other families plug in with their own table and a link that speaks their protocol
(ping, read, write, set_baud, broadcast_ping as :class:`~drivers.dynamixel.link.Link` has
them).

The steps, each usable alone (``hilsim setup`` and the start-up check use them):
:func:`find` (which IDs answer at which baud), :func:`read_settings` (one read per servo),
:func:`plan` (a :class:`Change` per register that differs from the :class:`Target`),
:func:`apply` (torque off, EEPROM writes, the ID, the baud last) and :func:`verify` (read
back at the new baud). Nothing here prints.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

from drivers.dynamixel.errors import CommError, CommTimeout, ServoError
from drivers.protocol2 import control_table as ct
from drivers.protocol2.control_table import Item, OperatingMode


class RegisterLink(Protocol):
    """What :mod:`configure` needs of a link (:class:`~drivers.dynamixel.link.Link`)."""

    @property
    def baud(self) -> int: ...
    def set_baud(self, baud: int) -> None: ...
    def ping(self, servo_id: int) -> tuple[int, int]: ...
    def broadcast_ping(self) -> dict[int, tuple[int, int]]: ...
    def read(self, servo_id: int, addr: int, size: int) -> bytes: ...
    def write_item(self, servo_id: int, item: Item, value: int) -> None: ...
    def settle(self) -> None: ...


@dataclass(frozen=True)
class Register:
    """One setting of a family: its key, where it lives, how a raw value reads."""

    key: str
    item: Item
    text: Callable[[int], str] = str


@dataclass(frozen=True)
class Family:
    """A servo family's registers and encodings (see the module docstring)."""

    name: str
    bauds: Mapping[int, int]  # Baud Rate register value -> bit/s
    id: Item
    baud: Item
    torque: Item
    #: the settings :func:`plan` compares, in the order :func:`apply` writes them (ID and
    #: baud are written after these, the baud last)
    registers: tuple[Register, ...]
    lock: Item | None = None
    #: the span one read covers (from address 0): every register above, and torque
    read_size: int = 0
    #: the rate servos leave the factory at
    factory_baud: int = 57_600

    def probe_order(self, first: int | None = None) -> list[int]:
        """The family's bauds in the order worth trying: ``first`` (the rig's), the factory
        rate, the rest ascending, the slowest last (a broadcast Ping there takes seconds)."""
        rates = sorted(set(self.bauds.values()))
        head = [b for b in (first, self.factory_baud) if b is not None]
        head = list(dict.fromkeys(head))
        rest = [b for b in rates[1:] if b not in head] + [b for b in rates[:1] if b not in head]
        return head + rest

    def register(self, key: str) -> Register:
        return next(r for r in self.registers if r.key == key)

    def baud_code(self, bps: int) -> int:
        for code, rate in self.bauds.items():
            if rate == bps:
                return code
        raise ValueError(f"{self.name}: no Baud Rate value for {bps} bit/s")


def _mode(raw: int) -> str:
    try:
        return f"{OperatingMode(raw).name.lower()} ({raw})"
    except ValueError:
        return f"unknown ({raw})"


def _shutdown(raw: int) -> str:
    return f"0x{raw:02X} ({ct.describe_hardware_error(raw)})"


#: Dynamixel X-series, Protocol 2.0 (the e-Manual's control table; no Lock register).
X_SERIES = Family(
    name="Dynamixel X (Protocol 2.0)",
    bauds=ct.BAUD_RATES,
    id=ct.ID,
    baud=ct.BAUD_RATE,
    torque=ct.TORQUE_ENABLE,
    registers=(
        Register("return_delay", ct.RETURN_DELAY_TIME, lambda raw: f"{raw * 2} us"),
        Register("mode", ct.OPERATING_MODE, _mode),
        Register("min_position", ct.MIN_POSITION_LIMIT),
        Register("max_position", ct.MAX_POSITION_LIMIT),
        Register("shutdown", ct.SHUTDOWN, _shutdown),
        Register("status_return", ct.STATUS_RETURN_LEVEL),
    ),
    read_size=ct.STATUS_RETURN_LEVEL.end,
)


@dataclass(frozen=True)
class Target:
    """What one servo should be after setup.

    ``position_ticks``: the Goal Position range the loop will use; the limits are widened
    to contain it (never narrowed). ``shutdown_bits``: bits the Shutdown mask must include.
    """

    id: int
    baud: int
    return_delay_us: float = 0.0
    operating_mode: int = OperatingMode.POSITION
    position_ticks: tuple[int, int] | None = None
    shutdown_bits: int = int(
        ct.HardwareError.OVERHEATING | ct.HardwareError.ELECTRICAL_SHOCK | ct.HardwareError.OVERLOAD
    )
    status_return_level: int = ct.STATUS_RETURN_ALL


@dataclass(frozen=True)
class Found:
    """A servo that answered: its ID, the baud it answered at, model and firmware."""

    id: int
    baud: int
    model_number: int
    model_name: str
    firmware: int


@dataclass(frozen=True)
class Change:
    """One register to write on one servo (``servo``: its ID now, at ``baud``)."""

    servo: int
    baud: int
    key: str
    name: str
    now: int | None
    wanted: int
    now_text: str
    wanted_text: str


@dataclass
class Settings:
    """One servo's settings as read (raw register values by key; None: not readable)."""

    values: dict[str, int] = field(default_factory=dict)
    torque_on: bool = False
    readable: bool = True


# ---------------------------------------------------------------------- find
def find(
    link: RegisterLink,
    bauds: Iterable[int],
    ids: Iterable[int] | None = None,
    *,
    unicast: bool = True,
    progress: Callable[[int, list[Found]], None] | None = None,
) -> list[Found]:
    """Every servo answering at each of ``bauds`` (a broadcast Ping per baud, and unicast
    Pings of ``ids`` where the broadcast found none of them: a servo at Status Return Level
    0 still answers Ping, but a reply lost in a broadcast is not retried). The link is left
    at the last baud.
    ``progress(baud, found_there)`` is called after each baud."""
    wanted = None if ids is None else sorted(set(ids))
    found: list[Found] = []
    for baud in bauds:
        link.set_baud(baud)
        answers = link.broadcast_ping()
        link.settle()  # replies still on the wire (slow rates, long Return Delay) would
        # arrive as the next request's reply
        if unicast and wanted is not None and not any(i in answers for i in wanted):
            for sid in wanted:
                try:
                    answers[sid] = link.ping(sid)
                except (CommError, ServoError):
                    continue
        here = [
            Found(sid, baud, model, ct.model_name(model), fw)
            for sid, (model, fw) in sorted(answers.items())
        ]
        found += here
        if progress is not None:
            progress(baud, here)
    return found


# ---------------------------------------------------------------------- read, plan
def read_settings(link: RegisterLink, family: Family, servo_id: int, attempts: int = 3) -> Settings:
    """The family's registers of one servo in one read; ``readable`` False when the servo
    answers Ping but not Read (Status Return Level 0)."""
    for k in range(attempts):
        try:
            block = link.read(servo_id, 0, family.read_size)
            break
        except CommTimeout:
            if k + 1 == attempts:
                return Settings(readable=False)
            link.settle()
    values = {r.key: r.item.decode(block) for r in family.registers}
    values["id"] = family.id.decode(block)
    values["baud"] = family.baud.decode(block)
    return Settings(values, family.torque.decode(block) == 1)


def plan(family: Family, found: Found, settings: Settings, target: Target) -> list[Change]:
    """Every register of ``found`` that differs from ``target``; ID then baud come last."""
    want: dict[str, int] = {
        "return_delay": int(target.return_delay_us // 2),
        "mode": int(target.operating_mode),
        "status_return": target.status_return_level,
    }
    v = settings.values
    if target.position_ticks is not None and int(target.operating_mode) == OperatingMode.POSITION:
        lo, hi = target.position_ticks
        want["min_position"] = min(lo, v.get("min_position", lo))
        want["max_position"] = max(hi, v.get("max_position", hi))
    want["shutdown"] = v.get("shutdown", 0) | target.shutdown_bits
    changes: list[Change] = []

    def add(key: str, name: str, now: int | None, wanted: int, text: Callable[[int], str]) -> None:
        if now != wanted:
            shown = "? (answers Ping only)" if now is None else text(now)
            changes.append(
                Change(found.id, found.baud, key, name, now, wanted, shown, text(wanted))
            )

    for reg in family.registers:
        if reg.key in want:
            add(reg.key, reg.item.name, v.get(reg.key), want[reg.key], reg.text)
    add("id", family.id.name, found.id, target.id, str)
    code = family.baud_code(target.baud)
    now_code = family.baud_code(found.baud) if found.baud in family.bauds.values() else None
    add("baud", family.baud.name, now_code, code, lambda c: f"{family.bauds[c]} bit/s")
    return changes


# ---------------------------------------------------------------------- write, verify
def apply(
    link: RegisterLink, family: Family, changes: Sequence[Change], attempts: int = 3
) -> list[str]:
    """Write ``changes`` (from :func:`plan`, possibly for several servos at several bauds):
    per servo, torque off and Lock off, the settings, Lock on, the ID; then every baud, last.
    Returns what could not be written (one line each); the caller verifies."""
    problems: list[str] = []
    by_servo: dict[tuple[int, int], list[Change]] = {}
    for c in changes:
        by_servo.setdefault((c.baud, c.servo), []).append(c)
    bauds: list[tuple[int, int, int]] = []  # (baud now, ID after, new baud code)
    for (baud, sid), items in sorted(by_servo.items()):
        link.set_baud(baud)
        settle_first = [c for c in items if c.key == "status_return"]  # writes answered after
        rest = [c for c in items if c.key not in ("status_return", "id", "baud")]
        new_id = next((c.wanted for c in items if c.key == "id"), sid)
        try:
            _write(link, sid, family.torque, 0, attempts, quiet=True)
            if family.lock is not None:
                _write(link, sid, family.lock, 0, attempts, quiet=True)
            for c in settle_first:  # a servo at level 0/1 does not answer writes until then
                _write(link, sid, family.register(c.key).item, c.wanted, attempts, quiet=True)
            for c in rest:
                _write(link, sid, family.register(c.key).item, c.wanted, attempts)
            if family.lock is not None:
                _write(link, sid, family.lock, 1, attempts)
            if new_id != sid:  # the reply may come from either ID: checked by a Ping
                _write(link, sid, family.id, new_id, 1, quiet=True)
                link.settle()
                link.ping(new_id)
        except (CommError, ServoError) as exc:
            problems.append(f"servo {sid}: {exc}")
            continue
        for c in items:
            if c.key == "baud":
                bauds.append((baud, new_id, c.wanted))
    for baud, sid, code in bauds:  # last: the servo hears only its new rate from here on
        link.set_baud(baud)
        try:
            _write(link, sid, family.baud, code, 1, quiet=True)
        except (CommError, ServoError) as exc:
            problems.append(f"servo {sid}: {exc}")
        link.settle()
    return problems


def _write(
    link: RegisterLink, sid: int, item: Item, value: int, attempts: int, *, quiet: bool = False
) -> None:
    """Write one register, retried on the wire; ``quiet``: a missing reply is not an error
    (Status Return Level below 2, a changed ID or baud: the read-back checks)."""
    for k in range(attempts):
        try:
            link.write_item(sid, item, value)
            return
        except CommTimeout:
            if quiet and k + 1 == attempts:
                return
            if k + 1 == attempts:
                raise
            link.settle()


def verify(
    link: RegisterLink, family: Family, targets: Sequence[Target], attempts: int = 3
) -> tuple[list[Change], list[int]]:
    """Read every target back at its baud: the registers that still differ, and the IDs
    that do not answer there."""
    left: list[Change] = []
    silent: list[int] = []
    for t in targets:
        link.set_baud(t.baud)
        try:
            model, fw = _ping(link, t.id, attempts)
        except (CommError, ServoError):
            silent.append(t.id)
            continue
        found = Found(t.id, t.baud, model, ct.model_name(model), fw)
        left += plan(family, found, read_settings(link, family, t.id, attempts), t)
    return left, silent


def _ping(link: RegisterLink, sid: int, attempts: int) -> tuple[int, int]:
    for k in range(attempts):
        try:
            return link.ping(sid)
        except CommError:
            if k + 1 == attempts:
                raise
            link.settle()
    raise AssertionError("unreachable")
