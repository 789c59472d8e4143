"""Latency of one tick's data: command to wire, command to motion, and feedback age.

A paced loop (absolute deadlines at ``rate_hz``) does what the real loop does on the bus:
one Sync Write of Goal Position, one (Fast) Sync Read of Present Position. Part way in, the
goals step by ``step_pulses``. Per tick, with ``t_tick`` the time the tick started:

* **command to wire** = last goal byte on the wire − ``t_tick``;
* **feedback age** = host has the positions (the read call returned) − the servos sampled
  them, the sample time taken as the reply's first byte on the wire;
* **command to motion** = first sample that has moved (≥ 1 pulse), and first sample at
  63 % of the step, − ``t_tick`` of the step tick (resolution: one tick).

Wire times come from the emulator's byte trace (``DxlBus.trace``, exact) or, on hardware,
from the host clock at each ``writePort`` plus the wire-time model (an estimate: USB and
driver delays are not seen). The method used is in ``LatencyResult.method``.
"""

from __future__ import annotations

import gc
import math
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from drivers.dynamixel.bench_session import (
    ADDR_RETURN_DELAY,
    ADDR_TORQUE,
    BenchBus,
    goal_bytes,
    position,
)
from drivers.protocol2.wire_time import DEFAULT_TURNAROUND_S, read_request_bytes, sync_write_bytes
from hilsim._types import JsonDict
from hilsim.bench.sched import DEFAULT_PRIORITY, percentile, realtime

if TYPE_CHECKING:
    from drivers.dxlsim.bus import TraceRecord

INST_SYNC_WRITE = 0x83
FRACTION_63 = 1.0 - math.exp(-1.0)  # 63.2 %: one time constant of a first-order lag


@dataclass(frozen=True)
class LatencyResult:
    """Per-tick arrays have shape (ticks,); times in seconds on the bus clock."""

    rate_hz: float
    ids: tuple[int, ...]
    fast: bool
    method: str
    t_tick: np.ndarray = field(repr=False)
    command_to_wire_s: np.ndarray = field(repr=False)
    feedback_age_s: np.ndarray = field(repr=False)
    sample_t: np.ndarray = field(repr=False)  # when the servos sampled (reply's first byte)
    positions: np.ndarray = field(repr=False)  # first servo's Present Position, ticks
    step_tick: int | None
    step_pulses: int
    overruns: int
    failures: int
    note: str = ""

    def _motion(self, fraction: float) -> float | None:
        if self.step_tick is None or self.step_tick < 1:
            return None
        k0 = self.step_tick
        p0 = self.positions[k0 - 1]
        moved = (self.positions[k0:] - p0) * math.copysign(1.0, self.step_pulses)
        need = max(1.0, fraction * abs(self.step_pulses)) if fraction > 0 else 1.0
        hits = np.flatnonzero(moved >= need - 1e-9)
        if len(hits) == 0:
            return None
        k = k0 + int(hits[0])
        return float(self.sample_t[k] - self.t_tick[k0])

    @property
    def motion_start_s(self) -> float | None:
        """Step tick start -> first sample that moved by at least one pulse."""
        return self._motion(0.0)

    @property
    def motion_63_s(self) -> float | None:
        """Step tick start -> first sample at 63 % of the step."""
        return self._motion(FRACTION_63)

    def as_dict(self) -> JsonDict:
        def stats(x: np.ndarray) -> JsonDict:
            x = x[np.isfinite(x)] * 1e6
            if len(x) == 0:
                return {"p50": None, "p99": None, "max": None}
            return {"p50": percentile(x, 50), "p99": percentile(x, 99), "max": float(x.max())}

        start, reach = self.motion_start_s, self.motion_63_s
        return {
            "rate_hz": self.rate_hz,
            "ids": list(self.ids),
            "read": "fast" if self.fast else "plain",
            "method": self.method,
            "ticks": len(self.t_tick),
            "overruns": self.overruns,
            "failures": self.failures,
            "command_to_wire_us": stats(self.command_to_wire_s),
            "feedback_age_us": stats(self.feedback_age_s),
            "command_to_motion_ms": {
                "step_pulses": self.step_pulses if self.step_tick is not None else None,
                "start": None if start is None else start * 1e3,
                "reach_63": None if reach is None else reach * 1e3,
                "resolution": 1e3 / self.rate_hz,
            },
            "note": self.note,
        }


def measure_latency(  # noqa: PLR0915 (one measurement, step by step)
    bb: BenchBus,
    ids: Sequence[int],
    *,
    rate_hz: float,
    duration_s: float,
    fast: bool,
    step_pulses: int = 40,
    move: bool = True,
    sched: str = "other",
    priority: int = DEFAULT_PRIORITY,
) -> LatencyResult:
    """Run the paced loop on ``bb`` for about ``duration_s`` and measure the three latencies.

    ``bb`` should be opened with ``stamped=True`` (hardware) and ``trace=True``
    (emulator). ``move=False`` never changes a goal (nothing moves; no motion figures).
    With ``move`` the servos' torque is switched on for the run and restored after. On a
    real clock the loop runs under ``realtime(sched)``; keep ``duration_s`` under ~0.6 s
    there, so a busy-polling SCHED_FIFO loop stays inside the kernel's RT budget.
    """
    ids = tuple(ids)
    clock = bb.clock
    bus = bb.bus  # (bb.emulated: bus is not None)
    trace = bus.trace if bus is not None else None
    write_times = getattr(bb.port, "write_times", None)
    if trace is None and write_times is None:
        raise ValueError("open the bus with stamped=True (hardware) or trace=True (emulator)")
    torque = {i: bb.read(i, ADDR_TORQUE, 1) for i in ids} if move else {}
    if move:
        for i in ids:
            bb.write1(i, ADDR_TORQUE, 1)
    start = bb.read_goals(ids)  # read after torque-on: written back unchanged, but for the step
    writer = bb.goal_writer(start)
    reader = bb.position_reader(ids)
    tx = writer.txPacket
    rx = reader.fastSyncRead if fast else reader.txRxPacket
    period = 1.0 / rate_hz

    # A few untimed cycles: warm the code paths and learn how long a cycle takes here.
    times = []
    for _ in range(7):
        t0 = clock.now()
        tx()
        rx()
        times.append(clock.now() - t0)
    cycle_s = sorted(times)[len(times) // 2]
    ticks = max(15, int(duration_s / max(period, cycle_s)))
    step_tick = max(5, ticks // 3) if move else None
    sign = 1 if start[ids[0]] < 2048 else -1
    step = sign * abs(step_pulses)

    t_tick = np.zeros(ticks)
    t_done = np.zeros(ticks)
    pos = np.full(ticks, np.nan)
    marks = [0] * (ticks + 1)  # trace / write-time index at each tick start
    failures = 0
    log = trace if trace is not None else write_times
    assert log is not None  # one of the two (checked above)
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        rt = realtime(sched, priority, rest_s=0.2) if not clock.virtual else nullcontext()
        with rt:
            next_due = clock.now() + period
            for k in range(ticks):
                t_tick[k] = clock.wait_until(next_due)
                next_due += period
                if k == step_tick:
                    for i in ids:
                        writer.changeParam(i, goal_bytes(start[i] + step))
                marks[k] = len(log)
                if tx() or rx():
                    failures += 1
                else:
                    pos[k] = position(reader, ids[0])
                t_done[k] = clock.now()
            marks[ticks] = len(log)
    finally:
        if gc_was_enabled:
            gc.enable()
        if move:
            for i in ids:
                writer.changeParam(i, goal_bytes(start[i]))
            tx()
            for i, was in torque.items():
                if was == 0:
                    bb.write1(i, ADDR_TORQUE, 0)

    if trace is not None:
        method = "emulator byte trace (exact wire times)"
        wire_end, reply_start = _from_trace(trace, marks)
        note = ""
    else:
        method = "host clock at writePort + wire-time model (estimate)"
        rdt = (bb.read(ids[0], ADDR_RETURN_DELAY, 1) or 0) * 2e-6
        assert write_times is not None  # no trace: the write times (checked above)
        wire_end, reply_start = _from_writes(
            write_times, marks, len(ids), bb.baud, rdt + DEFAULT_TURNAROUND_S
        )
        note = "USB and driver delays are not included"
    deadlines = t_tick[0] + period * np.arange(ticks)
    return LatencyResult(
        rate_hz=rate_hz,
        ids=ids,
        fast=fast,
        method=method,
        t_tick=t_tick,
        command_to_wire_s=wire_end - t_tick,
        feedback_age_s=t_done - reply_start,
        sample_t=reply_start,
        positions=pos,
        step_tick=step_tick,
        step_pulses=step,
        overruns=int(np.count_nonzero(t_tick - deadlines > period)),
        failures=failures,
        note=note,
    )


def _from_trace(trace: Sequence[TraceRecord], marks: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Per tick: end of the Sync Write on the wire, start of the first reply byte (NaN if none)."""
    ticks = len(marks) - 1
    wire_end = np.full(ticks, np.nan)
    reply_start = np.full(ticks, np.nan)
    for k in range(ticks):
        for rec in trace[marks[k] : marks[k + 1]]:
            if rec.direction == "tx" and len(rec.data) > 7 and rec.data[7] == INST_SYNC_WRITE:
                wire_end[k] = rec.t_end
            elif rec.direction == "rx" and math.isnan(reply_start[k]):
                reply_start[k] = rec.t_start
    return wire_end, reply_start


def _from_writes(
    write_times: list[float], marks: list[int], n: int, baud: int, delay_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """The same two times estimated from when the host wrote each packet and the wire model:
    bytes leave when written (or when the line is free), the reply starts ``delay_s``
    (Return Delay Time + turnaround) after the request's last byte."""
    ticks = len(marks) - 1
    bt = 10.0 / baud
    wire_end = np.full(ticks, np.nan)
    reply_start = np.full(ticks, np.nan)
    for k in range(ticks):
        writes = write_times[marks[k] : marks[k + 1]]
        if len(writes) < 2:
            continue
        sw_end = writes[0] + sync_write_bytes(n) * bt
        req_end = max(writes[1], sw_end) + read_request_bytes(n) * bt
        wire_end[k] = sw_end
        reply_start[k] = req_end + delay_s
    return wire_end, reply_start
