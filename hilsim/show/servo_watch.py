"""Deciding that a servo has failed — and that it has not: the loop's servo-side judgement.

:class:`ServoWatch` takes what each tick saw and turns it into a :class:`LoopFaultError`
naming the servo and the cause, or into a recovery. The rules and their numbers are in
:mod:`hilsim.show.monitors` (pure bookkeeping); this module adds the bus reads they need:

* **reads** (:meth:`ServoWatch.check_reads`): an Alert bit stops the show at once; a servo
  silent beyond the comm budget, host stalls not counted, stops it naming the servo.
* **following** (:meth:`ServoWatch.check_following`): present vs commanded beyond a joint's
  tolerance for longer than its time.
* **health** (:meth:`ServoWatch.check_reads`): where the tick's read carries every servo's
  torque and Bus Watchdog (``ServoBus.tick_health``, the X series' tick block), each servo is
  judged every tick: torque cut, watchdog trip, a RAM reset (the block itself gone). Else
  (:meth:`ServoWatch.maybe_read_health`) one servo's torque / hardware error / Bus Watchdog /
  RAM reset, round robin, only on ticks with time to spare. Temperature, voltage and load
  are read that way in both cases (one servo at a time, about once a second each).
* **after a bus silence** (:meth:`ServoWatch.after_bus_silence`): the host stalled long
  enough for a Bus Watchdog to trip: check every servo before sending goals; a trip that a
  host stall explains is recovered (cleared, goal = present, the joint rejoins through the
  safety filter's limits); one nothing explains is a fault.
* **a long host stall without a Bus Watchdog** (:meth:`ServoWatch.held_on_stall`, Feetech,
  Dynamixel Protocol 1.0): said in a ``held_last_goal`` event and counted; never a fault.
* **limp joints** (:meth:`ServoWatch.set_limp`, teach-by-hand): torque off is expected there
  and the following error is not checked; an Alert bit, silence, a hardware error, a reset
  or a tripped watchdog still stop the show.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence

import numpy as np
from numpy.typing import NDArray

from drivers.servo_bus import (
    ConditionRecord,
    HealthPart,
    HealthProblem,
    PresentReading,
    ReadStatus,
    ServoBus,
    ServoBusError,
    ServoHealth,
)
from hilsim._types import FloatArray
from hilsim.rig.joint_map import JointMap
from hilsim.rig.model import JointConfig
from hilsim.show.monitors import (
    CONDITION_EVERY_ROUNDS,
    FollowingMonitor,
    HealthSchedule,
    SilenceBudget,
)

#: a health read runs only when the tick has its expected time, times this, plus
#: HEALTH_SPARE_S (the SDK's own time) to spare: it must never make the tick late. Its
#: expected time is the longer of its bus time (the wire model) and the median of the last
#: HEALTH_COST_READS reads of the last HEALTH_COST_MEMORY_S as the clock measured them (the
#: host's work in them, an in-process emulator's included; the lower median, so one read stretched
#: by a host stall does not stop the reads; forgotten, so a slow spell does not stop them
#: for the rest of the show)
HEALTH_MARGIN = 1.1
HEALTH_SPARE_S = 150e-6
HEALTH_COST_READS = 5
HEALTH_COST_MEMORY_S = 2.0
#: ... but a bus that never has the time to spare still gets a health read this often (a
#: torque cut or a tripped watchdog is found, late, rather than never), at the price of a
#: tick that may run late; counted as forced in the summary
HEALTH_FLOOR_S = 1.0
#: a ``held_last_goal`` event at most this often (clock time); the rest counted into the next
HELD_EVENT_INTERVAL_S = 1.0


class LoopFaultError(RuntimeError):
    """A condition that stops the show: the message names the servo/joint and the cause."""


def failed_reads(status: NDArray[np.uint8]) -> int:
    """Servos whose read failed (not OK, and asked: UNREAD is no failure)."""
    return sum(1 for s in status.tolist() if s and s != ReadStatus.UNREAD)


class ServoWatch:
    """The failure rules of one show's servos.

    ``joints`` are the rig's joints (bus order); ``event(kind, message, **fields)`` writes an
    ``events.jsonl`` line; ``rejoin(i, joint_rad)`` is called after servo ``i`` was recovered
    at ``joint_rad`` (the loop resets the safety filter and this tick's command there).
    """

    def __init__(
        self,
        bus: ServoBus,
        joints: Sequence[JointConfig],
        joint_map: JointMap,
        *,
        period_s: float,
        comm_budget_ms: float,
        watchdog_s: float,
        event: Callable[..., None],
        rejoin: Callable[[int, float], None],
    ) -> None:
        self.bus, self.joints, self.map = bus, tuple(joints), joint_map
        self.clock = bus.clock
        n = len(self.joints)
        self.ids = tuple(j.servo_id for j in self.joints)
        self.names = tuple(j.name for j in self.joints)
        self.comm_budget_ms = comm_budget_ms
        self.watchdog_s = watchdog_s
        self._event, self._rejoin = event, rejoin
        self.silence = SilenceBudget(n, comm_budget_ms * 1e-3)
        self.following = FollowingMonitor(
            [j.tracking_tolerance_rad for j in self.joints],
            [j.tracking_time_s for j in self.joints],
            period_s,
        )
        # a backend whose health read covers temperature and the rest needs no reads of them
        self.health = HealthSchedule(n)
        if bus.condition_with_health:
            self.health.condition_every = 0
        #: each servo's last temperature, voltage and load, with when each was read
        self.condition = ConditionRecord(n)
        self._health_took: list[tuple[float, float]] = []  # the last reads: (when, took)
        self._health_cost_s = 0.0  # their median time
        self._last_health_t: float | None = None  # clock time of the last health read
        self.comm_errors = 0  # reads that were not OK, cumulative
        self.recoveries = 0
        self.held_stalls = 0  # no Bus Watchdog: host stalls >= watchdog_ms (servos held)
        self.held_max_s = 0.0
        self._held_event_t = -math.inf
        self._held_unreported = 0
        self.last_bus_t = -math.inf  # clock time of the last packet sent to the servos
        self.last_long_gap_t = -math.inf  # when the bus last went quiet for a watchdog's while
        self._last_health_ok = [-math.inf] * n
        self._block_ok_t = -math.inf  # when the tick's read last found every servo well
        #: joints (indices, bus order) limp on purpose: see :meth:`set_limp`
        self.limp: frozenset[int] = frozenset()

    def set_limp(self, joints: Iterable[int]) -> None:
        """Joints (indices in bus order) whose torque is off on purpose from now on (a person
        moves them: :mod:`hilsim.live.teach`); the others are held again. For a limp joint
        torque off is not a fault and present vs commanded is not compared; every other rule
        holds. Its periodic health read is the Bus Watchdog alone (one short transaction: a
        torque-off state read would take a second one to name the cause), where a watchdog
        at 0 although armed is a reset; the Alert bit of every tick's read reports a hardware
        error. ValueError for an index that is not a joint."""
        limp = frozenset(int(i) for i in joints)
        bad = sorted(i for i in limp if not 0 <= i < len(self.joints))
        if bad:
            raise ValueError(f"limp joints {bad}: there are {len(self.joints)} joints")
        self.limp = limp
        self.following.exempt(limp)

    def _who(self, i: int) -> str:
        return f"servo {self.ids[i]} ({self.names[i]})"

    # ------------------------------------------------------------------ the start
    def first_read(
        self, reading: PresentReading, stopping: Callable[[], bool]
    ) -> np.ndarray | None:
        """Every servo's present position (servo frame), from as many Sync Reads as the comm
        budget allows (at least three): one bad reply must not stop a show from starting.
        None if ``stopping()`` says a stop was requested first."""
        bus, period = self.bus, self.following.period_s
        attempts = max(3, min(100, math.ceil(self.comm_budget_ms * 1e-3 / period)))
        # a bus reading in rotation reads each servo once every n/per_tick reads: three rounds
        per_tick = getattr(bus, "per_tick", bus.n)
        attempts = max(attempts, 3 * math.ceil(bus.n / per_tick))
        positions = np.full(len(self.joints), np.nan)
        got = np.zeros(len(self.joints), dtype=bool)
        last = reading
        for attempt in range(attempts):
            if stopping():
                return None
            if attempt:
                self.clock.wait_until(self.clock.now() + period)
            last = bus.read_present(reading)
            good = (last.status == ReadStatus.OK) & np.isfinite(last.positions)
            positions[good] = last.positions[good]
            got |= good
            if got.all():
                return positions
        names = ", ".join(
            f"{self.names[i]} (servo {self.ids[i]}: {ReadStatus(int(last.status[i])).name})"
            for i in np.flatnonzero(~got)
        )
        raise LoopFaultError(f"cannot start: no present position for {names} in {attempts} reads")

    # ------------------------------------------------------------------ every tick
    def check_reads(
        self,
        reading: PresentReading,
        t_now: float,
        stall_total_s: float,
        host_late: bool,
        all_ok: bool | None = None,
        k: int = -1,
    ) -> None:
        """``all_ok``: the caller knows whether every status is OK (else it is looked up);
        ``k``: the tick (its events name it)."""
        status = reading.status
        if (not status.any()) if all_ok is None else all_ok:  # OK is 0: the common tick
            self.silence.all_ok(t_now, stall_total_s)
        else:
            self._check_statuses(reading, t_now, stall_total_s, host_late)
        block = self.bus.tick_health  # each servo's health in the same read
        if block is not None:
            if block == self.bus.tick_health_ok:
                self._block_ok_t = t_now
            else:
                self._check_block(block, k)

    def _check_block(self, block: list[int], k: int) -> None:
        """The servos whose state in this tick's read is not what the show set, judged."""
        ok = self.bus.tick_health_ok
        for i, state in enumerate(block):
            if state < 0 or state == ok[i]:  # not read (its status says so) / well
                continue
            health = self.bus.tick_health_of(i)
            seen_ok = max(self._last_health_ok[i], self._block_ok_t)
            self._handle(i, health, k, explained=self.last_long_gap_t > seen_ok)

    def _check_statuses(
        self, reading: PresentReading, t_now: float, stall_total_s: float, host_late: bool
    ) -> None:
        status = reading.status
        for i, s in enumerate(status):
            s = int(s)
            if s == ReadStatus.OK:
                self.silence.ok(i, t_now, stall_total_s)
                continue
            if s == ReadStatus.UNREAD:  # not asked this tick (a bus reading in rotation)
                continue
            self.comm_errors += 1
            if s == ReadStatus.ALERT:
                alert = f"hardware error: Alert bit set (ERR byte {int(reading.errors[i]):#04x})"
                raise LoopFaultError(f"{self._who(i)}: " + self.health_text(i, alert))
            silent = self.silence.failed(i, t_now, stall_total_s, host_late)
            if silent is not None:
                raise LoopFaultError(
                    f"{self._who(i)}: no valid reading for {silent * 1e3:.0f} ms "
                    f"({self.silence.failed_reads(i)} reads in a row; budget "
                    f"{self.comm_budget_ms:g} ms, host stalls not counted); "
                    f"last read {ReadStatus(s).name}"
                )

    def held_on_stall(self, stall_s: float, k: int, t_sim: float) -> None:
        """A bus without a Bus Watchdog (Feetech, Dynamixel Protocol 1.0): a host stall of
        ``safety.watchdog_ms`` or longer (one a watchdog would have acted on) is said and
        counted: the servos held their last goal meanwhile. Not a fault: the show goes on
        (a host hiccup is never a servo's failure, nor a reason to stop the show)."""
        if self.bus.has_watchdog or not self.watchdog_s or stall_s < self.watchdog_s:
            return
        self.held_stalls += 1
        self.held_max_s = max(self.held_max_s, stall_s)
        now = self.clock.now()
        if now - self._held_event_t < HELD_EVENT_INTERVAL_S:
            self._held_unreported += 1
            return
        more, self._held_unreported, self._held_event_t = self._held_unreported, 0, now
        self._event(
            "held_last_goal",
            f"the host stalled {stall_s * 1e3:.0f} ms at tick {k} (t = {t_sim:.2f} s): the "
            f"servos held their last goal for {stall_s * 1e3:.0f} ms (no Bus Watchdog on "
            f"these servos; safety.watchdog_ms = {self.watchdog_s * 1e3:g}); the host's "
            "stall, not a servo fault; the show goes on"
            + (f" ({more} more such stalls since the last report)" if more else ""),
            tick=k,
            t=t_sim,
            held_ms=round(stall_s * 1e3, 3),
            unreported=more,
        )

    def held_as_dict(self) -> dict[str, float | int]:
        """The summary's count of those stalls (``loop.host_stalls``)."""
        return {
            "held_last_goal": self.held_stalls,
            "held_max_ms": round(self.held_max_s * 1e3, 3),
        }

    def check_following(
        self, present: FloatArray | list[float], cmd: FloatArray | list[float]
    ) -> None:
        """``present`` and ``cmd`` in the joint frame (rad): arrays or lists of floats."""
        err = self.following.update(
            present if isinstance(present, list) else present.tolist(),
            cmd if isinstance(cmd, list) else cmd.tolist(),
        )
        if err is None:
            return
        j = err.joint
        raise LoopFaultError(
            f"{self._who(j)}: following error: present "
            f"{math.degrees(present[j]):.1f} deg vs commanded "
            f"{math.degrees(cmd[j]):.1f} deg for {err.duration_s * 1e3:.0f} ms (tolerance "
            f"{math.degrees(self.following.tolerance[j]):g} deg); "
            + self.health_text(j, "the servo does not follow its goals")
        )

    def health_text(self, i: int, fallback: str) -> str:
        """What the servo says about itself (a health read), for a fault message."""
        try:
            health = self.bus.read_health(self.ids[i], HealthPart.ALL)
        except (ServoBusError, ValueError):
            return f"{fallback} (its health could not be read)"
        if health.problem is None:  # health.ok, spelled so that the checker narrows it
            return f"{fallback} (it reports torque on, no hardware error)"
        return f"{health.problem.value}: {health.detail}"

    # ------------------------------------------------------------------ health
    def maybe_read_health(self, spare_s: float, t: float, k: int) -> None:
        """One servo's health, round robin, if this tick has time to spare for it (where
        the tick's read carries the health: its temperature, voltage and load alone)."""
        sched = self.health
        if not sched.due(t):
            return
        if self.bus.tick_health is not None:
            self._maybe_read_condition(spare_s, t)
            return
        took = self._health_took
        if took and t - took[0][0] > HEALTH_COST_MEMORY_S:
            self._health_cost_s = self._forget(t)
        bus = self.bus
        margin = HEALTH_SPARE_S + HEALTH_MARGIN * self._health_cost_s  # the measured cost
        # the figures (a longer read, one round in CONDITION_EVERY_ROUNDS) only where they
        # fit; the checks never wait on them
        fits = sched.next_part() is HealthPart.CONDITION and spare_s >= max(
            HEALTH_MARGIN * bus.condition_read_s + HEALTH_SPARE_S, margin
        )
        if spare_s < max(HEALTH_MARGIN * bus.health_read_s + HEALTH_SPARE_S, margin):
            last = self._last_health_t
            if last is None:
                self._last_health_t = t  # the floor counts from the first read that was due
            if last is None or t - last < HEALTH_FLOOR_S:
                sched.deferred += 1
                return
            sched.forced += 1
        self._last_health_t = t
        i, part = sched.take(t, condition=fits)
        if i in self.limp and part is not HealthPart.CONDITION:
            part = HealthPart.WATCHDOG
        sent = self.clock.now()
        try:
            health = self.bus.read_health(self.ids[i], part)
        except ServoBusError:
            return  # a failed read says nothing new: the per-tick reads keep the budget
        finally:
            took.append((t, self.clock.now() - sent))
            if len(took) > HEALTH_COST_READS:
                del took[0]
            self._health_cost_s = self._forget(t)
        self.last_bus_t = max(self.last_bus_t, sent)
        if health.condition is not None:
            self.condition.update(i, health.condition, sent)
        if part is HealthPart.CONDITION:
            return  # figures only: nothing judged
        self._handle(i, health, k, explained=self.last_long_gap_t > self._last_health_ok[i])

    def _maybe_read_condition(self, spare_s: float, t: float) -> None:
        """The figures alone, each servo's about once a second (the checks are the tick's);
        only where they fit, never forced: a late figure costs nothing but its age."""
        sched = self.health
        if spare_s < HEALTH_MARGIN * self.bus.condition_read_s + HEALTH_SPARE_S:
            sched.deferred += 1
            return
        i, _ = sched.take(t, condition=False)
        sched.postpone(t, CONDITION_EVERY_ROUNDS)
        sent = self.clock.now()
        try:
            health = self.bus.read_health(self.ids[i], HealthPart.CONDITION)
        except ServoBusError:
            return  # a failed read says nothing new: the per-tick reads keep the budget
        self.last_bus_t = max(self.last_bus_t, sent)
        if health.condition is not None:
            self.condition.update(i, health.condition, sent)

    def _forget(self, t: float) -> float:
        """Drop the health reads older than HEALTH_COST_MEMORY_S; the lower median time of
        the rest (of two, the quicker: one slow read among few does not stop the reads)."""
        took = self._health_took
        while took and t - took[0][0] > HEALTH_COST_MEMORY_S:
            del took[0]
        return sorted(d for _, d in took)[(len(took) - 1) // 2] if took else 0.0

    def after_bus_silence(self, gap_s: float, k: int) -> None:
        """The bus was quiet for a good part of the Bus Watchdog period (a host stall): check
        every servo before sending goals; recover tripped watchdogs."""
        self.last_long_gap_t = self.clock.now()
        self._event(
            "bus_silence",
            f"no packet on the bus for {gap_s * 1e3:.0f} ms ("
            + ("Bus Watchdog" if self.bus.has_watchdog else "safety.watchdog_ms, no Bus Watchdog")
            + f" {self.watchdog_s * 1e3:g} ms): checking every servo",
            tick=k,
            gap_ms=round(gap_s * 1e3, 3),
        )
        for i in range(len(self.joints)):
            try:
                health = self.bus.read_health(self.ids[i], HealthPart.ALL)
            except ServoBusError:
                continue  # silent now: the per-tick reads and the budget decide
            if health.condition is not None:
                self.condition.update(i, health.condition, self.clock.now())
            self._handle(i, health, k, explained=True, gap_s=gap_s)
        self.last_bus_t = self.clock.now()

    def _handle(
        self, i: int, health: ServoHealth, k: int, *, explained: bool, gap_s: float = 0.0
    ) -> None:
        limp = i in self.limp
        if health.problem is None or (limp and health.problem is HealthProblem.TORQUE_OFF):
            if (
                limp
                and health.torque_on is None
                and health.watchdog_armed is False
                and self.watchdog_s
            ):
                raise LoopFaultError(  # a limp servo's health read is the watchdog alone
                    f"{self._who(i)}: {HealthProblem.RESET.value}: Bus Watchdog 0 although it "
                    "was armed: the servo restarted (brownout or reboot), RAM back to defaults"
                )
            self._last_health_ok[i] = self.clock.now()
            return
        if health.problem is HealthProblem.WATCHDOG_TRIPPED and explained:
            self._recover(i, k, gap_s)
            return
        cause = health.detail
        if health.problem is HealthProblem.WATCHDOG_TRIPPED:
            cause += " (no host stall explains it: did another program stop talking to it?)"
        raise LoopFaultError(f"{self._who(i)}: {health.problem.value}: {cause}")

    def _recover(self, i: int, k: int, gap_s: float) -> None:
        """A Bus Watchdog tripped by a host stall: clear it, goal = present, rejoin."""
        bus = self.bus
        sid = self.ids[i]
        try:
            reading = bus.read_present(PresentReading.empty(bus.ids))
            pos = float(reading.positions[i])
            if reading.status[i] != ReadStatus.OK or not math.isfinite(pos):
                raise LoopFaultError(
                    f"{self._who(i)}: Bus Watchdog tripped after a host stall "
                    "and its present position cannot be read to recover"
                )
            bus.recover_watchdog(sid, pos)
        except ServoBusError as exc:
            raise LoopFaultError(
                f"{self._who(i)}: Bus Watchdog tripped after a host stall "
                f"and could not be recovered: {exc}"
            ) from exc
        joint_pos = self.map.joint_angle(i, pos)
        self._rejoin(i, joint_pos)
        self.following.reset(i)
        self._last_health_ok[i] = self.clock.now()
        self.recoveries += 1
        self._event(
            "recovered",
            f"{self._who(i)}: its Bus Watchdog had tripped "
            + (f"after {gap_s * 1e3:.0f} ms without a packet " if gap_s else "")
            + f"(a host stall); cleared, goal = present ({math.degrees(joint_pos):.1f} deg), "
            "rejoining the show within the speed and acceleration limits",
            tick=k,
            servo=sid,
        )
