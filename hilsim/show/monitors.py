"""What the loop watches besides its clock: the host's own stalls, servo silence, following
error, and when to read each servo's health. Pure bookkeeping: no I/O, no clock of its own, so
every rule here is tested on numbers alone.

**A host stall is not servo silence.** The loop measures how long the *host* was not running
in each tick (:class:`HostStalls`): lateness past a deadline it slept to, work outside the bus
far beyond its usual cost, and gaps between the driver's polls while it waited for a reply
(``ServoBus.host_stall_s``). A servo is declared silent (:class:`SilenceBudget`) only when
it failed at least :data:`MIN_FAILED_READS` reads in a row that were not host-late *and* the
time since its last good reading, minus the host's stalls in that time, exceeds the budget.

**A frozen figure is a fault.** :class:`FollowingMonitor` compares each joint's present
position with its command: beyond the joint's tolerance for longer than its time, the show
stops ("following error"). :class:`HealthSchedule` spreads health reads (torque, hardware
error, Bus Watchdog, RAM reset) over ticks that have time to spare, round robin.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from drivers.servo_bus import HealthPart

#: consecutive failed, not host-late reads before a servo can be declared silent
MIN_FAILED_READS = 3
#: host time beyond the usual that counts as a stall (s): below it is scheduling noise
STALL_ALLOWANCE_S = 1e-3
#: stalls at least this long are written to events.jsonl (s)
STALL_EVENT_S = 10e-3
#: at most one stall event per this many seconds of wall time; the rest are counted in it
STALL_EVENT_INTERVAL_S = 1.0
#: a round of health reads (one per servo) takes about this (s) when ticks have time to
#: spare; rounds alternate state and watchdog, so a cut torque is found within two rounds
HEALTH_PERIOD_S = 0.04
#: every this many rounds, the second of them is a round of condition reads (temperature,
#: voltage, load: each servo's about once a second, the first within the show's first
#: 0.1 s), inserted between the others
CONDITION_EVERY_ROUNDS = 25
#: a gap on the bus of at least this fraction of the Bus Watchdog period makes the loop check
#: every servo before it sends the next goals (the servo's 20 ms timer is coarse)
WATCHDOG_GAP_FRACTION = 0.5


@dataclass
class HostStalls:
    """The host's own stalls: per loop iteration, and books for the summary.

    ``tick_stall`` is given, per iteration (clock seconds): how late the loop woke from a
    sleep to its deadline (0 when there was nothing to sleep: the loop was already behind),
    the previous iteration's host work (its wall time less the sleep, the time inside bus
    calls and the catch-up simulation; None for the first), and the driver's poll gaps
    since the last call. Work is compared with the smallest of the last ``window``
    iterations', so a heavy but steady integration is cost, not a stall.
    """

    window: int = 64
    total_s: float = 0.0
    count: int = 0
    max_s: float = 0.0
    _works: list[float] = field(init=False, repr=False)  # the last `window` works, a ring
    _least: float = field(default=math.inf, init=False, repr=False)  # the least work ever
    _i: int = field(default=0, init=False, repr=False)

    def __post_init__(self) -> None:
        self._works = [math.inf] * self.window

    def tick_stall(self, sleep_late_s: float, work_s: float | None, poll_gaps_s: float) -> float:
        """This iteration's host stall (s), 0.0 for a healthy one; updates the books.

        ``poll_gaps_s``: what the driver measured inside its bus calls (``ServoBus.host_stall_s``
        differenced): device latency never counts there, only the host not running.
        """
        stall = poll_gaps_s if poll_gaps_s > 0.0 else 0.0
        if sleep_late_s > STALL_ALLOWANCE_S:
            stall += sleep_late_s
        if work_s is not None:
            # the least of the last `window` works is at least the least ever: only a work
            # beyond that by the allowance needs the window's own least (rarely: a slow tick)
            if work_s - self._least > STALL_ALLOWANCE_S:
                usual = min(self._works)
                if math.isfinite(usual) and work_s - usual > STALL_ALLOWANCE_S:
                    stall += work_s - usual
            i = self._i
            self._works[i % self.window] = work_s
            self._i = i + 1
            if work_s < self._least:
                self._least = work_s
        if stall > STALL_ALLOWANCE_S:
            self.total_s += stall
            self.count += 1
            self.max_s = max(self.max_s, stall)
            return stall
        return 0.0

    def as_dict(self) -> dict[str, float | int]:
        return {
            "count": self.count,
            "total_ms": round(self.total_s * 1e3, 3),
            "max_ms": round(self.max_s * 1e3, 3),
        }


class SilenceBudget:
    """Per servo: how long it has really been silent, not counting the host's stalls.

    ``update`` is called every tick for every servo with whether its read was OK, the clock
    time, the cumulative host stall time, and whether this tick was host-late. It returns the
    servo's silent time (s) when that exceeds ``budget_s`` and the servo has failed at least
    :data:`MIN_FAILED_READS` reads in a row that were not host-late; else None.
    """

    def __init__(self, n: int, budget_s: float, min_failed: int = MIN_FAILED_READS) -> None:
        self.budget_s = float(budget_s)
        self.min_failed = int(min_failed)
        self._last_ok = [0.0] * n
        self._stall_at_ok = [0.0] * n
        self._failed = [0] * n
        self._all_ok: tuple[float, float] | None = None  # the last all_ok, not yet applied

    def start(self, t: float, stall_total_s: float = 0.0) -> None:
        self.all_ok(t, stall_total_s)

    def all_ok(self, t: float, stall_total_s: float) -> None:
        """Every servo read well at ``t`` (the common tick: one call, no loop per servo;
        applied to each servo's books when one of them is next looked at)."""
        self._all_ok = (t, stall_total_s)

    def _settle(self) -> None:
        if self._all_ok is not None:
            t, stall_total_s = self._all_ok
            n = len(self._last_ok)
            self._last_ok[:] = [t] * n
            self._stall_at_ok[:] = [stall_total_s] * n
            self._failed[:] = [0] * n
            self._all_ok = None

    def ok(self, i: int, t: float, stall_total_s: float) -> None:
        self._settle()
        self._last_ok[i] = t
        self._stall_at_ok[i] = stall_total_s
        self._failed[i] = 0

    def failed(self, i: int, t: float, stall_total_s: float, host_late: bool) -> float | None:
        self._settle()
        if not host_late:
            self._failed[i] += 1
        silent = self.silent_s(i, t, stall_total_s)
        if self._failed[i] >= self.min_failed and silent > self.budget_s:
            return silent
        return None

    def silent_s(self, i: int, t: float, stall_total_s: float) -> float:
        """Time since servo ``i``'s last good reading, less the host's stalls since then."""
        self._settle()
        return (t - self._last_ok[i]) - (stall_total_s - self._stall_at_ok[i])

    def failed_reads(self, i: int) -> int:
        self._settle()
        return self._failed[i]


@dataclass(frozen=True)
class FollowingError:
    joint: int
    error_rad: float
    duration_s: float


class FollowingMonitor:
    """Commanded vs present per joint: beyond ``tolerance_rad`` for longer than ``time_s``.

    Time is counted in ticks of show time (``period_s`` each) over ticks with a valid reading;
    a tick without one neither adds nor resets. :meth:`reset` forgets a joint (after a
    recovery it rejoins from where it is). :meth:`exempt` leaves joints out (a limp joint,
    moved by hand, follows no command), at no cost per tick: their tolerance is infinite.
    """

    def __init__(
        self, tolerance_rad: Sequence[float], time_s: Sequence[float], period_s: float
    ) -> None:
        self.tolerance = [float(t) for t in tolerance_rad]
        self._given = list(self.tolerance)  # the tolerances asked, whatever is exempt
        self.limit_ticks = [max(1, math.ceil(t / period_s - 1e-9)) for t in time_s]
        self.period_s = float(period_s)
        self._count = [0] * len(self.tolerance)

    def update(self, present: Sequence[float], cmd: Sequence[float]) -> FollowingError | None:
        """One tick (joint frame, rad; NaN present = no reading). The first joint over its
        time, or None."""
        count, tolerance = self._count, self.tolerance
        if len(present) != len(count) or len(cmd) != len(count):
            raise ValueError(f"one present and one commanded position per joint ({len(count)})")
        for j in range(len(count)):
            p = present[j]
            if p != p:  # NaN: no reading this tick
                continue
            err = abs(p - cmd[j])
            if err > tolerance[j]:
                count[j] += 1
                if count[j] >= self.limit_ticks[j]:
                    return FollowingError(j, err, count[j] * self.period_s)
            else:
                count[j] = 0
        return None

    def reset(self, j: int) -> None:
        self._count[j] = 0

    def exempt(self, joints: frozenset[int]) -> None:
        """Check every joint but ``joints`` (indices) from now on; a joint that changes side
        starts counting from zero."""
        for j, given in enumerate(self._given):
            tol = math.inf if j in joints else given
            if tol != self.tolerance[j]:
                self.tolerance[j] = tol
                self._count[j] = 0


class HealthSchedule:
    """Round robin over the servos: which one to read next, and whether it is time.

    A round (one read per servo) takes about ``period_s`` (the interval between reads is
    ``period_s / n``), but reads happen only on a tick whose remaining time covers the read
    (the caller checks the spare time), so the tick rate is kept; a read that had no room
    waits for the next tick that has.
    """

    def __init__(
        self,
        n: int,
        period_s: float = HEALTH_PERIOD_S,
        condition_every: int = CONDITION_EVERY_ROUNDS,
    ) -> None:
        self.n = n
        self.interval_s = period_s / n
        self.condition_every = condition_every  # 0: no condition rounds
        self._next = 0
        self._round = 0
        self._checks = 0  # rounds of state or watchdog reads so far
        self._due = -math.inf
        self.reads = 0
        self.deferred = 0  # due reads put off: the tick had not the time to spare
        self.forced = 0  # reads taken without the time to spare (servo_watch.HEALTH_FLOOR_S)

    def due(self, t: float) -> bool:
        return t >= self._due

    def next_part(self, condition: bool = True) -> HealthPart:
        """What the next read reads (see :meth:`take`)."""
        every = self.condition_every
        if condition and every and self._round % every == 1:
            return HealthPart.CONDITION
        return HealthPart.STATE if self._checks % 2 == 0 else HealthPart.WATCHDOG

    def postpone(self, t: float, rounds: int) -> None:
        """The next read ``rounds`` intervals from ``t`` instead of one (the figures alone,
        where every tick's read carries the checks)."""
        self._due = t + rounds * self.interval_s

    def take(self, t: float, condition: bool = True) -> tuple[int, HealthPart]:
        """The servo to read now (its index) and what to read: rounds alternate between its
        state (torque, hardware error) and its Bus Watchdog, each short enough to fit in
        the spare part of a tick; every ``condition_every`` rounds a round of temperature,
        voltage and load is inserted. ``condition`` False (the longer read does not fit
        this tick): the servo's read in a condition round is a state or watchdog read
        instead, so the checks never wait on the figures. Schedules the next read."""
        i = self._next
        part = self.next_part(condition)
        self._next = (i + 1) % self.n
        if self._next == 0:
            if self.next_part() is not HealthPart.CONDITION:
                self._checks += 1
            self._round += 1
        self._due = t + self.interval_s
        self.reads += 1
        return i, part
