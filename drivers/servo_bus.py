"""The servo bus the real-time loop talks to: one small interface, any backend.

python-can style: public methods on :class:`ServoBus` validate their arguments and keep
the books (:class:`BusStats`), then call one small private hook a backend implements
(``write_goals`` -> ``_write_goals``). :class:`drivers.dynamixel.DynamixelBus` is the
Dynamixel backend; it runs on hardware or on the emulated bus alike.

Per tick the loop calls, at 500-1000 Hz::

    bus.write_goals(goal_rad)             # one Sync Write, (n,) rad in the servo frame
    reading = bus.read_present(reading)   # one (Fast) Sync Read into preallocated arrays

Positions are radians in the servo frame (0 rad = the servo's centre); mapping joints to
servos (sign, offset, gear) is the caller's business. A position is only ever a
measurement: wherever a servo gave no valid reading, :attr:`PresentReading.positions`
holds NaN and :attr:`PresentReading.status` says why (:class:`ReadStatus`).

Exceptions: every backend error derives from :class:`ServoBusError`, so the loop can
catch backend-neutrally; backends refine it (see :mod:`drivers.dynamixel.errors`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import IntEnum, StrEnum
from types import TracebackType
from typing import Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from drivers.clock import Clock


class ServoBusError(Exception):
    """Root of every error a servo bus raises."""


class BusClosed(ServoBusError, RuntimeError):  # noqa: N818
    """The bus was used after :meth:`ServoBus.close`."""


class ReadStatus(IntEnum):
    """Per-servo outcome of one :meth:`ServoBus.read_present` (stored as uint8).

    OK     valid reading.
    STALE  no reading: timeout, corrupt reply, or missing from the reply. Position NaN.
    ERROR  the servo answered with an error number (ERR bits 0-6 ≠ 0): its data is not a
           reading. Position NaN.
    ALERT  the Alert bit is set (a hardware error is latched; torque may be cut). The
           reading itself is valid when the error number is 0 (position finite), else NaN.
    UNREAD not asked this tick: a bus that reads its servos in rotation (single reads on
           AX or SCS servos, which have no Sync Read) asks a few per tick. Position NaN;
           not a failure (no comm error, no silence counted).
    """

    OK = 0
    STALE = 1
    ERROR = 2
    ALERT = 3
    UNREAD = 4


@dataclass(slots=True, eq=False)
class PresentReading:
    """One read of present positions; arrays shaped ``(n,)`` in the bus's ``ids`` order.

    Attributes:
        ids: servo IDs, same order as the arrays.
        positions: float64 rad, servo frame; NaN wherever there is no valid reading.
        status: uint8 :class:`ReadStatus` per servo.
        errors: uint8 raw status ERR byte per servo (0 if none or no reply).
        t: clock time (s) when the read request was sent; the servos sample just after.
        t_done: clock time (s) when the read finished (replies parsed or timed out).

    The arrays are filled in place by ``bus.read_present(out=reading)``; keep a
    :meth:`copy` if you store a reading beyond the next tick.
    """

    ids: tuple[int, ...]
    positions: NDArray[np.float64]
    status: NDArray[np.uint8]
    errors: NDArray[np.uint8]
    t: float = float("nan")
    t_done: float = float("nan")

    @classmethod
    def empty(cls, ids: Sequence[int]) -> PresentReading:
        """A reading with nothing in it yet: NaN positions, every servo STALE."""
        n = len(ids)
        return cls(
            tuple(ids),
            np.full(n, np.nan),
            np.full(n, ReadStatus.STALE, dtype=np.uint8),
            np.zeros(n, dtype=np.uint8),
        )

    @property
    def ok(self) -> NDArray[np.bool_]:
        """(n,) bool: the servo gave a valid reading with no error and no alert."""
        ok: NDArray[np.bool_] = self.status == ReadStatus.OK  # (numpy types == as Any)
        return ok

    @property
    def all_ok(self) -> bool:
        return not self.status.any()  # OK is 0

    def copy(self) -> PresentReading:
        return PresentReading(
            self.ids,
            self.positions.copy(),
            self.status.copy(),
            self.errors.copy(),
            self.t,
            self.t_done,
        )

    def problems(self) -> list[str]:
        """One line per servo that is not OK, naming it, e.g.
        ``"servo 2: ALERT (ERR 0x80), position 0.1534 rad"``."""
        lines = []
        rows = zip(self.ids, self.status, self.errors, self.positions, strict=True)
        for sid, st, err, pos in rows:
            if st == ReadStatus.OK:
                continue
            text = f"servo {sid}: {ReadStatus(st).name}"
            if err:
                text += f" (ERR 0x{err:02X})"
            text += ", no position" if np.isnan(pos) else f", position {pos:.4f} rad"
            lines.append(text)
        return lines


class ExitPolicy(StrEnum):
    """What the servos are left doing when the program stops."""

    HOLD = "hold"  # goal := present position, torque stays on, watchdog armed
    RELAX = "relax"  # torque off


@dataclass(frozen=True, slots=True)
class ExitReport:
    """Outcome of :meth:`ServoBus.apply_exit_policy`: which servos were confirmed (read
    back) in the policy's state, why the others were not, and anything the exit found and
    had to change on the way (``notes``, e.g. a Bus Watchdog that had tripped), which the
    caller must show: nothing is changed silently."""

    policy: ExitPolicy
    confirmed: tuple[int, ...]
    unconfirmed: tuple[tuple[int, str], ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return not self.unconfirmed

    @property
    def unconfirmed_ids(self) -> tuple[int, ...]:
        return tuple(sid for sid, _ in self.unconfirmed)

    def __str__(self) -> str:
        head = f"exit policy {self.policy.value!r}: {len(self.confirmed)} servo(s) confirmed"
        if self.ok:
            lines = [head]
        else:
            lines = [f"{head}, NOT confirmed on {len(self.unconfirmed)}:"]
            lines += [f"  servo {sid}: {why}" for sid, why in self.unconfirmed]
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


class HealthProblem(StrEnum):
    """Why a servo that answers is no longer following its goals (worst first)."""

    HARDWARE_ERROR = "hardware error"  # Hardware Error Status != 0 (torque cut per Shutdown)
    RESET = "reset"  # RAM back to defaults: a brownout or a reboot (torque off, watchdog 0)
    WATCHDOG_TRIPPED = "Bus Watchdog tripped"  # goals refused until the trip is cleared
    TORQUE_OFF = "torque off"  # Torque Enable reads 0 while the show needs it on


class HealthPart(StrEnum):
    """What one :meth:`ServoBus.read_health` reads."""

    STATE = "state"  # torque and hardware error
    WATCHDOG = "watchdog"  # the Bus Watchdog
    ALL = "all"
    CONDITION = "condition"  # temperature, input voltage and load alone (no judgement)


@dataclass(frozen=True, slots=True)
class ServoCondition:
    """A servo's temperature, input voltage and load (or current) as one read found them.
    NaN where the read did not measure it: a servo whose load register is a current reports
    ``current_a`` and a NaN ``load_pct``, and the other way round."""

    temperature_c: float
    voltage_v: float
    load_pct: float  # % of the servo's maximum torque, signed
    current_a: float = float("nan")


#: the figures a :class:`ConditionRecord` keeps, in the order it shows them
CONDITION_FIELDS = ("temperature_c", "voltage_v", "load_pct", "current_a")


class ConditionRecord:
    """Each servo's last temperature, voltage, load and current, and when each was read.

    Lists shaped ``(n,)`` in the bus's order: ``value[field][i]``, NaN if never read, and
    ``read_t[field][i]``, the clock time (s) of the read it came from. A failed read
    changes nothing (the last figure stays, with its time): a missing reading is never the
    servo's figure. ``max_temperature_c`` and ``min_voltage_v`` are the run's extremes.
    Written by the loop's thread only; element reads from another thread are safe.
    """

    def __init__(self, n: int) -> None:
        nan = float("nan")
        self.value = {f: [nan] * n for f in CONDITION_FIELDS}
        self.read_t = {f: [nan] * n for f in CONDITION_FIELDS}
        self.max_temperature_c = [nan] * n
        self.min_voltage_v = [nan] * n

    def update(self, i: int, cond: ServoCondition, t: float) -> None:
        """Servo ``i``'s figures from a read made at clock time ``t``; NaN ones are skipped."""
        for f in CONDITION_FIELDS:
            x = float(getattr(cond, f))
            if x == x:  # not NaN
                self.value[f][i] = x
                self.read_t[f][i] = t
        temp, volts = cond.temperature_c, cond.voltage_v
        if temp == temp and not temp <= self.max_temperature_c[i]:
            self.max_temperature_c[i] = float(temp)
        if volts == volts and not volts >= self.min_voltage_v[i]:
            self.min_voltage_v[i] = float(volts)

    def extremes(self, names: Sequence[str]) -> dict[str, dict[str, float | None]]:
        """Per servo (keyed by ``names``, bus order): the run's ``max_temperature_c`` and
        ``min_voltage_v``, None where never read."""
        return {
            name: {
                "max_temperature_c": None if hi != hi else hi,
                "min_voltage_v": None if lo != lo else lo,
            }
            for name, hi, lo in zip(names, self.max_temperature_c, self.min_voltage_v, strict=True)
        }

    def views(self, now: float) -> list[dict[str, float | None]]:
        """:meth:`view` of every servo, bus order."""
        return [self.view(i, now) for i in range(len(self.max_temperature_c))]

    def view(self, i: int, now: float) -> dict[str, float | None]:
        """Servo ``i`` as JSON-ready figures: each field (None if never read) and
        ``<field>_age_s``, how long ago it was read (s, by the clock of ``now``)."""
        out: dict[str, float | None] = {}
        for f in CONDITION_FIELDS:
            x, t = self.value[f][i], self.read_t[f][i]
            out[f] = None if x != x else round(x, 3)
            out[f + "_age_s"] = None if t != t else round(max(0.0, now - t), 3)
        return out


@dataclass(frozen=True, slots=True)
class ServoHealth:
    """One servo's state beyond its position, from :meth:`ServoBus.read_health`.

    ``problem`` is None when the servo can follow goals; otherwise the worst
    :class:`HealthProblem` and ``detail`` says it in words (decoded error bits, registers).
    ``condition``: its temperature, voltage and load when this read covered them.
    """

    servo_id: int
    torque_on: bool | None  # None: not read
    hardware_error: int | None  # Hardware Error Status bits, 0 = none; None: not read
    watchdog_tripped: bool | None
    watchdog_armed: bool | None
    problem: HealthProblem | None = None
    detail: str = ""
    condition: ServoCondition | None = None  # temperature, voltage, load, when read

    @property
    def ok(self) -> bool:
        return self.problem is None


@dataclass(slots=True)
class BusStats:
    """Books kept by :class:`ServoBus`; arrays are ``(n,)`` in ``ids`` order.

    ``status_counts[s, k]`` counts reads where servo ``k`` had :class:`ReadStatus` ``s``;
    ``consecutive_bad[k]`` counts reads in a row where servo ``k`` was not OK.
    """

    n: int
    writes: int = 0
    reads: int = 0
    consecutive_bad: NDArray[np.int64] = field(init=False)
    _not_ok: NDArray[np.int64] = field(init=False, repr=False)  # row OK stays 0

    def __post_init__(self) -> None:
        self.consecutive_bad = np.zeros(self.n, dtype=np.int64)
        self._not_ok = np.zeros((len(ReadStatus), self.n), dtype=np.int64)

    @property
    def status_counts(self) -> NDArray[np.int64]:
        """(len(ReadStatus), n) counts; a copy."""
        counts = self._not_ok.copy()
        counts[ReadStatus.OK] = self.reads - counts.sum(axis=0)
        return counts


class ServoBus(ABC):
    """A bus of position-controlled servos, addressed by ID, on an injected clock.

    Subclasses implement the ``_hooks``; the public methods here validate and keep books.
    The bus is a context manager (``close`` on exit; the exit policy is the caller's
    explicit step, see :meth:`apply_exit_policy`). Not thread-safe and not reentrant:
    call it from the loop's thread only, never from a signal handler.
    """

    def __init__(self, ids: Sequence[int], clock: Clock) -> None:
        ids = tuple(int(i) for i in ids)
        if not ids:
            raise ValueError("a servo bus needs at least one servo ID")
        if len(set(ids)) != len(ids):
            raise ValueError(f"repeated servo ID in {ids}")
        bad = [i for i in ids if not 0 <= i <= 252]
        if bad:
            raise ValueError(f"servo IDs must be 0..252, got {bad}")
        self._ids = ids
        self._n = len(ids)
        self._clock = clock
        self._closed = False
        self.stats = BusStats(self._n)
        self._cols = np.arange(self._n)

    # -- properties -------------------------------------------------------------------
    @property
    def ids(self) -> tuple[int, ...]:
        """Servo IDs; every ``(n,)`` array is in this order."""
        return self._ids

    @property
    def n(self) -> int:
        return self._n

    @property
    def clock(self) -> Clock:
        """The clock the bus's timeouts and reading times use."""
        return self._clock

    @property
    def closed(self) -> bool:
        return self._closed

    def _check_open(self) -> None:
        if self._closed:
            raise BusClosed(f"{self!r} is closed")

    # -- per tick ---------------------------------------------------------------------
    def write_goals(self, positions_rad: ArrayLike) -> None:
        """Send one goal per servo in one packet (no reply is awaited).

        ``positions_rad``: ``(n,)`` float, rad in the servo frame, ``ids`` order; all
        finite. Raises ValueError on a wrong shape, a non-finite value or a goal outside
        what the servo accepts (nothing is sent then), backend errors otherwise.
        """
        self._check_open()
        goals = np.asarray(positions_rad, dtype=np.float64)
        if goals.shape != (self._n,):
            raise ValueError(f"expected {self._n} goals shaped ({self._n},), got {goals.shape}")
        if not np.isfinite(goals).all():
            bad = [sid for sid, g in zip(self._ids, goals, strict=True) if not np.isfinite(g)]
            raise ValueError(f"non-finite goal for servo(s) {bad}; nothing sent")
        self._write_goals(goals)
        self.stats.writes += 1

    def read_present(self, out: PresentReading | None = None) -> PresentReading:
        """Read every servo's present position in one transaction; never retries.

        ``out``: a reading to fill in place (from :meth:`PresentReading.empty` with this
        bus's ``ids``); default a new one. Per-servo trouble is reported in
        ``status``/``errors`` with NaN positions, not raised; a bus-level failure (adapter
        gone, port busy) raises.
        """
        self._check_open()
        if out is None:
            out = PresentReading.empty(self._ids)
        elif out.ids != self._ids:
            raise ValueError(f"reading is for servos {out.ids}, this bus has {self._ids}")
        self._read_present(out)
        st = self.stats
        st.reads += 1
        status = out.status
        if status.any():  # OK is 0; the all-OK tick stays cheap
            st._not_ok[status, self._cols] += 1
            asked = status != ReadStatus.UNREAD  # a servo not asked keeps its count
            st.consecutive_bad[asked] += 1
            st.consecutive_bad *= (status != 0) | ~asked
        else:
            st.consecutive_bad.fill(0)
        return out

    # -- state changes ----------------------------------------------------------------
    def set_torque(self, on: bool, ids: Sequence[int] | None = None) -> None:
        """Torque on (hold) or off (limp) on every servo or on ``ids`` only (teach-by-hand); tries
        all, raises the first failure with the others noted; ValueError for an unknown ID."""
        self._check_open()
        chosen = self._ids if ids is None else tuple(dict.fromkeys(int(i) for i in ids))
        if not set(chosen) <= set(self._ids):
            raise ValueError(f"servo(s) {sorted(set(chosen) - set(self._ids))} not in {self._ids}")
        self._set_torque(bool(on), chosen)

    def arm_watchdog(self, period_s: float) -> None:
        """Make every servo stop on its own if the host is silent for ``period_s``."""
        self._check_open()
        if not period_s > 0.0:
            raise ValueError(f"watchdog period must be > 0 s, got {period_s!r}")
        self._arm_watchdog(float(period_s))

    def disarm_watchdog(self) -> None:
        """Disarm the watchdog on every servo (and clear a trip)."""
        self._check_open()
        self._disarm_watchdog()

    def read_health(self, servo_id: int, part: HealthPart = HealthPart.ALL) -> ServoHealth:
        """Read one servo's health in one transaction (not per tick: the loop spreads these
        over ticks with time to spare). ``part`` picks what is read: STATE (torque and
        hardware error, short), WATCHDOG (the Bus Watchdog alone, shorter) or ALL (both);
        what was not read is None in the result. When torque is off or a hardware error is
        set, the watchdog is read as well to name the cause. CONDITION reads temperature,
        voltage and load alone (``condition``; nothing judged). A backend whose one read
        covers them fills ``condition`` for every part.

        Raises a :class:`ServoBusError` if the servo does not answer properly.
        """
        self._check_open()
        if servo_id not in self._ids:
            raise ValueError(f"servo {servo_id} is not on this bus {self._ids}")
        return self._read_health(int(servo_id), HealthPart(part))

    #: False for a family without a Bus Watchdog (Dynamixel Protocol 1.0, Feetech): if the
    #: host dies its servos hold their last goal; :meth:`arm_watchdog` then arms nothing
    has_watchdog: bool = True

    #: True for a backend whose every :meth:`read_health` fills ``condition`` (one read
    #: covers torque through temperature): the loop then never asks for CONDITION alone
    condition_with_health: bool = False

    @property
    def health_read_s(self) -> float:
        """Expected bus time of a :meth:`read_health` of STATE (s), the longer of the two
        periodic parts: the loop schedules health reads only where a tick has that much time
        to spare."""
        return self._health_read_s()

    @property
    def condition_read_s(self) -> float:
        """Expected bus time of a :meth:`read_health` of CONDITION (s), for the same rule."""
        return self._condition_read_s()

    def _condition_read_s(self) -> float:
        return self._health_read_s()

    #: a backend whose every read carries each servo's health (the X series' tick block)
    #: sets this, per servo in bus order, to an opaque state of that read (-1: not read);
    #: None: the reads carry positions only, health is read between ticks (read_health)
    tick_health: list[int] | None = None

    @property
    def tick_health_ok(self) -> list[int]:
        """Per servo, the :attr:`tick_health` of a servo that follows its goals as the show
        set it (torque, Bus Watchdog)."""
        return []

    def tick_health_of(self, k: int) -> ServoHealth:
        """Servo ``k``'s (bus order) health from :attr:`tick_health`, judged as
        :meth:`read_health` judges; nothing read when the reads carry no health."""
        return ServoHealth(self._ids[k], None, None, None, None)

    #: the raw bytes of the latest corrupt reply to a read, for diagnosis (None if none yet);
    #: a backend that keeps them sets it, the caller may reset it to None after sampling it
    corrupt_sample: bytes | None = None

    @property
    def device_wait_s(self) -> float:
        """Cumulative time (s) spent inside transactions (waiting on the servos, and any host
        stall there, which :attr:`host_stall_s` reports); difference it. What is left of a
        caller's wall time is its own work. A backend that cannot tell returns 0."""
        return 0.0

    @property
    def host_stall_s(self) -> float:
        """Cumulative time (s) the host was not running while waiting for replies (the
        process was descheduled between polls); difference it to get one transaction's.
        A backend that cannot tell returns 0."""
        return 0.0

    def recover_watchdog(self, servo_id: int, goal_rad: float) -> None:
        """A servo whose Bus Watchdog tripped (the host was silent longer than its period):
        clear the trip, set its goal to ``goal_rad`` (servo frame; normally its present
        position, so nothing jumps) and arm the watchdog again, each confirmed by reading
        back. Raises a :class:`ServoBusError` when any step cannot be confirmed."""
        self._check_open()
        if servo_id not in self._ids:
            raise ValueError(f"servo {servo_id} is not on this bus {self._ids}")
        if not np.isfinite(goal_rad):
            raise ValueError(f"non-finite goal {goal_rad!r} for servo {servo_id}")
        self._recover_watchdog(int(servo_id), float(goal_rad))

    def apply_exit_policy(self, policy: ExitPolicy | str, retries: int = 3) -> ExitReport:
        """Leave every servo in ``policy``'s state, confirmed by reading back.

        Each step is retried up to ``retries`` times per servo. Returns the report when
        every servo is confirmed; otherwise raises a :class:`ServoBusError` whose
        ``report`` attribute is the :class:`ExitReport` naming the unconfirmed servos.
        Bounded in time even on a half-broken bus or with the adapter gone.
        """
        self._check_open()
        policy = ExitPolicy(policy)
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        return self._apply_exit_policy(policy, int(retries))

    def close(self) -> None:
        """Release the port. Idempotent; never raises for a vanished device."""
        if self._closed:
            return
        self._closed = True
        self._close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- hooks ------------------------------------------------------------------------
    @abstractmethod
    def _write_goals(self, goals: NDArray[np.float64]) -> None:
        """Send validated, finite ``(n,)`` goals (rad)."""

    @abstractmethod
    def _read_present(self, out: PresentReading) -> None:
        """Fill every field of ``out``."""

    @abstractmethod
    def _set_torque(self, on: bool, ids: tuple[int, ...]) -> None: ...

    @abstractmethod
    def _arm_watchdog(self, period_s: float) -> None: ...

    @abstractmethod
    def _disarm_watchdog(self) -> None: ...

    @abstractmethod
    def _apply_exit_policy(self, policy: ExitPolicy, retries: int) -> ExitReport: ...

    @abstractmethod
    def _read_health(self, servo_id: int, part: HealthPart) -> ServoHealth: ...

    @abstractmethod
    def _health_read_s(self) -> float: ...

    @abstractmethod
    def _recover_watchdog(self, servo_id: int, goal_rad: float) -> None: ...

    @abstractmethod
    def _close(self) -> None:
        """Release resources; must not raise."""
