"""Faults as data: a seeded, reproducible plan of what goes wrong on the emulated bus.

A plan is a tuple of :class:`Fault` rules. Two families:

*Reply faults* act on the status packets servos send, each time one is eligible
(in its time window, from a listed servo, under its ``count``, and with probability
``rate`` drawn from the plan's seeded generator):

========== =================================================================
drop       the servo stays silent (in a Sync/Bulk Read chain, so do the servos after it)
corrupt    one byte of the reply is flipped (the host sees a CRC error)
truncate   the reply stops part-way (the host sees a short/corrupt packet)
late       the reply is sent ``delay`` seconds late: it lands in a later transaction
garbage    ``nbytes`` random bytes precede the header on the wire
========== =================================================================

*Events* happen once, at time ``at`` (seconds after the bus started):

============== =============================================================
brownout       the servo is silent for ``duration`` s, then comes back with RAM reset
hardware_error Hardware Error Status bits ``bits`` latch (Alert bit; torque cut per Shutdown);
               on Protocol 1.0 servos the family's status error bits (p1servo.py)
torque_off     torque silently drops to 0
watchdog_trip  the Bus Watchdog trips as if the host had gone quiet (X series only)
duplicate_id   a second servo of the same model answers on the same ID (collisions)
unplug         the USB adapter disappears: every read/write raises SerialException
============== =============================================================

The text form used in URLs and on the command line is ``kind:key=value,...`` rules
joined by ``;`` (or ``+``), for example ``drop:id=2,rate=0.05;unplug:at=3``.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any


class FaultKind(StrEnum):
    DROP = "drop"
    CORRUPT = "corrupt"
    TRUNCATE = "truncate"
    LATE = "late"
    GARBAGE = "garbage"
    BROWNOUT = "brownout"
    HARDWARE_ERROR = "hardware_error"
    TORQUE_OFF = "torque_off"
    WATCHDOG_TRIP = "watchdog_trip"
    DUPLICATE_ID = "duplicate_id"
    UNPLUG = "unplug"


REPLY_FAULTS = frozenset(
    {FaultKind.DROP, FaultKind.CORRUPT, FaultKind.TRUNCATE, FaultKind.LATE, FaultKind.GARBAGE}
)
_ALIASES = {
    "hwerr": FaultKind.HARDWARE_ERROR,
    "hw_error": FaultKind.HARDWARE_ERROR,
    "torque": FaultKind.TORQUE_OFF,
    "watchdog": FaultKind.WATCHDOG_TRIP,
    "dup": FaultKind.DUPLICATE_ID,
    "duplicate": FaultKind.DUPLICATE_ID,
}
#: Hardware Error Status bits by name (addr 70).
HARDWARE_ERROR_BITS = {
    "voltage": 0x01,
    "overheating": 0x04,
    "encoder": 0x08,
    "electrical_shock": 0x10,
    "overload": 0x20,
}


class FaultSpecError(ValueError):
    """A fault rule that cannot be understood; the message says what is allowed."""


@dataclass(frozen=True)
class Fault:
    """One rule of a fault plan. Times are seconds after the bus started.

    ``ids`` limits the rule to those servo IDs (None: any servo; events need exactly
    one ID except ``unplug``). ``rate`` is the probability per eligible reply;
    ``count`` caps how many times a reply fault fires (None: unlimited).
    """

    kind: FaultKind
    ids: frozenset[int] | None = None
    rate: float = 1.0
    at: float = 0.0
    until: float = float("inf")
    count: int | None = None
    delay: float = 0.05  # late
    nbytes: int = 6  # garbage
    duration: float = 0.2  # brownout
    bits: int = 0x20  # hardware_error (overload)

    def __post_init__(self) -> None:
        if not 0.0 <= self.rate <= 1.0:
            raise FaultSpecError(f"{self.kind}: rate must be in [0, 1], got {self.rate}")
        if self.until < self.at:
            raise FaultSpecError(f"{self.kind}: until ({self.until}) is before at ({self.at})")
        if self.count is not None and self.count < 0:
            raise FaultSpecError(f"{self.kind}: count must be >= 0, got {self.count}")
        for key in ("delay", "duration"):
            value = getattr(self, key)
            if value < 0:
                raise FaultSpecError(f"{self.kind}: {key} must be >= 0 s, got {value}")
        if self.nbytes < 1:
            raise FaultSpecError(f"{self.kind}: nbytes must be >= 1, got {self.nbytes}")
        if not 0 < self.bits <= 0xFF:
            names = ", ".join(HARDWARE_ERROR_BITS)
            raise FaultSpecError(
                f"{self.kind}: bits must be 1..255 or one of {names}, got {self.bits}"
            )
        if self.kind is FaultKind.UNPLUG and self.ids is not None:
            given = ",".join(str(i) for i in sorted(self.ids))
            raise FaultSpecError(
                f"{self.kind}: the USB adapter goes for every servo; it takes no id= "
                f"(got id={given})"
            )
        if (
            self.is_event
            and self.kind is not FaultKind.UNPLUG
            and (self.ids is None or len(self.ids) != 1)
        ):
            raise FaultSpecError(f"{self.kind} is an event on one servo: give id=N")

    @property
    def is_event(self) -> bool:
        return self.kind not in REPLY_FAULTS


@dataclass
class FaultPlan:
    """The rules plus the seeded generator and counters that make them reproducible."""

    faults: tuple[Fault, ...] = ()
    seed: int = 0
    _rng: random.Random = field(init=False, repr=False)
    _fired: list[int] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.faults = tuple(self.faults)
        self._rng = random.Random(self.seed)
        self._fired = [0] * len(self.faults)

    @property
    def rng(self) -> random.Random:
        return self._rng

    @property
    def events(self) -> list[Fault]:
        return sorted((f for f in self.faults if f.is_event), key=lambda f: f.at)

    def reply_fault(self, servo_id: int, t: float) -> Fault | None:
        """The reply fault (if any) that strikes a reply from ``servo_id`` sent at ``t``.

        Rules are tried in plan order; the first that fires wins. Every eligible rule
        draws from the generator, so a plan replays identically for the same traffic.
        """
        for i, f in enumerate(self.faults):
            if f.is_event or not (f.at <= t < f.until):
                continue
            if f.ids is not None and servo_id not in f.ids:
                continue
            if f.count is not None and self._fired[i] >= f.count:
                continue
            if f.rate >= 1.0 or self._rng.random() < f.rate:
                self._fired[i] += 1
                return f
        return None

    def fired(self) -> dict[str, int]:
        """How many times each rule fired, keyed ``"<index>:<kind>"``."""
        pairs = zip(self.faults, self._fired, strict=True)
        return {f"{i}:{f.kind}": n for i, (f, n) in enumerate(pairs)}


_FLOAT_KEYS = {"rate", "at", "until", "delay", "duration"}
_INT_KEYS = {"count", "nbytes", "bits"}


def _parse_ids(text: str) -> frozenset[int]:
    from drivers.protocol2.ids import parse_ids

    return frozenset(parse_ids(text))


def parse_fault(text: str) -> Fault:
    """Parse one rule, ``kind[:key=value,...]``. See the module docstring for kinds."""
    text = text.strip()
    name, _, rest = text.partition(":")
    name = name.strip().lower().replace("-", "_")
    try:
        kind = _ALIASES.get(name) or FaultKind(name)
    except ValueError:
        choices = ", ".join(k.value for k in FaultKind)
        raise FaultSpecError(
            f"unknown fault kind {name!r} in {text!r}; choose from: {choices}"
        ) from None
    kwargs: dict[str, Any] = {}  # Fault's fields by the names the text gives; Fault checks them
    for item in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, value = item.partition("=")
        key = key.strip().lower()
        if not eq:
            raise FaultSpecError(f"{text!r}: expected key=value, got {item!r}")
        try:
            if key in ("id", "ids"):
                kwargs["ids"] = _parse_ids(value.replace("|", ","))
            elif key in _FLOAT_KEYS:
                kwargs[key] = float(value)
            elif key == "bits" and value.strip().lower() in HARDWARE_ERROR_BITS:
                kwargs["bits"] = HARDWARE_ERROR_BITS[value.strip().lower()]
            elif key in _INT_KEYS:
                kwargs[key] = int(value, 0)
            else:
                allowed = "id, rate, at, until, count, delay, nbytes, duration, bits"
                raise FaultSpecError(f"{text!r}: unknown key {key!r}; allowed: {allowed}")
        except ValueError as exc:
            if isinstance(exc, FaultSpecError):
                raise
            raise FaultSpecError(f"{text!r}: bad value for {key!r}: {value!r}") from None
    try:
        return Fault(kind, **kwargs)
    except FaultSpecError as exc:
        raise FaultSpecError(f"{text!r}: {exc}") from None


def parse_fault_plan(text: str, seed: int = 0) -> FaultPlan:
    """Parse ``rule;rule;...`` (``+`` also separates rules) into a :class:`FaultPlan`."""
    rules = [r for r in text.replace("+", ";").split(";") if r.strip()]
    return FaultPlan(tuple(parse_fault(r) for r in rules), seed=seed)
