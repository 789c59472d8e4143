"""DynamixelBus on the emulated bus (virtual clock, never sleeping): open/close, the
per-tick path, per-servo read status, wire failures, watchdog and latency timer."""

from __future__ import annotations

import itertools
import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import serial

from drivers.dxlsim import DxlBus, register_bus, unregister_bus
from drivers.dxlsim.protocol import encode_fast_status, encode_status
from drivers.dynamixel import units
from drivers.dynamixel.bus import DynamixelBus
from drivers.dynamixel.errors import (
    CommTimeout,
    CorruptPacket,
    ExitNotConfirmed,
    PortBusy,
    PortGone,
    ServoError,
)
from drivers.dynamixel.link import (
    PTY_LATENCY_MS,
    LatencyTimerWarning,
    device_allowance_ms,
    tune_latency_timer,
)
from drivers.dynamixel.port import PortHandler
from drivers.dynamixel.read_order import PLAIN_LATE_S, PLAIN_LENGTHS
from drivers.protocol2 import control_table as ct
from drivers.servo_bus import BusClosed, PresentReading, ReadStatus
from tests.drivers.conftest import make_bus
from tests.serial_stub import CannedPort

OK, STALE, ERROR, ALERT = (ReadStatus.OK, ReadStatus.STALE, ReadStatus.ERROR, ReadStatus.ALERT)
MODES = ["fast", "plain"]
_names = itertools.count()


def bus_opener():
    """``open_bus(ids_or_dxlbus=(1, 2, 3, 4), read_mode="fast", **make_bus_kw)`` ->
    ``(DynamixelBus, DxlBus)``; everything is closed and unregistered afterwards."""
    opened: list[tuple[DynamixelBus, str]] = []

    def _open(dx=(1, 2, 3, 4), *, read_mode="fast", ids=None, retries=2, **kw):
        if not isinstance(dx, DxlBus):
            dx = make_bus(dx, **kw)
        name = f"dyn-{next(_names)}"
        bus = DynamixelBus.open(
            register_bus(name, dx),
            baud=dx.baud,
            ids=ids or sorted({s.id for s in dx.servos}),
            read_mode=read_mode,
            retries=retries,
        )
        opened.append((bus, name))
        return bus, dx

    yield _open
    for bus, name in opened:
        bus.close()
        unregister_bus(name)


open_bus = pytest.fixture(bus_opener)


def servo_ticks(dx: DxlBus, addr: int = 132) -> list[int]:
    """What each emulated servo holds at ``addr`` (4 bytes, signed), read device-side."""
    t = dx.clock.now()
    return [int.from_bytes(s.read(addr, 4, t)[1], "little", signed=True) for s in dx.servos]


def canned(bus: DynamixelBus, reply: bytes) -> None:
    bus.link.port.ser = CannedPort(bus.clock, reply)


def pos_bytes(tick: int) -> bytes:
    return tick.to_bytes(4, "little", signed=True)


# ------------------------------------------------------------------ open / close
def test_open_close_context_manager_and_close_twice():
    with DynamixelBus.open(
        "dxlsim://?ids=1-4&rdt_us=0&clock=virtual", baud=1_000_000, ids=[1, 2, 3, 4]
    ) as bus:
        assert not bus.closed and bus.ids == (1, 2, 3, 4) and bus.n == 4
        assert bus.read_present().all_ok
        assert bus.clock.virtual
    assert bus.closed
    bus.close()  # twice: nothing happens
    with pytest.raises(BusClosed):
        bus.read_present()
    with pytest.raises(BusClosed):
        bus.write_goals(np.zeros(4))


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"baud": 1234}, "baud 1234"),
        ({"ids": [1, 1]}, "repeated"),
        ({"ids": []}, "at least one"),
        ({"read_mode": "turbo"}, "turbo"),
    ],
)
def test_open_rejects_bad_arguments(kw, match):
    args = {"baud": 1_000_000, "ids": [1], **kw}
    with pytest.raises(ValueError, match=match):
        DynamixelBus.open("dxlsim://?ids=1&rdt_us=0&clock=virtual", **args)


def test_the_driver_opens_dxlsim_urls_without_importing_the_emulator():
    """port.py names the emulator's package to pyserial; pyserial imports it when a
    ``dxlsim://`` URL is opened. The driver itself never imports ``drivers.dxlsim``."""
    code = (
        "import sys\n"
        "import drivers.dynamixel.bus, drivers.dynamixel.scan, drivers.dynamixel.bench_session\n"
        "assert 'drivers.dxlsim' not in sys.modules, 'imported the emulator'\n"
        "from drivers.dynamixel.link import Link\n"
        "link = Link.open('dxlsim://?ids=1&rdt_us=0&clock=virtual', baud=1_000_000)\n"
        "print(link.ping(1)[0])\n"
        "link.close()\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=False, timeout=60
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "1020"


def test_open_bad_url_is_a_value_error_and_missing_device_is_port_gone():
    with pytest.raises(ValueError, match="unknown key"):
        DynamixelBus.open("dxlsim://?colour=red", baud=1_000_000, ids=[1])
    with pytest.raises(PortGone, match="cannot open"):
        DynamixelBus.open("/dev/ttyDOESNOTEXIST", baud=1_000_000, ids=[1])


def test_auto_read_mode_follows_firmware(open_bus):
    assert open_bus(read_mode="auto")[0].read_mode == "fast"
    assert open_bus(read_mode="auto", firmware=44)[0].read_mode == "plain"  # X430 needs >= 45
    assert open_bus(read_mode="plain")[0].read_mode == "plain"


# ------------------------------------------------------------------ the per-tick path
@pytest.mark.parametrize("mode", MODES)
def test_goals_round_trip_with_motion(open_bus, mode):
    bus, dx = open_bus(read_mode=mode)
    bus.set_torque(True)
    goals = np.array([0.5, -0.5, 0.25, -1.0])
    reading = bus.read_present()
    assert reading.all_ok and np.allclose(reading.positions, 0.0)
    clock, t0 = bus.clock, bus.clock.now()
    distance = [np.abs(reading.positions - goals)]
    for k in range(1, 1501):  # 1.5 s at 1 kHz
        clock.wait_until(t0 + k * 1e-3)
        bus.write_goals(goals)
        bus.read_present(reading)
        assert reading.all_ok
        if k in (10, 30):
            distance.append(np.abs(reading.positions - goals))
    assert all((b < a).all() for a, b in itertools.pairwise(distance))  # approaching
    assert np.allclose(reading.positions, goals, atol=units.RAD_PER_TICK)
    assert servo_ticks(dx, 116) == units.rad_to_ticks(goals).tolist()
    assert reading.t < reading.t_done <= clock.now()
    assert (bus.stats.writes, bus.stats.reads) == (1500, 1501)
    assert bus.stats.status_counts[OK].tolist() == [1501] * 4


def test_fast_and_plain_read_the_same_positions(open_bus):
    fast, dx = open_bus(read_mode="fast")
    plain, _ = open_bus(dx, read_mode="plain")
    fast.set_torque(True)
    fast.write_goals(np.array([0.3, -0.7, 1.2, -2.5]))
    dx.clock.advance(2.0)  # at rest
    a, b = fast.read_present(), plain.read_present()
    assert a.all_ok and b.all_ok
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.positions, units.ticks_to_rad(servo_ticks(dx)))


def test_one_sync_write_and_one_fast_sync_read_per_tick(open_bus):
    bus, dx = open_bus(trace=True)
    n_before = len(dx.trace)
    bus.write_goals(np.array([0.0, 0.1, -0.1, 3.0]))
    bus.read_present()
    tx = [r for r in dx.trace[n_before:] if r.direction == "tx"]
    assert len(tx) == 2
    write, read = tx[0].data, tx[1].data
    assert write[7] == 0x83 and len(write) == 14 + 5 * 4  # Sync Write, 4 bytes each
    assert write[8:12] == bytes([116, 0, 4, 0])
    assert write[12:17] == bytes([1]) + pos_bytes(2048)
    assert write[27:32] == bytes([4]) + pos_bytes(units.rad_to_ticks(3.0))
    assert read[7] == 0x8A and len(read) == 14 + 4  # Fast Sync Read
    rx = [r for r in dx.trace[n_before:] if r.direction == "rx"]
    assert sum(len(r.data) for r in rx) == 8 + 4 * 8  # one packet, four blocks


@pytest.mark.parametrize(
    ("goals", "match"),
    [
        (np.zeros(3), "shaped"),
        (np.array([0.0, math.nan, 0.0, 0.0]), "non-finite goal for servo"),
        (np.array([0.0, 0.0, math.inf, 0.0]), r"servo\(s\) \[3\]"),
        (
            np.array([0.0, 0.0, 0.0, 3.2]),
            "servo 4: \\+3.2000 rad = tick 4134 outside \\[0, 4095\\]",
        ),
        (np.array([0.0, -3.2, 0.0, 0.0]), "servo 2: -3.2000 rad = tick -38 outside"),
    ],
)
def test_write_goals_validates_before_sending(open_bus, goals, match):
    bus, dx = open_bus()
    bus.write_goals(np.full(4, 0.0))
    sent = dx.stats["instructions"]
    with pytest.raises(ValueError, match=match):
        bus.write_goals(goals)
    assert dx.stats["instructions"] == sent  # nothing reached the wire


def test_goal_range_comes_from_the_servos_limits(open_bus):
    bus, _ = open_bus(min_position_limit=1024, max_position_limit=3072)
    bus.write_goals(np.full(4, 3.1))  # default range 0..4095 until check()
    from drivers.dynamixel.startup import Expectation

    bus.check([Expectation(i) for i in bus.ids])
    bus.write_goals(np.full(4, math.pi / 2))
    with pytest.raises(ValueError, match="outside \\[1024, 3072\\]"):
        bus.write_goals(np.full(4, 1.6))


def test_reading_buffers_are_reused_and_checked(open_bus):
    bus, _ = open_bus()
    out = PresentReading.empty(bus.ids)
    assert bus.read_present(out) is out
    kept = out.copy()
    bus.read_present(out)
    assert kept.positions is not out.positions
    with pytest.raises(ValueError, match="reading is for servos"):
        bus.read_present(PresentReading.empty((1, 2)))


# ------------------------------------------------------------------ per-servo status
@pytest.mark.parametrize("mode", MODES)
def test_silent_servo_is_stale_and_moves_to_the_back(open_bus, mode):
    bus, _ = open_bus(read_mode=mode, faults="drop:id=2")
    r = bus.read_present()
    # The chain breaks at servo 2: 3 and 4 waited for it and never answered either.
    assert r.status.tolist() == [OK, STALE, STALE, STALE]
    assert np.isfinite(r.positions[0]) and np.isnan(r.positions[1:]).all()
    if mode == "plain":  # to the back of the chain: the others are read every time after
        assert bus.read_order == (1, 3, 4, 2)
        bus.read_present(r)
        assert r.status.tolist() == [OK, STALE, OK, OK]
        assert np.isnan(r.positions).tolist() == [False, True, False, False]
        assert r.problems() == ["servo 2: STALE, no position"]
        assert bus.stats.consecutive_bad.tolist() == [0, 2, 0, 0]
        bus.read_present(r)
        assert r.status.tolist() == [OK, STALE, OK, OK] and bus.read_order == (1, 3, 4, 2)
        return
    # Fast: missing at a later place it is asked first (a late block of its own, without
    # the header, could otherwise fill its place), missing first it may not be first again
    # for a while (its late reply would start with its header), and where a late block of
    # it could be taken for its reading nothing from it on is: the others miss some reads,
    # never 3 in a row, and never get a wrong value, until its budget ends the show
    assert bus.read_order[0] == 2
    run, read_all = [0, 0, 0], 0
    for _ in range(40):
        bus.clock.advance(0.002)
        bus.read_present(r)
        assert r.status[1] == STALE and np.isnan(r.positions[1])
        for j in (0, 2, 3):
            assert r.status[j] in (OK, STALE)
        run = [n + 1 if r.status[j] == STALE else 0 for n, j in zip(run, (0, 2, 3), strict=True)]
        assert max(run) < 3
        read_all += r.status[[0, 2, 3]].tolist() == [OK, OK, OK]
    assert "servo 2: STALE, no position" in r.problems()
    assert read_all >= 20  # of 40


@pytest.mark.parametrize("mode", MODES)
def test_corrupt_reply_is_stale(open_bus, mode):
    bus, _ = open_bus(read_mode=mode, faults="corrupt:id=2", seed=3)
    others_ok = 0
    r = PresentReading.empty(bus.ids)
    for _ in range(30):
        bus.clock.advance(1e-3)
        bus.read_present(r)
        assert r.status[1] == STALE and math.isnan(r.positions[1])
        if mode == "plain":
            assert r.status[0] == OK  # before the bad reply: never affected
            # its real packet may yet come late (and those its bad one swallowed), never
            # the packet of a servo read before it
            assert all(1 in b and 0 not in b for b in bus._orders.busy_lengths.values())
        others_ok += r.status[[0, 2, 3]].tolist() == [OK, OK, OK]
    # a flipped CRC byte may also cost the next block; Fast asks the servo first after it
    # failed at a later place (its own late block could fill it) and last after it failed
    # first: the others are read every other time
    assert others_ok >= (20 if mode == "plain" else 12)


@pytest.mark.parametrize("mode", MODES)
def test_hardware_error_is_alert_and_names_the_servo(open_bus, mode):
    bus, _ = open_bus(read_mode=mode, faults="hardware_error:id=2,at=0.05,bits=overload")
    bus.set_torque(True)
    bus.clock.advance(0.1)
    r = bus.read_present()
    assert r.status.tolist() == [OK, ALERT, OK, OK]
    assert r.errors.tolist() == [0, 0x80, 0, 0]
    assert np.isfinite(r.positions).all()  # the reading itself is valid
    assert r.problems() == ["servo 2: ALERT (ERR 0x80), position 0.0000 rad"]
    assert bus.hardware_error_status(2) == ct.HardwareError.OVERLOAD
    with pytest.raises(ServoError, match="servo 2: Result Fail") as info:
        bus.set_torque(True)  # overload is in Shutdown: torque stays off until Reboot
    assert info.value.alert


def test_fast_blocks_with_errors(open_bus):
    bus, _ = open_bus()
    canned(
        bus,
        encode_fast_status(
            [
                (0x00, 1, pos_bytes(2048 + 100)),
                (0x04, 2, bytes(4)),
                (0x80, 3, pos_bytes(1000)),
                (0x87, 4, bytes(4)),
            ]
        ),
    )
    r = bus.read_present()
    assert r.status.tolist() == [OK, ERROR, ALERT, ALERT]
    assert r.errors.tolist() == [0, 0x04, 0x80, 0x87]
    assert r.positions[0] == pytest.approx(100 * units.RAD_PER_TICK)
    assert r.positions[2] == pytest.approx(units.ticks_to_rad(1000))
    assert np.isnan(r.positions[[1, 3]]).all()  # an error number means no reading


def test_plain_replies_with_errors(open_bus):
    bus, _ = open_bus(read_mode="plain")
    canned(
        bus,
        encode_status(1, 0, pos_bytes(-5))
        + encode_status(2, 0x07)
        + encode_status(3, 0x80, pos_bytes(4095))
        + encode_status(4, 0, pos_bytes(2048)),
    )
    r = bus.read_present()
    assert r.status.tolist() == [OK, ERROR, ALERT, OK]
    assert r.positions[0] == pytest.approx(units.ticks_to_rad(-5))
    assert np.isnan(r.positions[1]) and r.positions[3] == 0.0


def _fast_reply(ticks=(2100, 2200, 2300, 2400)) -> bytearray:
    return bytearray(encode_fast_status([(0, i + 1, pos_bytes(t)) for i, t in enumerate(ticks)]))


def test_fast_block_crcs_salvage_the_intact_prefix(open_bus):
    bus, _ = open_bus()
    reply = _fast_reply()
    reply[8 + 8 + 3] ^= 0x10  # a data byte of servo 2's block
    canned(bus, bytes(reply))
    r = bus.read_present()
    # Blocks after a bad one are not trusted (they may be another reply spliced in): the
    # servos behind it lose this tick, as behind a silent one.
    assert r.status.tolist() == [OK, STALE, STALE, STALE]
    assert r.positions[0] == pytest.approx(units.ticks_to_rad(2100))
    assert np.isnan(r.positions[1:]).all()


def test_short_fast_reply_keeps_the_blocks_that_arrived(open_bus):
    bus, _ = open_bus()
    canned(bus, bytes(_fast_reply()[: 8 + 2 * 8 + 3]))  # servo 3 stopped mid-block
    r = bus.read_present()
    assert r.status.tolist() == [OK, OK, STALE, STALE]
    assert r.positions[1] == pytest.approx(units.ticks_to_rad(2200))


def test_fast_reply_without_header_is_all_stale(open_bus):
    bus, _ = open_bus()
    canned(bus, b"\x00\x01\x02")
    assert bus.read_present().status.tolist() == [STALE] * 4


def test_plain_corrupt_packet_costs_only_that_servo(open_bus):
    bus, _ = open_bus(read_mode="plain")
    packets = [bytearray(encode_status(i, 0, pos_bytes(2048 + i))) for i in (1, 2, 3, 4)]
    packets[1][10] ^= 0xFF
    canned(bus, b"".join(packets))
    r = bus.read_present()
    assert r.status.tolist() == [OK, STALE, OK, OK]
    assert r.positions[2] == pytest.approx(3 * units.RAD_PER_TICK)


def test_plain_late_packet_of_a_failed_read_is_never_a_later_reading(open_bus):
    """After a plain read that failed, the next reads ask another length: a late status
    packet of the failed read (its length) is passed over where the servo's own reply of
    this read is expected, and the next packets still place; later the length is 4 again."""
    bus, _ = open_bus(read_mode="plain")
    asked = []

    def reply(*packets: tuple[int, int, int]) -> None:  # (id, position, data bytes)
        canned(
            bus, b"".join(encode_status(i, 0, pos_bytes(t) + bytes(n - 4)) for i, t, n in packets)
        )
        write = bus.link.port.ser.write
        bus.link.port.ser.write = lambda data: asked.append(data[10]) or write(data)

    reply((1, 2001, 4))  # servo 2 silent: 2, 3 and 4 unread, 2 asked last from now on
    r = bus.read_present()
    assert r.status.tolist() == [OK, STALE, STALE, STALE] and bus.read_order == (1, 3, 4, 2)
    bus.clock.advance(1e-3)
    # servo 2's late packet of the first read (2002, 4 bytes) comes just before its own
    reply((1, 2011, 5), (3, 2013, 5), (4, 2014, 5), (2, 2002, 4), (2, 2012, 5))
    bus.read_present(r)
    assert r.status.tolist() == [OK, OK, OK, OK]
    assert np.rint(r.positions / units.RAD_PER_TICK).tolist() == [-37, -36, -35, -34]  # 201x
    # one late packet before the first place does not end the read either
    bus.clock.advance(1e-3)
    reply((3, 2003, 4), (1, 2021, 5), (3, 2023, 5), (4, 2024, 5), (2, 2022, 5))
    bus.read_present(r)
    assert r.status.tolist() == [OK, OK, OK, OK] and asked == [4, 5, 5]
    bus.clock.advance(PLAIN_LATE_S)
    reply((1, 2031, 4), (3, 2033, 4), (4, 2034, 4), (2, 2032, 4))
    assert bus.read_present(r).all_ok and asked[-1] == 4


def test_plain_late_error_packet_is_passed_over_where_a_late_one_may_come(open_bus):
    # servo 1 may send a late packet of 4 bytes; an error packet carries no data at all,
    # so its length cannot tell which read it answers (review of b2e6cfc)
    bus, _ = open_bus(read_mode="plain")

    def late_4_bytes(bus) -> None:  # servo 1 (index 0) may send 4 bytes late; nothing else
        bus._orders.busy_lengths.clear()
        bus._orders.busy_lengths[4] = {0: bus.clock.now() + 0.01}
        bus._set_order([0, 1, 2, 3])  # (a STALE servo 1 went last)

    late_4_bytes(bus)
    packets = [encode_status(i, 0, pos_bytes(2000 + i) + b"\0") for i in (1, 2, 3, 4)]
    canned(bus, encode_status(1, 0x01, b"") + b"".join(packets))
    r = bus.read_present()  # late, as its own reply right after it shows
    assert r.status.tolist() == [OK] * 4 and r.errors.tolist() == [0] * 4
    late_4_bytes(bus)
    canned(bus, encode_status(1, 0x01, b"") + b"".join(packets[1:]))
    r = bus.read_present()  # its own? then no reply of servo 1 follows: not a reading either
    assert r.status.tolist() == [STALE, OK, OK, OK] and r.errors.tolist() == [0] * 4
    late_4_bytes(bus)
    canned(bus, packets[0] + encode_status(1, 0x01, b"") + b"".join(packets[1:]))
    assert bus.read_present(r).all_ok  # elsewhere: passed over
    # a servo no late packet is expected of: its error packet is this read's
    late_4_bytes(bus)
    canned(bus, packets[0] + encode_status(2, 0x01, b"") + b"".join(packets[2:]))
    assert bus.read_present(r).status.tolist() == [OK, ERROR, OK, OK]


def test_a_shows_other_read_that_got_no_reply_makes_its_length_busy(open_bus):
    """A watchdog recovery's read-back of Goal Position (4 bytes) that timed out: its late
    reply would pass for a plain read's of servo 2, so servo 2 is busy at 4 bytes."""
    bus, _ = open_bus(read_mode="plain", faults="drop:id=2,at=0.01,count=1")
    bus.clock.advance(0.01)
    with pytest.raises(CommTimeout):
        bus.link.read_item(2, ct.GOAL_POSITION)
    assert set(bus._orders.busy_lengths) == {4} and set(bus._orders.busy_lengths[4]) == {1}
    port, timeouts, asked = bus.link.port, [], []
    set_timeout, write = port.setPacketTimeoutMillis, port.writePort
    port.setPacketTimeoutMillis = lambda ms: timeouts.append(ms) or set_timeout(ms)
    port.writePort = lambda data: asked.append(bytes(data)) or write(data)
    r = bus.read_present()
    assert r.all_ok and asked[-1][10] == 5  # it asked 5 bytes a servo
    # ... and waits the 4 servos' extra byte longer than a read of 4
    assert timeouts[-1] == pytest.approx(bus._plain_timeout_ms + 4 * bus.link.port.tx_time_per_byte)
    bus.link.read_item(2, ct.TORQUE_ENABLE)  # (1 byte: never a plain read's length)
    assert set(bus._orders.busy_lengths) == {4}


def test_a_corrupt_reply_to_a_shows_other_read_counts_too_but_not_on_a_fast_bus(open_bus):
    for mode, busy in (("plain", {4}), ("fast", set())):
        bus, _ = open_bus(read_mode=mode, faults="corrupt:id=3,at=0.01,count=1")
        bus.clock.advance(0.01)
        with pytest.raises(CorruptPacket):
            bus.link.read_item(3, ct.PRESENT_POSITION)
        assert set(bus._orders.busy_lengths) == busy, mode


def test_plain_read_with_every_length_busy_does_not_keep_those_servos_readings(open_bus):
    bus, _ = open_bus(read_mode="plain")
    t = bus.clock.now()
    # servo 2 (index 1) may send a late packet of every length; servo 4 of one more
    bus._orders.busy_lengths.update({n: {1: t + 0.01} for n in PLAIN_LENGTHS})
    bus._orders.busy_lengths[4][3] = t + 0.01
    r = bus.read_present()  # every servo answers, but servo 2's packet may be a late one
    assert r.status.tolist() == [OK, STALE, OK, OK] and np.isnan(r.positions[1])
    assert bus.read_order == (1, 2, 3, 4)  # nobody went missing: the order stays
    bus.clock.advance(0.02)
    assert bus.read_present(r).all_ok


# ------------------------------------------------------------------ wire failures
def test_port_busy_raises_and_later_calls_recover(open_bus):
    bus, _ = open_bus()
    bus.link.port.is_using = True  # e.g. Ctrl-C landed inside the SDK
    with pytest.raises(PortBusy):
        bus.write_goals(np.zeros(4))
    with pytest.raises(PortBusy):
        bus.read_present()
    bus.set_torque(True)  # non-tick calls free the port first
    assert bus.read_present().all_ok


def test_link_transactions_raise_named_exceptions(open_bus):
    bus, dx = open_bus(faults="watchdog_trip:id=1,at=0.05")
    link = bus.link
    assert link.ping(3) == (1020, dx.servos[2].firmware)
    with pytest.raises(CommTimeout, match="servo 9: no reply to Ping") as info:
        link.ping(9)
    assert isinstance(info.value, TimeoutError) and info.value.servo_id == 9
    link.write_item(1, ct.TORQUE_ENABLE, 1)
    bus.clock.advance(0.1)
    with pytest.raises(ServoError, match="Data Range Error") as info:
        link.write_item(1, ct.GOAL_POSITION, 1000)  # goals refused while tripped
    assert (info.value.servo_id, info.value.number) == (1, 4)


def test_unplug_is_port_gone_and_close_neither_raises_nor_hangs(open_bus):
    bus, _ = open_bus(faults="unplug:at=0.5")
    bus.read_present()
    bus.clock.advance(1.0)
    with pytest.raises(PortGone) as info:
        bus.read_present()
    assert isinstance(info.value.__cause__, serial.SerialException)
    with pytest.raises(PortGone):
        bus.write_goals(np.zeros(4))
    t = bus.clock.now()
    with pytest.raises(ExitNotConfirmed) as info:
        bus.apply_exit_policy("relax")
    assert info.value.servo_ids == (1, 2, 3, 4)
    assert isinstance(info.value.__cause__, PortGone)
    assert "adapter gone" in str(info.value)
    assert bus.clock.now() - t < 1e-3  # no timeouts waited
    bus.close()
    bus.close()


def test_set_torque_tries_every_servo_and_notes_the_others(open_bus):
    bus, dx = open_bus(faults="drop:id=2|3")
    with pytest.raises(CommTimeout, match="servo 2") as info:
        bus.set_torque(True)
    assert any("servo 3" in note for note in info.value.__notes__)
    # Every servo was asked (the writes arrived; only the replies of 2 and 3 were lost).
    assert [s.torque_enabled for s in dx.servos] == [True] * 4


# ------------------------------------------------------------------ watchdog
def test_watchdog_arms_trips_and_disarms(open_bus):
    bus, dx = open_bus()
    bus.set_torque(True)
    bus.arm_watchdog(0.1)
    assert [s.read(98, 1, dx.clock.now())[1] for s in dx.servos] == [b"\x05"] * 4
    dx.clock.advance(0.15)  # the host goes quiet
    assert [bus.link.read_item(i, ct.BUS_WATCHDOG) for i in bus.ids] == [-1] * 4
    bus.disarm_watchdog()
    assert [bus.link.read_item(i, ct.BUS_WATCHDOG) for i in bus.ids] == [0] * 4
    with pytest.raises(ValueError, match=r"0\.02\.\.2\.54"):
        bus.arm_watchdog(3.0)
    with pytest.raises(ValueError, match="> 0"):
        bus.arm_watchdog(0.0)


# ------------------------------------------------------------------ latency timer
def test_emulated_latency_sets_the_packet_timeout():
    url = "dxlsim://?ids=1&rdt_us=0&latency_ms=1&clock=virtual"
    with DynamixelBus.open(url, baud=1_000_000, ids=[1]) as bus:
        assert bus.link.latency_timer_ms == 1.0
    with DynamixelBus.open(url, baud=1_000_000, ids=[1], latency_timer_ms=4.0) as bus:
        assert bus.link.latency_timer_ms == 4.0  # an explicit value wins


class _FakeSerial:
    def __init__(self, low_latency_ok: bool) -> None:
        self.ok, self.calls = low_latency_ok, []

    def set_low_latency_mode(self, on: bool) -> None:
        self.calls.append(on)
        if not self.ok:
            raise ValueError("Failed to update ASYNC_LOW_LATENCY flag")


def _sysfs(tmp_path: Path, value: str) -> Path:
    (tmp_path / "ttyUSB0").mkdir()
    (tmp_path / "ttyUSB0" / "latency_timer").write_text(value + "\n")
    return tmp_path


def test_latency_timer_is_lowered_when_permitted(tmp_path):
    sysfs = _sysfs(tmp_path, "16")
    ser = _FakeSerial(low_latency_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert tune_latency_timer(ser, "/dev/ttyUSB0", sysfs) == 1.0
    assert ser.calls == [True]
    assert (sysfs / "ttyUSB0" / "latency_timer").read_text().strip() == "1"


def test_latency_timer_stuck_high_warns_with_the_fix(tmp_path, monkeypatch):
    sysfs = _sysfs(tmp_path, "16")

    def refuse(self, *a, **k):
        raise PermissionError("Permission denied")

    monkeypatch.setattr(Path, "write_text", refuse)
    with pytest.warns(LatencyTimerWarning) as record:
        assert tune_latency_timer(_FakeSerial(False), "/dev/ttyUSB0", sysfs) == 16.0
    text = str(record[0].message)
    assert "echo 1 | sudo tee /sys/bus/usb-serial/devices/ttyUSB0/latency_timer" in text
    assert 'ATTR{latency_timer}="1"' in text


def test_devices_without_a_latency_timer_keep_the_sdk_allowance(tmp_path):
    # The adapter latency (what the capacity check counts) and the timeout allowance are
    # two facts: a pty has ~1 ms of latency but its server may be descheduled, so its
    # timeouts keep the SDK's 2 x 16 ms however low the latency is.
    assert tune_latency_timer(_FakeSerial(True), "/dev/pts/3", tmp_path) == PTY_LATENCY_MS
    assert tune_latency_timer(_FakeSerial(True), "COM3", tmp_path) == 16.0
    for dev in ("/dev/pts/3", "COM3", "/dev/ttyACM0"):
        assert device_allowance_ms(_FakeSerial(True), dev, tmp_path) == 32.0
    assert device_allowance_ms(_FakeSerial(True), "/dev/ttyUSB0", _sysfs(tmp_path, "1")) == 0.0


def test_timeout_margin_tops_the_latency_up_to_the_device_allowance():
    port = PortHandler("unused", latency_timer_ms=1.0, device_allowance_ms=32.0)
    port.tx_time_per_byte = 0.01
    assert port.timeout_margin_ms == 30.0
    port.setPacketTimeout(10)
    assert port.packet_timeout == pytest.approx(0.1 + 2 * 1.0 + 2.0 + 30.0)  # = SDK stock
    port.latency_timer_ms = 16.0
    assert port.timeout_margin_ms == 0.0
    assert PortHandler("unused", latency_timer_ms=1.0).timeout_margin_ms == 0.0


def test_tick_read_timeouts_follow_the_device_margin():
    url = "dxlsim://?ids=1-4&rdt_us=0&latency_ms=1&clock=virtual"
    with DynamixelBus.open(url, baud=1_000_000, ids=[1, 2, 3, 4], read_mode="fast") as bus:
        assert bus.link.timeout_margin_ms == 0.0  # the emulator in-process: its model is exact
        fast = bus._fast_timeout_ms
        assert fast == pytest.approx(0.6 + 2.0 + 2.0 + 0.5 + 0.05)  # + factory RDT until check
        bus.link.port.device_allowance_ms = 32.0  # as on a pty
        bus._update_timeouts()
        assert bus._fast_timeout_ms == pytest.approx(fast + 30.0)
