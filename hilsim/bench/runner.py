"""What the bench measures (a :class:`BenchPlan`) and running it into a :class:`BenchReport`.

Order: loop timing first (nothing else running in this process): the loop sleeping only
(spin window 0), cyclictest right after it (like with like: both sleep), then the loop with
its spin window, apart; then the diagnosis of the bus under test (its facts also say
whether Fast Sync Read exists), the bus-rate rows, and the latency loop. Progress lines go
to ``progress`` (stderr in the CLI).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from drivers.clock import MonotonicClock
from drivers.dynamixel.bench_session import BenchError
from hilsim.bench import cyclictest
from hilsim.bench.busrate import measure_bus_rate
from hilsim.bench.diagnose import diagnose, gather_facts
from hilsim.bench.latency import measure_latency
from hilsim.bench.ports import emulator_url, open_bus
from hilsim.bench.report import BenchReport, LoopResult
from hilsim.bench.sched import DEFAULT_PRIORITY, SCHED_FIFO, measure_scheduler

DEFAULT_SERVO_COUNTS = (1, 4, 8, 16)
DEFAULT_EMULATOR_BAUDS = (1_000_000, 4_000_000)
MIN_LOOP_TICKS = 100
#: one bus-rate row takes about this × its measurement + BUS_ROW_SETUP_S (its warm-up, the
#: emulator's start; a 2-core VM), for the expected length
BUS_ROW_FACTOR = 1.6
BUS_ROW_SETUP_S = 0.1


@dataclass(frozen=True)
class BusTarget:
    """A bus to measure: ``ids`` is None to discover them; ``read`` is auto, fast or plain."""

    url: str
    baud: int
    ids: tuple[int, ...] | None = None
    read: str = "auto"


@dataclass(frozen=True)
class BenchPlan:
    """Everything ``hilsim bench`` will do; durations in seconds of measurement."""

    quick: bool = False
    clock: str = "real"  # emulated buses: "virtual" gives the model exactly (loop timing skipped)
    loop_rates_hz: tuple[float, ...] = (1000.0,)
    loop_duration_s: float = 10.0  # per rate (at least MIN_LOOP_TICKS ticks)
    spin_us: float = 200.0
    sched: str = "auto"
    priority: int = DEFAULT_PRIORITY
    use_cyclictest: bool = True
    # bus under test (diagnosis, latency; and the rate rows when ``sweep`` is empty)
    target: BusTarget | None = None  # None: 4 emulated servos at 1 Mbps
    # emulator sweep: (servo count, baud) rows, plain and Fast; empty: measure ``target``
    sweep: tuple[tuple[int, int], ...] = tuple(
        (n, b) for b in DEFAULT_EMULATOR_BAUDS for n in DEFAULT_SERVO_COUNTS
    )
    bus_duration_s: float = 1.2
    latency_rate_hz: float = 500.0
    latency_duration_s: float = 0.6  # SCHED_FIFO busy-polls: stay inside the RT budget
    move: bool = True
    step_pulses: int = 40
    subject: str = "the built-in emulator (dxlsim, real clock)"
    rig_rate_hz: float | None = None
    command: str = "hilsim bench"
    #: how long the sections the CLI runs after the bus side take (s): the tick cost, and
    #: CPU over a pty (for the expected length only)
    host_s: float = 0.0

    def expected_s(self) -> float:
        """About how long the whole command takes (s): the planned measurements plus the
        setting up around them, as measured on a 2-core VM (a slower host takes longer)."""
        t = 4.0  # start, diagnosis, plots
        if self.clock != "virtual":  # sleep only, cyclictest, the spin window: per rate
            runs = 1 + (1 if self.use_cyclictest else 0) + (1 if self.spin_us > 0 else 0)
            each = [max(MIN_LOOP_TICKS / r, self.loop_duration_s) for r in self.loop_rates_hz]
            t += runs * sum(each)
        rows = max(1, len(self.sweep)) * 2
        t += rows * (BUS_ROW_FACTOR * self.bus_duration_s + BUS_ROW_SETUP_S)
        t += self.latency_duration_s + 1.0
        return t + self.host_s


def run_bench(plan: BenchPlan, progress: Callable[[str], None] = lambda _s: None) -> BenchReport:
    """Measure everything in ``plan``. Raises :class:`BenchError` when the bus cannot be used."""
    report = BenchReport(
        command=plan.command, quick=plan.quick, subject=plan.subject, rig_rate_hz=plan.rig_rate_hz
    )
    progress(f"expected to take about {plan.expected_s():.0f} s")
    if plan.clock == "virtual":
        report.notes.append("virtual clock: loop timing skipped; bus figures are the model's")
    else:
        _loops(plan, report, progress)

    t = plan.target or BusTarget(emulator_url((1, 2, 3, 4), 1_000_000, clock=plan.clock), 1_000_000)
    with open_bus(t.url, t.baud, clock=plan.clock) as bb:
        emulated = report.emulated = bb.emulated
        ids = t.ids or tuple(bb.discover_ids())
        progress(f"diagnosing {t.url} ({len(ids)} servo(s) at {t.baud} bps)")
        report.diagnosis = diagnose(gather_facts(bb, ids))
    facts = report.diagnosis.facts
    if any(s.model_number is None for s in facts.servos):
        report.notes.append("some servos did not answer: bus rate and latency skipped")
        return report
    fast_ok = facts.fast_read
    latency_ms = None if emulated else facts.latency_timer_ms

    rows = [
        (tuple(range(1, n + 1)), b, emulator_url(range(1, n + 1), b, clock=plan.clock))
        for n, b in plan.sweep
    ]
    rows = rows or [(ids, t.baud, t.url)]
    modes = {"auto": (False, True), "fast": (True,), "plain": (False,)}[t.read]
    if not plan.sweep and not fast_ok and True in modes:
        report.notes.append("the servos' firmware has no Fast Sync Read: plain rows only")
        modes = (False,)
    # Fast: the SDK's own read of positions, then the X-series tick block hilsim reads
    reads = [(fast, block) for fast in modes for block in ((False, True) if fast else (False,))]
    for row_ids, baud, url in rows:
        for fast, block in reads:
            what = "the tick block" if block else "Present Position"
            progress(
                f"bus rate: {len(row_ids)} servo(s) at {baud} bps, "
                f"{'Fast' if fast else 'plain'} Sync Read of {what} ({plan.bus_duration_s:g} s)"
            )
            with open_bus(url, baud, clock=plan.clock) as rb:
                report.bus.append(
                    measure_bus_rate(
                        rb,
                        row_ids,
                        fast,
                        duration_s=plan.bus_duration_s,
                        latency_timer_ms=latency_ms,
                        sched=plan.sched,
                        priority=plan.priority,
                        block=block,
                    )
                )

    fast = fast_ok and t.read != "plain"
    move = plan.move or emulated
    progress(f"latency at {plan.latency_rate_hz:g} Hz ({plan.latency_duration_s:g} s)")
    with open_bus(t.url, t.baud, clock=plan.clock, trace=True, stamped=True) as lb:
        report.latency = measure_latency(
            lb,
            ids,
            rate_hz=plan.latency_rate_hz,
            duration_s=plan.latency_duration_s,
            fast=fast,
            step_pulses=plan.step_pulses,
            move=move,
            sched=plan.sched,
            priority=plan.priority,
        )
    return report


def _loops(plan: BenchPlan, report: BenchReport, progress: Callable[[str], None]) -> None:
    ct_path = cyclictest.find() if plan.use_cyclictest else None
    if plan.use_cyclictest and ct_path is None:
        report.notes.append(
            f"cyclictest (rt-tests) is not installed; install it for the C reference: "
            f"{cyclictest.INSTALL_HINT}"
        )
    for rate in plan.loop_rates_hz:
        ticks = max(MIN_LOOP_TICKS, round(plan.loop_duration_s * rate))
        progress(f"loop timing at {rate:g} Hz, sleep only ({ticks / rate:.1f} s)")
        ours = measure_scheduler(
            MonotonicClock(spin_s=0.0), rate, ticks, sched=plan.sched, priority=plan.priority
        )
        ct = None
        if ct_path is not None:
            progress(f"cyclictest at {rate:g} Hz, right after ({ticks / rate:.1f} s)")
            ct = cyclictest.run(
                round(1e6 / rate),
                ticks,
                fifo=ours.sched == SCHED_FIFO,
                priority=plan.priority,
                path=ct_path,
            )
            if ct is not None and ct.sched != ours.sched:
                report.notes.append(
                    f"cyclictest ran in {ct.sched}, ours in {ours.sched}: not the same class"
                )
        spin = None
        if plan.spin_us > 0:
            progress(f"loop timing at {rate:g} Hz, spin window {plan.spin_us:g} µs")
            spin = measure_scheduler(
                MonotonicClock(spin_s=plan.spin_us * 1e-6),
                rate,
                ticks,
                sched=plan.sched,
                priority=plan.priority,
            )
        installed = ct_path is not None or not plan.use_cyclictest
        report.loops.append(LoopResult(ours, ct, installed, spin))


__all__ = ["BenchError", "BenchPlan", "BusTarget", "run_bench"]
