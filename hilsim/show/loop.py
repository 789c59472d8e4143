"""The real-time HIL loop: one tick every period, against absolute deadlines.

One tick (k = 0, 1, ...; t_k = k·period of simulation time)::

    clock.wait_until(t0 + t_k)             sleep, then spin the last stretch (virtual: jump)
    after a long silence on the bus        check every servo; recover tripped watchdogs
    stepper.command                        the safety filter: the only way to the wire
    joint_map.to_servo                     servo angle = home + direction · joint angle
    bus.write_goals, bus.read_present      one Sync Write, one (Fast) Sync Read
    director.tick, stepper.sample          live inputs and cues; u(t_k)
    telemetry.record(TickRecord)           queued; a writer thread owns the disk
    servo_watch                            faults that stop the show, raised once recorded
    stepper.advance                        the springs to t_{k+1} (substeps)
    one health read                        round robin, if the tick has time to spare (X series
                                           with the tick block: temperature and the rest only)

Simulation time is ``k·period``, never the clock, so the numbers are the same on the real
clock and the virtual one. A tick that ends after the next deadline is an overrun: counted,
and with ``overrun_policy = "stop"`` a fault. A loop more than a period behind simulates the
missed ticks without bus traffic (``skipped_ticks``) so the figure stays in step.

The show goes on through a host stall: the host's own stalls are measured (:mod:`.monitors`)
and never counted as servo silence. A stall long enough to trip the servos' Bus Watchdog is
followed by a check of every servo; a tripped one is recovered and rejoins through the speed
and acceleration limits. The show never ends on a frozen figure: health reads and a
following-error monitor (:mod:`.servo_watch`) stop it, naming the servo and the cause.

Every way out (the end, ``duration``, a stop request, a fault) applies the rig's exit policy
once anything was energised; exit codes are in :mod:`hilsim.exit_codes`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from drivers.fill import Packed
from drivers.servo_bus import ExitReport, PresentReading, ServoBus, ServoBusError
from hilsim._types import JsonDict
from hilsim.exit_codes import ExitCode, for_signal
from hilsim.rig import OverrunPolicy
from hilsim.show.events import ShowLog
from hilsim.show.monitors import STALL_EVENT_S, WATCHDOG_GAP_FRACTION, HostStalls
from hilsim.show.parts import Parts
from hilsim.show.realtime import REALTIME_SWITCH_INTERVAL_S, realtime
from hilsim.show.servo_watch import LoopFaultError, ServoWatch, failed_reads
from hilsim.show.status import status_figures
from hilsim.show.stepper import Stepper, TickBuffers
from hilsim.show.stop import StopFlag, signal_name
from hilsim.show.warm_up import warm_up
from hilsim.telemetry import TelemetryWriter, WriterFailedError
from hilsim.telemetry.format import TickRecord

#: the loop stops when integrating one tick has cost more than this share of the period on
#: every tick for INTEGRATION_BEHIND_S of wall time: it can never catch up
INTEGRATION_SHARE = 0.9
INTEGRATION_BEHIND_S = 0.5
#: with a shared start (several buses, hilsim.show.group): a bus begins its start-up (first
#: read, torque on, Bus Watchdog armed) this long before the shared tick 0, and at most 0.4 of
#: its watchdog period, so its servos never wait out their watchdog before the first tick
SHARED_START_LEAD_S = 0.1

log = logging.getLogger(__name__)

__all__ = ["HilLoop", "LoopFaultError", "RunResult"]


@dataclass
class RunResult:
    """How :meth:`HilLoop.run` ended. ``loop`` holds the facts only the loop knows, for the
    summary's ``loop`` section (``docs/summary.md``)."""

    exit_code: int
    reason: str
    ticks: int
    exit_policy: str = ""
    exit_policy_confirmed: bool | None = None
    loop: JsonDict = field(default_factory=dict)


class HilLoop:
    """Runs one show's parts on one open bus. Build, then :meth:`run` once.

    Parameters
    ----------
    parts: what :func:`hilsim.show.parts.build_parts` made from the rig (joints in bus order).
    bus: an open :class:`~drivers.servo_bus.ServoBus` whose IDs are the rig's servo IDs.
    telemetry: the run's writer; closed by the caller after :meth:`run` returns.
    duration_s: stop after this much show time; None = the animation's length (or forever).
    stop: a :class:`StopFlag` a signal handler sets.
    on_status: called about twice a second of wall time with a dict for a live status line.
    start_at: tick 0 at this instant of the real clock (the buses of one figure share it; the
        start-up runs just before it, see SHARED_START_LEAD_S); None: at once. A virtual clock
        ignores it.
    on_stop: called once with the exit code and reason the moment the loop stops, before the
        exit policy (a figure's other buses are stopped then, not after this bus's record).
    """

    def __init__(
        self,
        parts: Parts,
        bus: ServoBus,
        telemetry: TelemetryWriter,
        *,
        duration_s: float | None = None,
        stop: StopFlag | None = None,
        on_status: Callable[[JsonDict], None] | None = None,
        start_at: float | None = None,
        on_stop: Callable[[int, str], None] | None = None,
    ) -> None:
        rig = parts.rig
        if tuple(bus.ids) != rig.servo_ids:
            raise ValueError(f"bus IDs {tuple(bus.ids)} do not match the rig's {rig.servo_ids}")
        if parts.targets.n_joints != len(rig.joints):
            raise ValueError("one target track per joint is needed")
        if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
            raise ValueError(f"duration_s must be finite and > 0, got {duration_s!r}")
        self.rig, self.bus, self.telemetry = rig, bus, telemetry
        self.targets, self.map = parts.targets, parts.joint_map
        self.safety, self.integrator = parts.safety, parts.integrator
        #: live inputs and the show runtime (hilsim.live.director), or None
        self.director = parts.director
        #: joints (indices) a person moves by hand, torque off (the show's [teach])
        teach = getattr(self.director, "teach", None)
        self._limp: tuple[int, ...] = tuple(teach.limp_indices) if teach is not None else ()
        self.clock = bus.clock
        self.stop = stop or StopFlag()
        self.on_status, self.on_stop = on_status, on_stop
        self.start_at = None if self.clock.virtual else start_at
        self.duration_s = parts.targets.duration if duration_s is None else duration_s
        self.period = rig.loop.period_s
        n = len(rig.joints)
        # the tick's arrays (joint frame); the recorded ones are one block, copied at once
        buffers = TickBuffers.zeros(n)
        block = buffers.block
        self.u, self.x, self.v = buffers.u, buffers.x, buffers.v
        self.cmd, self.present, self.du = buffers.cmd, buffers.present, buffers.du
        #: the bus-free half of the tick: safety filter, targets, springs
        self.stepper = Stepper.of(parts, buffers)
        self.reading = PresentReading.empty(rig.servo_ids)
        # the tick reads and writes these through views (drivers.fill: no numpy call)
        self._cmd_view, self._present_view = Packed(self.cmd), Packed(self.present)
        self._positions_view = Packed(self.reading.positions)
        self._status_view = Packed(self.reading.status)
        self.integrator.held_step(rig.loop.h_s)  # now: in tick 0 it overran a 1 kHz show
        self.rec = TickRecord(
            target=self.u,
            sim_x=self.x,
            sim_v=self.v,
            cmd=self.cmd,
            present=self.present,
            status=self.reading.status,
            joint_block=block,
        )
        self.stalls = HostStalls()
        self.log = ShowLog(telemetry, self.safety, bus)
        self.watch = ServoWatch(
            bus,
            rig.joints,
            self.map,
            period_s=self.period,
            comm_budget_ms=rig.safety.comm_failure_budget_ms,
            watchdog_s=(rig.safety.watchdog_ms or 0.0) * 1e-3,
            event=self.log.event,
            rejoin=self._rejoin,
        )
        self._energised = False  # torque may be on: every way out applies the exit policy
        self._recording = True
        self._behind_since: float | None = None
        self._k = 0
        self.overruns = 0  # for the live status line; the summary counts them from telemetry
        #: what only the loop knows, for the summary's ``loop`` section
        self.loop_stats: JsonDict = {"skipped_ticks": 0, "sched": "SCHED_OTHER"}

    # ------------------------------------------------------------------ start / stop
    def _stopping(self) -> bool:
        return self.stop.signum is not None or self.stop.command is not None

    def _start(self) -> bool:
        """Read where the figure is, hold it there with torque on, seed the springs.

        Returns False, with nothing energised, if a stop was requested before torque went on.
        """
        try:
            servo_present = self.watch.first_read(self.reading, self._stopping)
            if servo_present is None or self._stopping():
                return False
            bus = self.bus
            bus.write_goals(servo_present)  # torque on must not jump
            if self._stopping():
                return False
            self._energised = True
            bus.set_torque(True)
            if self.watch.watchdog_s:
                bus.arm_watchdog(self.watch.watchdog_s)
            if self._limp:  # teach-by-hand: these go limp for a person to move them
                bus.set_torque(False, ids=[self.rig.joints[i].servo_id for i in self._limp])
                self.watch.set_limp(self._limp)
        except ServoBusError as exc:
            raise LoopFaultError(f"cannot start: {exc}") from exc
        self.map.to_joint(servo_present, self.present)
        event = self.safety.start(self.present)
        if event is not None:
            self.log.event("safety", str(event), fsync=True)
        for i, jt in enumerate(self.rig.joints):
            self.x[i] = self.present[i] if jt.initial_rad is None else jt.initial_rad
        self.v[:] = 0.0
        self.watch.last_bus_t = self.clock.now()
        return True

    def _apply_exit_policy(self) -> tuple[str, bool]:
        """Apply the rig's exit policy; returns the report text and whether it was confirmed."""
        rig = self.rig
        policy = rig.safety.exit_policy.value
        try:
            if self._limp and policy == "hold":  # a taught joint is held where it was left
                self.watch.set_limp(())
                self.bus.set_torque(True, ids=[rig.joints[i].servo_id for i in self._limp])
            report = self.bus.apply_exit_policy(policy, retries=rig.safety.exit_retries)
        except Exception as exc:  # the bus may be gone: say so loudly, never hang
            partial: ExitReport | None = getattr(exc, "report", None)  # ExitPolicyError's
            if partial is None:
                msg = f"exit policy {policy!r} NOT confirmed: {exc}"
                self.log.event("exit_policy", msg, confirmed=[], unconfirmed=list(self.bus.ids))
            else:
                msg = str(partial)
                self.log.event(
                    "exit_policy",
                    msg,
                    confirmed=list(partial.confirmed),
                    unconfirmed=list(partial.unconfirmed_ids),
                    notes=list(partial.notes),
                )
            return msg, False
        msg = str(report)
        self.log.event(
            "exit_policy", msg, confirmed=list(report.confirmed), notes=list(report.notes)
        )
        return msg, True

    # ------------------------------------------------------------------ the run
    def run(self) -> RunResult:
        """Run the show; every way out (end, signal, fault, exception) applies the exit policy
        once anything was energised. KeyboardInterrupt and SystemExit are re-raised after it.
        SCHED_FIFO and the CPU pin the rig asks for hold for the run only."""
        loop = self.rig.loop
        with realtime(loop.realtime_priority, loop.cpu) as sched:
            self.loop_stats["sched"] = sched
            return self._run(sched)

    def _run(self, sched: str) -> RunResult:
        rig = self.rig
        self.log.event(
            "start", f"{rig.name}: {len(rig.joints)} joints at {rig.loop.rate_hz:g} Hz, {sched}"
        )
        # the telemetry writer is a Python thread: have it let go of the GIL quickly
        switch = sys.getswitchinterval()
        if not self.clock.virtual:
            sys.setswitchinterval(min(switch, REALTIME_SWITCH_INTERVAL_S))
        exit_code, reason, fault = int(ExitCode.OK), "end of show", False
        interrupted: BaseException | None = None
        k = 0
        try:
            if self.start_at is not None:  # start up just before the figure's shared tick 0
                wd = self.watch.watchdog_s
                lead = min(SHARED_START_LEAD_S, 0.4 * wd) if wd else SHARED_START_LEAD_S
                self.clock.wait_until(self.start_at - lead)
            k = self._ticks() if self._start() else 0
            if self._stopping():
                stop = self.stop
                if stop.signum is not None:
                    exit_code = for_signal(stop.signum)
                    reason = f"stopped by {signal_name(stop.signum)}"
                else:
                    exit_code, reason = int(ExitCode.STOPPED), f"stopped by {stop.command}"
                if not self._energised:
                    reason += " before the show started: nothing was energised"
                self.log.event("signal" if stop.signum is not None else "stop", reason, tick=k)
        except LoopFaultError as exc:
            exit_code, reason, fault = int(ExitCode.FAULT), str(exc), True
            if not self._energised:  # refused before anything could move: a clear error
                exit_code = int(ExitCode.USAGE)
        except WriterFailedError as exc:
            exit_code, fault = int(ExitCode.FAULT), True
            reason = f"telemetry: the writer failed ({exc.__cause__ or exc}); show stopped"
        except Exception as exc:
            exit_code, fault = int(ExitCode.FAULT), True
            reason = f"internal error: {type(exc).__name__}: {exc}"
            self.log.event("crash", reason, traceback=traceback.format_exc())
        except BaseException as exc:  # KeyboardInterrupt, SystemExit: clean up, then re-raise
            interrupted = exc
            exit_code, reason = int(ExitCode.SIGINT), f"interrupted ({type(exc).__name__})"
        finally:
            sys.setswitchinterval(switch)
        if self.on_stop is not None:  # a report, never a reason to skip the exit policy
            with contextlib.suppress(Exception):
                self.on_stop(exit_code, reason)
        if fault:
            k = self._k
            self.log.event("fault", reason, tick=k, t=k * self.period)
        result = RunResult(exit_code, reason, k, loop=self.loop_stats)
        if self._energised:
            result.exit_policy, confirmed = self._apply_exit_policy()
            result.exit_policy_confirmed = confirmed
            if not confirmed and not fault:
                result.exit_code = int(ExitCode.UNSAFE_EXIT)
        else:
            result.exit_policy = "not applied: nothing was energised"
        if self.safety.started:  # clamps: one owner, the summary's safety_limits
            counters = self.safety.counters
            self.telemetry.stats.set_safety_counts(
                counters.by_kind(), ticks=counters.ticks, held_ticks=counters.fault_ticks
            )
            self.log.safety_limits(k, k * self.period)
        self.loop_stats.update(
            recoveries=self.watch.recoveries,
            host_stalls=self.stalls.as_dict()
            | ({} if self.bus.has_watchdog else self.watch.held_as_dict()),
            health_reads=self.watch.health.reads,
            health_deferred=self.watch.health.deferred,
            health_forced=self.watch.health.forced,
            health_every_tick=self.bus.tick_health is not None,
            servo_condition=self.watch.condition.extremes(self.watch.names),
            spin_window_us=None if self.clock.virtual else getattr(self.clock, "window_s", 0) * 1e6,
        )
        if interrupted is not None:
            raise interrupted
        return result

    def _ticks(self) -> int:
        """Tick until the show ends, a stop is requested or a fault is raised; returns ticks run."""
        clock, period = self.clock, self.period
        n_ticks = None if self.duration_s is None else round(self.duration_s / period) + 1
        # the telemetry writer formats rows only while we sleep (never during a tick's work):
        # between ticks, and in the clock's waits inside one (an in-process emulator's wire)
        slack = getattr(self.telemetry, "slack", None) if not clock.virtual else None
        shared = slack is not None and getattr(clock, "idle", False) is None
        if shared:
            clock.idle = slack
        try:
            # tick 0 as warm as later ones
            cold = (
                None if clock.virtual else warm_up(self.stepper, self.map, self.telemetry, self.rec)
            )
            if cold:
                self.log.event("warm_up", f"tick 0 runs cold: the warm-up failed ({cold})")
            t0 = self._begin()
            k = 0
            while n_ticks is None or k < n_ticks:
                if self._stopping():
                    break
                t_sched = t0 + k * period
                t_top = clock.now()
                t_actual = clock.wait_until(t_sched, slack)
                self._k = k
                self._tick(k, t_sched, t_top, t_actual)
                k = self._after_tick(k + 1, t_sched, t_actual, n_ticks)
            return k
        finally:
            if shared:
                clock.idle = None

    def _begin(self) -> float:
        """The books the ticks keep, started at tick 0 (``hilsim bench`` starts them too, to
        time :meth:`_tick` as the show runs it). Returns the clock time of tick 0."""
        clock, period = self.clock, self.period
        self.recent_lateness_us = np.zeros(512)  # lateness ring for the live status line
        if self.start_at is not None and not self._stopping():
            clock.wait_until(self.start_at)  # at once if the start-up took longer: late, said
        t0 = self._t0 = clock.now()
        self.loop_stats["clock_t0"] = t0  # the clock time of tick 0 (fault plans use it)
        if self.director is not None:
            self.director.begin(t0, self.log.event, self.stop)
        self.watch.silence.start(t0)
        self._next_status = time.perf_counter() + 0.5
        # host-stall accounting per iteration: wall time less the sleep, the time the driver
        # waited on the servos, and the catch-up's cost is host work
        self._prev: tuple[float, float] | None = None  # (t_actual, device wait) of the last
        self._excluded = 0.0  # the last iteration's catch-up cost: not host work
        self._integ_s = math.inf  # the least integrating one tick has cost (clock time)
        self._gaps_mark = self.bus.host_stall_s
        self._limits_every = max(1, round(1.0 / period))  # clamps logged once a second at most
        self._next_limits_tick = self._limits_every
        return t0

    # ------------------------------------------------------------------ one tick
    # long on purpose: hot path: the tick in the order it runs
    def _tick(self, k: int, t_sched: float, t_top: float, t_actual: float) -> None:  # noqa: PLR0915
        """Tick k: safety filter, Sync Write + Sync Read, telemetry, the checks, the springs
        to tick k+1. Its stage times go into the tick record.

        ``p_*`` are perf_counter stamps where each stage starts (the stage columns' edges);
        ``t_*`` are the bus clock's times the servos' watchdog and the checks need."""
        clock, bus, rec, watch, perf = self.clock, self.bus, self.rec, self.watch, time.perf_counter
        # late from a sleep it had to take: the host was not running (else it was behind)
        sleep_late = t_actual - t_sched if t_top < t_sched else 0.0
        waited = bus.device_wait_s
        prev = self._prev
        work = None if prev is None else t_top - prev[0] - (waited - prev[1]) - self._excluded
        self._prev, self._excluded = (t_actual, waited), 0.0
        t_sim = k * self.period
        p_safety = perf()
        event = self.stepper.command()  # the only way to the wire
        if event is not None:
            # a fatal one never reaches the wire (no row: nothing was sent or read); the
            # simulation state that caused it is kept in the event
            state = {
                "sim_x": self.x.tolist(),
                "sim_v": self.v.tolist(),
                "cmd_held": self.cmd.tolist(),
            }
            self.log.event(
                "safety", str(event), tick=k, t=t_sim, fsync=True, **(state if event.fatal else {})
            )
            if event.fatal:
                raise LoopFaultError(f"safety: {event}")
        t_goals = clock.now()  # (a microsecond before the Sync Write: early, never late)
        checks = 0.0  # the servo checks after a bus silence: bus time, not the filter's
        if watch.watchdog_s:  # a long silence on the bus: have the servos stopped?
            gap = t_goals - watch.last_bus_t
            if gap >= WATCHDOG_GAP_FRACTION * watch.watchdog_s:
                c_checks = perf()
                watch.after_bus_silence(gap, k)
                checks = perf() - c_checks
                t_goals = clock.now()
        # the joint map on Python floats: a few joints cost less than numpy's calls
        jmap, cmd = self.map, self._cmd_view.tolist()
        goals = jmap.to_servo_list(cmd)
        p_bus = perf()
        try:  # one Sync Write, one (Fast) Sync Read
            bus.write_goals(goals)
            reading = bus.read_present(self.reading)
        except ServoBusError as exc:
            raise LoopFaultError(f"bus: {exc}") from exc
        p_bus_end = perf()
        t_read = clock.now()
        watch.last_bus_t = t_goals  # the servos' watchdog counts from the last packet they got
        view = self._positions_view
        if view.arr is not reading.positions:  # another reading (not the loop's own)
            view = self._positions_view = Packed(reading.positions)
        present = jmap.to_joint_list(view.tolist())
        self._present_view.put(*present)
        if self.director is not None:  # live inputs, cues, timecode: this tick's targets
            self.director.tick(k, t_sim, present)
            for i in self._limp:  # the spring and the filter sit where the hand put the joint,
                p = present[i]  # so the next goal is there: torque coming back moves nothing
                if p == p:  # (a stale read is NaN: the last position holds)
                    self.x[i], self.v[i] = p, 0.0
                    self.safety.rejoin(i, p)
        # u(t_k) recorded; u and u' as tuples for the springs (u' needs no array of its own)
        target = self.stepper.sample(t_sim)
        p_record = perf()
        # the host's own stall in or just before this tick: a late wake-up, the last
        # iteration's host work beyond its usual cost, and what the driver saw of the host
        # not running inside its bus calls (the health read's too)
        gaps = bus.host_stall_s
        stall = self.stalls.tick_stall(sleep_late, work, gaps - self._gaps_mark)
        self._gaps_mark = gaps
        status = reading.status
        view = self._status_view
        if view.arr is not status:
            view = self._status_view = Packed(status)
        all_ok = not any(view.tolist())  # OK is 0; no numpy reduction
        rec.tick, rec.t_sched, rec.t_actual, rec.status = k, t_sim, t_actual - self._t0, status
        rec.t_sim_us, rec.t_telemetry_us, rec.overrun = math.nan, math.nan, False
        rec.t_safety_us = (p_bus - p_safety - checks) * 1e6
        rec.t_bus_us = (p_bus_end - p_bus + checks) * 1e6
        rec.comm_errors = watch.comm_errors + (0 if all_ok else failed_reads(status))
        rec.host_stall_us = stall * 1e6
        if self._recording:
            try:
                self.telemetry.record(rec)
            except WriterFailedError as exc:
                self._telemetry_failed(exc)
        p_checks = perf()
        # -- faults that stop the show, raised once the tick is in telemetry
        if stall >= STALL_EVENT_S:
            self.log.host_stall(stall, k, t_sim)
            if stall >= WATCHDOG_GAP_FRACTION * watch.watchdog_s:
                watch.last_long_gap_t = t_read  # explains a watchdog trip found later
            watch.held_on_stall(stall, k, t_sim)
        watch.check_reads(reading, t_read, self.stalls.total_s, stall > 0.0, all_ok, k)
        watch.check_following(present, cmd)
        # -- advance the springs to the next tick (target held over each step)
        t_springs = clock.now()
        self.stepper.advance(t_sim, target)
        integ_s = clock.now() - t_springs
        if integ_s < self._integ_s:  # the least one tick has cost (min() parses keywords)
            self._integ_s = integ_s
        p_end = perf()
        rec.t_sim_us = (p_end - p_checks + p_record - p_bus_end) * 1e6
        rec.t_telemetry_us = (p_checks - p_record) * 1e6
        self._integ_share = (p_end - p_checks) / self.period

    def _after_tick(self, k: int, t_sched: float, t_actual: float, n_ticks: int | None) -> int:
        """The end of tick k-1 (``k`` is the next): overrun and its policy, the catch-up or a
        health read in the spare time, the once-a-second logs and the status line. Returns
        the next tick to run."""
        clock, period, t0, rec = self.clock, self.period, self._t0, self.rec
        t_end = clock.now()
        late = t_end > t0 + k * period
        if self._recording:
            rec.overrun = late
            self.telemetry.amend(rec)
        self._check_integration_keeps_up(self._integ_share, t_end)
        self.recent_lateness_us[k % 512] = (t_actual - t_sched) * 1e6
        if late:
            self.overruns += 1
            if self.rig.loop.overrun_policy is OverrunPolicy.STOP:
                raise LoopFaultError(
                    f"overrun at tick {k - 1}: the tick took {(t_end - t_actual) * 1e3:.2f} ms "
                    f"(period {period * 1e3:g} ms; overrun_policy = 'stop')"
                )
            caught_up = k
            k = self._catch_up(k, t0, t_end, n_ticks)
            self._excluded += (
                k - caught_up
            ) * self._integ_s  # its cost; a stall in it is the host's
        elif n_ticks is None or k < n_ticks:
            self.watch.maybe_read_health(t0 + k * period - t_end, t_end, k - 1)
        t_sim = rec.t_sched
        if k >= self._next_limits_tick:  # once a second: what the filter did, a corrupt reply
            self._next_limits_tick = k + self._limits_every
            self.log.safety_limits(k - 1, t_sim)
            self.log.corrupt_reply(k - 1, t_sim)
        if self.on_status is not None and time.perf_counter() >= self._next_status:
            self._next_status += 0.5
            self.on_status(status_figures(self, k, t_sim, t_end))
        return k

    # ------------------------------------------------------------------ per-tick parts
    def _telemetry_failed(self, exc: WriterFailedError) -> None:
        """The writer died recording the tick's row: stop the show or, with
        ``telemetry.on_failure = "continue"`` (or ``auto``, endless), only the recording."""
        if not self.rig.telemetry.on_failure.continues(endless=self.duration_s is None):
            raise exc
        self._recording = False
        log.warning(
            "telemetry stopped (%s); the show goes on (telemetry.on_failure = '%s')",
            exc.__cause__ or exc,
            self.rig.telemetry.on_failure,
        )

    def _rejoin(self, i: int, joint_rad: float) -> None:
        """Servo i was recovered where it stopped: the filter and this tick's goal start there
        (the filter ran already this tick)."""
        self.safety.rejoin(i, joint_rad)
        self.cmd[i] = joint_rad

    def _catch_up(self, k: int, t0: float, t_end: float, n_ticks: int | None) -> int:
        """After an overrun of more than a whole period, simulate the missed ticks without bus
        traffic so the show stays in time; returns the next tick to run. Stops early on a
        stop request."""
        period = self.period
        behind = int((t_end - t0) / period) - k
        for _ in range(max(0, behind)):
            if (n_ticks is not None and k >= n_ticks) or self._stopping():
                break
            self.stepper.advance(k * period)
            k += 1
            self.loop_stats["skipped_ticks"] += 1
        # the next row carries the count, so a reader tells these ticks (no row by design) from
        # rows lost; the late tick's row keeps the count before (amend rewrites only its times)
        self.rec.skipped_ticks = self.loop_stats["skipped_ticks"]
        return k

    def _check_integration_keeps_up(self, share: float, t_end: float) -> None:
        """Integration that costs more than a tick can never catch up: stop, say why."""
        if self.clock.virtual or share < INTEGRATION_SHARE:
            self._behind_since = None
            return
        if self._behind_since is None:
            self._behind_since = t_end
        elif t_end - self._behind_since >= INTEGRATION_BEHIND_S:
            loop = self.rig.loop
            raise LoopFaultError(
                f"the host cannot keep up: integrating one tick takes {share * 100:.0f} % of "
                f"the {loop.period_s * 1e3:g} ms period ({loop.substeps} substep(s), "
                f"{loop.integrator}) on every tick for {INTEGRATION_BEHIND_S:g} s. Lower "
                "loop.substeps or loop.rate_hz."
            )
