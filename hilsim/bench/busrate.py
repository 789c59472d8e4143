"""Bus rate: back-to-back write+read cycles through the unmodified SDK, beside the wire model.

One cycle = ``GroupSyncWrite.txPacket()`` (Goal Position, 4 B) + ``GroupSyncRead.txRxPacket()``
(plain) or ``.fastSyncRead()`` (Fast) of Present Position, 4 B, as fast as they go; or, a
``block`` row, the Fast read of the 7 B hilsim's X-series tick reads (position, Torque Enable,
Bus Watchdog, Status Return Level through Indirect Data 1-7: ``drivers/dynamixel/tick_block``). The
achieved rate is cycles / elapsed time on the bus's clock; the model rate comes from
:mod:`drivers.protocol2.wire_time` with the bus's own Return Delay Times (read from addr 9),
turnaround and latency timer. On a real clock the gap between them is host time (Python
packet code, the SDK's busy-poll, the OS); on a virtual clock there is none, so the
measurement must equal the model.

What the cycle loop does per cycle and nothing more: two bound-method calls and a result
check. The group objects are built once; the goals are the servos' own Goal Position
registers (writing them back changes nothing) and never change; the garbage collector is
paused while timing.
"""

from __future__ import annotations

import gc
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from drivers.dynamixel.bench_session import ADDR_RETURN_DELAY, BenchBus, BenchError
from drivers.protocol2 import control_table as ct
from drivers.protocol2.wire_time import DEFAULT_TURNAROUND_S, cycle_time_s
from hilsim._types import JsonDict
from hilsim.bench.sched import DEFAULT_PRIORITY, SCHED_OTHER, realtime


@dataclass(frozen=True)
class CycleTiming:
    """Raw result of a run of cycles. Times in seconds on the bus clock; ``cpu_s`` is
    process CPU time (meaningless on a virtual clock)."""

    cycles: int
    failures: int
    elapsed_s: float
    cpu_s: float
    sched: str = SCHED_OTHER

    @property
    def rate_hz(self) -> float:
        return self.cycles / self.elapsed_s if self.elapsed_s > 0 else float("nan")


@dataclass(frozen=True)
class BusRate:
    """One row of the bus table: achieved vs model cycle rate for ``ids`` at ``baud``."""

    ids: tuple[int, ...]
    baud: int
    fast: bool
    timing: CycleTiming
    model_s: float
    return_delay_us: float
    turnaround_us: float
    latency_timer_ms: float
    clock: str  # "real" or "virtual"
    port: str
    read_bytes: int = 4  # what each servo's reply carries: 4 (position) or the tick block

    @property
    def carries(self) -> str:
        """What each servo's reply carries, in a few words."""
        return "position" if self.read_bytes == 4 else "tick block"

    @property
    def achieved_hz(self) -> float:
        return self.timing.rate_hz

    @property
    def model_hz(self) -> float:
        return 1.0 / self.model_s

    @property
    def ratio(self) -> float:
        return self.achieved_hz / self.model_hz

    @property
    def host_us_per_cycle(self) -> float:
        """Measured cycle time minus the model's (µs): what the host adds per cycle."""
        return (1.0 / self.achieved_hz - self.model_s) * 1e6

    def as_dict(self) -> JsonDict:
        return {
            "ids": list(self.ids),
            "baud": self.baud,
            "read": "fast" if self.fast else "plain",
            "read_bytes": self.read_bytes,
            "achieved_hz": self.achieved_hz,
            "model_hz": self.model_hz,
            "ratio": self.ratio,
            "return_delay_us": self.return_delay_us,
            "turnaround_us": self.turnaround_us,
            "latency_timer_ms": self.latency_timer_ms,
            "cycles": self.timing.cycles,
            "failures": self.timing.failures,
            "elapsed_s": self.timing.elapsed_s,
            "host_us_per_cycle": self.host_us_per_cycle,
            "cpu_percent": 100.0 * self.timing.cpu_s / self.timing.elapsed_s
            if self.clock == "real"
            else None,
            "clock": self.clock,
            "sched": self.timing.sched,
            "port": self.port,
        }


def run_cycles(
    bb: BenchBus,
    ids: Sequence[int],
    fast: bool,
    *,
    duration_s: float | None = None,
    cycles: int | None = None,
    warmup: int = 20,
    goals: dict[int, int] | None = None,
    chunk_s: float = 0.4,
    gap_s: float = 0.2,
    sched: str = "other",
    priority: int = DEFAULT_PRIORITY,
    block: bool = False,
) -> CycleTiming:
    """Time write+read cycles for ``duration_s`` (bus clock) or exactly ``cycles`` of them
    (``block``: the read is the tick block, from Indirect Data 1 at 224).

    ``goals`` default to the servos' own Goal Position registers (nothing changes). On a
    real clock a timed run is cut into chunks of at most ``chunk_s``, each run under
    :func:`~hilsim.bench.sched.realtime` (``sched``) after a rest of ``gap_s`` outside
    SCHED_FIFO: a throttled SCHED_FIFO busy-poll would show up as a slow bus. The class in
    effect is returned in ``CycleTiming.sched``.
    """
    if (duration_s is None) == (cycles is None):
        raise ValueError("give exactly one of duration_s and cycles")
    if goals is None:
        goals = bb.read_goals(ids)
    writer = bb.goal_writer(goals)
    reader = bb.position_reader(ids, ct.INDIRECT_DATA_1.addr if block else None)
    tx = writer.txPacket
    rx = reader.fastSyncRead if fast else reader.txRxPacket
    now = bb.clock.now
    if bb.clock.virtual:  # nothing else runs in virtual time: one chunk, no OS scheduling
        return _timed(tx, rx, now, warmup, duration_s, cycles, SCHED_OTHER)
    if cycles is not None:
        with realtime(sched, priority, rest_s=gap_s) as (actual, _locked):
            return _timed(tx, rx, now, warmup, None, cycles, actual)
    assert duration_s is not None  # exactly one of the two (checked above)
    parts = []
    n_chunks = max(1, math.ceil(duration_s / chunk_s - 1e-9))
    for _ in range(n_chunks):
        with realtime(sched, priority, rest_s=gap_s) as (actual, _locked):
            parts.append(_timed(tx, rx, now, warmup, duration_s / n_chunks, None, actual))
    return CycleTiming(
        cycles=sum(p.cycles for p in parts),
        failures=sum(p.failures for p in parts),
        elapsed_s=sum(p.elapsed_s for p in parts),
        cpu_s=sum(p.cpu_s for p in parts),
        sched=parts[0].sched if len({p.sched for p in parts}) == 1 else "mixed",
    )


def _timed(
    tx: Callable[[], int],
    rx: Callable[[], int],
    now: Callable[[], float],
    warmup: int,
    duration_s: float | None,
    cycles: int | None,
    sched: str,
) -> CycleTiming:
    """The timed loop itself: two bound-method calls and a result check per cycle."""
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        for _ in range(warmup):
            tx()
            rx()
        failures = n = 0
        c0, t0 = time.process_time(), now()
        if cycles is not None:
            for _ in range(cycles):
                if tx() or rx():
                    failures += 1
            n = cycles
        else:
            assert duration_s is not None  # exactly one of the two (run_cycles)
            end = t0 + duration_s
            while now() < end:
                if tx() or rx():
                    failures += 1
                n += 1
        elapsed, cpu = now() - t0, time.process_time() - c0
    finally:
        if gc_was_enabled:
            gc.enable()
    return CycleTiming(n, failures, elapsed, cpu, sched)


def return_delays_s(bb: BenchBus, ids: Sequence[int]) -> list[float]:
    """Each servo's Return Delay Time (addr 9, 2 µs units), read over the bus, seconds."""
    out = []
    for servo_id in ids:
        units = bb.read(servo_id, ADDR_RETURN_DELAY, 1)
        if units is None:
            raise BenchError(f"{bb.url}: servo {servo_id} does not answer a Read of addr 9")
        out.append(units * 2e-6)
    return out


def bus_timing_facts(bb: BenchBus, latency_timer_ms: float | None = None) -> tuple[float, float]:
    """``(turnaround_s, latency_s)`` for the model: the emulator's own figures, or on
    hardware the assumed 20 µs turnaround and the given latency timer (default 0)."""
    bus = bb.bus
    if bus is not None:
        return bus.turnaround_s, bus.latency_s
    return DEFAULT_TURNAROUND_S, (latency_timer_ms or 0.0) * 1e-3


def measure_bus_rate(
    bb: BenchBus,
    ids: Sequence[int],
    fast: bool,
    *,
    duration_s: float | None = None,
    cycles: int | None = None,
    latency_timer_ms: float | None = None,
    sched: str = "other",
    priority: int = DEFAULT_PRIORITY,
    block: bool = False,
) -> BusRate:
    """Achieved vs model cycle rate of ``ids`` on ``bb`` (plain or Fast Sync Read).

    ``latency_timer_ms`` is the adapter's latency timer for the model on hardware (the
    emulator brings its own); ``sched``/``priority`` as in :func:`run_cycles`; ``block``:
    the read is the X series' tick block (Fast only), not Present Position alone.
    """
    ids = tuple(ids)
    if block and not fast:
        raise ValueError("the tick block is read by Fast Sync Read only")
    rdts = return_delays_s(bb, ids)
    turnaround_s, latency_s = bus_timing_facts(bb, latency_timer_ms)
    timing = run_cycles(
        bb,
        ids,
        fast,
        duration_s=duration_s,
        cycles=cycles,
        sched=sched,
        priority=priority,
        block=block,
    )
    size = ct.TICK_BLOCK_SIZE if block else ct.PRESENT_POSITION.size
    model_s = cycle_time_s(
        len(ids),
        bb.baud,
        fast,
        return_delay_s=rdts,
        turnaround_s=turnaround_s,
        latency_s=latency_s,
        read_data_bytes=size,
    )
    return BusRate(
        ids=ids,
        baud=bb.baud,
        fast=fast,
        timing=timing,
        model_s=model_s,
        return_delay_us=round(max(rdts) * 1e6, 6),
        turnaround_us=round(turnaround_s * 1e6, 6),
        latency_timer_ms=round(latency_s * 1e3, 9),
        clock="virtual" if bb.clock.virtual else "real",
        port=bb.url,
        read_bytes=size,
    )
