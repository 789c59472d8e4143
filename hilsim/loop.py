"""The real-time HIL loop: one tick every period, against absolute deadlines.

One tick (k = 0, 1, ...; t_k = k·period of simulation time)::

    clock.wait_until(t0 + t_k)             sleep, then spin the last stretch (virtual: jump)
    command x_k                            the springs' state at t_k, joint frame (rad)
    safety.filter                          finite? within limits, speed, acceleration? soft start
    joint map                              servo angle = home + direction · joint angle
    bus.write_goals                        one Sync Write
    bus.read_present                       one (Fast) Sync Read, per-servo status
    comm budget / hardware alerts          a servo silent for longer than the budget -> safe stop
    telemetry.record                       queued; a writer thread owns the disk
    targets.sample + integrator.step       x_k -> x_{k+1} (substeps; target held over each step)

Simulation time is ``k·period``, never the clock, so the commanded numbers are the same
whether the loop runs on the real clock or the virtual one. A tick that finishes after the
next deadline is an overrun: counted, and (``overrun_policy = "stop"``) a fault. When the
loop has fallen more than a whole period behind, the missed ticks are simulated without bus
traffic so the figure stays in step with the show (counted as ``skipped_ticks``).

Stops: the end of the show or ``duration``, a stop request (SIGINT/SIGTERM, exit codes 130/143),
or a fault (exit code 3, naming the servo and the cause). Every stop applies the rig's exit
policy (``hold`` or ``relax``) before returning.
"""

from __future__ import annotations

import math
import os
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from drivers.servo_bus import PresentReading, ReadStatus, ServoBus, ServoBusError
from hilsim.integrators import make_integrator
from hilsim.rig import OverrunPolicy, Rig
from hilsim.safety import SafetyFilter
from hilsim.targets import TargetSet
from hilsim.telemetry import TelemetryWriter

#: GIL switch interval while a show runs on the real clock (see HilLoop.run)
REALTIME_SWITCH_INTERVAL_S = 100e-6

EXIT_OK = 0
EXIT_FAULT = 3
EXIT_SIGINT = 130
EXIT_SIGTERM = 143


class LoopFaultError(RuntimeError):
    """A condition that stops the show: the message names the servo/joint and the cause."""


@dataclass
class StopFlag:
    """Set from a signal handler; the loop looks at it once per tick."""

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
        #: loop books for the summary (read statuses and comm errors are counted by telemetry)
        self.stats: dict = {"overruns": 0, "skipped_ticks": 0, "sched": "SCHED_OTHER"}

    # ------------------------------------------------------------------ start / stop
    def _start(self) -> None:
        """Read where the figure is, hold it there with torque on, seed the springs."""
        try:
            self._start_on_bus()
        except ServoBusError as exc:
            raise LoopFaultError(f"cannot start: {exc}") from exc

    def _start_on_bus(self) -> None:
        bus, rig = self.bus, self.rig
        reading = bus.read_present()
        bad = [
            i
            for i in range(len(rig.joints))
            if reading.status[i] != ReadStatus.OK or not math.isfinite(reading.positions[i])
        ]
        if bad:
            names = ", ".join(
                f"{rig.joints[i].name} (servo {rig.joints[i].servo_id}: "
                f"{ReadStatus(int(reading.status[i])).name})"
                for i in bad
            )
            raise LoopFaultError(f"cannot start: no present position for {names}")
        servo_present = reading.positions.copy()
        bus.write_goals(servo_present)  # torque on must not jump
        bus.set_torque(True)
        if rig.safety.watchdog_ms:
            bus.arm_watchdog(rig.safety.watchdog_ms * 1e-3)
        np.subtract(servo_present, self.home, out=self.present)
        self.present *= self.direction
        event = self.safety.start(self.present)
        if event is not None:
            self.telemetry.event("safety", str(event), fsync=True)
        for i, jt in enumerate(rig.joints):
            self.x[i] = self.present[i] if jt.initial_rad is None else jt.initial_rad
        self.v[:] = 0.0

    def _apply_exit_policy(self) -> str:
        rig = self.rig
        policy = rig.safety.exit_policy.value
        try:
            report = self.bus.apply_exit_policy(policy, retries=rig.safety.exit_retries)
        except Exception as exc:  # the bus may be gone: say so loudly, never hang
            msg = f"exit policy {policy!r} NOT confirmed: {exc}"
            self.telemetry.event("exit_policy", msg, fsync=True)
            return msg
        msg = str(report)
        self.telemetry.event("exit_policy", msg, fsync=True, confirmed=list(report.confirmed))
        return msg

    # ------------------------------------------------------------------ the loop
    def run(self) -> RunResult:
        rig, tel = self.rig, self.telemetry
        self.stats["sched"] = try_realtime(rig.loop.realtime_priority, rig.loop.cpu)
        tel.event(
            "start",
            f"{rig.name}: {len(rig.joints)} joints at {rig.loop.rate_hz:g} Hz, "
            f"{self.stats['sched']}",
            fsync=False,
        )
        self._k = 0
        # The telemetry writer is a Python thread: when the loop wakes from its sleep it may
        # wait for the GIL up to the interpreter's switch interval (5 ms by default). Ask the
        # holder to let go within 100 µs while the show runs on the real clock.
        switch = sys.getswitchinterval()
        if not self.clock.virtual:
            sys.setswitchinterval(min(switch, REALTIME_SWITCH_INTERVAL_S))
        try:
            self._start()
            k = self._ticks()
            if self.stop.signum is not None:
                exit_code = 128 + self.stop.signum
                reason = f"stopped by signal {self.stop.signum}"
                tel.event("signal", reason, tick=k)
            else:
                exit_code, reason = EXIT_OK, "end of show"
        except LoopFaultError as exc:
            exit_code, reason, k = EXIT_FAULT, str(exc), self._k
            tel.event("fault", reason, tick=k, t=k * rig.loop.period_s)
        finally:
            sys.setswitchinterval(switch)
        self.stats["exit_policy"] = self._apply_exit_policy()
        self.stats["safety"] = self.safety.counters.as_dict()
        return RunResult(exit_code, reason, k, self.stats)

    def _ticks(self) -> int:
        """Tick until the show ends, a stop is requested or a fault is raised; returns ticks run."""
        rig, bus, clock, tel = self.rig, self.bus, self.clock, self.telemetry
        period = rig.loop.period_s
        h = rig.loop.h_s
        substeps = rig.loop.substeps
        budget_s = rig.safety.comm_failure_budget_ms * 1e-3
        stop_on_overrun = rig.loop.overrun_policy is OverrunPolicy.STOP
        n = len(rig.joints)
        x, v, u, du = self.x, self.v, self.u, self.du
        cmd, goal, present = self.cmd, self.servo_goal, self.present
        home, direction = self.home, self.direction
        targets, safety, integ = self.targets, self.safety, self.integrator
        names, ids = rig.joint_names, rig.servo_ids
        n_ticks = None if self.duration_s is None else round(self.duration_s / period) + 1
        perf = time.perf_counter
        # the telemetry writer formats rows only while we sleep (never during a tick)
        slack = getattr(tel, "slack", None) if not clock.virtual else None
        ok = int(ReadStatus.OK)
        alert = int(ReadStatus.ALERT)
        nan = math.nan
        recent = np.zeros(512)  # lateness ring for the live status line
        t0 = clock.now()
        self.stats["clock_t0"] = t0  # the clock time of tick 0 (fault plans use the bus clock)
        last_ok = [t0] * n
        comm_errors = 0
        next_status = perf() + 0.5
        k = 0
        while n_ticks is None or k < n_ticks:
            if self.stop.signum is not None:
                break
            t_sched = t0 + k * period
            t_actual = clock.wait_until(t_sched, slack)
            t_sim = k * period
            self._k = k
            c0 = perf()
            # -- safety: the only way to the wire
            event = safety.filter(x, cmd)
            if event is not None:
                tel.event("safety", str(event), tick=k, t=t_sim, fsync=True)
                if event.fatal:
                    raise LoopFaultError(f"safety: {event}")
            np.multiply(cmd, direction, out=goal)
            goal += home
            c1 = perf()
            # -- one Sync Write, one (Fast) Sync Read
            try:
                bus.write_goals(goal)
                reading = bus.read_present(self.reading)
            except ServoBusError as exc:
                raise LoopFaultError(f"bus: {exc}") from exc
            c2 = perf()
            np.subtract(reading.positions, home, out=present)
            present *= direction
            status = reading.status
            t_now = clock.now()
            for i in range(n):
                s = int(status[i])
                if s == ok:
                    last_ok[i] = t_now
                    continue
                comm_errors += 1
                if s == alert:
                    raise LoopFaultError(
                        f"servo {ids[i]} ({names[i]}): hardware error: Alert bit set "
                        f"(ERR byte {int(reading.errors[i]):#04x}); read Hardware Error "
                        "Status (addr 70) and reboot the servo to clear it"
                    )
                if t_now - last_ok[i] > budget_s:
                    raise LoopFaultError(
                        f"servo {ids[i]} ({names[i]}): no valid reading for "
                        f"{(t_now - last_ok[i]) * 1e3:.0f} ms (budget "
                        f"{rig.safety.comm_failure_budget_ms:g} ms); last read "
                        f"{ReadStatus(s).name}"
                    )
            # -- record this tick (its target u(t_k) also drives the first substep below);
            # stage times known only later are amended
            targets.sample(t_sim, u, du)
            c3 = perf()
            tel.record(
                k,
                t_sim,
                t_actual - t0,
                u,
                x,
                v,
                cmd,
                present,
                status,
                nan,
                (c1 - c0) * 1e6,
                (c2 - c1) * 1e6,
                nan,
                False,
                comm_errors,
            )
            c4 = perf()
            # -- advance the springs to the next tick (target held over each step)
            integ.step(x, v, h, t_sim, (u, du))
            for j in range(1, substeps):
                ts = t_sim + j * h
                targets.sample(ts, u, du)
                integ.step(x, v, h, ts, (u, du))
            k += 1
            t_end = clock.now()
            late = t_end > t0 + k * period
            c5 = perf()
            tel.amend(
                k - 1,
                overrun=late,
                t_sim_us=(c5 - c4 + c3 - c2) * 1e6,
                t_telemetry_us=(c4 - c3) * 1e6,
            )
            recent[k % 512] = (t_actual - t_sched) * 1e6
            if late:
                self.stats["overruns"] += 1
                if stop_on_overrun:
                    raise LoopFaultError(
                        f"overrun at tick {k - 1}: the tick took {(t_end - t_actual) * 1e3:.2f} ms "
                        f"(period {period * 1e3:g} ms; overrun_policy = 'stop')"
                    )
                k = self._catch_up(k, t0, t_end, n_ticks)
            if self.on_status is not None and perf() >= next_status:
                next_status += 0.5
                filled = recent[: min(k, 512)]
                self.on_status(
                    {
                        "tick": k,
                        "t": t_sim,
                        "comm_errors": comm_errors,
                        "overruns": self.stats["overruns"],
                        "lateness_p99_us": float(np.percentile(filled, 99)),
                    }
                )
        return k

    def _catch_up(self, k: int, t0: float, t_end: float, n_ticks: int | None) -> int:
        """After an overrun of more than a whole period, simulate the missed ticks without bus
        traffic so the show stays in time; returns the next tick to run."""
        period, h, substeps = self.rig.loop.period_s, self.rig.loop.h_s, self.rig.loop.substeps
        behind = int((t_end - t0) / period) - k
        for _ in range(max(0, behind)):
            if n_ticks is not None and k >= n_ticks:
                break
            t_sim = k * period
            for j in range(substeps):
                ts = t_sim + j * h
                self.targets.sample(ts, self.u, self.du)
                self.integrator.step(self.x, self.v, h, ts, (self.u, self.du))
            k += 1
            self.stats["skipped_ticks"] += 1
        return k
