"""Host-side robustness of the reads (issue 9): the show goes on, and never lies.

* a host stall between two polls is not a timeout: the port takes what arrived first, and
  measures the stall (``host_stall_s``); a servo that is really silent still times out;
* Fast Sync Read and plain Sync Read on mutated replies never raise and never report a
  value the servo did not send in this very transaction;
* a late reply is never read as a later tick's (emulator ``late`` faults, checked against
  the emulator's byte trace), and after a failed read the rest of the chain is waited out;
* two servos on one ID collide under Fast Sync Read and are never an OK reading;
* start-up hints; ``hilsim emulate``'s pty: what it prints, and its baud.

Nothing sleeps: a virtual clock, or a hand-made clock that moves a microsecond each time
it is read (a busy host's clock) and jumps where the test puts an OS preemption.
"""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys
import tomllib
import types

import dynamixel_sdk as sdk
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.dxlsim import DxlBus, VirtualServo, register_bus, unregister_bus
from drivers.dxlsim.faults import Fault, FaultKind, FaultPlan, parse_fault_plan
from drivers.dxlsim.protocol import HEADER, encode_fast_status, encode_status
from drivers.dynamixel import units
from drivers.dynamixel.bus import DynamixelBus
from drivers.dynamixel.errors import CommTimeout, CorruptPacket, StartupMismatch
from drivers.dynamixel.port import HOST_STALL_THRESHOLD_S
from drivers.dynamixel.startup import Expectation
from drivers.protocol2 import control_table as ct
from drivers.servo_bus import PresentReading, ReadStatus
from tests.drivers.conftest import asked, make_bus
from tests.serial_stub import CannedPort

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
IDS = (1, 2, 3, 4)
BAUD = 1_000_000
OK, STALE = ReadStatus.OK, ReadStatus.STALE
_names = itertools.count()


@pytest.fixture
def opened():
    """``opened(dxlbus, read_mode=...)`` -> a DynamixelBus on it; closed afterwards."""
    made: list[tuple[DynamixelBus, str]] = []

    def _open(dx: DxlBus, *, read_mode: str = "fast", retries: int = 2) -> DynamixelBus:
        name = f"rr-{next(_names)}"
        bus = DynamixelBus.open(
            register_bus(name, dx),
            baud=dx.baud,
            ids=sorted({s.id for s in dx.servos}),
            read_mode=read_mode,
            retries=retries,
        )
        made.append((bus, name))
        return bus

    yield _open
    for bus, name in made:
        bus.close()
        unregister_bus(name)


def device_ticks(dx: DxlBus) -> dict[int, int]:
    """Present Position of the first servo on each ID, read device-side now."""
    t, out = dx.clock.now(), {}
    for s in dx.servos:
        out.setdefault(s.id, int.from_bytes(s.read(132, 4, t)[1], "little", signed=True))
    return out


def reading_ticks(r: PresentReading, k: int) -> int:
    return round(r.positions[k] / units.RAD_PER_TICK) + units.CENTER_TICK


# ------------------------------------------------------------------ host stalls
class StepClock:
    """A real-time clock (``virtual = False``: the port busy-polls) that moves 1 µs every
    time it is read, as a polling host's clock does; :meth:`stall` jumps it, as an OS
    preemption does."""

    virtual = False

    def __init__(self, step: float = 1e-6) -> None:
        self.t, self.step = 0.0, step
        self.reads = 0

    def now(self) -> float:
        self.t += self.step
        self.reads += 1
        return self.t

    def wait_until(self, t: float, idle=None) -> float:
        self.t = max(self.t, t)
        return self.t

    def stall(self, seconds: float) -> None:
        self.t += seconds


def stepped_bus(clock: StepClock, *, latency_ms: float = 1.0, faults=None) -> DxlBus:
    servos = [VirtualServo("XM430-W350", i, baud=BAUD, return_delay_us=0, t=clock.t) for i in IDS]
    return DxlBus(servos, baud=BAUD, clock=clock, latency_timer_ms=latency_ms, faults=faults)


def busy_polling(bus: DynamixelBus) -> DynamixelBus:
    """The port polls with timeout 0 and no wait, as the SDK's own ``PortHandler`` does
    (hilsim's waits on the emulator's clock): between two polls is where a preemption
    hurts, and what the drain after a stall is for."""
    bus.link.port._wait = "poll"
    return bus


def preempt(port, clock: StepClock, when: str, seconds: float = 0.060) -> list[int]:
    """Deschedule the host for ``seconds`` right after a poll returns - between the
    SDK's ``readPort()`` and its ``isPacketTimeout()``, where a preemption hurts: after
    the first poll (``"first"``), or after the first poll that got some bytes
    (``"bytes"``). Once. Returns the byte count of every poll."""
    read, polls, done = port.readPort, [], []

    def poll(n):
        data = read(n)
        polls.append(len(data))
        if not done and (when == "first" or data):
            done.append(True)
            clock.stall(seconds)
        return data

    port.readPort = poll
    return polls


@pytest.mark.parametrize("read_mode", ["fast", "plain"])
@pytest.mark.parametrize(("latency_ms", "when"), [(1.0, "first"), (0.0, "bytes")])
def test_a_host_stall_inside_the_poll_is_drained_not_a_timeout(opened, read_mode, latency_ms, when):
    clock = StepClock()
    dx = stepped_bus(clock, latency_ms=latency_ms)
    bus = busy_polling(opened(dx, read_mode=read_mode))
    port = bus.link.port
    assert not bus.clock.virtual and port.host_stall_s == 0.0 and port.host_stalls == 0
    polls = preempt(port, clock, when)
    r = bus.read_present()
    assert r.all_ok, r.problems()
    assert [reading_ticks(r, k) for k in range(4)] == list(device_ticks(dx).values())
    assert r.t_done - r.t > 0.060  # it woke up long after the deadline, and used the reply
    assert 0.060 < port.host_stall_s < 0.060 + HOST_STALL_THRESHOLD_S and port.host_stalls == 1
    assert len(polls) > 2
    # The next read, with no stall, adds nothing.
    assert bus.read_present().all_ok and port.host_stalls == 1


def test_the_sdks_own_timeout_check_calls_the_same_stall_a_silent_servo(opened):
    """The bug the port fixes: with the SDK's ``isPacketTimeout`` the 60 ms preemption is
    a timeout while the whole reply sits in the buffer."""
    clock = StepClock()
    dx = stepped_bus(clock)
    bus = busy_polling(opened(dx, read_mode="fast"))
    port = bus.link.port
    port.isPacketTimeout = types.MethodType(sdk.PortHandler.isPacketTimeout, port)
    preempt(port, clock, "first")
    r = bus.read_present()
    assert r.status.tolist() == [STALE] * 4
    assert dx.in_waiting() == 8 + 8 * 4  # the complete Fast Sync Read reply, unread


@pytest.mark.parametrize("read_mode", ["fast", "plain"])
def test_a_silent_servo_still_times_out_on_the_busy_poll(opened, read_mode):
    clock = StepClock()
    dx = stepped_bus(clock)
    bus = busy_polling(opened(dx, read_mode=read_mode))
    dx.faults = parse_fault_plan("drop:id=1,count=1")  # the chain's first servo: all silent
    r = bus.read_present()
    assert r.status.tolist() == [STALE] * 4
    timeout_ms = bus._fast_timeout_ms if read_mode == "fast" else bus._plain_timeout_ms
    assert timeout_ms * 1e-3 <= r.t_done - r.t < timeout_ms * 1e-3 + 1e-3
    assert bus.link.port.host_stalls == 0  # busy-polling to the deadline is no stall


def test_unicast_and_broadcast_ping_drain_after_a_stall(opened):
    clock = StepClock()
    dx = stepped_bus(clock)
    bus = busy_polling(opened(dx, read_mode="plain"))
    link, port = bus.link, bus.link.port
    model = ct.model_number("XM430-W350")
    preempt(port, clock, "first")
    assert link.ping(3)[0] == model
    preempt(port, clock, "first")
    assert link.read_item(2, ct.PRESENT_POSITION) == device_ticks(dx)[2]
    preempt(port, clock, "first", seconds=1.0)  # beyond the broadcast ping's 772 ms window
    assert sorted(link.broadcast_ping()) == list(IDS)
    assert port.host_stalls == 3
    # the SDK's own check, same stall: "no reply"
    port.isPacketTimeout = types.MethodType(sdk.PortHandler.isPacketTimeout, port)
    preempt(port, clock, "first")
    with pytest.raises(CommTimeout):
        link.ping(3)


@pytest.mark.parametrize("read_mode", ["fast", "plain"])
def test_hilsims_port_waits_on_the_emulators_clock_instead_of_polling(opened, read_mode):
    # the emulator in this process on the real clock: a read sleeps until its bytes are due
    # (the clock's wait), so a tick does not spin for the wire time; the same reading
    clock = StepClock()
    dx = stepped_bus(clock)
    reads = {}
    for mode in ("clock", "poll"):
        bus = opened(dx, read_mode=read_mode)
        assert bus.link.port._wait == "clock"
        if mode == "poll":
            busy_polling(bus)
        before = clock.reads
        r = bus.read_present()
        assert r.all_ok, r.problems()
        assert [reading_ticks(r, k) for k in range(4)] == list(device_ticks(dx).values())
        reads[mode] = clock.reads - before  # a poll reads the clock; a wait jumps it
        assert bus.link.port.host_stalls == 0
    assert reads["poll"] > 10 * reads["clock"]


def test_no_host_stall_is_counted_on_a_virtual_clock(opened):
    dx = make_bus(IDS, latency_timer_ms=1.0, faults="drop:id=2,rate=0.3", seed=4)
    bus = opened(dx)
    stale = 0
    for _ in range(50):
        stale += int((bus.read_present().status == STALE).sum())
        dx.clock.advance(0.25)  # the loop sleeping between ticks is not a stall either
    assert bus.link.port.host_stall_s == 0.0 and bus.link.port.host_stalls == 0
    assert stale > 0  # some reads did time out: a jump to the deadline is no stall


# ------------------------------------------------------------------ parsers, fuzzed
def host_reading(read_mode: str, order: tuple[int, ...], stream: bytes) -> PresentReading:
    """What the host makes of ``stream`` as the reply to a Sync Read listing ``order``."""
    with DynamixelBus.open(
        "dxlsim://?ids=1-4&rdt_us=0&clock=virtual", baud=BAUD, ids=IDS, read_mode=read_mode
    ) as bus:
        bus._set_order([IDS.index(i) for i in order])
        bus.link.port.ser = CannedPort(bus.clock, stream)
        return bus.read_present()


def pos(tick: int) -> bytes:
    return tick.to_bytes(4, "little", signed=True)


int32 = st.integers(-(2**31), 2**31 - 1)


@st.composite
def mutated(draw, reply: bytes, stale: bytes | None) -> bytes:
    """One to three of: bit flips, truncation (any length, 0-7 bytes too), garbage before
    or after, a new LEN field, random bytes; with ``stale`` (an earlier transaction's
    reply) also a splice of this reply's head onto its tail, or the whole of it first."""
    kinds = ["flip", "truncate", "prefix", "suffix", "len", "random"]
    if stale is not None:
        kinds += ["splice", "stale_first"]
    data = bytearray(reply)
    for kind in draw(st.lists(st.sampled_from(kinds), min_size=1, max_size=3)):
        if kind == "flip" and data:
            for _ in range(draw(st.integers(1, 3))):
                i = draw(st.integers(0, len(data) - 1))
                data[i] ^= draw(st.integers(1, 255))
        elif kind == "truncate":
            data = data[: draw(st.integers(0, len(data)))]
        elif kind == "prefix":
            data = bytearray(draw(st.binary(max_size=30))) + data
        elif kind == "suffix":
            data += draw(st.binary(max_size=30))
        elif kind == "len" and len(data) >= 7:
            data[5], data[6] = draw(st.integers(0, 255)), draw(st.integers(0, 1))
        elif kind == "random":
            data = bytearray(draw(st.binary(max_size=80)))
        elif kind == "splice":
            cut = draw(st.integers(0, len(data)))
            data = data[:cut] + stale[draw(st.integers(0, len(stale))) :]
        elif kind == "stale_first":
            data = bytearray(stale) + data
    return bytes(data)


@st.composite
def transaction(draw, fast: bool):
    """(order asked, {id: tick sent in this transaction}, what reached the host)."""
    order = tuple(draw(st.permutations(IDS)))
    sent = {i: draw(int32) for i in IDS}
    if fast:
        reply = encode_fast_status([(0, i, pos(sent[i])) for i in order])
        # An earlier transaction's reply: other values, and another first servo (one
        # missing first is not asked first while its whole late reply may come:
        # drivers/dynamixel/read_order.py).
        old = {i: (sent[i] + draw(st.integers(1, 2**20)) + 2**31) % 2**32 - 2**31 for i in IDS}
        old_order = draw(st.permutations(IDS).filter(lambda o: o[0] != order[0]))
        stale = encode_fast_status([(0, i, pos(old[i])) for i in old_order])
    else:  # plain: a whole earlier status packet is indistinguishable; see the docs
        reply = b"".join(encode_status(i, 0, pos(sent[i])) for i in order)
        stale = None
    return order, sent, draw(mutated(reply, stale)), reply


def assert_never_a_lie(r: PresentReading, sent: dict[int, int]) -> None:
    for k, sid in enumerate(IDS):
        if r.status[k] in (ReadStatus.OK, ReadStatus.ALERT):
            assert reading_ticks(r, k) == sent[sid], f"servo {sid}: not what it sent"
        else:
            assert np.isnan(r.positions[k])


@settings(max_examples=400, deadline=None)
@given(transaction(fast=True))
def test_fast_sync_read_on_mutated_replies_never_raises_nor_lies(case):
    order, sent, stream, reply = case
    r = host_reading("fast", order, stream)
    assert_never_a_lie(r, sent)
    if stream == reply:
        assert r.all_ok


@settings(max_examples=300, deadline=None)
@given(transaction(fast=False))
def test_plain_sync_read_on_mutated_replies_never_raises_nor_lies(case):
    order, sent, stream, reply = case
    r = host_reading("plain", order, stream)
    assert_never_a_lie(r, sent)
    if stream == reply:
        assert r.all_ok


@pytest.mark.parametrize("n", range(8))
def test_a_fast_reply_cut_to_under_8_bytes_is_stale_not_an_exception(n):
    reply = encode_fast_status([(0, i, pos(2048)) for i in IDS])
    assert host_reading("fast", IDS, reply[:n]).status.tolist() == [STALE] * 4


def test_row_8_splice_yields_nothing_from_the_earlier_reply():
    """The trace of reliability.md row 8: this reply's block 1, then blocks 3-4 of the
    previous (late) reply. The old salvage re-seeded each block's CRC from the previous
    block's transmitted CRC, so the spliced blocks verified and became this tick's."""
    old = encode_fast_status([(0, i, pos(1000 + i)) for i in IDS])
    new = encode_fast_status([(0, i, pos(3000 + i)) for i in (1, 3, 4, 2)])
    spliced = new[: 8 + 8] + old[8 + 8 :]  # blocks at 2, 3, 4 carry IDs 2, 3, 4
    r = host_reading("fast", (1, 3, 4, 2), spliced)
    assert r.status.tolist() == [OK, STALE, STALE, STALE]
    assert reading_ticks(r, 0) == 3001


def test_plain_takes_replies_in_chain_order_only():
    """A whole status packet of an earlier chain, ahead of this one: the old code filed it
    under its ID (and dropped the servo's real reply as "a second one"). Out of chain
    order, it ends the read instead; a corrupt packet still costs only its own place."""
    chain = [encode_status(i, 0, pos(3000 + i)) for i in IDS]
    r = host_reading("plain", IDS, encode_status(2, 0, pos(1002)) + b"".join(chain))
    assert r.status.tolist() == [STALE] * 4
    broken = bytearray(chain[1])
    broken[10] ^= 0xFF
    r = host_reading("plain", IDS, chain[0] + bytes(broken) + chain[2] + chain[3])
    assert r.status.tolist() == [OK, STALE, OK, OK]
    assert [reading_ticks(r, k) for k in (0, 2, 3)] == [3001, 3003, 3004]


# ------------------------------------------------------------------ late replies
def sent_in(trace, mark: int) -> dict[int, int]:
    """{id: tick} in the replies the emulator sent to the Fast Sync Read request that is
    the first trace record from ``mark`` (a late one too: it answered this request)."""
    tx = trace[mark]
    assert tx.direction == "tx" and tx.data[7] == 0x8A
    out = {}
    for rec in itertools.takewhile(lambda r: r.direction == "rx", trace[mark + 1 :]):
        o = 8 if rec.data[:4] == HEADER else 0
        out[rec.data[o + 1]] = int.from_bytes(rec.data[o + 2 : o + 6], "little", signed=True)
    return out


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_late_reply_is_never_a_later_ticks_reading(opened, seed):
    dx = make_bus(IDS, latency_timer_ms=1.0, trace=True)
    bus = opened(dx, read_mode="fast")
    bus.set_torque(True)
    dx.faults = parse_fault_plan("late:rate=0.05,delay=0.006", seed=seed)
    out, period, t = PresentReading.empty(bus.ids), 0.004, dx.clock.now()
    checked = 0
    for j in range(1000):
        sign = 1.0 if (j // 100) % 2 else -1.0  # keep them moving: every tick a new value
        bus.write_goals(sign * np.array([1.0, 0.8, 0.6, 0.4]))
        mark = len(dx.trace)
        bus.read_present(out)
        sent = sent_in(dx.trace, mark)
        for k, sid in enumerate(bus.ids):
            if out.status[k] == OK:
                assert reading_ticks(out, k) == sent[sid], f"tick {j}, servo {sid}"
                checked += 1
        t += period
        dx.clock.wait_until(t)
    late = [r for r in dx.trace if "fault=late" in r.note]
    assert len(late) >= 30 and checked > 0.8 * 4000
    # and they did land where a later transaction was under way
    starts = [r.t_start for r in dx.trace if r.direction == "tx"]
    landed = sum(any(r.t_start < s < r.t_end + 1e-3 for s in starts) for r in late)
    assert landed >= 10


def _slow_lead(bus: DynamixelBus) -> FaultPlan:
    """Servo 1 starts its reply 0.7 ms before the read's deadline: it is on the wire, and
    held 1 ms by the adapter, when the read gives up."""
    start_s = 10 * (14 + 4) / BAUD + 20e-6  # request on the wire, then the turnaround
    delay = bus._fast_timeout_ms * 1e-3 - start_s - 0.7e-3
    return FaultPlan((Fault(FaultKind.LATE, frozenset({1}), delay=delay, count=1),))


def test_after_a_failed_read_the_rest_of_the_chain_is_waited_out(opened):
    dx = make_bus(IDS, latency_timer_ms=1.0, trace=True)
    bus = opened(dx, read_mode="fast")
    dx.faults = _slow_lead(bus)
    assert bus.read_present().status.tolist() == [STALE] * 4
    assert bus.read_order == (2, 3, 4, 1)
    r = bus.read_present()  # the late reply was discarded, not read as this one's
    assert r.all_ok
    late = next(x for x in dx.trace if "fault=late" in x.note)
    request = [x for x in dx.trace if x.direction == "tx"][-1]
    assert request.t_start >= late.t_end + 1e-3  # readable by then, and flushed


def test_without_the_wait_the_late_reply_costs_the_next_tick_but_is_never_read(opened):
    dx = make_bus(IDS, latency_timer_ms=1.0, trace=True)
    bus = opened(dx, read_mode="fast")
    dx.faults = _slow_lead(bus)
    bus.link.port.hold_until_quiet = lambda t: None
    truth = device_ticks(dx)
    bus.read_present()
    r = bus.read_present()  # the late packet came first: its order is not this read's
    assert r.status.tolist() == [STALE] * 4
    assert_never_a_lie(r, truth)


def test_a_late_ping_reply_is_not_taken_as_a_reads_answer(opened):
    """test_faults' classic field bug, through the Link: the Read's reply length is
    checked, so the stale Ping status is a corrupt reply, not the LED's value."""
    dx = make_bus((1, 2), rdt_us=500.0, trace=True)
    bus = opened(dx, read_mode="plain")
    link = bus.link
    link.write_item(1, ct.LED, 1)
    dx.faults = FaultPlan((Fault(FaultKind.LATE, frozenset({1}), delay=0.040, count=1),))
    t_ping = dx.clock.now()
    with pytest.raises(CommTimeout):
        link.ping(1)
    dx.clock.wait_until(t_ping + 0.0403)
    with pytest.raises(CorruptPacket):
        link.read_item(1, ct.LED)
    assert link.read_item(1, ct.LED) == 1


# ------------------------------------------------------------------ duplicate IDs
def test_two_servos_on_one_id_collide_under_fast_sync_read_never_a_reading(opened):
    dx = make_bus(IDS, trace=True, faults="duplicate_id:id=2,at=2.0")
    bus = opened(dx, read_mode="fast")
    bus.set_torque(True)
    bus.write_goals([0.3, -0.5, 0.2, 0.1])
    dx.clock.wait_until(dx.t0 + 2.1)  # there; then the twin (at the centre) appears
    truth = device_ticks(dx)
    assert truth[2] != 2048
    ph, port = bus.link.ph, bus.link.port
    # The SDK alone calls the packet fine: servos 3 and 4 ran their CRCs on over the
    # merged bytes they heard, so the last CRC holds over the garbled block 2.
    assert ph.syncReadTx(port, 132, 4, list(IDS), 4, True) == sdk.COMM_SUCCESS
    port.setPacketTimeoutMillis(10.0)
    packet, result = ph.rxPacket(port, True)
    assert result == sdk.COMM_SUCCESS
    assert packet[16 + 2 : 16 + 6] != list(pos(truth[2]))  # block 2: neither twin's value
    assert "collision" in dx.trace[-3].note
    dx.clock.advance(0.004)
    r = bus.read_present()
    assert r.status.tolist() == [OK, STALE, STALE, STALE]  # nothing after the collision
    assert_never_a_lie(r, truth)
    # missing at a later place, servo 2 is asked first (a late block of its own cannot
    # come with a header); colliding there, nothing is read, and it goes to the back
    assert bus.read_order == (2, 1, 3, 4)
    r = bus.read_present()
    assert r.status.tolist() == [STALE] * 4
    assert_never_a_lie(r, truth)
    assert bus.read_order == (1, 3, 4, 2)
    r = bus.read_present()
    assert r.status.tolist() == [OK, STALE, OK, OK]
    assert_never_a_lie(r, truth)


# ------------------------------------------------------------------ start-up hints
def _check_rows(dx: DxlBus, opened) -> list:
    bus = opened(dx, read_mode="plain")
    try:
        bus.check([Expectation(id=i, model="XM430-W350", return_delay_us_max=500) for i in IDS])
    except StartupMismatch as exc:
        return list(exc.rows)
    return []


def test_duplicate_id_at_start_up_is_named(opened):
    dx = make_bus(IDS, faults="duplicate_id:id=2,at=0", present_position=1000)
    (row,) = _check_rows(dx, opened)
    assert (row.servo_id, row.item) == (2, "read control table")
    assert "whole packets with a bad CRC" in row.found and "two servos with this ID" in row.fix


@pytest.mark.parametrize("fault", ["truncate:id=2,count=3", "late:id=2,count=3,delay=0.00193"])
def test_cut_or_late_replies_at_start_up_are_not_called_a_duplicate(opened, fault):
    (row,) = _check_rows(make_bus(IDS, faults=fault), opened)
    assert (row.servo_id, row.item) == (2, "answers Ping")
    assert "3 of 3 cut short or late" in row.found
    assert "two servos" not in row.fix


@pytest.mark.parametrize(("delay", "pings"), [(0.0025, 2), (0.0004, 1), (0.05, 2)])
def test_one_late_reply_costs_one_try_not_the_check(opened, delay, pings):
    dx = make_bus(IDS, faults=f"late:id=2,count=1,delay={delay}", trace=True)
    assert _check_rows(dx, opened) == []
    # the reply was late (within the Ping's timeout it is still taken; past it, one more try)
    tries = [a for a in asked(dx) if a.instruction == sdk.INST_PING]
    assert next(a.replies for a in tries if a.id == 2) == ["id=2 fault=late"]
    assert [a.id for a in tries] == [1] + [2] * pings + [3, 4]


# ------------------------------------------------------------------ hilsim emulate (pty)
def _emulate(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "hilsim", "emulate", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _lines(proc: subprocess.Popen, n: int) -> list[str]:
    """The first ``n`` lines of stdout (printed at once; EOF gives empty lines)."""
    lines = [proc.stdout.readline().rstrip("\n") for _ in range(n)]
    if not lines[0].startswith("/dev/"):
        proc.kill()
        pytest.fail(f"hilsim emulate printed {lines!r}; stderr: {proc.stderr.read()}")
    return lines


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="no pseudo-terminals")
def test_emulate_pty_prints_the_port_and_rig_lines_and_the_demo_runs_on_it(tmp_path):
    proc = _emulate()
    try:
        lines = _lines(proc, 8)
        path = lines[0]
        assert path.startswith("/dev/") and lines[1] == f"--port {path}"
        rig = tomllib.loads("\n".join(lines[lines.index("[bus]") :]))
        assert rig == {"bus": {"port": path, "baud": 1_000_000, "latency_timer_ms": 1}}
        # What the demo needs, out of the box: IDs 1-4 and a latency that passes the
        # 250 Hz capacity check, with the pty's timeout allowance kept.
        with DynamixelBus.open(path, baud=BAUD, ids=IDS) as bus:
            assert bus.link.latency_timer_ms == 1.0 and bus.link.timeout_margin_ms == 30.0
        demo = ["configs/demo.toml", "--port", path, "--duration", "0.5", "--no-plots"]
        run = subprocess.run(
            [sys.executable, "-m", "hilsim", "run", *demo, "--out", str(tmp_path / "run")],
            capture_output=True,
            text=True,
            timeout=120,
            cwd=ROOT,
        )
        assert run.returncode == 0, run.stderr
    finally:
        _stop(proc)


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="no pseudo-terminals")
def test_emulate_pty_answers_only_at_its_baud():
    proc = _emulate("--ids", "1", "--baud", "57600")
    try:
        path = _lines(proc, 1)[0]
        ph = sdk.PacketHandler(2.0)
        port = sdk.PortHandler(path)  # the SDK's own
        assert port.openPort()
        assert port.setBaudRate(1_000_000)
        assert ph.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT  # noise to a 57600 servo
        assert port.setBaudRate(57_600)
        assert ph.ping(port, 1)[1] == sdk.COMM_SUCCESS
        port.closePort()
    finally:
        _stop(proc)
