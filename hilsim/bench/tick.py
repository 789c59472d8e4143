"""The host's cost of one tick: hilsim's whole tick beside a bare dynamixel-sdk cycle.

Both run in this process, interleaved call for call, on the same kind of port: an
:class:`InstantSerial` under a ``PortHandler``, whose writes are recorded and whose reads
return at once a correct Fast Sync Read reply for the servos asked (their positions
changing from reply to reply), so the wire's time is left out and only the host's work is
timed:

* **bare SDK**: the cheapest cycle dynamixel-sdk offers (``syncWriteTxOnly``,
  ``syncReadTx`` fast, ``rxPacket``, positions out of the reply) on its own ``PortHandler``:
  the first performance round's baseline; its group objects cost 20-50 µs more and would
  flatter the ratio;
* **hilsim tick**: :meth:`hilsim.show.loop.HilLoop._tick` itself (springs, targets, safety
  filter, joint map, the driver's Sync Write and Fast Sync Read, the checks, the telemetry
  row) and the row's amendment, on a rig of ``n`` joints (RK4 springs, sine targets) and
  :class:`~drivers.dynamixel.bus.DynamixelBus` on hilsim's ``PortHandler``. The telemetry
  writer is the real one but for its thread (rows are taken out between rounds).

Each figure is the median of ``reps`` calls, the best of ``rounds`` rounds. Wall-clock
medians on a shared machine vary by up to 2x from run to run; ``tools/tick_instructions.py``
counts instructions instead. The stage breakdown times each part alone right after a tick;
"rest" is the tick less the parts (the checks, the host-stall books, the loop's own code)."""

from __future__ import annotations

import copy
import json
import math
import os
import statistics
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import dynamixel_sdk as sdk

from drivers.clock import MonotonicClock
from drivers.dynamixel.bus import DynamixelBus
from drivers.dynamixel.link import Link
from drivers.dynamixel.port import PortHandler
from drivers.dynamixel.startup import ReadMode
from drivers.fill import Packed
from drivers.protocol2 import control_table as ct
from drivers.protocol2.crc import crc16
from hilsim._types import JsonDict
from hilsim.bench import report
from hilsim.rig import load_rig
from hilsim.show.loop import HilLoop
from hilsim.show.parts import build_parts
from hilsim.telemetry import TelemetryWriter

SERVO_COUNTS = (4, 8, 16)  # servo counts the bench compares
#: stages of the breakdown, in the tick's order
STAGES = ("safety", "map", "driver", "targets", "telemetry", "springs")
_FAST_SYNC_READ = 0x8A
_BAUD = 1_000_000
#: the SDK's PortHandler or hilsim's (a subclass); the SDK has no type information
_Port = TypeVar("_Port", bound=sdk.PortHandler)


# ----------------------------------------------------------------------- the fake port
class InstantSerial:
    """A pyserial stand-in answering a Fast Sync Read of Present Position at once.

    ``write`` records the packet (:attr:`writes`, :attr:`last_write`); a Fast Sync Read
    instruction makes the next reads return a correct reply for the IDs it lists, in its
    order: header, then per servo ``ERR ID position(4) CRC(2)``, each CRC the running CRC
    of the packet up to its data. ``variants`` replies per ID order are built once, their
    positions ``centre + amplitude·sin(...)`` ticks, and taken in turn (no CRC is computed
    while timing). Any other packet gets no reply.
    """

    def __init__(self, variants: int = 64, centre: int = 2048, amplitude: int = 20) -> None:
        self.variants, self.centre, self.amplitude = variants, centre, amplitude
        self.timeout = 0
        self.baudrate = _BAUD
        self.is_open = True
        self.port = "instant://"
        self.writes = 0
        self.last_write = b""
        self._pending = b""
        self._replies: dict[tuple[int, ...], list[bytes]] = {}
        self._turn = 0

    def reply(self, ids: tuple[int, ...], k: int) -> bytes:
        """The ``k``-th canned reply for ``ids`` (the same bytes every time)."""
        replies = self._replies.get(ids)
        if replies is None:
            replies = [self._make(ids, i) for i in range(self.variants)]
            self._replies[ids] = replies
        return replies[k % self.variants]

    def _make(self, ids: tuple[int, ...], k: int) -> bytes:
        length = 1 + 8 * len(ids)  # INST + blocks
        out = bytearray(b"\xff\xff\xfd\x00\xfe")
        out += bytes((length & 0xFF, length >> 8, 0x55))
        crc = crc16(out)
        for j, sid in enumerate(ids):
            tick = self.centre + round(self.amplitude * math.sin(0.1 * k + j))
            block = bytes((0, sid)) + tick.to_bytes(4, "little", signed=True)
            out += block
            crc = crc16(block, crc)
            out += bytes((crc & 0xFF, crc >> 8))
            crc = crc16(out[-2:], crc)
        return bytes(out)

    def write(self, data: Iterable[int]) -> int:  # bytes, or the SDK's list of ints
        data = bytes(data)
        self.writes += 1
        self.last_write = data
        if len(data) > 12 and data[7] == _FAST_SYNC_READ:
            self._pending = self.reply(tuple(data[12:-2]), self._turn)
            self._turn += 1
        return len(data)

    def read(self, size: int = 1) -> bytes:
        pending = self._pending
        self._pending = pending[size:]
        return pending[:size]

    @property
    def in_waiting(self) -> int:
        return len(self._pending)

    def reset_input_buffer(self) -> None:
        self._pending = b""

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self.is_open = False


def _opened(port: _Port, ser: InstantSerial) -> _Port:
    """``port`` as ``openPort``/``setupPort`` leave it, on ``ser``."""
    port.ser = ser
    port.baudrate = _BAUD
    port.tx_time_per_byte = (1000.0 / _BAUD) * 10.0
    port.is_open = True
    ser.reset_input_buffer()
    return port


def sdk_port(ser: InstantSerial) -> sdk.PortHandler:
    """dynamixel-sdk's own ``PortHandler`` on ``ser`` (what an SDK user has)."""
    return _opened(sdk.PortHandler("instant://"), ser)


def hilsim_port(ser: InstantSerial) -> PortHandler:
    """hilsim's :class:`~drivers.dynamixel.port.PortHandler` on ``ser``, on the host clock."""
    return _opened(PortHandler("instant://", clock=MonotonicClock(), latency_timer_ms=1.0), ser)


# ----------------------------------------------------------------------- the two cycles
class BareSdkCycle:
    """A Sync Write of Goal Position and a Fast Sync Read of Present Position for servos
    1..n, the cheapest way dynamixel-sdk's packet handler offers."""

    def __init__(self, n: int, ser: InstantSerial | None = None) -> None:
        self.ser = ser or InstantSerial()
        self.port, self.ph = sdk_port(self.ser), sdk.PacketHandler(2.0)
        self.ids = list(range(1, n + 1))
        self.n = n
        self._wparam = bytearray()
        for sid in self.ids:
            self._wparam += bytes((sid, 0, 8, 0, 0))
        self._rparam = bytes(self.ids)
        self._goals = [[2048 + (k * 7 + j) % 41 - 20 for j in range(n)] for k in range(64)]
        self._k = 0
        self.positions: list[int] = []

    def __call__(self) -> None:
        goals = self._goals[self._k % 64]
        self._k += 1
        ph, port, wparam, n = self.ph, self.port, self._wparam, self.n
        for j, pulses in enumerate(goals):
            wparam[5 * j + 1 : 5 * j + 5] = pulses.to_bytes(4, "little", signed=True)
        goal, present = ct.GOAL_POSITION, ct.PRESENT_POSITION
        if ph.syncWriteTxOnly(port, goal.addr, goal.size, wparam, 5 * n) != sdk.COMM_SUCCESS:
            raise RuntimeError("bare SDK cycle: Sync Write failed")
        if ph.syncReadTx(port, present.addr, present.size, self._rparam, n, True) != 0:
            raise RuntimeError("bare SDK cycle: Fast Sync Read failed")
        packet, result = ph.rxPacket(port, True)
        if result != sdk.COMM_SUCCESS:
            raise RuntimeError("bare SDK cycle: Fast Sync Read reply failed")
        # blocks from byte 8: ERR ID position(4) CRC(2)
        self.positions = [
            int.from_bytes(packet[10 + 8 * j : 14 + 8 * j], "little", signed=True) for j in range(n)
        ]


#: the bench's rig: a 500 Hz show, RK4 springs following sines, the watchdog check on
_RIG_HEAD = """name = "bench-tick"
bus = {{ port = "instant://", baud = {baud} }}
loop = {{ rate_hz = 500, integrator = "rk4" }}
safety = {{ comm_failure_budget_ms = 100, watchdog_ms = 100, soft_start_s = 0.0 }}
"""
_JOINT = """[[joints]]
name = "j{i}"
servo_id = {sid}
min_deg = -90
max_deg = 90
max_speed_deg_s = 270  # within the XM430-W350 default model (276 deg/s)
max_accel_deg_s2 = 8000
spring = {{ frequency_hz = 3.0, damping_ratio = 0.7, response = 0.3 }}
target = {{ type = "sine", amplitude_deg = 3, frequency_hz = 0.5, phase_deg = {phase} }}
"""


class _RowsOnly(TelemetryWriter):
    """The telemetry writer without its thread: ``record``/``amend`` as in a show; the
    rows are taken out (not formatted) between rounds by :meth:`drop_rows`."""

    def _run(self) -> None:
        return

    def drop_rows(self) -> None:
        ring = self._ring
        ring.publish_pending()
        ring.tail = ring.handed_over()

    def close(
        self, summary: Mapping[str, Any] | None = None, *, timeout_s: float = 10.0
    ) -> JsonDict:
        self._close_files()
        return {}


class HilsimTick:
    """hilsim's tick for ``n`` joints on servos 1..n, started as a show starts it: the
    servos' positions read, the safety filter and the springs started there."""

    def __init__(self, n: int, workdir: Path, ser: InstantSerial | None = None) -> None:
        text = _RIG_HEAD.format(baud=_BAUD) + "".join(
            _JOINT.format(i=i, sid=i + 1, phase=30 * i) for i in range(n)
        )
        path = workdir / f"rig{n}.toml"
        path.write_text(text, encoding="utf-8")
        rig = load_rig(path)
        self.ser = ser or InstantSerial()
        self.bus = DynamixelBus(Link(hilsim_port(self.ser)), rig.servo_ids, ReadMode.FAST, 0)
        self.telemetry = _RowsOnly(
            workdir / f"run{n}", rig.joint_names, servo_ids=rig.servo_ids, queue_size=1 << 14
        )
        loop = self.loop = HilLoop(build_parts(rig), self.bus, self.telemetry)
        servo = loop.watch.first_read(loop.reading, lambda: False)
        if servo is None:
            raise RuntimeError("the instant port gave no reading")
        self.bus.write_goals(servo)  # as HilLoop._start, without the torque and watchdog writes
        loop.map.to_joint(servo, loop.present)
        loop.safety.start(loop.present)
        loop.x[:] = loop.present
        loop.v[:] = 0.0
        loop.watch.last_bus_t = loop.clock.now()
        loop._begin()
        self._k = 0

    def __call__(self) -> None:
        loop, now = self.loop, time.perf_counter()  # the port's clock (MonotonicClock) reads it
        loop._tick(self._k, now, now, now)  # woken on time: no sleep to be late from
        self.telemetry.amend(loop.rec)
        self._k += 1

    def between_rounds(self) -> None:  # rows out of the ring, unformatted (no disk)
        self.telemetry.drop_rows()

    def stages(self) -> dict[str, Callable[[], object]]:
        """Each stage of the tick as a call on copies of the tick's parts, in its state."""
        loop = self.loop
        safety, integ = copy.deepcopy(loop.safety), copy.deepcopy(loop.integrator)
        targets, jmap = copy.deepcopy(loop.targets), loop.map
        x, v, cmd, u, du = (a.copy() for a in (loop.x, loop.v, loop.cmd, loop.u, loop.du))
        present, reading, bus, h = loop.present.copy(), loop.reading, self.bus, loop.stepper.h
        sampled = targets.sample_into(0.0, u, du)
        workdir = Path(self.telemetry.run_dir).parent
        tel = _RowsOnly(workdir / f"stages{len(x)}", loop.rig.joint_names, queue_size=1 << 14)
        self._stage_telemetry = tel
        rec = copy.copy(loop.rec)

        def springs() -> None:
            integ.step(x, v, h, 0.0, sampled)

        cmd_view, present_view = Packed(cmd), Packed(present)
        positions_view = Packed(reading.positions)

        def mapping() -> None:
            jmap.to_servo_list(cmd_view.tolist())
            present_view.put(*jmap.to_joint_list(positions_view.tolist()))

        def driver() -> None:
            bus.write_goals(jmap.to_servo_list(cmd_view.tolist()))
            bus.read_present(reading)

        def telemetry() -> None:
            tel.record(rec)
            tel.amend(rec)
            if tel._ring.full():
                tel.drop_rows()

        return {
            "safety": lambda: safety.filter(x, cmd),
            "map": mapping,
            "driver": driver,
            "targets": lambda: targets.sample_into(0.1, u, du),
            "telemetry": telemetry,
            "springs": springs,
        }

    def close(self) -> None:
        for tel in (self.telemetry, getattr(self, "_stage_telemetry", None)):
            if tel is not None:
                tel.close()
        self.bus.close()


# ----------------------------------------------------------------------- measuring
@dataclass
class TickRow:
    servos: int
    bare_sdk_us: float
    tick_us: float
    stages_us: dict[str, float] = field(default_factory=dict)

    @property
    def ratio(self) -> float:
        return self.tick_us / self.bare_sdk_us

    def as_dict(self) -> JsonDict:
        return {**asdict(self), "ratio": self.ratio}


@dataclass
class TickCost:
    rows: list[TickRow]
    rounds: int
    reps: int
    load_before: list[float] | None = None
    load_after: list[float] | None = None

    def as_dict(self) -> JsonDict:
        return {
            "what": "host CPU of one tick (no wire time): hilsim's HilLoop._tick + the row's "
            "amendment vs a bare dynamixel-sdk Sync Write + Fast Sync Read cycle (changeParam, "
            "txPacket, fastSyncRead, getData), both on an instant in-process fake port, "
            "interleaved; median of reps, best of rounds",
            "rounds": self.rounds,
            "reps": self.reps,
            "load_average": {"before": self.load_before, "after": self.load_after},
            "rows": [r.as_dict() for r in self.rows],
        }

    def text(self) -> str:
        lines = [
            "Tick cost: host CPU per tick on an instant in-process fake port (no wire time, no "
            f"servo), median of {self.reps}, best of {self.rounds}; ratio: hilsim's whole tick "
            "(springs, safety, telemetry row) over the bare SDK cycle alone",
            f"  {'servos':>6}{'bare SDK µs':>13}{'hilsim tick µs':>16}{'ratio':>8}",
        ]
        for r in self.rows:
            lines.append(f"  {r.servos:>6}{r.bare_sdk_us:>13.1f}{r.tick_us:>16.1f}{r.ratio:>8.2f}")
        staged = [r for r in self.rows if r.stages_us]
        if staged:
            names = [*STAGES, "rest"]
            lines.append("  where a tick's time goes (µs; each part alone, after a tick):")
            lines.append(f"  {'servos':>6}" + "".join(f"{s:>10}" for s in names))
            for r in staged:
                lines.append(
                    f"  {r.servos:>6}"
                    + "".join(f"{r.stages_us.get(s, math.nan):>10.1f}" for s in names)
                )
        if self.load_before and self.load_after:
            load = f"{self.load_before[0]:.2f} before, {self.load_after[0]:.2f} after"
            lines.append(f"  load average {load}")
        return "\n".join(lines) + "\n"

    def add_to_json(self, path: str | Path) -> None:
        """Add this as ``"tick_cost"`` to the JSON object in ``path``."""
        p = Path(path)
        data = json.loads(p.read_text(encoding="utf-8"))
        data["tick_cost"] = report._finite(self.as_dict())  # JSON has no NaN
        p.write_text(json.dumps(data, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")


def _load() -> list[float] | None:
    return list(os.getloadavg()) if hasattr(os, "getloadavg") else None


def interleaved(
    calls: dict[str, Callable[[], object]],
    *,
    rounds: int,
    reps: int,
    between: Callable[[], object] = lambda: None,
    clock: Callable[[], float] = time.perf_counter,
) -> dict[str, float]:
    """Seconds per call of each of ``calls``: every round calls them in turn ``reps``
    times (one after the other, so they share the machine's state), takes each one's
    median; the least median over the rounds."""
    best = dict.fromkeys(calls, math.inf)
    items = list(calls.items())
    for _ in range(rounds):
        times: dict[str, list[float]] = {name: [] for name in calls}
        for _ in range(reps):
            for name, call in items:
                t = clock()
                call()
                times[name].append(clock() - t)
        between()
        for name, ts in times.items():
            best[name] = min(best[name], statistics.median(ts))
    return best


def measure_row(
    n: int, workdir: Path, *, rounds: int, reps: int, warmup: int = 300, stages: bool = True
) -> TickRow:
    """The bare cycle and hilsim's tick for ``n`` servos (and the tick's stages)."""
    bare, tick = BareSdkCycle(n), HilsimTick(n, workdir)
    try:
        for _ in range(warmup):
            bare()
            tick()
        tick.between_rounds()
        best = interleaved(
            {"bare": bare, "tick": tick}, rounds=rounds, reps=reps, between=tick.between_rounds
        )
        row = TickRow(n, best["bare"] * 1e6, best["tick"] * 1e6)
        if stages:
            calls: dict[str, Callable[[], object]] = {
                "tick": tick,
                **{f"stage:{k}": c for k, c in tick.stages().items()},
            }
            staged = interleaved(
                calls, rounds=max(2, rounds // 2), reps=reps, between=tick.between_rounds
            )
            row.stages_us = {k.split(":", 1)[1]: s * 1e6 for k, s in staged.items() if ":" in k}
            row.stages_us["rest"] = max(0.0, row.tick_us - sum(row.stages_us.values()))
        return row
    finally:
        tick.close()


def measure_tick_cost(
    counts: tuple[int, ...] = SERVO_COUNTS,
    *,
    quick: bool = False,
    rounds: int | None = None,
    reps: int | None = None,
    stages: bool = True,
    progress: Callable[[str], None] = lambda _s: None,
) -> TickCost:
    """The table ``hilsim bench`` prints: for each servo count, the bare cycle, hilsim's
    tick and their ratio (and the tick's stages)."""
    rounds = rounds or (3 if quick else 7)
    reps = reps or (200 if quick else 500)
    load_before = _load()
    rows = []
    with tempfile.TemporaryDirectory(prefix="hilsim-tick-") as tmp:
        for n in counts:
            progress(f"tick cost: {n} servos, bare SDK cycle vs hilsim's tick")
            rows.append(measure_row(n, Path(tmp), rounds=rounds, reps=reps, stages=stages))
    return TickCost(rows, rounds, reps, load_before, _load())
