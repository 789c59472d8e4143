"""Bus rate of a Feetech or Dynamixel Protocol 1.0 rig: the tick's own bus calls, timed, beside
the family's wire model.

One cycle is what one tick of a show puts on the bus through
:class:`~drivers.p1bus.bus.P1ServoBus`: ``write_goals`` (one Sync Write of the servos' present
positions: nothing moves) and ``read_present`` (Sync Read, Bulk Read, or the tick's share of
single reads in rotation). The achieved time per cycle is measured on the bus's clock; the
model is :meth:`~drivers.p1bus.bus.P1ServoBus.model_cycle_s` with the Return Delay Times the
start-up check read and the adapter's latency timer. On a virtual clock the two must agree;
on a real one the gap is the host's time per cycle, split in two: the **bus time** (the port's
``device_wait_s``: from each transaction's transmit to its last reply byte in hand, the
device's own delays included: an in-process emulator's CPU, a pty's delivery, a host stall
inside a transaction, itself said: the port's ``host_stall_s``, a lower bound of the time the
process was not running) and the **host's** (building the goals' packet, parsing the replies,
the driver's bookkeeping: the rest). Also said: how often each servo is read at the rig's
tick rate.
"""

from __future__ import annotations

import gc
from dataclasses import dataclass

import numpy as np

from hilsim._types import JsonDict
from hilsim.rig import Rig


@dataclass(frozen=True)
class P1Rate:
    """One rig's bus: achieved and model seconds per cycle, and the reads."""

    families: tuple[str, ...]
    method: str
    servos: int
    baud: int
    reads_per_tick: int
    cycles: int
    failed_reads: int
    achieved_s: float
    model_s: float
    bus_s: float  # of achieved_s: in the port's transactions (device_wait_s)
    stall_s: float  # of bus_s: the process not running inside them (host_stall_s)
    read_hz_per_servo: float
    rate_hz: float
    clock: str

    @property
    def ratio(self) -> float:
        return self.achieved_s / self.model_s

    @property
    def bus_ratio(self) -> float:
        return self.bus_s / self.model_s

    def as_dict(self) -> JsonDict:
        return {**self.__dict__, "ratio": self.ratio, "bus_ratio": self.bus_ratio}

    def text(self) -> str:
        return (
            f"bus ({', '.join(self.families)}, {self.method}, {self.servos} servos at "
            f"{self.baud} bit/s, {self.clock} clock): {self.achieved_s * 1e3:.3f} ms a tick "
            f"measured over {self.cycles} ticks vs {self.model_s * 1e3:.3f} ms wire model "
            f"({(self.ratio - 1) * 100:+.1f} %); {self.failed_reads} failed reads\n"
            f"  of which bus time {self.bus_s * 1e3:.3f} ms a tick "
            f"({(self.bus_ratio - 1) * 100:+.1f} % vs the wire model: transmit to last reply "
            f"byte, the device's delays included; {self.stall_s * 1e3:.3f} ms of it host stalls), "
            f"host {(self.achieved_s - self.bus_s) * 1e3:.3f} ms (packets built and parsed)\n"
            f"  reads: {self.reads_per_tick} of {self.servos} servos a tick: each servo read "
            f"{self.read_hz_per_servo:.4g} times a second at {self.rate_hz:g} Hz\n"
        )


def measure(rig: Rig, port: str, cycles: int = 2000) -> P1Rate:
    """Open the rig's bus (``port``: the rig's or another), run its start-up check, and time
    ``cycles`` tick-like cycles. Raises what the session raises for a bus that cannot run."""
    from hilsim.show.session import check_bus, open_bus

    bus = open_bus(rig, port)
    try:
        check_bus(rig, bus, lambda _msg: None)
        from drivers.p1bus.bus import P1ServoBus

        assert isinstance(bus, P1ServoBus)
        reading = bus.read_present()
        for _ in range(3 * bus.n):  # every servo's position, through the rotation too
            if np.isfinite(reading.positions).all():
                break
            more = bus.read_present()
            reading.positions[np.isnan(reading.positions)] = more.positions[
                np.isnan(reading.positions)
            ]
        goals = np.nan_to_num(reading.positions)
        clock = bus.clock
        failed = 0
        port = bus.link.port
        gc.disable()
        try:
            wait0, stall0 = port.device_wait_s, port.host_stall_s
            t0 = clock.now()
            for _ in range(cycles):
                bus.write_goals(goals)
                r = bus.read_present(reading)
                if r.status.any():  # (one numpy call on the all-OK tick, as the loop's)
                    failed += int(((r.status != 0) & (r.status != 4)).sum())
            elapsed = clock.now() - t0
            waited, stalled = port.device_wait_s - wait0, port.host_stall_s - stall0
        finally:
            gc.enable()
        return P1Rate(
            bus.families,
            str(bus.read_mode),
            bus.n,
            bus.link.baud,
            bus.per_tick,
            cycles,
            failed,
            elapsed / cycles,
            bus.model_cycle_s(),
            waited / cycles,
            stalled / cycles,
            bus.read_rate_hz(rig.loop.rate_hz),
            rig.loop.rate_hz,
            "virtual" if clock.virtual else "real",
        )
    finally:
        bus.close()
