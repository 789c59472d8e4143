"""The start-up check: what the rig expects of each servo (:class:`Expectation`), how one
servo is checked against it (:func:`check_servo`), what was found (:class:`ServoCheck`,
:class:`ServoState`, :class:`StartupReport`), and how the bus reads (:class:`ReadMode`).
:meth:`~drivers.dynamixel.bus.DynamixelBus.check` runs :func:`check_servo` on every servo
and applies what it found (goal ranges, Return Delay Times, the read mode).

Imports neither ``dynamixel_sdk`` nor the bus (:func:`check_servo` takes an open
:class:`~drivers.dynamixel.link.Link`), so a rig can be turned into expectations (and a
report read) without loading the SDK.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from enum import StrEnum
from functools import partial
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from drivers.dynamixel.errors import CommError, CommTimeout, CorruptPacket, Mismatch, ServoError
from drivers.dynamixel.units import goal_tick_range, rad_to_ticks, ticks_to_rad
from drivers.protocol2 import control_table as ct
from drivers.protocol2.control_table import Item, OperatingMode, check_unicast_id

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from drivers.dynamixel.link import Link

T = TypeVar("T")


class ReadMode(StrEnum):
    """How :meth:`DynamixelBus.read_present` reads: Fast Sync Read, plain Sync Read, or
    ``auto`` (fast when every servo's firmware supports it)."""

    AUTO = "auto"
    FAST = "fast"
    PLAIN = "plain"


@dataclass(frozen=True)
class Expectation:
    """What the rig expects of one servo; :meth:`DynamixelBus.check` compares.

    Attributes:
        id: servo ID.
        model: model name (``"XM430-W350"``); None accepts any model.
        operating_mode: Operating Mode (addr 11).
        position_range_rad: ``(lo, hi)`` rad, servo frame, the loop will command; must
            lie within Min/Max Position Limit in Position mode. None: not checked.
        return_delay_us_max: largest acceptable Return Delay Time, µs (factory 500; 0
            is what a 1 kHz loop wants).
        allow_torque_on: False makes torque already on at start a mismatch; True (default)
            only reports it (:attr:`StartupReport.torque_on_ids`) and the loop decides.
        shutdown_bits: Hardware Error bits the servo's Shutdown mask (addr 63) must include,
            so it cuts its own torque on them (default the factory's: overheating,
            electrical shock, overload); 0: not checked.
    """

    id: int
    model: str | None = None
    operating_mode: OperatingMode = OperatingMode.POSITION
    position_range_rad: tuple[float, float] | None = None
    return_delay_us_max: float = 0.0
    allow_torque_on: bool = True
    shutdown_bits: int = int(
        ct.HardwareError.OVERHEATING | ct.HardwareError.ELECTRICAL_SHOCK | ct.HardwareError.OVERLOAD
    )

    def __post_init__(self) -> None:
        check_unicast_id(self.id)
        if self.model is not None:
            ct.model_number(self.model)  # raises ValueError naming the known models
        object.__setattr__(self, "operating_mode", OperatingMode(self.operating_mode))
        if self.position_range_rad is not None:
            lo, hi = (float(x) for x in self.position_range_rad)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(
                    f"servo {self.id}: position_range_rad must be finite "
                    f"(lo, hi) with lo <= hi, got {self.position_range_rad}"
                )
            object.__setattr__(self, "position_range_rad", (lo, hi))
        if not self.return_delay_us_max >= 0:
            raise ValueError(f"servo {self.id}: return_delay_us_max must be >= 0")


@dataclass(frozen=True)
class ServoState:
    """What :meth:`DynamixelBus.check` found on one servo (raw control-table values,
    plus Present Position in rad, servo frame)."""

    id: int
    model_number: int
    model_name: str
    firmware: int
    fast_read: bool
    operating_mode: int
    torque_on: bool
    return_delay_us: float
    status_return_level: int
    hardware_error: int
    bus_watchdog: int
    position_limits: tuple[int, int]  # Min, Max Position Limit, ticks
    position_rad: float


@dataclass(frozen=True)
class StartupReport:
    """Result of a passing :meth:`DynamixelBus.check`."""

    port: str
    baud: int
    read_mode: ReadMode  # FAST or PLAIN: what read_present will use
    servos: tuple[ServoState, ...]
    notes: tuple[str, ...] = ()

    @property
    def torque_on_ids(self) -> tuple[int, ...]:
        return tuple(s.id for s in self.servos if s.torque_on)

    @property
    def positions_rad(self) -> NDArray[np.float64]:
        """(n,) Present Position at check time, rad, servo frame, in ``ids`` order."""
        return np.array([s.position_rad for s in self.servos])

    def __str__(self) -> str:
        lines = [
            f"{self.port} @ {self.baud} bit/s, {len(self.servos)} servo(s), "
            f"{self.read_mode.value} sync read"
        ]
        lines += [
            f"  servo {s.id}: {s.model_name} fw {s.firmware}, mode {s.operating_mode}, "
            f"torque {'on' if s.torque_on else 'off'}, {s.position_rad:+.4f} rad"
            for s in self.servos
        ]
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


@dataclass(frozen=True)
class ServoCheck:
    """What :func:`check_servo` found on one servo.

    Attributes:
        state: the servo as read; None when it could not be read (``rows`` say why).
        rows: every difference from its expectation, in the order checked.
        notes: what is worth saying but not a mismatch (torque already on).
        goal_range: Goal Position ticks the servo accepts (Min/Max Position Limit, or the
            multi-turn range); None outside the position modes or when not read.
        return_delay_s: its Return Delay Time (s); None when not read.
    """

    state: ServoState | None
    rows: tuple[Mismatch, ...] = ()
    notes: tuple[str, ...] = ()
    goal_range: tuple[int, int] | None = None
    return_delay_s: float | None = None


def all_support_fast(link: Link, ids: Iterable[int], attempts: int) -> bool:
    """Whether every servo answers Ping (``attempts`` times each at most) with a model and
    firmware that have Fast Sync Read: ``read_mode = "auto"`` before the check has run."""
    for sid in ids:
        try:
            model, fw = retry(attempts, partial(link.ping, sid), settle=link.settle)
        except (CommError, ServoError):
            return False
        if not ct.supports_fast_read(model, fw):
            return False
    return True


def retry(
    attempts: int,
    fn: Callable[[], T],
    seen: list[CommError] | None = None,
    settle: Callable[[], None] | None = None,
) -> T:
    """Call ``fn`` up to ``attempts`` times while it fails on the wire (:class:`CommError`),
    the last failure raised; each failure is appended to ``seen`` when given, and
    ``settle`` (:meth:`Link.settle`) called before the next try. The retry rule of every
    step outside the tick (start-up check, torque, watchdog)."""
    for k in range(attempts):
        try:
            return fn()
        except CommError as exc:
            if seen is not None:
                seen.append(exc)
            if k + 1 == attempts:
                raise
            if settle is not None:
                settle()
    raise AssertionError("unreachable")


# long on purpose: one servo's start-up check, each fact in turn
def check_servo(link: Link, exp: Expectation, *, attempts: int, fast_required: bool) -> ServoCheck:  # noqa: C901
    """Compare one servo with its :class:`Expectation` over ``link``; read-only.

    Pings it, then reads its control table up to Present Position in one Read (each step
    tried ``attempts`` times). ``fast_required``: firmware without Fast Sync Read is a
    mismatch (read mode ``"fast"``). What is checked: see
    :meth:`~drivers.dynamixel.bus.DynamixelBus.check`. Wire failures that are answers
    (timeout, corrupt replies, an error status) become rows; others (the adapter gone,
    the port busy) propagate.
    """
    sid = exp.id
    rows: list[Mismatch] = []
    notes: list[str] = []

    def add(item: str, expected: str, found: str, fix: str = "") -> None:
        rows.append(Mismatch(sid, item, expected, found, fix))

    def failed() -> ServoCheck:
        return ServoCheck(None, tuple(rows), tuple(notes))

    # Each step is tried ``attempts`` times: a reply that comes late (after its timeout)
    # is discarded at the next transmit or read as that try's reply (the same request's
    # answer), so one late reply costs one try, never the check.
    seen: list[CommError] = []
    try:
        model, fw = retry(attempts, lambda: link.ping(sid), seen, link.settle)
    except CommTimeout:
        add(
            "answers Ping",
            "yes",
            "no (timeout)",
            f"check ID, power, wiring and baud ({link.baud})",
        )
        return failed()
    except CorruptPacket:
        add("answers Ping", "yes", *_corrupt_hint(seen, link.baud))
        return failed()
    except ServoError as exc:
        add("answers Ping", "yes", f"error reply: {exc.name}", "")
        return failed()
    name = ct.model_name(model)
    if exp.model is not None and model != ct.model_number(exp.model):
        add(
            "model",
            f"{exp.model} ({ct.model_number(exp.model)})",
            f"{name} ({model})",
            "fix the rig file or the servo",
        )
    fast = ct.supports_fast_read(model, fw)
    if fast_required and not fast:
        least = ct.fast_read_min_firmware(model)
        add(
            "firmware (Fast Sync Read)",
            f">= {least}" if least else "known model",
            str(fw),
            "update firmware (DYNAMIXEL Wizard 2.0) or read_mode='plain'",
        )
    block_item = ct.STARTUP_BLOCK
    seen = []
    try:
        block = retry(attempts, lambda: link.read(sid, 0, block_item.size), seen, link.settle)
    except CommTimeout:
        add(
            "Status Return Level",
            "2",
            "0? (answers Ping, not Read)",
            "write 2 to addr 68 (Status Return Level)",
        )
        return failed()
    except CorruptPacket:
        add("read control table", "a reply", *_corrupt_hint(seen, link.baud))
        return failed()
    except ServoError as exc:
        add("read control table", "a reply", str(exc), "")
        return failed()

    def get(item: Item) -> int:
        return item.decode(block)

    mode, rdt_us = get(ct.OPERATING_MODE), get(ct.RETURN_DELAY_TIME) * 2.0
    srl, hw, wd = (
        get(ct.STATUS_RETURN_LEVEL),
        get(ct.HARDWARE_ERROR_STATUS),
        get(ct.BUS_WATCHDOG),
    )
    torque = get(ct.TORQUE_ENABLE) == 1
    lo_lim, hi_lim = get(ct.MIN_POSITION_LIMIT), get(ct.MAX_POSITION_LIMIT)
    present = ticks_to_rad(get(ct.PRESENT_POSITION))
    if mode != exp.operating_mode:
        add(
            "Operating Mode",
            _mode_text(exp.operating_mode),
            _mode_text(mode),
            "write addr 11 (torque off)",
        )
    goal_range = None
    if mode in ct.POSITION_MODES:
        lo_t, hi_t = goal_range = goal_tick_range(mode, lo_lim, hi_lim)
        if exp.position_range_rad is not None:
            want = rad_to_ticks(np.array(exp.position_range_rad))
            if want[0] < lo_t or want[1] > hi_t:
                r = exp.position_range_rad
                add(
                    "position range",
                    f"[{r[0]:+.3f}, {r[1]:+.3f}] rad = ticks [{want[0]}, {want[1]}]",
                    f"limits [{lo_t}, {hi_t}] ticks",
                    "widen Min/Max Position Limit (addr 52/48) or narrow the joint",
                )
    if rdt_us > exp.return_delay_us_max:
        add(
            "Return Delay Time",
            f"<= {exp.return_delay_us_max:g} us",
            f"{rdt_us:g} us",
            f"write {int(exp.return_delay_us_max // 2)} to addr 9 (2 us units)",
        )
    if srl != ct.STATUS_RETURN_ALL:
        add("Status Return Level", "2", str(srl), "write 2 to addr 68")
    shutdown = get(ct.SHUTDOWN)
    if exp.shutdown_bits & ~shutdown:
        want = exp.shutdown_bits
        add(
            "Shutdown (torque cut on)",
            f"includes 0x{want:02X} ({ct.describe_hardware_error(want)})",
            f"0x{shutdown:02X} ({ct.describe_hardware_error(shutdown)})",
            f"write {shutdown | want} to addr 63 (torque off): the servo protects itself",
        )
    if hw:
        add(
            "Hardware Error Status",
            "0",
            f"0x{hw:02X} ({ct.describe_hardware_error(hw)})",
            "remove the cause, then Reboot the servo",
        )
    if wd == ct.WATCHDOG_TRIPPED:
        add(
            "Bus Watchdog",
            "not tripped",
            "tripped (-1)",
            "write 0 to addr 98 (bus.disarm_watchdog())",
        )
    if torque:
        if not exp.allow_torque_on:
            add("Torque Enable", "off", "on", "bus.set_torque(False)")
        else:
            notes.append(f"servo {sid}: torque already on, holding {present:+.4f} rad")
    state = ServoState(
        sid, model, name, fw, fast, mode, torque, rdt_us, srl, hw, wd, (lo_lim, hi_lim), present
    )
    return ServoCheck(state, tuple(rows), tuple(notes), goal_range, rdt_us * 1e-6)


def _corrupt_hint(seen: list[CommError], baud: int) -> tuple[str, str]:
    """(found, fix) for a servo whose replies stayed corrupt. Two servos on one ID is
    suggested only when every try got a whole packet - valid header, this ID, every
    LEN byte - with a bad CRC (two replies merged on the wire); a reply cut short or
    arriving late (a busy host, a pty) says so instead."""
    garbled = sum(1 for e in seen if getattr(e, "complete", False))
    if garbled == len(seen):
        return (
            f"corrupt replies ({garbled} of {garbled} whole packets with a bad CRC)",
            "two servos with this ID? (connect them one at a time)",
        )
    return (
        f"corrupt replies ({len(seen) - garbled} of {len(seen)} cut short or late)",
        f"check wiring, termination and baud ({baud}); a busy host delays pty replies",
    )


def _mode_text(mode: int) -> str:
    try:
        return f"{OperatingMode(mode).name.lower()} ({mode})"
    except ValueError:
        return f"unknown ({mode})"
