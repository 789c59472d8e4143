"""The fault matrix (32 rows: a fault or bad input, the behaviour expected, what must never be
lost) as tests, one or more per row, named ``test_row_NN_...``. The table row -> test ->
behaviour is ``docs/fault_matrix.md``.

Every show runs through ``hilsim run`` (or, for driver-level rows, ``DynamixelBus``) on a named
emulated bus on the virtual clock, with the fault seeded in the emulator. Besides the exit code and
the run directory, each test decodes the emulator's byte trace to assert what reached the wire:

* **KR** (keep running): a Sync Write every tick to the end, carrying exactly the commanded pose
  (``cmd`` in telemetry, as ticks); every reading marked OK is the value that servo put on the wire
  in reply to that very tick's Sync Read, and every reading that is not has no number.
* **SS** (safe stop): no Sync Write after the tick that tripped the fault, that tick and every one
  before it in telemetry, the fault named (servo and cause) in the exit reason, the fault event and
  ``summary.json``, then the exit policy's own packets (``hold``: Goal Position := present and the
  Bus Watchdog armed, per servo, read back).
* **CE** (clear error): exit 2 with one message naming the servo and what differs, and not one
  write of any kind on the wire.

"Never lost" (every row): the telemetry row of every tick up to the fault, the fault record, the
last commanded pose (telemetry ``cmd`` = the last Sync Write) and the last measured pose.
"""

from __future__ import annotations

import contextlib
import errno
import itertools
import math
import os
import re
import shutil
import signal
import time
import types
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import hilsim.show.loop as loop_mod
import hilsim.show.parts as parts_mod
import hilsim.telemetry.writer as tm
from drivers.clock import VirtualClock
from drivers.dxlsim import DxlBus, VirtualServo, register_bus, unregister_bus
from drivers.dxlsim.bus import TraceRecord
from drivers.dxlsim.protocol import (
    HEADER,
    Instruction,
    StreamParser,
    decode,
    encode_fast_status,
    encode_status,
)
from drivers.dynamixel.bus import DynamixelBus
from drivers.dynamixel.errors import PortGone
from drivers.dynamixel.startup import Expectation
from drivers.dynamixel.units import CENTER_TICK, RAD_PER_TICK, TICKS_PER_RAD
from drivers.servo_bus import PresentReading, ReadStatus
from hilsim.cli import main
from hilsim.exit_codes import ExitCode
from hilsim.rig import load_rig
from hilsim.targets import TargetSet, Track
from hilsim.telemetry import TelemetryWriter
from hilsim.telemetry.reader import Run, read_run
from hilsim.telemetry.stats import comm_errors
from tests.hilsim.clocks import NotVirtual
from tests.hilsim.disk_layer import FailsOnce, SmallDisk
from tests.serial_stub import CannedPort

OK, STALE, ERROR, ALERT = (int(ReadStatus[n]) for n in ("OK", "STALE", "ERROR", "ALERT"))
BAUD = 1_000_000
PERIOD = 0.004
DEG = math.pi / 180
INST = Instruction
#: Control-table addresses the exit policy and the start-up use
TORQUE_ENABLE, GOAL_POSITION, BUS_WATCHDOG = 64, 116, 98

RIG = """
name = "fm"
[bus]
port = "dxlsim://unused"
baud = 1000000
[loop]
rate_hz = 250
[safety]
comm_failure_budget_ms = 40
soft_start_s = 0.2
watchdog_ms = 100
exit_policy = "hold"
exit_retries = 3
[[joints]]
name = "pan"
servo_id = 1
min_deg = -50
max_deg = 50
max_speed_deg_s = 200
max_accel_deg_s2 = 3000
spring = { frequency_hz = 3.0, damping_ratio = 0.7 }
target = { type = "keyframes", keys = [[0, 0], [0.5, 30], [1.0, -30], [1.5, 0]], easing = "ease_in_out" }
[[joints]]
name = "tail"
servo_id = 2
min_deg = -60
max_deg = 60
max_speed_deg_s = 240
max_accel_deg_s2 = 3000
spring = { m = 1.0, c = 0.8, k = 25.0 }
initial_deg = 35
target = { type = "hold", value_deg = 0 }
[[joints]]
name = "jaw"
servo_id = 3
direction = -1
min_deg = -5
max_deg = 30
spring = { frequency_hz = 5.0, damping_ratio = 0.9, response = 0.5 }
target = { type = "sine", amplitude_deg = 15, frequency_hz = 1.0, offset_deg = 12 }
"""
PAN_TARGET = (
    'target = { type = "keyframes", keys = [[0, 0], [0.5, 30], [1.0, -30], [1.5, 0]], '
    'easing = "ease_in_out" }'
)
_names = itertools.count()


class HostKilled(BaseException):
    """The host process dies on the spot (SIGKILL, power loss): nothing after it."""


# ============================================================================ the emulated rig
@dataclass
class Emu:
    """One named emulated bus, a rig file pointing at it, and where its run goes."""

    bus: DxlBus
    path: Path
    out: Path

    @property
    def rig(self):
        return load_rig(self.path)

    def run(self, *extra: str, duration: float | None = 1.5) -> int:
        args = ["run", str(self.path), "--virtual-time", "--no-plots", "--out", str(self.out)]
        if duration is not None:
            args += ["--duration", str(duration)]
        return main([*args, *extra])

    def read(self) -> Run:
        return read_run(self.out)

    def show_time(self, run: Run, t_bus: float) -> float:
        """A bus-clock time (fault plans) on the run's time axis (0 = tick 0)."""
        return t_bus - (run.summary["loop"]["clock_t0"] - self.bus.t0)

    def hook_writes(self, hook) -> None:
        """Call ``hook(data)`` before every packet the host puts on the wire."""
        write = self.bus.write

        def hooked(data: bytes) -> float:
            hook(bytes(data))
            return write(data)

        self.bus.write = hooked


@pytest.fixture
def emulated(tmp_path):
    """``emulated(rig_text, ids=, faults=, seed=, per_servo={id: {...}}, servo_cls=, **servo_kw)``
    builds a named emulated bus (trace on, virtual clock, 1 ms latency timer) and a rig file."""
    names: list[str] = []

    def make(
        rig_text: str = RIG,
        *,
        ids=(1, 2, 3),
        faults=None,
        seed: int = 0,
        per_servo: dict | None = None,
        servo_cls=VirtualServo,
        servo_baud: int = BAUD,
        **servo_kw,
    ) -> Emu:
        servos = []
        for i in ids:
            kw = {**servo_kw, **(per_servo or {}).get(i, {})}
            model = kw.pop("model", "XM430-W350")
            cls = kw.pop("cls", servo_cls)
            servos.append(cls(model, i, baud=servo_baud, return_delay_us=0, t=0.0, **kw))
        bus = DxlBus(
            servos,
            baud=BAUD,
            clock=VirtualClock(),
            latency_timer_ms=1.0,
            faults=faults,
            seed=seed,
            trace=True,
        )
        name = f"fm{os.getpid()}-{next(_names)}"
        register_bus(name, bus)
        names.append(name)
        path = tmp_path / f"{name}.toml"
        path.write_text(rig_text.replace("dxlsim://unused", f"dxlsim://{name}"))
        return Emu(bus, path, tmp_path / f"run-{name}")

    yield make
    for n in names:
        unregister_bus(n)


# ============================================================================ the wire, decoded
@dataclass
class Tx:
    """One instruction packet the host sent, and the reply records that answered it."""

    t: float
    inst: int
    id: int
    params: bytes
    replies: list[TraceRecord] = field(default_factory=list)

    @property
    def addr(self) -> int:
        return self.params[0] | self.params[1] << 8

    def goals(self) -> dict[int, int] | None:
        """Goal Position per servo if this is a Sync Write of Goal Position, else None."""
        if self.inst != INST.SYNC_WRITE or self.addr != GOAL_POSITION:
            return None
        body = self.params[4:]
        return {
            body[k]: int.from_bytes(body[k + 1 : k + 5], "little", signed=True)
            for k in range(0, len(body), 5)
        }

    def write(self) -> tuple[int, int, int] | None:
        """(id, addr, value) of a unicast Write, else None."""
        if self.inst != INST.WRITE:
            return None
        return self.id, self.addr, int.from_bytes(self.params[2:], "little", signed=True)

    def sent_positions(self) -> dict[int, int]:
        """Present Position each servo put on the wire, intact, in reply to this Sync Read.

        Replies hit by a fault that destroys them (drop, corrupt, truncate, a collision) are
        left out; a late reply is its own request's reply, wherever it landed."""
        out: dict[int, int] = {}
        for rec in self.replies:
            fault = rec.note.partition("fault=")[2]
            if "collision" in rec.note or fault in ("drop", "corrupt", "truncate"):
                continue
            data = rec.data[6:] if fault == "garbage" else rec.data  # 6 junk bytes (default)
            if data.startswith(HEADER) and data[4] != 0xFE:  # a plain status packet
                p = decode(data)
                out[p.id] = int.from_bytes(p.params[:4], "little", signed=True)
                continue
            if data.startswith(HEADER):  # the Fast Sync Read header, then blocks
                data = data[8:]
            for k in range(0, len(data) - 7, 8):
                out[data[k + 1]] = int.from_bytes(data[k + 2 : k + 6], "little", signed=True)
        return out


def transactions(bus: DxlBus) -> list[Tx]:
    """Every instruction on the wire, in order, each with the reply records it caused (the
    emulator traces replies when it hears the request, so a late reply stays with its own)."""
    out: list[Tx] = []
    parser = StreamParser()
    for rec in bus.trace:
        if rec.direction == "tx":
            for frame in parser.feed(rec.data):
                p = frame.packet
                assert p is not None, f"the host sent a corrupt packet: {frame.raw.hex()}"
                out.append(Tx(rec.t_start, p.instruction, p.id, p.params))
        elif out:
            out[-1].replies.append(rec)
    return out


@dataclass
class Wire:
    """The trace seen per tick: ``ticks[0]`` is the hold-at-start Sync Write, ``ticks[r + 1]``
    telemetry row r's (goals, positions sent in reply to the Sync Read after it)."""

    txs: list[Tx]
    ticks: list[tuple[dict[int, int], dict[int, int] | None]]
    reads: list[Tx | None]  # per entry of ticks: the Sync Read after that Sync Write
    last_sync_write: int  # index into txs, -1 if none

    @classmethod
    def of(cls, bus: DxlBus) -> Wire:
        txs = transactions(bus)
        ticks, reads, last = [], [], -1
        for i, tx in enumerate(txs):
            goals = tx.goals()
            if goals is None:
                continue
            last = i
            read = None
            for nxt in txs[i + 1 :]:
                if nxt.goals() is not None:
                    break
                if nxt.inst in (INST.SYNC_READ, INST.FAST_SYNC_READ):
                    read = nxt
                    break
            ticks.append((goals, None if read is None else read.sent_positions()))
            reads.append(read)
        return cls(txs, ticks, reads, last)

    def goals(self, sid: int) -> np.ndarray:
        return np.array([g[sid] for g, _ in self.ticks])

    def after_last_sync_write(self) -> list[Tx]:
        return self.txs[self.last_sync_write + 1 :]

    def exit_writes(self) -> list[tuple[int, int, int]]:
        """Unicast writes after the last Sync Write (the exit policy): (id, addr, value)."""
        return [w for tx in self.after_last_sync_write() if (w := tx.write()) is not None]

    def instructions(self) -> set[int]:
        return {tx.inst for tx in self.txs}


WRITING = {
    INST.WRITE,
    INST.REG_WRITE,
    INST.ACTION,
    INST.SYNC_WRITE,
    INST.BULK_WRITE,
    INST.REBOOT,
    INST.FACTORY_RESET,
    INST.CLEAR,
}


def servo_ticks(rig, joint_values: np.ndarray) -> np.ndarray:
    """Joint-frame radians (rows x joints) as Goal/Present Position ticks, as the bus converts."""
    direction = np.array([float(j.direction) for j in rig.joints])
    home = np.array([j.home_rad for j in rig.joints])
    return np.rint((joint_values * direction + home) * TICKS_PER_RAD) + CENTER_TICK


def assert_wire_is_telemetry(emu: Emu, run: Run, wire: Wire, *, extra_writes: int = 0) -> None:
    """Each telemetry row's ``cmd`` is what its Sync Write carried; each OK reading is what that
    servo sent in reply to that tick's Sync Read; no other reading carries a number."""
    rig = emu.rig
    assert len(wire.ticks) == run.n_ticks + 1 + extra_writes
    cmd_ticks = servo_ticks(rig, run.joint("cmd"))
    present = run.joint("present")
    present_ticks = servo_ticks(rig, np.nan_to_num(present))
    status = run.joint("status")
    for r in range(run.n_ticks):
        goals, sent = wire.ticks[r + 1]
        for j, jt in enumerate(rig.joints):
            assert goals[jt.servo_id] == cmd_ticks[r, j], (r, jt.name)
            if status[r, j] in (OK, ALERT) and not math.isnan(present[r, j]):
                assert sent is not None and sent.get(jt.servo_id) == present_ticks[r, j], (
                    f"row {r}: {jt.name} reads {present_ticks[r, j]:.0f}, but servo "
                    f"{jt.servo_id} sent {None if sent is None else sent.get(jt.servo_id)}"
                )
            else:
                assert status[r, j] != OK and math.isnan(present[r, j]), (r, jt.name)


def assert_rows_complete(run: Run) -> None:
    """Telemetry holds a row for every tick that went to the bus, from tick 0 on, the last line
    whole. The only gaps are ticks the loop simulated without bus traffic to catch up after an
    overrun (a read timeout takes longer than a tick), counted as ``skipped_ticks`` (the
    summary's, and across each gap the rows')."""
    assert not run.truncated and run.tick[0] == 0
    gaps = np.diff(run.tick) - 1
    assert gaps.min(initial=0) >= 0 and gaps.sum() == run.summary["loop"]["skipped_ticks"]
    np.testing.assert_array_equal(gaps, np.diff(run.columns["skipped_ticks"]))  # the rows say it
    t = run.summary["telemetry"]
    assert t["rows_lost"] == 0 and t["rows_dropped"] == 0


def assert_hold_exit_on_the_wire(wire: Wire, confirmed: tuple[int, ...]) -> None:
    """After the last Sync Write: each confirmed servo got Goal Position := a present position
    and its Bus Watchdog armed (5 x 20 ms), nothing else moved it."""
    writes = wire.exit_writes()
    for sid in confirmed:
        assert any(w[0] == sid and w[1] == GOAL_POSITION for w in writes), sid
        assert (sid, BUS_WATCHDOG, 5) in writes, sid
    assert not any(tx.goals() is not None for tx in wire.after_last_sync_write())


def assert_safe_stop(emu: Emu, run: Run, wire: Wire, *names: str, unrecorded: int = 0) -> None:
    """SS: exit 3, the reason names the servo(s), a fault event for the last recorded tick,
    summary.json complete, no Sync Write after the fault tick."""
    s = run.summary
    assert s["exit_code"] == ExitCode.FAULT
    for name in names:
        assert name in s["exit_reason"], (name, s["exit_reason"])
    faults = [e for e in run.events if e["kind"] == "fault"]
    assert len(faults) == 1 and faults[0]["message"] == s["exit_reason"]
    assert faults[0]["tick"] == int(run.tick[-1]) + unrecorded  # the tripping tick is recorded
    assert [f["message"] for f in s["faults"]] == [s["exit_reason"]]
    assert s["exit_policy"] and s["exit_policy_confirmed"] is not None
    assert len(wire.ticks) == run.n_ticks + 1  # no goal after the fault tick


def events(run: Run, kind: str) -> list[dict]:
    return [e for e in run.events if e["kind"] == kind]


# ============================================================================ rows 1-4: timeouts
def test_row_01_one_missing_status_packet_keeps_running(emulated):
    emu = emulated(faults="drop:id=2,at=1.0,count=1")
    assert emu.run() == ExitCode.OK
    run, wire = emu.read(), Wire.of(emu.bus)
    status = run.joint("status")
    assert (status[:, 1] == STALE).sum() == 1  # that one tick, marked stale
    assert (status[:, 0] == STALE).sum() == 0  # servo 1 answers before servo 2 in the chain
    assert (status != OK).sum() <= 2  # servo 3, behind 2 in the chain, at most that tick
    assert comm_errors(run.summary, servo=2) == 1
    assert_wire_is_telemetry(emu, run, wire)  # never an invented reading; goals every tick
    assert_rows_complete(run)
    assert run.summary["exit_policy_confirmed"] is True


def test_row_02_intermittent_timeouts_keep_running_without_fabricated_values(emulated):
    emu = emulated(faults="drop:rate=0.03", seed=7)
    assert emu.run() == ExitCode.OK
    run, wire = emu.read(), Wire.of(emu.bus)
    status, present = run.joint("status"), run.joint("present")
    bad = status != OK
    assert bad.sum() > 20  # the plan did strike
    assert np.all(np.isnan(present[bad])) and np.all(np.isfinite(present[~bad]))
    assert not np.any(present[bad] == 0.0)  # no fabricated zeros
    # the per-tick comm-status field: cumulative failed reads, tick by tick
    np.testing.assert_array_equal(run.comm_errors, np.cumsum(bad.sum(axis=1)))
    assert_wire_is_telemetry(emu, run, wire)
    assert_rows_complete(run)


def test_row_03_sustained_silence_beyond_the_budget_is_a_safe_stop(emulated):
    emu = emulated(faults="drop:id=2,at=1.0")
    assert emu.run(duration=3) == ExitCode.FAULT
    run, wire = emu.read(), Wire.of(emu.bus)
    assert_safe_stop(emu, run, wire, "servo 2 (tail)", "no valid reading", "budget 40 ms")
    s = run.summary
    t = run.columns["t_actual"]
    status = run.joint("status")[:, 1]
    first_bad = int(np.argmax(status != OK))
    # the time of the first failure and the budget used are in the record
    assert np.all(status[:first_bad] == OK) and np.all(status[first_bad:] == STALE)
    assert t[first_bad] == pytest.approx(emu.show_time(run, 1.0), abs=PERIOD + 1e-9)
    silent_ms = float(re.search(r"no valid reading for (\d+) ms", s["exit_reason"])[1])
    assert 40 < silent_ms <= 40 + 2 * PERIOD * 1e3  # stopped once the budget was spent ...
    assert 0.040 - 2 * PERIOD <= t[-1] - emu.show_time(run, 1.0) <= 0.040 + PERIOD  # ... no later
    assert comm_errors(s, servo=2) == len(status) - first_bad  # the fatal reads are counted too
    assert_wire_is_telemetry(emu, run, wire)
    # last good measured pose of the silent servo, last commanded pose: both in telemetry
    assert np.isfinite(run.joint("present")[first_bad - 1, 1])
    # the exit policy: the two servos that answer held and confirmed; servo 2 named, not
    # confirmed, and the exit code stays 3 (a fault)
    assert s["exit_policy_confirmed"] is False and "servo 2" in s["exit_policy"]
    assert_hold_exit_on_the_wire(wire, confirmed=(1, 3))
    assert_rows_complete(run)


def test_row_04_adapter_removed_is_a_safe_stop_with_nothing_after_it(emulated):
    emu = emulated(faults="unplug:at=0.7")
    assert emu.run() == ExitCode.FAULT
    run, wire = emu.read(), Wire.of(emu.bus)
    s = run.summary
    assert s["exit_reason"].startswith("bus:") and "adapter gone" in s["exit_reason"]
    assert "device disconnected" in s["exit_reason"]  # the exception text
    assert run.columns["t_actual"][-1] == pytest.approx(emu.show_time(run, 0.7), abs=0.005)
    assert s["exit_policy_confirmed"] is False and "adapter gone" in s["exit_policy"]
    # nothing reached the wire after the unplug: no exit packets, no reconnect attempt
    assert all(tx.t < emu.bus.t0 + 0.7 for tx in wire.txs)
    assert len(wire.ticks) == run.n_ticks + 1
    assert_wire_is_telemetry(emu, run, wire)
    assert np.all(np.isfinite(run.joint("present")[-1]))  # the last good pose
    assert_rows_complete(run)


def test_row_04_port_is_released_and_never_reopened(emulated):
    emu = emulated(faults="unplug:at=0.1")
    bus = DynamixelBus.open(emu.rig.bus.port, baud=BAUD, ids=[1, 2, 3])
    try:
        assert bus.read_present().all_ok
        bus.clock.advance(0.2)
        with pytest.raises(PortGone):
            bus.read_present()
        assert bus.link.port.is_using is False  # the SDK's flag is not left stuck
        with pytest.raises(PortGone):
            bus.write_goals(np.zeros(3))
    finally:
        bus.close()


# ============================================================================ rows 5-10: packets
def _first_sync_read_time(emulated) -> float:
    """Bus time at which a fault-free run of RIG sends its first (Fast) Sync Read (the show's
    first read); the run is deterministic, so the same run with a fault plan reaches it too."""
    emu = emulated()
    assert emu.run(duration=0.1) == ExitCode.OK
    return next(
        tx.t for tx in transactions(emu.bus) if tx.inst in (INST.FAST_SYNC_READ, INST.SYNC_READ)
    )


def test_row_05_corrupt_replies_are_discarded_and_the_show_goes_on(emulated):
    t_first = _first_sync_read_time(emulated)
    # the first read of the show corrupted once, then 5 % of servo 2's replies
    plan = f"corrupt:id=1,at={t_first},count=1;corrupt:id=2,at={t_first + 0.01},rate=0.05"
    emu = emulated(faults=plan, seed=3)
    assert emu.run() == ExitCode.OK  # the first read is retried within the budget
    run, wire = emu.read(), Wire.of(emu.bus)
    first_read = next(tx for tx in wire.txs if tx.inst == INST.FAST_SYNC_READ)
    assert "fault=corrupt" in first_read.replies[0].note
    corrupted = [r for tx in wire.txs for r in tx.replies if "fault=corrupt" in r.note]
    assert len(corrupted) > 10
    assert (run.joint("status")[:, 1] != OK).sum() > 10
    assert_wire_is_telemetry(emu, run, wire)  # no corrupted value was ever taken as a reading
    assert_rows_complete(run)


def test_row_05_corrupted_raw_bytes_are_sampled(emulated):
    emu = emulated(faults="corrupt:id=2,rate=0.05", seed=3)
    assert emu.run(duration=1.0) == ExitCode.OK
    run = emu.read()
    raw = {
        r.data.hex()
        for tx in transactions(emu.bus)
        for r in tx.replies
        if "fault=corrupt" in r.note
    }
    record = (emu.out / "events.jsonl").read_text() + (emu.out / "summary.json").read_text()
    assert run.summary and any(h in record.replace(" ", "").lower() for h in raw)


def test_row_06_truncated_replies_are_counted_failures_never_a_crash(emulated):
    emu = emulated(faults="truncate:rate=0.05", seed=1)  # from t = 0: start-up and show
    assert emu.run() == ExitCode.OK
    run, wire = emu.read(), Wire.of(emu.bus)
    cut = [r for tx in wire.txs for r in tx.replies if "fault=truncate" in r.note]
    assert len(cut) > 20
    assert (run.joint("status") != OK).sum() > 10
    assert not events(run, "crash") and not events(run, "fault")
    assert_wire_is_telemetry(emu, run, wire)
    assert_rows_complete(run)


@pytest.mark.parametrize("mode", ["fast", "plain"])
def test_row_06_every_cut_of_a_reply_reads_stale_never_raises(mode):
    """Driver level: the reply to one (Fast) Sync Read cut after every possible byte."""
    ticks = (2100, 2200, 2300)
    if mode == "fast":
        whole = encode_fast_status(
            [(0, i + 1, t.to_bytes(4, "little")) for i, t in enumerate(ticks)]
        )
    else:
        whole = b"".join(
            encode_status(i + 1, 0, t.to_bytes(4, "little")) for i, t in enumerate(ticks)
        )
    dx = DxlBus([VirtualServo("XM430-W350", i, baud=BAUD, return_delay_us=0) for i in (1, 2, 3)])
    name = f"fm{os.getpid()}-{next(_names)}"
    bus = DynamixelBus.open(register_bus(name, dx), baud=BAUD, ids=[1, 2, 3], read_mode=mode)
    try:
        for n in range(len(whole)):
            bus.link.port.ser = CannedPort(dx.clock, whole[:n], every_request=True)
            bus._set_order([0, 1, 2])
            r = bus.read_present(PresentReading.empty((1, 2, 3)))
            for k, t in enumerate(ticks):
                if r.status[k] == OK:  # only a block that arrived whole, with its CRC
                    assert r.positions[k] == pytest.approx((t - CENTER_TICK) * RAD_PER_TICK)
                else:
                    assert r.status[k] == STALE and math.isnan(r.positions[k])
            assert not r.all_ok
    finally:
        bus.close()
        unregister_bus(name)


def test_row_07_garbage_before_the_header_is_skipped(emulated):
    emu = emulated(faults="garbage:rate=0.1", seed=2)
    assert emu.run() == ExitCode.OK
    run, wire = emu.read(), Wire.of(emu.bus)
    junk = [r for tx in wire.txs for r in tx.replies if "fault=garbage" in r.note]
    assert len(junk) > 50
    assert_wire_is_telemetry(emu, run, wire)
    # junk before a reply's header: the parser resynchronises and reads every servo (junk
    # in the middle of a Fast Sync Read reply breaks the blocks after it: those are STALE,
    # and for 10 ms their servos are read only from the first place: read_order.py)
    status = run.joint("status")
    resynced = [r for r in range(run.n_ticks) if _only_junk_before_the_header(wire.reads[r + 1])]
    every = np.all(status[resynced] == OK, axis=1)
    assert len(resynced) > 10 and every.mean() > 0.75
    assert np.all((status[resynced] == OK) | (status[resynced] == STALE))
    assert_rows_complete(run)


def _only_junk_before_the_header(read: Tx) -> bool:
    """Whether this Fast Sync Read's reply had junk before its header, nothing else wrong."""
    notes = [r.note for r in read.replies]
    return len(notes) == 3 and "fault=garbage" in notes[0] and "fault" not in notes[1] + notes[2]


@pytest.mark.parametrize("mode", ["fast", "plain"])
@pytest.mark.parametrize("tick", [0x00FDFFFF, -196607, 0x7FFDFFFF, -(2**31), 2**31 - 1])
def test_row_07_values_that_need_byte_stuffing_decode_exactly(mode, tick):
    """Present Position bytes containing FF FF FD (stuffed in a plain status packet)."""
    dx = DxlBus(
        [
            VirtualServo(
                "XM430-W350",
                i,
                baud=BAUD,
                return_delay_us=0,
                operating_mode=4,
                present_position=tick,
            )
            for i in (1, 2)
        ]
    )
    name = f"fm{os.getpid()}-{next(_names)}"
    bus = DynamixelBus.open(register_bus(name, dx), baud=BAUD, ids=[1, 2], read_mode=mode)
    try:
        r = bus.read_present()
        assert r.all_ok
        assert np.all(np.rint(r.positions * TICKS_PER_RAD) + CENTER_TICK == tick)
    finally:
        bus.close()
        unregister_bus(name)


def read_mode(rig_text: str, mode: str) -> str:
    """The rig read with ``read = mode`` (fast or plain)."""
    return rig_text.replace("[bus]\n", f'[bus]\nread = "{mode}"\n', 1)


@pytest.mark.parametrize("mode", ["auto", "plain"])
def test_row_08_a_late_reply_is_never_taken_for_a_later_tick_or_another_servo(emulated, mode):
    # late replies from the start-up on: a retry waits a late reply out (Link.settle);
    # before, the plain start-up's retries met seed 5's late replies 2 times in 3 and stopped
    emu = emulated(read_mode(RIG, mode), faults="late:rate=0.05,delay=0.006", seed=5)
    assert emu.run() == ExitCode.OK
    run, wire = emu.read(), Wire.of(emu.bus)
    late = [r for tx in wire.txs for r in tx.replies if "fault=late" in r.note]
    assert len(late) > 20
    # every OK reading is the value that servo sent for that very tick's read
    assert_wire_is_telemetry(emu, run, wire)
    assert_rows_complete(run)


@pytest.mark.parametrize("mode", ["fast", "plain"])
@pytest.mark.parametrize("seed", range(12))
def test_row_08_many_late_replies_never_a_later_ticks_value(emulated, seed, mode):
    # row 8 harder: 15 % of replies 4-9.5 ms late, over 3 s: late blocks and late whole
    # replies outlive the read after their own and meet reads that miss their own reply
    # (Fast: the front-only rule of 6dd01be took a value from an earlier read in 2 of these
    # 12; plain: asking 4 bytes every time did in all 12, as did a suspicion like Fast's)
    delay = 0.004 + 0.0005 * seed
    # (with 15 % of replies late a servo goes unread for 40 ms now and then, which stops a
    # show on row 8's 40 ms budget, as it should: here the demo's 100 ms, so the show runs)
    rig = read_mode(
        RIG.replace("comm_failure_budget_ms = 40", "comm_failure_budget_ms = 100"), mode
    )
    emu = emulated(rig, faults=f"late:rate=0.15,delay={delay},at=0.2", seed=seed)
    assert emu.run(duration=3.0) == ExitCode.OK
    run, wire = emu.read(), Wire.of(emu.bus)
    assert_wire_is_telemetry(emu, run, wire)


def test_row_09_two_servos_on_one_id_at_start_up_is_a_clear_error(emulated, capsys):
    # the twin powers up at the factory pose (2048); the servos of the rig stand elsewhere
    emu = emulated(faults="duplicate_id:id=2,at=0", present_position=1900)
    assert emu.run() == ExitCode.USAGE
    err = capsys.readouterr().err
    assert "two servos with this ID" in err
    assert any(line.lstrip().startswith("2 ") for line in err.splitlines())  # servo 2's row
    assert not Wire.of(emu.bus).instructions() & WRITING
    assert not emu.out.exists()


def test_row_09_a_second_servo_on_an_id_mid_show_is_a_safe_stop(emulated):
    emu = emulated(faults="duplicate_id:id=2,at=1.0", present_position=1900)
    assert emu.run() == ExitCode.FAULT
    run, wire = emu.read(), Wire.of(emu.bus)
    assert_safe_stop(emu, run, wire, "servo 2 (tail)")
    assert run.columns["t_actual"][-1] >= emu.show_time(run, 1.0)
    assert_wire_is_telemetry(emu, run, wire)  # a merged reply is never a reading
    assert_rows_complete(run)


def test_row_10_wrong_baud_is_a_clear_error_naming_the_baud(emulated, capsys):
    emu = emulated(servo_baud=57600)
    assert emu.run() == ExitCode.USAGE
    err = capsys.readouterr().err
    assert "57600 bit/s (answers there, not at 1000000)" in err  # found at their baud
    assert "hilsim setup" in err
    for sid in (1, 2, 3):
        assert any(line.lstrip().startswith(f"{sid} ") for line in err.splitlines()), sid
    assert not Wire.of(emu.bus).instructions() & WRITING
    assert not emu.out.exists()


# ============================================================================ rows 11-15: servo state
class RefusesWatchdogWrite(VirtualServo):
    """Answers a write of a non-zero Bus Watchdog with Data Range Error (0x04)."""

    def write(self, addr: int, data: bytes, t: float) -> int:
        if addr == BUS_WATCHDOG and data[0]:
            return 0x04
        return super().write(addr, data, t)


class RefusesGoalsFrom(VirtualServo):
    """From bus time ``REFUSE_AT`` on, refuses every Goal Position (Data Limit Error, 0x06):
    a Sync Write has no status packet, so only the figure shows it."""

    REFUSE_AT = 0.65

    def write(self, addr: int, data: bytes, t: float) -> int:
        if addr == GOAL_POSITION and t >= self.REFUSE_AT:
            return 0x06
        return super().write(addr, data, t)


def test_row_11_a_write_refused_at_start_up_names_servo_register_and_error(emulated):
    emu = emulated(per_servo={2: {"cls": RefusesWatchdogWrite}})
    code = emu.run()
    assert code == ExitCode.FAULT  # torque was on by then: the exit policy ran
    run, wire = emu.read(), Wire.of(emu.bus)
    reason = run.summary["exit_reason"]
    assert "cannot start" in reason and "servo 2" in reason
    assert "Data Range Error (4)" in reason and "at 98" in reason  # error number + register
    assert run.n_ticks == 0 and len(wire.ticks) == 1  # no show tick: nothing moved ...
    goals = wire.ticks[0][0]  # ... the one Sync Write held every servo where it stood
    first_read = next(tx for tx in wire.txs if tx.inst == INST.FAST_SYNC_READ)
    assert goals == first_read.sent_positions()
    assert events(run, "fault") and run.summary["exit_policy"]


def test_row_11_goals_refused_mid_show_are_a_safe_stop(emulated):
    emu = emulated(per_servo={1: {"cls": RefusesGoalsFrom}})
    assert emu.run() == ExitCode.FAULT
    run, wire = emu.read(), Wire.of(emu.bus)
    assert_safe_stop(emu, run, wire, "servo 1 (pan)", "following error")
    t_refused = emu.show_time(run, RefusesGoalsFrom.REFUSE_AT)
    assert t_refused < run.columns["t_actual"][-1] <= t_refused + 0.5
    assert_wire_is_telemetry(emu, run, wire)
    assert_rows_complete(run)


def test_row_12_hardware_error_is_a_safe_stop_with_the_decoded_cause(emulated, capsys):
    emu = emulated(faults="hardware_error:id=3,at=0.5,bits=overheating")
    assert emu.run() == ExitCode.FAULT
    # the tick count comes first: "reboot the servo after 123 ticks" read as an instruction
    line = next(x for x in capsys.readouterr().err.splitlines() if "hardware error" in x)
    assert re.match(r"hilsim run: stopped after \d+ ticks \([^)]*\): servo 3 \(jaw\): ", line)
    assert "reboot the servo; exit policy" in line
    run, wire = emu.read(), Wire.of(emu.bus)
    assert_safe_stop(emu, run, wire, "servo 3 (jaw)", "hardware error")
    reason = run.summary["exit_reason"]
    # never lost: the HW error byte decoded, temperature, voltage, load
    assert "0x04" in reason and "overheating" in reason
    assert "°C" in reason and " V" in reason and "load" in reason
    assert run.columns["t_actual"][-1] == pytest.approx(emu.show_time(run, 0.5), abs=0.01)
    assert INST.REBOOT not in wire.instructions()  # no auto-reboot
    assert_wire_is_telemetry(emu, run, wire)
    assert_hold_exit_on_the_wire(wire, confirmed=(1, 2))
    assert "servo 3" in run.summary["exit_policy"]  # torque cut: cannot hold, said so
    assert_rows_complete(run)


def test_row_13_torque_silently_off_is_a_safe_stop(emulated):
    emu = emulated(faults="torque_off:id=2,at=0.8")
    assert emu.run() == ExitCode.FAULT
    run, wire = emu.read(), Wire.of(emu.bus)
    assert_safe_stop(emu, run, wire, "servo 2 (tail)", "torque off")
    t_fault = emu.show_time(run, 0.8)
    assert t_fault < run.columns["t_actual"][-1] <= t_fault + 0.15  # within a health round
    assert_wire_is_telemetry(emu, run, wire)
    assert_hold_exit_on_the_wire(wire, confirmed=(1, 3))
    assert_rows_complete(run)


def test_row_14_tripped_watchdog_at_start_is_named_before_anything_moves(emulated, capsys):
    """The matrix asks for CE; the driver clears a trip left by a previous run's hold exit and
    says so (hilsim run, deliberate). What must hold either way: the servo is named, and the
    trip is cleared before any goal or torque write."""
    emu = emulated(faults="watchdog_trip:id=2,at=0")
    code = emu.run(duration=0.5)
    err = capsys.readouterr().err
    assert "servo(s) 2: Bus Watchdog had tripped" in err
    writes = [(i, tx) for i, tx in enumerate(Wire.of(emu.bus).txs) if tx.inst in WRITING]
    first_clear = next(i for i, tx in writes if tx.write() == (2, BUS_WATCHDOG, 0))
    assert all(i >= first_clear for i, _ in writes)
    assert code == ExitCode.OK


def test_row_14_watchdog_trip_mid_show_is_a_safe_stop_never_cleared_silently(emulated):
    emu = emulated(faults="watchdog_trip:id=2,at=1.0")
    assert emu.run() == ExitCode.FAULT
    run, wire = emu.read(), Wire.of(emu.bus)
    assert_safe_stop(emu, run, wire, "servo 2 (tail)", "Bus Watchdog tripped")
    assert "no host stall explains it" in run.summary["exit_reason"]
    t_fault = emu.show_time(run, 1.0)
    assert t_fault < run.columns["t_actual"][-1] <= t_fault + 0.15
    # hold needs the trip cleared: that is said in the exit policy's record, never silent
    (policy,) = events(run, "exit_policy")
    assert any("servo 2" in n and "tripped" in n for n in policy["notes"])
    assert (2, BUS_WATCHDOG, 0) in wire.exit_writes()
    assert not events(run, "recovered")  # no host stall: nothing to recover from
    assert_wire_is_telemetry(emu, run, wire)
    assert_rows_complete(run)


@pytest.mark.parametrize(("duration", "cause"), [(0.03, "reset"), (0.2, "no valid reading")])
def test_row_15_brownout_is_a_safe_stop_never_re_enabled(emulated, duration, cause):
    emu = emulated(faults=f"brownout:id=2,at=1.0,duration={duration}")
    assert emu.run() == ExitCode.FAULT
    run, wire = emu.read(), Wire.of(emu.bus)
    assert_safe_stop(emu, run, wire, "servo 2 (tail)", cause)
    t_fault = emu.show_time(run, 1.0)
    assert t_fault < run.columns["t_actual"][-1] <= t_fault + duration + 0.15
    # torque is never switched on again without the start-up checks
    t_brown = emu.bus.t0 + 1.0
    assert not [tx for tx in wire.txs if tx.t > t_brown and tx.write() == (2, TORQUE_ENABLE, 1)]
    assert_wire_is_telemetry(emu, run, wire)
    assert_rows_complete(run)


def test_row_15_brownout_fault_record_carries_the_voltage(emulated):
    emu = emulated(faults="brownout:id=2,at=1.0,duration=0.03")
    assert emu.run() == ExitCode.FAULT
    assert " V" in emu.read().summary["exit_reason"]


# ============================================================================ rows 16-19: start-up
@pytest.mark.parametrize(
    ("per_servo", "rig_extra", "expected"),
    [
        ({2: {"model": "XL430-W250"}}, "", ("model", "XM430-W350 (1020)", "XL430-W250 (1060)")),
        ({2: {"firmware": 40}}, 'read = "fast"\n', ("firmware (Fast Sync Read)", ">= 45", "40")),
    ],
    ids=["model", "firmware"],
)
def test_row_16_model_or_firmware_mismatch_is_a_clear_error(
    emulated, capsys, per_servo, rig_extra, expected
):
    emu = emulated(
        RIG.replace("baud = 1000000\n", "baud = 1000000\n" + rig_extra), per_servo=per_servo
    )
    assert emu.run() == ExitCode.USAGE
    err = capsys.readouterr().err
    row = [ln for ln in err.splitlines() if ln.lstrip().startswith("2 ") and expected[0] in ln]
    assert row
    assert all(text in row[0] for text in expected)  # the expected/found table
    assert not Wire.of(emu.bus).instructions() & WRITING
    assert not emu.out.exists()


def test_row_17_configuration_differences_are_one_clear_table(emulated, capsys):
    emu = emulated(
        per_servo={
            1: {"operating_mode": 1},  # velocity instead of position
            2: {"status_return_level": 1},
            3: {"min_position_limit": 1900},  # jaw's range needs ticks 1707..2105
        }
    )
    assert emu.run() == ExitCode.USAGE
    err = capsys.readouterr().err
    for sid, item in ((1, "Operating Mode"), (2, "Status Return Level"), (3, "position range")):
        assert any(ln.lstrip().startswith(f"{sid} ") and item in ln for ln in err.splitlines())
    assert "3 problem(s)" in err  # one table, every difference
    assert not Wire.of(emu.bus).instructions() & WRITING  # EEPROM never rewritten
    assert not emu.out.exists()


def test_row_17_a_shutdown_mask_that_differs_is_a_clear_error(emulated, capsys):
    emu = emulated(per_servo={1: {"shutdown": 0}})
    assert emu.run(duration=0.2) == ExitCode.USAGE
    assert "Shutdown" in capsys.readouterr().err


def test_row_18_torque_already_on_adopts_the_present_pose_then_ramps(emulated, capsys):
    # a previous crash left torque on, the servos still moving towards old goals
    emu = emulated(torque_enable=1, present_position=2100, goal_position=2600)
    assert emu.run() == ExitCode.OK
    assert "torque already on" in capsys.readouterr().err
    run, wire = emu.read(), Wire.of(emu.bus)
    first_write = next(i for i, tx in enumerate(wire.txs) if tx.inst in WRITING)
    read_before = [tx for tx in wire.txs[:first_write] if tx.inst == INST.FAST_SYNC_READ][-1]
    adopted = read_before.sent_positions()
    assert wire.ticks[0][0] == adopted  # goal = present, first thing written
    assert all(2100 < v < 2600 for v in adopted.values())  # caught mid-move
    assert not [tx for tx in wire.txs if tx.write() == (1, TORQUE_ENABLE, 0)]  # never limp
    rig = emu.rig
    for j in rig.joints:  # then a ramp: no step beyond the speed limit
        step = np.abs(np.diff(wire.goals(j.servo_id)))
        assert step.max() <= math.ceil(j.max_speed_rad_s * PERIOD * TICKS_PER_RAD) + 1
    assert_wire_is_telemetry(emu, run, wire)


def test_row_19_a_missing_servo_is_a_clear_error_listing_it(emulated, capsys):
    emu = emulated(ids=(1, 3))
    assert emu.run() == ExitCode.USAGE
    err = capsys.readouterr().err
    assert any(ln.lstrip().startswith("2 ") and "no (timeout)" in ln for ln in err.splitlines())
    assert not Wire.of(emu.bus).instructions() & WRITING
    assert not emu.out.exists()


# ============================================================================ rows 20-24: numbers
class BadAfter(Track):
    """0.3·sin(t) until ``t_bad``, then ``bad`` (NaN or ±inf)."""

    def __init__(self, t_bad: float, bad: float) -> None:
        self.t_bad, self.bad = t_bad, bad

    def sample(self, t: float) -> tuple[float, float]:
        return (self.bad, 0.0) if t >= self.t_bad else (0.3 * math.sin(t), 0.3 * math.cos(t))

    @property
    def duration(self) -> None:
        return None


def replace_track(monkeypatch, joint: int, make) -> None:
    """``hilsim run`` builds its targets through parts.build_targets: swap one joint's track
    (``make(original_track)``)."""
    build = parts_mod.build_targets

    def patched(rig):
        targets = build(rig)
        tracks = list(targets.tracks)
        tracks[joint] = make(tracks[joint])
        return TargetSet(tracks, rig.joint_names)

    monkeypatch.setattr(parts_mod, "build_targets", patched)


# track_check's speed estimate of an infinite target (inf - inf) warns inside numpy
@pytest.mark.filterwarnings("ignore:invalid value encountered in subtract:RuntimeWarning")
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
def test_row_20_non_finite_target_is_a_latched_safe_stop_never_on_the_wire(
    emulated, monkeypatch, bad
):
    replace_track(monkeypatch, 0, lambda _t: BadAfter(0.6, bad))
    emu = emulated()
    assert emu.run() == ExitCode.FAULT
    run, wire = emu.read(), Wire.of(emu.bus)
    # the tick whose spring state is non-finite stops in the safety filter, before the bus
    # and before its row (the safety event keeps its state): the fault event names that tick
    assert_safe_stop(emu, run, wire, "safety", "non-finite", "pan", unrecorded=1)
    # the offending value: the target in telemetry, the spring's state in the reason
    assert "(nan rad)" in run.summary["exit_reason"] or f"({bad} rad)" in run.summary["exit_reason"]
    assert np.all(np.isfinite(run.joint("cmd")))
    last_target = run.joint("target")[-1, 0]
    assert np.isnan(last_target) if math.isnan(bad) else last_target == bad
    assert np.all(np.isfinite(run.joint("sim_x")[:-1]))  # the sim state up to it
    rig = emu.rig
    lo = servo_ticks(rig, np.array([[j.min_rad for j in rig.joints]]))[0]
    hi = servo_ticks(rig, np.array([[j.max_rad for j in rig.joints]]))[0]
    for k, j in enumerate(rig.joints):  # and every goal within the joint's limits
        g = wire.goals(j.servo_id)
        assert np.all((g >= min(lo[k], hi[k])) & (g <= max(lo[k], hi[k]))), j.name
    assert events(run, "safety")
    assert_wire_is_telemetry(emu, run, wire)
    assert_rows_complete(run)


def test_row_20_the_offending_values_and_sim_state_are_kept(emulated, monkeypatch):
    # The poisoned tick sends and reads nothing, so it has no telemetry row (a row would have to
    # invent a read status); the safety event keeps the spring state and the held command.
    replace_track(monkeypatch, 0, lambda _t: BadAfter(0.6, math.nan))
    emu = emulated()
    assert emu.run() == ExitCode.FAULT
    run = emu.read()
    (fault,) = events(run, "fault")
    safety = [e for e in events(run, "safety") if e["tick"] == fault["tick"]]
    assert safety and math.isnan(safety[0]["sim_x"][0])
    assert all(math.isfinite(c) for c in safety[0]["cmd_held"])
    assert int(run.tick[-1]) == fault["tick"] - 1  # every tick before it is recorded


@pytest.mark.parametrize(
    ("old", "new", "extra"),
    [
        ("k = 25.0", "k = nan", ()),
        ("frequency_hz = 3.0", "frequency_hz = inf", ()),
        ("", "", ("--duration", "nan")),
    ],
    ids=["spring-nan", "spring-inf", "duration-nan"],
)
def test_row_20_non_finite_config_is_refused_before_anything_moves(emulated, old, new, extra):
    emu = emulated(RIG.replace(old, new) if old else RIG)
    assert emu.run(*extra, duration=None) == ExitCode.USAGE
    assert not emu.bus.trace  # the bus was never touched
    assert not emu.out.exists()


PAN_500 = (
    'target = { type = "keyframes", keys = [[0, 0], [0.5, 500], [1.0, 0]], easing = "linear" }'
)


def test_row_21_target_outside_the_limits_is_clamped_and_counted(emulated):
    emu = emulated(RIG.replace(PAN_TARGET, PAN_500))
    assert emu.run(duration=1.0) == ExitCode.OK
    run, wire = emu.read(), Wire.of(emu.bus)
    rig = emu.rig
    pan = rig.joints[0]
    target, cmd = run.joint("target")[:, 0], run.joint("cmd")[:, 0]
    # raw and clamped values both in telemetry
    assert target.max() == pytest.approx(500 * DEG, rel=1e-3)
    assert cmd.max() <= pan.max_rad and cmd.min() >= pan.min_rad
    assert np.any(np.isclose(cmd, pan.max_rad))
    hi = servo_ticks(rig, np.array([[pan.max_rad, 0, 0]]))[0, 0]
    assert wire.goals(1).max() == hi  # on the wire: exactly up to the limit, never beyond
    assert run.summary["safety_limits"]["position"]["pan"] > 50
    assert_wire_is_telemetry(emu, run, wire)


def test_row_21_clamps_are_counted_in_summary_safety_limits_and_warned_at_load(emulated, capsys):
    emu = emulated(RIG.replace(PAN_TARGET, PAN_500))
    assert emu.run(duration=1.0) == ExitCode.OK
    err = capsys.readouterr().err
    warning = [ln for ln in err.splitlines() if "warning" in ln and "pan" in ln]
    assert warning and "500" in warning[0] and "max_deg" in warning[0]  # joint, time, value
    limits = emu.read().summary["safety_limits"]
    assert limits["position"]["pan"] > 50 and limits["position"]["tail"] == 0


def test_row_22_a_step_beyond_the_speed_limit_is_rate_limited(emulated):
    step = 'target = { type = "step", at_s = 0.5, before_deg = 0, after_deg = 45 }'
    emu = emulated(RIG.replace(PAN_TARGET, step))
    assert emu.run(duration=1.2) == ExitCode.OK
    run, wire = emu.read(), Wire.of(emu.bus)
    pan = emu.rig.joints[0]
    g = wire.goals(1).astype(float)
    v_ticks = pan.max_speed_rad_s * PERIOD * TICKS_PER_RAD
    a_ticks = pan.max_accel_rad_s2 * PERIOD**2 * TICKS_PER_RAD
    assert np.abs(np.diff(g)).max() <= math.ceil(v_ticks) + 1  # rounding: one tick
    assert np.abs(np.diff(g, 2)).max() <= a_ticks + 2
    target, cmd = run.joint("target")[:, 0], run.joint("cmd")[:, 0]
    jump = int(np.argmax(target > 0))
    assert target[jump] == pytest.approx(45 * DEG)  # raw ...
    assert abs(cmd[jump] - cmd[jump - 1]) <= pan.max_speed_rad_s * PERIOD * (1 + 1e-9)  # limited
    assert run.summary["safety_limits"]["speed"]["pan"] > 0
    assert_wire_is_telemetry(emu, run, wire)


def test_row_23_a_start_far_away_and_outside_the_limits_walks_in_at_the_speed_limit(emulated):
    outside = 2048 + round(70 * DEG * TICKS_PER_RAD)  # pan at +70 deg: 20 deg beyond max_deg
    far = 2048 - round(45 * DEG * TICKS_PER_RAD)  # tail 45 deg from where its spring starts
    emu = emulated(per_servo={1: {"present_position": outside}, 2: {"present_position": far}})
    assert emu.run(duration=1.0) == ExitCode.OK
    run, wire = emu.read(), Wire.of(emu.bus)
    rig = emu.rig
    assert wire.goals(1)[0] == outside and wire.goals(2)[0] == far  # soft start from there
    for j in rig.joints:
        step = np.abs(np.diff(wire.goals(j.servo_id)))
        assert step.max() <= math.ceil(j.max_speed_rad_s * PERIOD * TICKS_PER_RAD) + 1, j.name
    pan = rig.joints[0]
    cmd, t = run.joint("cmd")[:, 0], run.columns["t_sched"]
    inside = np.flatnonzero(cmd <= pan.max_rad)
    bound = 20 * DEG / pan.max_speed_rad_s + pan.max_speed_rad_s / pan.max_accel_rad_s2
    assert inside.size and t[inside[0]] <= bound + rig.safety.soft_start_s
    assert np.all(cmd[inside[0] :] <= pan.max_rad)  # and stays inside
    assert np.all(np.diff(cmd[: inside[0] + 1]) <= 0)  # never further out on the way in
    assert any("outside the limits" in e["message"] for e in events(run, "safety"))
    assert_wire_is_telemetry(emu, run, wire)


class StallAt(Track):
    """Wraps a track; the first time it is sampled at or after ``at`` the host stalls for
    ``stall_s`` (the emulator's clock jumps: a GC pause, a busy neighbour, SIGSTOP)."""

    def __init__(self, inner: Track, clock: VirtualClock, at: float, stall_s: float) -> None:
        self.inner, self.clock, self.at, self.stall_s, self.done = inner, clock, at, stall_s, False

    def sample(self, t: float) -> tuple[float, float]:
        if not self.done and t >= self.at:
            self.done = True
            self.clock.advance(self.stall_s)
        return self.inner.sample(t)

    def sample_array(self, t):  # the load-time track check: no stall there
        return self.inner.sample_array(t)

    @property
    def duration(self):
        return self.inner.duration


def test_row_24_a_host_stall_is_caught_up_and_tripped_watchdogs_recovered(emulated, monkeypatch):
    holder: dict = {}
    replace_track(monkeypatch, 1, lambda tr: StallAt(tr, holder["clock"], 0.8, 0.2))
    emu = emulated()
    holder["clock"] = emu.bus.clock
    assert emu.run() == ExitCode.OK
    run, wire = emu.read(), Wire.of(emu.bus)
    loop = run.summary["loop"]
    assert 40 <= loop["skipped_ticks"] <= 60  # 200 ms of ticks simulated without bus traffic
    assert loop["host_stalls"]["max_ms"] >= 190
    (stall,) = events(run, "host_stall")
    assert stall["stall_ms"] >= 190 and "not counted against any servo" in stall["message"]
    assert events(run, "bus_silence")
    assert loop["recoveries"] == 3 and len(events(run, "recovered")) == 3
    assert comm_errors(run.summary) == 0  # the host, not a servo
    # each servo stopped itself (watchdog); recovered at where it stopped, then rejoined
    for j in emu.rig.joints:
        g = wire.goals(j.servo_id)
        assert np.abs(np.diff(g)).max() <= math.ceil(j.max_speed_rad_s * PERIOD * TICKS_PER_RAD) + 1
    recovered = [w for tx in wire.txs if (w := tx.write()) and w[1] == GOAL_POSITION]
    assert {w[0] for w in recovered} >= {1, 2, 3}
    assert_wire_is_telemetry(emu, run, wire)
    assert run.summary["exit_policy_confirmed"] is True


def test_row_24_the_servo_checks_after_a_silence_are_bus_time_not_the_safety_filters(
    emulated, monkeypatch
):
    """The checks of every servo after a bus silence (health reads, recoveries: bus
    transactions) happen between the safety filter and the Sync Write: their time goes in
    the tick's bus stage, not in its safety stage (a 200 ms stall once showed a 46 ms
    "safety" stage)."""
    holder: dict = {}
    replace_track(monkeypatch, 1, lambda tr: StallAt(tr, holder["clock"], 0.8, 0.2))
    emu = emulated()
    clock = holder["clock"] = emu.bus.clock
    # the stages timed on the emulator's clock: the filter costs no time, the bus its wire time
    monkeypatch.setattr(
        loop_mod, "time", types.SimpleNamespace(perf_counter=clock.now, monotonic=clock.now)
    )
    assert emu.run() == ExitCode.OK
    run = emu.read()
    (silence,) = events(run, "bus_silence")
    assert run.summary["loop"]["recoveries"] == 3
    row = int(np.flatnonzero(run.tick == silence["tick"])[0])
    safety, bus = run.stage_us("safety"), run.stage_us("bus")
    assert np.nanmax(safety) < 1.0, np.nanmax(safety)  # never more than float round-off
    others = np.delete(bus, row)
    # three servos checked and recovered: reads and writes of their own on the wire
    assert bus[row] > np.nanmax(others) + 1000.0, (bus[row], np.nanmax(others))


def test_row_24_integration_that_never_keeps_up_is_a_safe_stop(emulated, monkeypatch):
    emu = emulated()
    clock = emu.bus.clock
    # time in the loop is the emulator's clock; integrating one tick costs 95 % of the period
    monkeypatch.setattr(
        loop_mod, "time", types.SimpleNamespace(perf_counter=clock.now, monotonic=clock.now)
    )
    init = loop_mod.HilLoop.__init__

    def slow_host(self, *a, **kw):
        init(self, *a, **kw)
        self.clock = NotVirtual(clock)
        step = self.integrator.step

        def slow_step(x, v, h, t, target):
            step(x, v, h, t, target)
            clock.advance(0.95 * PERIOD)

        self.integrator.step = slow_step

    monkeypatch.setattr(loop_mod.HilLoop, "__init__", slow_host)
    assert emu.run(duration=3) == ExitCode.FAULT
    run, wire = emu.read(), Wire.of(emu.bus)
    assert_safe_stop(emu, run, wire, "cannot keep up", "substeps")
    assert run.columns["t_actual"][-1] < 1.5  # persistent for 0.5 s, then stopped
    assert_hold_exit_on_the_wire(wire, confirmed=(1, 2, 3))
    assert_rows_complete(run)


# ============================================================================ rows 25-27: signals
def signal_when(emu: Emu, signum: int, predicate) -> dict:
    """Raise ``signum`` in this process (the handler ``hilsim run`` installed runs at once)
    from inside the first bus write for which ``predicate(data, t)`` holds."""
    fired: dict = {}

    def hook(data: bytes) -> None:
        if not fired and predicate(data, emu.bus.clock.now()):
            fired["t"] = emu.bus.clock.now()
            handler = signal.getsignal(signum)
            if handler in (signal.SIG_DFL, signal.SIG_IGN, signal.default_int_handler, None):
                fired["unhandled"] = True  # never kill the test process: fail the test instead
                return
            signal.raise_signal(signum)

    emu.hook_writes(hook)
    return fired


def _sync_write_after(t_bus: float):
    return lambda data, t: t >= t_bus and data[7] == INST.SYNC_WRITE


def _signal_mid_show(emulated, signum, code) -> None:
    emu = emulated()
    fired = signal_when(emu, signum, _sync_write_after(0.9))  # during a Sync Write
    assert emu.run() == code
    assert "unhandled" not in fired
    run, wire = emu.read(), Wire.of(emu.bus)
    s = run.summary
    assert s["exit_code"] == code and signal.Signals(signum).name in s["exit_reason"]
    (sig,) = events(run, "signal")
    assert sig["tick"] == run.n_ticks
    # full telemetry up to the signal: every tick, the one it landed in included
    assert run.columns["t_actual"][-1] == pytest.approx(emu.show_time(run, fired["t"]), abs=0.005)
    assert_rows_complete(run)
    assert_wire_is_telemetry(emu, run, wire)
    # then the exit policy, confirmed, within a bound, and no goal after it
    assert s["exit_policy_confirmed"] is True
    assert_hold_exit_on_the_wire(wire, confirmed=(1, 2, 3))
    assert wire.txs[-1].t - fired["t"] < 0.1


def test_row_25_sigint_during_a_write_applies_the_exit_policy(emulated):
    _signal_mid_show(emulated, signal.SIGINT, 130)


def test_row_25_a_keyboard_interrupt_raised_in_the_loop_is_130_in_the_summary_too(emulated):
    """Ctrl-C as KeyboardInterrupt inside the loop (not through the handlers): the exit policy
    runs, the process exits 130, and summary.json says 130, not a crash's 1."""
    emu = emulated()
    raised: dict = {}

    def hook(data: bytes) -> None:
        if not raised and emu.bus.clock.now() >= 0.5 and data[7] == INST.SYNC_WRITE:
            raised["t"] = emu.bus.clock.now()
            raise KeyboardInterrupt

    emu.hook_writes(hook)
    assert emu.run() == ExitCode.SIGINT
    s = emu.read().summary
    assert s["exit_code"] == ExitCode.SIGINT and "KeyboardInterrupt" in s["exit_reason"]
    assert_hold_exit_on_the_wire(Wire.of(emu.bus), confirmed=(1, 2, 3))


def test_row_26_sigterm_applies_the_exit_policy_well_within_the_bound(emulated):
    _signal_mid_show(emulated, signal.SIGTERM, 143)


def _nth(inst: int, n: int):
    """A predicate for :func:`signal_when`: the ``n``-th packet with instruction ``inst``."""
    seen = [0]

    def predicate(data: bytes, _t: float) -> bool:
        seen[0] += data[7] == inst
        return seen[0] == n

    return predicate


def _signal_during_startup(emulated, signum, code, during) -> None:
    emu = emulated()
    fired = signal_when(emu, signum, _nth(*during))
    assert emu.run() == code
    assert fired and "unhandled" not in fired
    wire = Wire.of(emu.bus)
    assert not [tx for tx in wire.txs if tx.write() and tx.write()[1] == TORQUE_ENABLE]
    assert not [tx for tx in wire.txs if tx.goals() is not None]  # nothing energised or moved
    # the loop begins at its first read: from then on, and not before, there is a record
    assert emu.out.exists() == (during == STARTUP_MOMENTS["first-read"])
    if emu.out.exists():  # and it says so
        run = emu.read()
        assert run.summary["exit_code"] == code and run.n_ticks == 0
        assert "nothing was energised" in run.summary["exit_reason"]
        assert run.summary["exit_policy_confirmed"] is None


#: (instruction, n-th occurrence) during start-up: the Bus Watchdog read before the check (the
#: three Pings before it are ``DynamixelBus.open``'s, before ``hilsim run`` takes signals), a
#: Ping of the start-up check, the loop's first Fast Sync Read (telemetry open, torque off)
STARTUP_MOMENTS = {
    "watchdog-read": (INST.READ, 1),
    "check-ping": (INST.PING, 5),
    "first-read": (INST.FAST_SYNC_READ, 1),
}


@pytest.mark.parametrize("during", STARTUP_MOMENTS.values(), ids=STARTUP_MOMENTS.keys())
def test_row_25_sigint_during_start_up_never_enables_torque(emulated, during):
    _signal_during_startup(emulated, signal.SIGINT, 130, during)


@pytest.mark.parametrize("during", STARTUP_MOMENTS.values(), ids=STARTUP_MOMENTS.keys())
def test_row_26_sigterm_during_start_up_never_enables_torque(emulated, during):
    _signal_during_startup(emulated, signal.SIGTERM, 143, during)


@pytest.mark.parametrize("fsync_first", [False, True], ids=["any-moment", "after-an-fsync"])
def test_row_27_host_killed_mid_show_servos_stop_and_telemetry_parses(
    emulated, monkeypatch, tmp_path, fsync_first
):
    """SIGKILL / power loss, in process: at a Sync Write 0.75 s in, the run directory is copied
    as the OS has it (SIGKILL) and as fsync left it (power loss), and from then on not one
    more byte reaches the bus. ``after-an-fsync``: the kill lands just after the writer's
    fsync (as after a periodic one), so the power-loss copy holds every row handed over."""
    emu = emulated()
    synced: dict[str, int] = {}  # file -> size at its last fsync (what a power cut keeps)
    real_fsync = os.fsync

    def fsync(fd: int) -> None:
        real_fsync(fd)
        with contextlib.suppress(OSError):
            synced[os.path.basename(os.readlink(f"/proc/self/fd/{fd}"))] = os.fstat(fd).st_size

    monkeypatch.setattr(tm.os, "fsync", fsync)
    got = capture_writer(monkeypatch)
    killed: dict = {}

    def hook(data: bytes) -> None:
        t = emu.bus.clock.now()
        if not killed and t >= 0.75 and data[7] == INST.SYNC_WRITE:
            if fsync_first:
                got["writer"].flush(timeout_s=30)
            # SIGKILL: what the OS has stays; power loss: what was fsync-ed stays
            for view in ("sigkill", "power"):
                shutil.copytree(emu.out, tmp_path / view)
            for name in ("telemetry.csv", "events.jsonl"):  # never fsync-ed: nothing kept
                os.truncate(tmp_path / "power" / name, synced.get(name, 0))
            killed["t"], killed["synced"] = t, dict(synced)
        if killed:
            raise HostKilled  # the host is gone: not one more byte reaches the bus

    emu.hook_writes(hook)
    with pytest.raises(HostKilled):
        emu.run()
    wire = Wire.of(emu.bus)
    last_packet = max(r.t_end for r in emu.bus.trace if r.direction == "tx")
    assert last_packet < killed["t"]
    # the Bus Watchdog (100 ms, 20 ms units) stops every servo on its own
    clock = emu.bus.clock
    clock.wait_until(last_packet + 0.1 + 0.02 + 1e-3)
    t1 = clock.now()
    for s in emu.bus.servos:
        assert s.read(BUS_WATCHDOG, 1, t1)[1] == b"\xff", s.id  # tripped: -1
    before = [s.read(132, 4, t1)[1] for s in emu.bus.servos]
    clock.advance(0.5)
    t2 = clock.now()
    assert [s.read(132, 4, t2)[1] for s in emu.bus.servos] == before  # not moving
    assert all(s.read(122, 1, t2)[1] == b"\x00" for s in emu.bus.servos)  # Moving 0
    refused = [s.write(GOAL_POSITION, (2048).to_bytes(4, "little"), t2) for s in emu.bus.servos]
    assert [e & 0x7F for e in refused] == [4, 4, 4]  # a zombie host's goals: Data Range Error
    # telemetry as the kill left it parses; its rows are exactly the run's first rows
    full = read_run(emu.out)  # (the in-process stand-in still closed it afterwards)
    views = ["sigkill"] + (["power"] if "telemetry.csv" in killed["synced"] else [])
    for view in views:
        run = read_run(tmp_path / view)
        n = run.n_ticks
        np.testing.assert_array_equal(run.tick, np.arange(n))
        for name, column in run.columns.items():
            np.testing.assert_array_equal(column, full.columns[name][:n])
    if "events.jsonl" in killed["synced"]:  # the start event is fsync-ed when written
        assert read_run(tmp_path / "power").events[0]["kind"] == "start"
    if fsync_first:  # every tick before the kill is durable
        assert read_run(tmp_path / "power").n_ticks == len(wire.ticks) - 1 > 150


# ============================================================================ rows 28-31: host side
class _Disk:
    """A disk with ``free`` bytes left: writes beyond it raise ENOSPC (after writing what fits,
    so the line in progress is torn, as on a full file system)."""

    def __init__(self, free: int) -> None:
        self.free = free
        self.hit = False

    def file(self, inner):
        disk = self

        class Full:
            def write(self, text: str) -> int:
                data = text.encode()
                if len(data) > disk.free:
                    inner.write(data[: disk.free].decode(errors="ignore"))
                    disk.free = 0
                    disk.hit = True
                    raise OSError(errno.ENOSPC, "No space left on device")
                disk.free -= len(data)
                return inner.write(text)

            def __getattr__(self, name):
                return getattr(inner, name)

            def __enter__(self):
                return self

            def __exit__(self, *exc):
                inner.close()

        return Full()


def capture_writer(monkeypatch) -> dict:
    """Capture the TelemetryWriter ``hilsim run`` creates."""
    got: dict = {}
    init = TelemetryWriter.__init__

    def patched(self, *a, **kw):
        got["writer"] = self
        init(self, *a, **kw)

    monkeypatch.setattr(TelemetryWriter, "__init__", patched)
    return got


def writer_dies_by(emu, got: dict, t_bus: float) -> None:
    """Make the telemetry writer meet the full disk by bus time ``t_bus`` and be dead before
    the loop goes on: at the first Sync Write from then on, flush it, and wait until its death
    is registered (it is a real thread, and it may also have died on its own just now: in
    virtual time the loop would notice only after many ticks)."""

    def hook(data: bytes) -> None:
        writer = got.get("writer")  # None during the start-up check
        if writer is None or writer.failed:
            return
        if emu.bus.clock.now() >= t_bus and data[7] == INST.SYNC_WRITE:
            with contextlib.suppress(Exception):
                writer.flush(timeout_s=30)
            deadline = time.monotonic() + 10
            while not writer.failed and time.monotonic() < deadline:
                time.sleep(0.001)

    emu.hook_writes(hook)


def test_row_28_writer_thread_death_is_a_safe_stop_never_silent(emulated, monkeypatch, capsys):
    disk = _Disk(free=20_000)  # the header and a few dozen rows fit
    opener = TelemetryWriter._open

    def _open(self, path, mode):
        inner = opener(self, path, mode)
        return disk.file(inner) if path.name == "telemetry.csv" else inner

    monkeypatch.setattr(TelemetryWriter, "_open", _open)
    got = capture_writer(monkeypatch)
    emu = emulated()

    writer_dies_by(emu, got, 0.6)
    assert emu.run() == ExitCode.FAULT
    err = capsys.readouterr().err
    assert disk.hit and "No space left on device" in err
    run, wire = emu.read(), Wire.of(emu.bus)
    s = run.summary
    assert s["exit_code"] == ExitCode.FAULT and "telemetry" in s["exit_reason"]
    assert "No space left" in s["exit_reason"] and "No space left" in s["telemetry"]["error"]
    assert [f["message"] for f in s["faults"]] == [s["exit_reason"]]  # the fault record
    # the show stopped (no goal after the tick that found the writer dead), then the exit
    # policy: confirmed, on the wire
    assert len(wire.ticks) <= emu.show_time(run, 0.6) / PERIOD + 3
    assert s["exit_policy_confirmed"] is True
    assert_hold_exit_on_the_wire(wire, confirmed=(1, 2, 3))
    # what reached the disk parses: whole rows, from tick 0, a torn last line tolerated
    np.testing.assert_array_equal(run.tick, np.arange(run.n_ticks))
    assert run.n_ticks > 10


def test_row_28_writer_death_keeps_its_traceback(emulated, monkeypatch, capsys):
    disk = _Disk(free=5_000)
    opener = TelemetryWriter._open
    monkeypatch.setattr(
        TelemetryWriter,
        "_open",
        lambda self, p, m: (
            disk.file(opener(self, p, m)) if p.name == "telemetry.csv" else opener(self, p, m)
        ),
    )
    emu = emulated()
    assert emu.run(duration=3) == ExitCode.FAULT
    record = capsys.readouterr().err + (emu.out / "summary.json").read_text()
    assert "Traceback" in record and "in write" in record


def test_row_28_an_exception_in_the_loop_thread_is_a_safe_stop_with_its_traceback(emulated):
    emu = emulated()
    raised: dict = {}

    def hook(data: bytes) -> None:  # a bug in a driver: anything but a bus error, once
        if not raised and emu.bus.clock.now() >= 0.8 and data[7] == INST.SYNC_WRITE:
            raised["t"] = emu.bus.clock.now()
            raise RuntimeError("send_fn exploded")

    emu.hook_writes(hook)
    assert emu.run() == ExitCode.FAULT
    run, wire = emu.read(), Wire.of(emu.bus)
    s = run.summary
    assert s["exit_reason"] == "internal error: RuntimeError: send_fn exploded"
    (crash,) = events(run, "crash")
    assert "Traceback" in crash["traceback"] and "send_fn exploded" in crash["traceback"]
    assert events(run, "fault")
    assert run.columns["t_actual"][-1] == pytest.approx(emu.show_time(run, raised["t"]), abs=0.005)
    assert s["exit_policy_confirmed"] is True
    assert_hold_exit_on_the_wire(wire, confirmed=(1, 2, 3))
    assert_rows_complete(run)


def test_row_29_a_failing_exit_step_is_bounded_named_and_exit_code_4(emulated, capsys):
    clean = emulated()
    assert clean.run() == ExitCode.OK
    w = Wire.of(clean.bus)
    t_exit = w.after_last_sync_write()[0].t  # the exit policy's first packet
    emu = emulated(faults=f"drop:id=2,at={t_exit - 1e-4}")  # servo 2 silent from then on
    assert emu.run() == ExitCode.UNSAFE_EXIT  # the show ended normally: 4, not 0
    err = capsys.readouterr().err
    run, wire = emu.read(), Wire.of(emu.bus)
    s = run.summary
    assert s["exit_code"] == ExitCode.UNSAFE_EXIT and s["exit_reason"] == "end of show"
    assert s["exit_policy_confirmed"] is False
    assert "NOT confirmed" in s["exit_policy"] and "servo 2" in s["exit_policy"]
    assert "servo 2" in err and "NOT confirmed" in err  # loud
    (policy,) = events(run, "exit_policy")
    assert policy["unconfirmed"] == [2] and sorted(policy["confirmed"]) == [1, 3]
    # servo 2's first step (is its torque on?) tried 1 + exit_retries times, unanswered: the
    # retries happened, and no more; then the exit goes on to servo 3, and is quick
    asked = [(tx.inst, tx.addr, tx.replies) for tx in wire.after_last_sync_write() if tx.id == 2]
    assert asked == [(INST.READ, TORQUE_ENABLE, [])] * (1 + emu.rig.safety.exit_retries)
    assert wire.txs[-1].t - t_exit < 0.1
    assert_hold_exit_on_the_wire(wire, confirmed=(1, 3))
    assert_wire_is_telemetry(emu, run, wire)
    assert_rows_complete(run)


def _full_disk(monkeypatch, free: int) -> _Disk:
    """Every file the telemetry writes (CSV, events, summary) shares ``free`` bytes."""
    disk = _Disk(free)

    def full_open(path, mode="r", *a, **kw):
        inner = open(path, mode, *a, **kw)  # noqa: SIM115 (the writer closes it)
        return disk.file(inner) if any(c in mode for c in "wax") else inner

    monkeypatch.setattr(tm, "open", full_open, raising=False)
    return disk


def test_row_30_disk_full_is_a_safe_stop_reported_on_stderr(emulated, monkeypatch, capsys):
    disk = _full_disk(monkeypatch, free=30_000)
    got = capture_writer(monkeypatch)
    emu = emulated()

    writer_dies_by(emu, got, 0.6)
    assert emu.run() == ExitCode.FAULT  # default telemetry.on_failure = "stop"
    err = capsys.readouterr().err
    assert disk.hit
    assert "No space left on device" in err and "exit code 3" in err  # the reason, on stderr
    wire = Wire.of(emu.bus)
    assert len(wire.ticks) < 0.7 / PERIOD  # stopped: not the whole 1.5 s show
    assert_hold_exit_on_the_wire(wire, confirmed=(1, 2, 3))  # the exit policy still ran
    run = read_run(emu.out)  # whatever reached the disk parses
    np.testing.assert_array_equal(run.tick, np.arange(run.n_ticks))


def test_row_30_disk_full_keeps_the_show_running_when_the_rig_allows(emulated, monkeypatch, capsys):
    disk = _full_disk(monkeypatch, free=30_000)
    got = capture_writer(monkeypatch)
    emu = emulated(RIG.replace('name = "fm"', 'name = "fm"\n[telemetry]\non_failure = "continue"'))

    def hook(data: bytes) -> None:  # make sure the writer has met the full disk by 0.6 s
        if emu.bus.clock.now() >= 0.6 and data[7] == INST.SYNC_WRITE and not disk.hit:
            with contextlib.suppress(Exception):
                got["writer"].flush(timeout_s=30)

    emu.hook_writes(hook)
    assert emu.run() == ExitCode.OK  # the show completed, as the rig asked...
    err = capsys.readouterr().err
    assert "verdict:" in err and "telemetry failed" in err  # ...and it says its record did not
    wire = Wire.of(emu.bus)
    assert len(wire.ticks) == round(1.5 / PERIOD) + 2  # every tick went to the servos
    assert "telemetry stopped" in err and "the show goes on" in err
    assert_hold_exit_on_the_wire(wire, confirmed=(1, 2, 3))


def _record_agrees(emu: Emu, rc: int, err: str) -> dict | None:
    """What every run must hold however its disk failed: summary.json, when there is one, says
    the exit code the process returned, and a fault in its faults and in events.jsonl; no
    summary only with exit 3; an OS error is a line on stderr, never a traceback; the exit
    policy went out on the wire."""
    assert_hold_exit_on_the_wire(Wire.of(emu.bus), confirmed=(1, 2, 3))
    path = emu.out / "summary.json"
    if not path.exists():
        assert rc == ExitCode.FAULT and "summary.json" in err
        assert "Traceback" not in err
        return None
    run = read_run(emu.out)
    s = run.summary
    assert s["exit_code"] == rc, (s["exit_code"], s["exit_reason"], rc)
    assert s["exit_policy_confirmed"] is True
    if rc == ExitCode.OK:
        assert s["exit_reason"] == "end of show" and s["telemetry"]["error"] is None
        assert not s["faults"] and not events(run, "fault")
    else:
        assert rc == ExitCode.FAULT and "telemetry" in s["exit_reason"]
        assert [f["message"] for f in s["faults"]] == [s["exit_reason"]]
        assert [e["message"] for e in events(run, "fault")] == [s["exit_reason"]]
        assert s["telemetry"]["error"]
    assert "Traceback" not in err
    return s


def test_row_30_a_write_failing_anywhere_in_close_never_contradicts_the_exit_code(
    emulated, monkeypatch, capsys
):
    """Every operation the writer makes on the disk from the moment it is closed (the last
    rows, events, flushes, fsyncs, closes, the summary's own writes), failing in turn (a full
    disk, an I/O error, a file system gone read-only): the summary and the exit code agree,
    and the show's exit policy went out regardless."""
    got = capture_writer(monkeypatch)

    def closing() -> bool:
        w = got.get("writer")
        return w is not None and w._close_requested

    def run(at, err=errno.ENOSPC):
        emu = emulated()
        with monkeypatch.context() as m:
            disk = FailsOnce(m, emu.out, closing, at, err)
            rc = emu.run(duration=0.2)
        return emu, disk, rc

    _, clean, rc = run(None)
    assert rc == ExitCode.OK
    points = list(dict.fromkeys(clean.points))  # each kind of operation, in order
    assert {op for op, _ in points} >= {"write", "flush", "fsync", "close"}
    for at, err in zip(points, itertools.cycle([errno.ENOSPC, errno.EIO, errno.EROFS])):
        for _ in range(5):  # whether rows are left for close to write depends on the threads
            capsys.readouterr()
            emu, disk, rc = run(at, err)
            if disk.fired:
                break
        assert disk.fired, at
        out = capsys.readouterr().err
        _record_agrees(emu, rc, out)
        if rc != ExitCode.OK:
            assert os.strerror(err) in out, at


def test_row_30_a_full_disk_keeps_the_fault_record_and_the_summary(emulated, monkeypatch, capsys):
    """The run directory's disk fills up mid-show: the show stops safely (exit 3), and what
    the end must write is there all the same: the fault in events.jsonl and summary.json,
    the exit policy's event, the summary saying exit 3; the OS error is one line on stderr,
    its traceback in a file of the run directory."""
    emu = emulated()
    disk = SmallDisk(monkeypatch, emu.out, capacity=80_000)
    assert emu.run() == ExitCode.FAULT
    err = capsys.readouterr().err
    assert disk.full
    s = _record_agrees(emu, ExitCode.FAULT, err)
    assert s is not None and "No space left on device" in s["exit_reason"]
    run = read_run(emu.out)
    assert [e["kind"] for e in run.events][:1] == ["start"]
    (policy,) = events(run, "exit_policy")
    assert sorted(policy["confirmed"]) == [1, 2, 3]
    np.testing.assert_array_equal(run.tick, np.arange(run.n_ticks))
    assert 10 < run.n_ticks < 1.5 / PERIOD  # stopped when the disk filled
    tel = s["telemetry"]  # the rows it says are there are the rows there
    assert tel["rows_written"] == run.n_ticks and tel["rows_lost"] == s["ticks"] - run.n_ticks
    line = [ln for ln in err.splitlines() if "No space left on device" in ln]
    assert line and all(ln.startswith("hilsim run: ") for ln in line)
    files = [p for p in emu.out.iterdir() if p.is_file()]  # (show_files/ holds the copies)
    tracebacks = [p for p in files if "Traceback" in p.read_text(errors="replace")]
    assert [p.name for p in tracebacks if p.name != "summary.json"] == ["telemetry_error.txt"]


def test_row_30_no_room_for_the_end_record_at_start_is_one_line_and_the_show_goes_on(
    emulated, monkeypatch, capsys
):
    """A disk too full to set aside the end record's space: said in one line, and the show
    starts all the same (it stops when the rows find the disk full, exit 3)."""
    emu = emulated()
    SmallDisk(monkeypatch, emu.out, capacity=12_000)
    rc = emu.run()
    err = capsys.readouterr().err
    warned = [ln for ln in err.splitlines() if "set aside" in ln]
    assert len(warned) == 1 and "No space left on device" in warned[0]
    assert len(Wire.of(emu.bus).ticks) > 1  # the show started
    assert rc == ExitCode.FAULT
    _record_agrees(emu, rc, err)


def test_row_31_a_torn_last_line_is_tolerated_and_every_earlier_record_parses(emulated, tmp_path):
    emu = emulated()
    assert emu.run(duration=0.5) == ExitCode.OK
    full = emu.read()
    csv = (emu.out / "telemetry.csv").read_bytes()
    ev = (emu.out / "events.jsonl").read_bytes()
    rng = np.random.default_rng(31)
    line_ends = [i + 1 for i, b in enumerate(csv) if b == ord("\n")]
    for k, cut in enumerate(sorted(rng.integers(line_ends[0] + 1, len(csv), 12))):
        d = tmp_path / f"cut{k}"
        d.mkdir()
        (d / "telemetry.csv").write_bytes(csv[:cut])
        (d / "events.jsonl").write_bytes(ev[: len(ev) - 7])  # the last event torn too
        run = read_run(d)
        whole = sum(1 for e in line_ends if e <= cut) - 1  # complete rows before the cut
        assert run.n_ticks == whole and run.truncated == (cut not in line_ends)
        for name, column in run.columns.items():
            np.testing.assert_array_equal(column, full.columns[name][:whole])
        assert len(run.events) == len(full.events) - 1
        assert any("incomplete" in w for w in run.warnings)


# ============================================================================ row 32: decoding
@settings(max_examples=60, deadline=None, derandomize=True)
@given(
    present=st.lists(st.integers(-(2**31), 2**31 - 1), min_size=3, max_size=3),
    goals=st.lists(st.integers(-1_048_575, 1_048_575), min_size=3, max_size=3),
    mode=st.sampled_from(["fast", "plain"]),
)
def test_row_32_signed_32_bit_positions_round_trip_exactly(present, goals, mode):
    dx = DxlBus(
        [
            VirtualServo(
                "XM430-W350",
                i + 1,
                baud=BAUD,
                return_delay_us=0,
                operating_mode=4,
                present_position=p,
            )
            for i, p in enumerate(present)
        ],
        trace=True,
    )
    name = f"fm{os.getpid()}-{next(_names)}"
    bus = DynamixelBus.open(register_bus(name, dx), baud=BAUD, ids=[1, 2, 3], read_mode=mode)
    try:
        r = bus.read_present()
        assert r.all_ok
        assert (np.rint(r.positions * TICKS_PER_RAD) + CENTER_TICK).astype(
            np.int64
        ).tolist() == present
        bus.check([Expectation(i, operating_mode=4) for i in (1, 2, 3)])
        bus.write_goals((np.array(goals, dtype=float) - CENTER_TICK) * RAD_PER_TICK)
        (sent,) = [tx.goals() for tx in transactions(dx) if tx.goals() is not None]
        assert sent == {1: goals[0], 2: goals[1], 3: goals[2]}
    finally:
        bus.close()
        unregister_bus(name)
