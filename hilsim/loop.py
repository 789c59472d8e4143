"""The real-time HIL loop: one tick every period, against absolute deadlines.

One tick (k = 0, 1, ...; t_k = k·period of simulation time)::

    clock.wait_until(t0 + t_k)             sleep, then spin the last stretch (virtual: jump)
    after a long silence on the bus        check every servo's health; recover tripped watchdogs
    safety.filter                          finite? within limits, speed, acceleration? soft start
    joint map                              servo angle = home + direction · joint angle
    bus.write_goals                        one Sync Write
    bus.read_present                       one (Fast) Sync Read, per-servo status
    telemetry.record                       queued; a writer thread owns the disk
    reads, following error                 faults that stop the show, raised once recorded
    targets.sample + integrator.step       x_k -> x_{k+1} (substeps; target held over each step)
    one health read                        round robin, only if the tick has time to spare

Simulation time is ``k·period``, never the clock, so the commanded numbers are the same
whether the loop runs on the real clock or the virtual one. A tick that finishes after the
next deadline is an overrun: counted, and (``overrun_policy = "stop"``) a fault. When the
loop has fallen more than a whole period behind, the missed ticks are simulated without bus
traffic so the figure stays in step with the show (counted as ``skipped_ticks``).

**The show goes on through a host stall** (:mod:`hilsim.monitors`): the host's own stalls
are measured and logged (``host_stall`` events, the ``host_stall_us`` column) and never
counted as servo silence. A stall long enough for the servos' Bus Watchdog to trip is
followed by a health check of every servo; a tripped watchdog is cleared, the goal set to
where the servo stopped, and the joint rejoins the show through the speed and acceleration
limits (a ``recovered`` event).

**The show never ends on a frozen figure.** Health reads (torque, hardware error, watchdog,
RAM reset) spread over ticks with time to spare, and a following-error monitor, stop the
show naming the servo and the cause.

Stops: the end of the show or ``duration``, a stop request (SIGINT/SIGTERM), or a fault
(naming the servo and the cause: a servo, the bus, the host, the telemetry, or an internal
error). Every way out applies the rig's exit policy (``hold`` or ``relax``) once anything
was energised; exit codes are in :mod:`hilsim.exit_codes`.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import sys
import time
import traceback
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from drivers.servo_bus import (
    HealthPart,
    HealthProblem,
    PresentReading,
    ReadStatus,
    ServoBus,
    ServoBusError,
    ServoHealth,
)
from hilsim.exit_codes import ExitCode, for_signal
from hilsim.integrators import make_integrator
from hilsim.monitors import (
    STALL_EVENT_INTERVAL_S,
    STALL_EVENT_S,
    WATCHDOG_GAP_FRACTION,
    FollowingMonitor,
    HealthSchedule,
    HostStalls,
    SilenceBudget,
)
from hilsim.rig import OverrunPolicy, Rig, TelemetryFailurePolicy
from hilsim.safety import SafetyFilter
from hilsim.targets import TargetSet
from hilsim.telemetry import TelemetryWriter, WriterFailedError

#: GIL switch interval while a show runs on the real clock (see HilLoop.run)
REALTIME_SWITCH_INTERVAL_S = 100e-6
#: the loop stops when integrating one tick has cost more than this share of the period on
#: every tick for INTEGRATION_BEHIND_S of wall time: it can never catch up
INTEGRATION_SHARE = 0.9
INTEGRATION_BEHIND_S = 0.5
#: a health read runs only when the tick has its expected bus time, times this, plus
#: HEALTH_SPARE_S (the SDK's own time) to spare: it must never make the tick late
HEALTH_MARGIN = 1.1
HEALTH_SPARE_S = 150e-6

EXIT_OK = ExitCode.OK
EXIT_FAULT = ExitCode.FAULT
EXIT_SIGINT = ExitCode.SIGINT
EXIT_SIGTERM = ExitCode.SIGTERM


class LoopFaultError(RuntimeError):
    """A condition that stops the show: the message names the servo/joint and the cause."""


@dataclass
class StopFlag:
    """Set from a signal handler; the loop looks at it once per tick (and during start-up)."""

    signum: int | None = None

    def request(self, signum: int) -> None:
        if self.signum is None:
            self.signum = signum


@dataclass
class RunResult:
    exit_code: int
    reason: str
    ticks: int
    summary: dict = field(default_factory=dict)


def try_realtime(priority: int | None, cpu: int | None) -> str:
    """Ask for SCHED_FIFO and CPU affinity; warn (never fail) when not permitted.

    Returns the scheduling class in force, e.g. ``"SCHED_FIFO:50"`` or ``"SCHED_OTHER"``.
    """
    if cpu is not None:
        try:
            os.sched_setaffinity(0, {cpu})
        except (OSError, AttributeError, ValueError) as exc:
            warnings.warn(f"could not pin the loop to CPU {cpu}: {exc}", stacklevel=2)
    sched = "SCHED_OTHER"
    if priority is not None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            sched = f"SCHED_FIFO:{priority}"
        except (OSError, AttributeError) as exc:
            warnings.warn(
                f"SCHED_FIFO priority {priority} not permitted ({exc}); running as SCHED_OTHER. "
                "Grant it with: sudo setcap cap_sys_nice+ep $(readlink -f $(which python3)) "
                "or run under a user with an rtprio limit (/etc/security/limits.conf).",
                stacklevel=2,
            )
    return sched


def _signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


class HilLoop:
    """Runs one rig on one open bus. Build, then :meth:`run` once.

    Parameters
    ----------
    rig: the loaded rig (joints in bus order).
    bus: an open :class:`~drivers.servo_bus.ServoBus` whose IDs are the rig's servo IDs.
    targets: one track per joint, in joint order.
    telemetry: the run's writer; closed by the caller after :meth:`run` returns.
    duration_s: stop after this much show time; None = the animation's length (or forever).
    stop: a :class:`StopFlag` a signal handler sets.
    on_status: called about twice a second of wall time with a dict for a live status line.
    """

    def __init__(
        self,
        rig: Rig,
        bus: ServoBus,
        targets: TargetSet,
        telemetry: TelemetryWriter,
        *,
        duration_s: float | None = None,
        stop: StopFlag | None = None,
        on_status: Callable[[dict], None] | None = None,
    ) -> None:
        if tuple(bus.ids) != rig.servo_ids:
            raise ValueError(f"bus IDs {tuple(bus.ids)} do not match the rig's {rig.servo_ids}")
        if targets.n_joints != len(rig.joints):
            raise ValueError("one target track per joint is needed")
        if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
            raise ValueError(f"duration_s must be finite and > 0, got {duration_s!r}")
        self.rig, self.bus, self.targets, self.telemetry = rig, bus, targets, telemetry
        self.clock = bus.clock
        self.stop = stop or StopFlag()
        self.on_status = on_status
        end = targets.duration if duration_s is None else duration_s
        self.duration_s = end
        n = len(rig.joints)
        j = rig.joints
        self.home = np.array([jt.home_rad for jt in j])
        self.direction = np.array([float(jt.direction) for jt in j])
        period = rig.loop.period_s
        self.safety = SafetyFilter(
            np.array([jt.min_rad for jt in j]),
            np.array([jt.max_rad for jt in j]),
            np.array([jt.max_speed_rad_s for jt in j]),
            np.array([jt.max_accel_rad_s2 for jt in j]),
            period,
            soft_start_s=rig.safety.soft_start_s,
            joint_names=rig.joint_names,
        )
        self.integrator = make_integrator(rig.loop.integrator, rig.spring_bank())
        # Preallocated per-tick buffers (joint frame unless named servo_*).
        self.x = np.zeros(n)
        self.v = np.zeros(n)
        self.u = np.zeros(n)
        self.du = np.zeros(n)
        self.cmd = np.zeros(n)
        self.servo_goal = np.zeros(n)
        self.present = np.zeros(n)
        self.reading = PresentReading.empty(rig.servo_ids)
        # monitors (hilsim.monitors)
        self.stalls = HostStalls()
        self.silence = SilenceBudget(n, rig.safety.comm_failure_budget_ms * 1e-3)
        self.following = FollowingMonitor(
            [jt.tracking_tolerance_rad for jt in j], [jt.tracking_time_s for jt in j], period
        )
        self.health = HealthSchedule(n)
        self._watchdog_s = (rig.safety.watchdog_ms or 0.0) * 1e-3
        self._energised = False  # torque may be on: every way out applies the exit policy
        self._recording = True
        self._last_bus_t = -math.inf  # clock time of the last packet sent to the servos
        self._last_long_gap_t = -math.inf  # when the bus last went quiet for a watchdog's while
        self._last_health_ok = [-math.inf] * n
        self._stall_event_t = -math.inf
        self._stalls_unreported = 0
        self._behind_since: float | None = None
        self._k = 0
        #: loop books for the summary (read statuses and comm errors are counted by telemetry)
        self.stats: dict = {
            "overruns": 0,
            "skipped_ticks": 0,
            "sched": "SCHED_OTHER",
            "recoveries": 0,
        }

    # ------------------------------------------------------------------ start / stop
    def _stopping(self) -> bool:
        return self.stop.signum is not None

    def _start(self) -> bool:
        """Read where the figure is, hold it there with torque on, seed the springs.

        Returns False, with nothing energised, if a stop was requested before torque went on.
        """
        try:
            servo_present = self._first_read()
            if servo_present is None or self._stopping():
                return False
            bus = self.bus
            bus.write_goals(servo_present)  # torque on must not jump
            if self._stopping():
                return False
            self._energised = True
            bus.set_torque(True)
            if self._watchdog_s:
                bus.arm_watchdog(self._watchdog_s)
        except ServoBusError as exc:
            raise LoopFaultError(f"cannot start: {exc}") from exc
        np.subtract(servo_present, self.home, out=self.present)
        self.present *= self.direction
        event = self.safety.start(self.present)
        if event is not None:
            self._event("safety", str(event), fsync=True)
        for i, jt in enumerate(self.rig.joints):
            self.x[i] = self.present[i] if jt.initial_rad is None else jt.initial_rad
        self.v[:] = 0.0
        self._last_bus_t = self.clock.now()
        return True

    def _first_read(self) -> np.ndarray | None:
        """Every servo's present position (servo frame), from as many Sync Reads as the comm
        budget allows (at least three): one bad reply must not stop a show from starting."""
        rig, bus = self.rig, self.bus
        period = rig.loop.period_s
        attempts = max(3, min(100, math.ceil(rig.safety.comm_failure_budget_ms * 1e-3 / period)))
        n = len(rig.joints)
        positions = np.full(n, np.nan)
        got = np.zeros(n, dtype=bool)
        last = self.reading
        for attempt in range(attempts):
            if self._stopping():
                return None
            if attempt:
                self.clock.wait_until(self.clock.now() + period)
            last = bus.read_present(self.reading)
            good = (last.status == ReadStatus.OK) & np.isfinite(last.positions)
            positions[good] = last.positions[good]
            got |= good
            if got.all():
                return positions
        names = ", ".join(
            f"{rig.joints[i].name} (servo {rig.joints[i].servo_id}: "
            f"{ReadStatus(int(last.status[i])).name})"
            for i in np.flatnonzero(~got)
        )
        raise LoopFaultError(f"cannot start: no present position for {names} in {attempts} reads")

    def _apply_exit_policy(self) -> tuple[str, bool]:
        """Apply the rig's exit policy; returns the report text and whether it was confirmed."""
        rig = self.rig
        policy = rig.safety.exit_policy.value
        try:
            report = self.bus.apply_exit_policy(policy, retries=rig.safety.exit_retries)
        except Exception as exc:  # the bus may be gone: say so loudly, never hang
            report = getattr(exc, "report", None)
            if report is None:
                msg = f"exit policy {policy!r} NOT confirmed: {exc}"
                self._event("exit_policy", msg, confirmed=[], unconfirmed=list(self.bus.ids))
            else:
                msg = str(report)
                self._event(
                    "exit_policy",
                    msg,
                    confirmed=list(report.confirmed),
                    unconfirmed=list(report.unconfirmed_ids),
                    notes=list(report.notes),
                )
            return msg, False
        msg = str(report)
        self._event("exit_policy", msg, confirmed=list(report.confirmed), notes=list(report.notes))
        return msg, True

    def _event(self, kind: str, message: str, **fields) -> None:
        """An events.jsonl line; never raises (it may run while handling a failure)."""
        with contextlib.suppress(Exception):  # a broken writer must not stop the exit path
            self.telemetry.event(kind, message, **fields)

    # ------------------------------------------------------------------ the loop
    def run(self) -> RunResult:
        """Run the show; every way out (end, signal, fault, exception) applies the exit policy
        once anything was energised. KeyboardInterrupt and SystemExit are re-raised after it."""
        rig = self.rig
        self.stats["sched"] = try_realtime(rig.loop.realtime_priority, rig.loop.cpu)
        self._event(
            "start",
            f"{rig.name}: {len(rig.joints)} joints at {rig.loop.rate_hz:g} Hz, "
            f"{self.stats['sched']}",
        )
        # The telemetry writer is a Python thread: when the loop wakes from its sleep it may
        # wait for the GIL up to the interpreter's switch interval (5 ms by default). Ask the
        # holder to let go within 100 µs while the show runs on the real clock.
        switch = sys.getswitchinterval()
        if not self.clock.virtual:
            sys.setswitchinterval(min(switch, REALTIME_SWITCH_INTERVAL_S))
        exit_code, reason, fault = int(ExitCode.OK), "end of show", False
        interrupted: BaseException | None = None
        k = 0
        try:
            k = self._ticks() if self._start() else 0
            if self._stopping():
                exit_code = for_signal(self.stop.signum)
                reason = f"stopped by {_signal_name(self.stop.signum)}"
                if not self._energised:
                    reason += " before the show started: nothing was energised"
                self._event("signal", reason, tick=k)
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
            self._event("crash", reason, traceback=traceback.format_exc())
        except BaseException as exc:  # KeyboardInterrupt, SystemExit: clean up, then re-raise
            interrupted = exc
            exit_code, reason = int(ExitCode.SIGINT), f"interrupted ({type(exc).__name__})"
        finally:
            sys.setswitchinterval(switch)
        if fault:
            k = self._k
            self._event("fault", reason, tick=k, t=k * rig.loop.period_s)
        if self._energised:
            self.stats["exit_policy"], confirmed = self._apply_exit_policy()
            self.stats["exit_policy_confirmed"] = confirmed
            if not confirmed and not fault:
                exit_code = int(ExitCode.UNSAFE_EXIT)
        else:
            self.stats["exit_policy"] = "not applied: nothing was energised"
            self.stats["exit_policy_confirmed"] = None
        if self.safety.started:  # clamps: one owner, the summary's safety_limits
            counters = self.safety.counters
            self.telemetry.stats.set_safety_counts(
                counters.by_kind(), ticks=counters.ticks, held_ticks=counters.fault_ticks
            )
            self._log_safety_limits(k, k * rig.loop.period_s)
        self.stats["host_stalls"] = self.stalls.as_dict()
        self.stats["health_reads"] = self.health.reads
        if interrupted is not None:
            raise interrupted
        return RunResult(exit_code, reason, k, self.stats)

    def _ticks(self) -> int:
        """Tick until the show ends, a stop is requested or a fault is raised; returns ticks run."""
        rig, bus, clock = self.rig, self.bus, self.clock
        period = rig.loop.period_s
        stop_on_overrun = rig.loop.overrun_policy is OverrunPolicy.STOP
        x, cmd, goal, present = self.x, self.cmd, self.servo_goal, self.present
        home, direction, safety = self.home, self.direction, self.safety
        n_ticks = None if self.duration_s is None else round(self.duration_s / period) + 1
        perf = time.perf_counter
        # the telemetry writer formats rows only while we sleep (never during a tick)
        slack = getattr(self.telemetry, "slack", None) if not clock.virtual else None
        recent = np.zeros(512)  # lateness ring for the live status line
        t0 = clock.now()
        self.stats["clock_t0"] = t0  # the clock time of tick 0 (fault plans use the bus clock)
        self.silence.start(t0)
        self._comm_errors = 0
        next_status = perf() + 0.5
        # host-stall accounting per iteration: wall time less the sleep, the time the driver
        # waited on the servos, and the catch-up's cost is host work
        prev_actual: float | None = None
        prev_wait = 0.0
        prev_excluded = 0.0
        integ_s = math.inf  # the least integrating one tick has cost (clock time)
        gaps_mark = bus.host_stall_s
        limits_every = max(1, round(1.0 / period))  # clamps are logged once a second at most
        next_limits_tick = limits_every
        self._limits_seen: dict[str, dict[str, int]] = {}
        k = 0
        while n_ticks is None or k < n_ticks:
            if self._stopping():
                break
            t_sched = t0 + k * period
            t_top = clock.now()
            t_actual = clock.wait_until(t_sched, slack)
            # late from a sleep it had to take: the host was not running (else it was behind)
            sleep_late = t_actual - t_sched if t_top < t_sched else 0.0
            waited = bus.device_wait_s
            work = (
                None
                if prev_actual is None
                else t_top - prev_actual - (waited - prev_wait) - prev_excluded
            )
            excluded = 0.0  # this iteration's catch-up cost: not host work
            t_sim = k * period
            self._k = k
            c0 = perf()
            # -- safety: the only way to the wire
            event = safety.filter(x, cmd)
            if event is not None:
                # a fatal one never reaches the wire (no row: nothing was sent or read); the
                # simulation state that caused it is kept in the event
                state = (
                    {"sim_x": x.tolist(), "sim_v": self.v.tolist(), "cmd_held": cmd.tolist()}
                    if event.fatal
                    else {}
                )
                self._event("safety", str(event), tick=k, t=t_sim, fsync=True, **state)
                if event.fatal:
                    raise LoopFaultError(f"safety: {event}")
            if self._watchdog_s:  # a long silence on the bus: have the servos stopped?
                gap = clock.now() - self._last_bus_t
                if gap >= WATCHDOG_GAP_FRACTION * self._watchdog_s:
                    self._after_bus_silence(gap, k)
            np.multiply(cmd, direction, out=goal)
            goal += home
            tb = clock.now()
            c1 = perf()
            # -- one Sync Write, one (Fast) Sync Read
            try:
                bus.write_goals(goal)
                reading = bus.read_present(self.reading)
            except ServoBusError as exc:
                raise LoopFaultError(f"bus: {exc}") from exc
            c2 = perf()
            tc = clock.now()
            self._last_bus_t = tb  # the servos' watchdog counts from the last packet they got
            np.subtract(reading.positions, home, out=present)
            present *= direction
            self.targets.sample(t_sim, self.u, self.du)
            c3 = perf()
            # the host's own stall in or just before this tick: a late wake-up, the last
            # iteration's host work beyond its usual cost, and what the driver saw of the host
            # not running inside its bus calls (the health read's too)
            stall = self.stalls.tick_stall(sleep_late, work, bus.host_stall_s - gaps_mark)
            gaps_mark = bus.host_stall_s
            self._record(k, t_sim, t_actual - t0, reading.status, c1 - c0, c2 - c1, stall)
            c4 = perf()
            # -- faults that stop the show, raised once the tick is in telemetry
            if stall >= STALL_EVENT_S:
                self._stall_event(stall, k, t_sim)
                if stall >= WATCHDOG_GAP_FRACTION * self._watchdog_s:
                    self._last_long_gap_t = tc  # explains a watchdog trip found later
            self._check_reads(reading, tc, stall > 0.0)
            self._check_following(k)
            # -- advance the springs to the next tick (target held over each step)
            t_int = clock.now()
            self._integrate(t_sim, first_target_sampled=True)
            integ_s = min(integ_s, clock.now() - t_int)  # the least one tick has cost
            c5 = perf()
            k += 1
            t_end = clock.now()
            late = t_end > t0 + k * period
            if self._recording:
                self.telemetry.amend(
                    k - 1,
                    overrun=late,
                    t_sim_us=(c5 - c4 + c3 - c2) * 1e6,
                    t_telemetry_us=(c4 - c3) * 1e6,
                )
            self._check_integration_keeps_up((c5 - c4) / period, t_end)
            recent[k % 512] = (t_actual - t_sched) * 1e6
            if late:
                self.stats["overruns"] += 1
                if stop_on_overrun:
                    raise LoopFaultError(
                        f"overrun at tick {k - 1}: the tick took {(t_end - t_actual) * 1e3:.2f} ms "
                        f"(period {period * 1e3:g} ms; overrun_policy = 'stop')"
                    )
                caught_up = k
                k = self._catch_up(k, t0, t_end, n_ticks)
                excluded += (k - caught_up) * integ_s  # its cost; a stall in it is the host's
            elif n_ticks is None or k < n_ticks:
                self._maybe_read_health(t0 + k * period - t_end, t_end, k - 1)
            prev_actual, prev_wait, prev_excluded = t_actual, waited, excluded
            if k >= next_limits_tick:  # once a second: what the filter did, a corrupt reply
                next_limits_tick = k + limits_every
                self._log_safety_limits(k - 1, t_sim)
                if bus.corrupt_sample is not None:
                    self._event(
                        "corrupt_reply",
                        "a corrupt reply (bytes as received; the latest of the last second)",
                        tick=k - 1,
                        t=t_sim,
                        raw=bus.corrupt_sample.hex(" "),
                    )
                    bus.corrupt_sample = None
            if self.on_status is not None and perf() >= next_status:
                next_status += 0.5
                filled = recent[: min(k, 512)]
                self.on_status(
                    {
                        "tick": k,
                        "t": t_sim,
                        "duration": self.duration_s,
                        "comm_errors": self._comm_errors,
                        "overruns": self.stats["overruns"],
                        "host_stalls": self.stalls.count,
                        "lateness_p99_us": float(np.percentile(filled, 99)),
                    }
                )
        return k

    # ------------------------------------------------------------------ per-tick parts
    def _record(self, k: int, t_sim: float, t_rel: float, status, safety_s, bus_s, stall_s) -> None:
        """Queue the tick's telemetry row; a dead writer stops the show or, with
        ``telemetry.on_failure = "continue"``, only the recording (said once, on stderr)."""
        if not self._recording:
            return
        try:
            self.telemetry.record(
                k,
                t_sim,
                t_rel,
                self.u,
                self.x,
                self.v,
                self.cmd,
                self.present,
                status,
                math.nan,
                safety_s * 1e6,
                bus_s * 1e6,
                math.nan,
                False,
                self._comm_errors + int(np.count_nonzero(status)),
                stall_s * 1e6,
            )
        except WriterFailedError as exc:
            if self.rig.telemetry.on_failure is not TelemetryFailurePolicy.CONTINUE:
                raise
            self._recording = False
            print(
                f"hilsim run: telemetry stopped ({exc.__cause__ or exc}); the show goes on "
                "(telemetry.on_failure = 'continue')",
                file=sys.stderr,
            )

    def _stall_event(self, stall: float, k: int, t_sim: float) -> None:
        """One ``host_stall`` event per STALL_EVENT_INTERVAL_S at most; the rest counted in."""
        now = time.monotonic()
        self._stalls_unreported += 1
        if now - self._stall_event_t < STALL_EVENT_INTERVAL_S:
            return
        more = self._stalls_unreported - 1
        self._event(
            "host_stall",
            f"the host stalled {stall * 1e3:.0f} ms at tick {k} (t = {t_sim:.2f} s): the "
            "process was not running; not counted against any servo"
            + (f" ({more} shorter stalls since the last report)" if more else ""),
            tick=k,
            t=t_sim,
            stall_ms=round(stall * 1e3, 3),
            unreported=more,
        )
        self._stall_event_t = now
        self._stalls_unreported = 0

    def _check_reads(self, reading: PresentReading, t_now: float, host_late: bool) -> None:
        rig = self.rig
        status = reading.status
        if not status.any():  # OK is 0: the common tick stays cheap
            self.silence.all_ok(t_now, self.stalls.total_s)
            return
        ids, names = rig.servo_ids, rig.joint_names
        for i, s in enumerate(status):
            s = int(s)
            if s == ReadStatus.OK:
                self.silence.ok(i, t_now, self.stalls.total_s)
                continue
            self._comm_errors += 1
            if s == ReadStatus.ALERT:
                alert = f"hardware error: Alert bit set (ERR byte {int(reading.errors[i]):#04x})"
                raise LoopFaultError(f"servo {ids[i]} ({names[i]}): " + self._health_text(i, alert))
            silent = self.silence.failed(i, t_now, self.stalls.total_s, host_late)
            if silent is not None:
                raise LoopFaultError(
                    f"servo {ids[i]} ({names[i]}): no valid reading for {silent * 1e3:.0f} ms "
                    f"({self.silence.failed_reads(i)} reads in a row; budget "
                    f"{rig.safety.comm_failure_budget_ms:g} ms, host stalls not counted); "
                    f"last read {ReadStatus(s).name}"
                )

    def _log_safety_limits(self, k: int, t_sim: float) -> None:
        """One ``safety_limit`` event naming each joint and limit that acted since the last
        one (a second of show at most): rate-limited, never a line per tick."""
        counts = self.safety.counters.by_kind()
        seen = self._limits_seen
        acted = []
        for kind, per_joint in counts.items():
            for joint, n in per_joint.items():
                new = n - seen.get(kind, {}).get(joint, 0)
                if new:
                    acted.append(f"{joint} {kind} x{new}")
        self._limits_seen = counts
        if acted:
            self._event(
                "safety_limit",
                "limits acted in the last second: " + ", ".join(acted),
                tick=k,
                t=t_sim,
            )

    def _check_following(self, k: int) -> None:
        err = self.following.update(self.present.tolist(), self.cmd.tolist())
        if err is None:
            return
        j = err.joint
        jt = self.rig.joints[j]
        raise LoopFaultError(
            f"servo {jt.servo_id} ({jt.name}): following error: present "
            f"{math.degrees(self.present[j]):.1f} deg vs commanded "
            f"{math.degrees(self.cmd[j]):.1f} deg for {err.duration_s * 1e3:.0f} ms (tolerance "
            f"{math.degrees(self.following.tolerance[j]):g} deg); "
            + self._health_text(j, "the servo does not follow its goals")
        )

    def _health_text(self, i: int, fallback: str) -> str:
        """What the servo says about itself (a health read), for a fault message."""
        try:
            health = self.bus.read_health(self.rig.servo_ids[i], HealthPart.ALL)
        except (ServoBusError, ValueError):
            return f"{fallback} (its health could not be read)"
        if health.ok:
            return f"{fallback} (it reports torque on, no hardware error)"
        return f"{health.problem.value}: {health.detail}"

    def _integrate(self, t_sim: float, *, first_target_sampled: bool) -> None:
        """Advance the springs one tick from ``t_sim`` (the target held over each substep)."""
        rig = self.rig
        h, substeps = rig.loop.h_s, rig.loop.substeps
        x, v, u, du = self.x, self.v, self.u, self.du
        targets, integ = self.targets, self.integrator
        if not first_target_sampled:
            targets.sample(t_sim, u, du)
        integ.step(x, v, h, t_sim, (u, du))
        for j in range(1, substeps):
            ts = t_sim + j * h
            targets.sample(ts, u, du)
            integ.step(x, v, h, ts, (u, du))

    def _catch_up(self, k: int, t0: float, t_end: float, n_ticks: int | None) -> int:
        """After an overrun of more than a whole period, simulate the missed ticks without bus
        traffic so the show stays in time; returns the next tick to run. Stops early on a
        stop request."""
        period = self.rig.loop.period_s
        behind = int((t_end - t0) / period) - k
        for _ in range(max(0, behind)):
            if (n_ticks is not None and k >= n_ticks) or self._stopping():
                break
            self._integrate(k * period, first_target_sampled=False)
            k += 1
            self.stats["skipped_ticks"] += 1
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

    # ------------------------------------------------------------------ health
    def _maybe_read_health(self, spare_s: float, t: float, k: int) -> None:
        """One servo's health, round robin, if this tick has time to spare for it."""
        sched = self.health
        if not sched.due(t):
            return
        if spare_s < HEALTH_MARGIN * self.bus.health_read_s + HEALTH_SPARE_S:
            sched.deferred += 1
            return
        i, part = sched.take(t)
        sent = self.clock.now()
        try:
            health = self.bus.read_health(self.rig.servo_ids[i], part)
        except ServoBusError:
            return  # a failed read says nothing new: the per-tick reads keep the budget
        self._last_bus_t = max(self._last_bus_t, sent)
        self._handle_health(i, health, k, explained=self._last_long_gap_t > self._last_health_ok[i])

    def _after_bus_silence(self, gap_s: float, k: int) -> None:
        """The bus was quiet for a good part of the Bus Watchdog period (a host stall): check
        every servo before sending goals; recover tripped watchdogs."""
        self._last_long_gap_t = self.clock.now()
        self._event(
            "bus_silence",
            f"no packet on the bus for {gap_s * 1e3:.0f} ms (Bus Watchdog "
            f"{self._watchdog_s * 1e3:g} ms): checking every servo",
            tick=k,
            gap_ms=round(gap_s * 1e3, 3),
        )
        for i in range(len(self.rig.joints)):
            try:
                health = self.bus.read_health(self.rig.servo_ids[i], HealthPart.ALL)
            except ServoBusError:
                continue  # silent now: the per-tick reads and the budget decide
            self._handle_health(i, health, k, explained=True, gap_s=gap_s)
        self._last_bus_t = self.clock.now()

    def _handle_health(
        self, i: int, health: ServoHealth, k: int, *, explained: bool, gap_s: float = 0.0
    ) -> None:
        jt = self.rig.joints[i]
        if health.ok:
            self._last_health_ok[i] = self.clock.now()
            return
        who = f"servo {jt.servo_id} ({jt.name})"
        if health.problem is HealthProblem.WATCHDOG_TRIPPED and explained:
            self._recover(i, health, k, gap_s)
            return
        cause = health.detail
        if health.problem is HealthProblem.WATCHDOG_TRIPPED:
            cause += " (no host stall explains it: did another program stop talking to it?)"
        raise LoopFaultError(f"{who}: {health.problem.value}: {cause}")

    def _recover(self, i: int, health: ServoHealth, k: int, gap_s: float) -> None:
        """A Bus Watchdog tripped by a host stall: clear it, goal = present, rejoin."""
        jt = self.rig.joints[i]
        bus = self.bus
        try:
            reading = bus.read_present(PresentReading.empty(bus.ids))
            pos = float(reading.positions[i])
            if reading.status[i] != ReadStatus.OK or not math.isfinite(pos):
                raise LoopFaultError(
                    f"servo {jt.servo_id} ({jt.name}): Bus Watchdog tripped after a host stall "
                    "and its present position cannot be read to recover"
                )
            bus.recover_watchdog(jt.servo_id, pos)
        except ServoBusError as exc:
            raise LoopFaultError(
                f"servo {jt.servo_id} ({jt.name}): Bus Watchdog tripped after a host stall "
                f"and could not be recovered: {exc}"
            ) from exc
        joint_pos = (pos - self.home[i]) * self.direction[i]
        self.safety.rejoin(i, joint_pos)
        self.cmd[i] = joint_pos  # this tick's goal: where it stopped (the filter ran already)
        self.following.reset(i)
        self._last_health_ok[i] = self.clock.now()
        self.stats["recoveries"] += 1
        self._event(
            "recovered",
            f"servo {jt.servo_id} ({jt.name}): its Bus Watchdog had tripped "
            + (f"after {gap_s * 1e3:.0f} ms without a packet " if gap_s else "")
            + f"(a host stall); cleared, goal = present ({math.degrees(joint_pos):.1f} deg), "
            "rejoining the show within the speed and acceleration limits",
            tick=k,
            servo=jt.servo_id,
        )
