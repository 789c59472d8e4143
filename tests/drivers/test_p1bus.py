"""dxlsim's Protocol 1.0-framed bus, byte for byte and in time: AX/MX (P1) and Feetech STS/SCS.

In process on the virtual clock: every packet is built with :mod:`drivers.protocol1.packet`
and every reply split with it; times are exact sums of the wire model.
"""

from __future__ import annotations

import math

import pytest

from drivers.clock import VirtualClock
from drivers.dxlsim.p1bus import P1Bus
from drivers.dxlsim.p1servo import P1Servo
from drivers.dxlsim.url import DxlsimUrl
from drivers.protocol1 import packet as p1
from drivers.protocol1.control_table import DxlP1Error
from drivers.protocol1.wire_time import (
    cycle_time_s,
    status_bytes,
    sync_read_time_s,
    sync_write_bytes,
    wire_time_s,
)

BAUD = 1_000_000
TURN = 20e-6


def make(model: str, ids: range | list[int], *, rdt_us: float = 0.0, **kw: object) -> P1Bus:
    clock = VirtualClock()
    servos = [P1Servo(model, i, return_delay_us=rdt_us, t=clock.now()) for i in ids]
    return P1Bus(servos, baud=BAUD, clock=clock, **kw)


def txrx(bus: P1Bus, packet: bytes, wait: float = 0.01) -> bytes:
    bus.write(packet)
    bus.clock.advance(wait)  # type: ignore[attr-defined]
    return bus.read(100_000)


def test_status_packets_byte_for_byte() -> None:
    bus = make("STS3215", [1])
    assert txrx(bus, p1.ping(1)) == bytes.fromhex("FF FF 01 02 00 FC")
    # Model Number 777 = 0x0309, little endian at address 3
    assert txrx(bus, p1.read(1, 3, 2)) == bytes.fromhex("FF FF 01 04 00 09 03 EE")
    ax = make("AX-12A", [1])
    assert txrx(ax, p1.read(1, 0, 2)) == p1.encode_status(1, 0, b"\x0c\x00")  # model 12
    scs = make("SCS0009", [1])
    assert txrx(scs, p1.read(1, 3, 2)) == p1.encode_status(1, 0, b"\x05\x04")  # 1284, big end


def test_sts_sync_read_of_12_takes_the_wire_model_time() -> None:
    bus = make("STS3215", range(1, 13))
    t0 = bus.clock.now()
    bus.write(p1.sync_read(56, 2, range(1, 13)))
    last = bus.visible_at(12 * status_bytes(2))
    assert last is not None
    assert last - t0 == pytest.approx(sync_read_time_s(12, BAUD, turnaround_s=TURN), abs=1e-12)
    assert bus.visible_at(12 * status_bytes(2) + 1) is None  # nothing more comes
    bus.clock.advance(0.01)
    replies = p1.split_status_stream(bus.read(1000))
    assert [r.id for r in replies] == list(range(1, 13))  # one packet each, in the packet's order
    assert all(r.code == 0 and r.params == (2048).to_bytes(2, "little") for r in replies)


def test_sts_cycle_is_the_wire_model() -> None:
    """Sync Write of goals then Sync Read: 1.60 ms of bytes at 1 Mbit/s + 12 turnarounds."""
    bus = make("STS3215", range(1, 13))
    t0 = bus.clock.now()
    end_write = bus.write(p1.sync_write(42, 2, {i: b"\x00\x08" for i in range(1, 13)}))
    assert end_write - t0 == pytest.approx(wire_time_s(sync_write_bytes(12), BAUD))
    bus.write(p1.sync_read(56, 2, range(1, 13)))
    last = bus.visible_at(12 * 8)
    assert last is not None
    model = cycle_time_s(12, BAUD, "sync_read", turnaround_s=TURN)
    assert last - t0 == pytest.approx(model, abs=1e-12)
    assert model == pytest.approx(1.60e-3 + 12 * TURN)


def test_mx_bulk_read_chain_and_timing() -> None:
    bus = make("MX-28", [1, 2, 3])
    t0 = bus.clock.now()
    bus.write(p1.bulk_read([(3, 36, 2), (1, 43, 1), (2, 0, 2)]))
    last = bus.visible_at(8 + 7 + 8)
    assert last is not None
    assert last - t0 == pytest.approx(wire_time_s(7 + 9 + 23, BAUD) + 3 * TURN)
    bus.clock.advance(0.01)
    replies = p1.split_status_stream(bus.read(1000))
    assert [(r.id, r.params) for r in replies] == [
        (3, (2048).to_bytes(2, "little")),
        (1, bytes((30,))),
        (2, (29).to_bytes(2, "little")),
    ]
    ax = make("AX-12A", [1, 2])  # AX answers no Bulk Read; STS no Bulk Read either
    assert txrx(ax, p1.bulk_read([(1, 36, 2)])) == b""
    assert txrx(make("STS3215", [1]), p1.bulk_read([(1, 56, 2)])) == b""
    assert txrx(make("SCS0009", [1]), p1.sync_read(56, 2, [1])) == b""  # SCS: no Sync Read


def test_return_delay_in_2us_units() -> None:
    bus = make("AX-12A", [1], rdt_us=500)
    t0 = bus.clock.now()
    bus.write(p1.ping(1))
    first = bus.visible_at(1)
    assert first == pytest.approx(t0 + wire_time_s(6, BAUD) + 500e-6 + TURN + wire_time_s(1, BAUD))
    bus.clock.advance(0.01)
    bus.read(100)
    assert txrx(bus, p1.write(1, 5, b"\x00"))  # Return Delay Time := 0 (answered)
    t1 = bus.clock.now()
    bus.write(p1.ping(1))
    assert bus.visible_at(6) == pytest.approx(t1 + wire_time_s(12, BAUD) + TURN)


def test_status_return_level_per_family() -> None:
    ax = make("AX-12A", [1])
    txrx(ax, p1.write(1, 16, b"\x01"))  # level 1: PING and READ only
    assert txrx(ax, p1.write(1, 25, b"\x01")) == b""
    assert txrx(ax, p1.read(1, 25, 1)) == p1.encode_status(1, 0, b"\x01")
    txrx(ax, p1.write(1, 16, b"\x00"))  # level 0: PING only
    assert txrx(ax, p1.read(1, 25, 1)) == b""
    assert txrx(ax, p1.ping(1)) == p1.encode_status(1, 0)
    sts = make("STS3215", [1])
    txrx(sts, p1.write(1, 8, b"\x00"))  # Feetech level 0: READ and PING only
    assert txrx(sts, p1.write(1, 40, b"\x01")) == b""
    assert txrx(sts, p1.read(1, 40, 1)) == p1.encode_status(1, 0, b"\x01")


def test_dynamixel_range_and_angle_limit_errors() -> None:
    ax = make("AX-12A", [1])
    reply = p1.decode(txrx(ax, p1.write(1, 30, (1024).to_bytes(2, "little"))))
    assert reply.code == DxlP1Error.RANGE
    assert p1.decode(txrx(ax, p1.write(1, 36, b"\x00\x00"))).code == DxlP1Error.RANGE  # R only
    txrx(ax, p1.write(1, 6, (100).to_bytes(2, "little")))  # CW Angle Limit 100
    reply = p1.decode(txrx(ax, p1.write(1, 30, (50).to_bytes(2, "little"))))
    assert reply.code == DxlP1Error.ANGLE_LIMIT
    assert p1.decode(txrx(ax, p1.encode_instruction(1, 0x7F))).code == DxlP1Error.INSTRUCTION
    sts = make("STS3215", [1])
    assert txrx(sts, p1.encode_instruction(1, 0x7F)) == b""  # Feetech: silent


def test_checksum_errors_per_family() -> None:
    bad = bytearray(p1.write(1, 25, b"\x01"))
    bad[-1] ^= 0x55
    ax = make("AX-12A", [1])
    assert p1.decode(txrx(ax, bytes(bad))).code == DxlP1Error.CHECKSUM
    assert ax.servo(1).raw("LED") == 0  # never executed
    sts = make("STS3215", [1])
    assert txrx(sts, bytes(bad)) == b""


def test_feetech_lock_keeps_eeprom_writes_only_when_unlocked() -> None:
    bus = make("STS3215", [1])
    s = bus.servo(1)
    assert s.raw("Lock") == 1  # power-up
    txrx(bus, p1.write(1, 9, (100).to_bytes(2, "little")))  # Min Position Limit, locked
    assert s.raw("Min Position Limit") == 100  # in effect...
    s.brownout(bus.clock.now())
    assert s.raw("Min Position Limit") == 0  # ...but not kept over a power cycle
    txrx(bus, p1.write(1, 55, b"\x00"))  # unlock
    txrx(bus, p1.write(1, 9, (100).to_bytes(2, "little")))
    s.brownout(bus.clock.now())
    assert s.raw("Min Position Limit") == 100 and s.raw("Lock") == 1


def test_dynamixel_lock_refuses_eeprom_until_power_off() -> None:
    bus = make("AX-12A", [1])
    s = bus.servo(1)
    txrx(bus, p1.write(1, 47, b"\x01"))
    txrx(bus, p1.write(1, 6, (10).to_bytes(2, "little")))
    assert s.raw("CW Angle Limit") == 0
    txrx(bus, p1.write(1, 47, b"\x00"))  # only a power cycle clears it
    assert s.raw("Lock") == 1
    s.brownout(bus.clock.now())
    assert s.raw("Lock") == 0
    txrx(bus, p1.write(1, 6, (10).to_bytes(2, "little")))
    assert s.raw("CW Angle Limit") == 10


def test_reg_write_action_and_broadcast_ping() -> None:
    bus = make("STS3215", [1, 2])
    txrx(bus, p1.encode_instruction(1, p1.Inst.REG_WRITE, bytes((40, 1))))
    assert bus.servo(1).raw("Torque Enable") == 0
    assert txrx(bus, p1.encode_instruction(p1.BROADCAST_ID, p1.Inst.ACTION)) == b""
    assert bus.servo(1).raw("Torque Enable") == 1
    pings = p1.split_status_stream(txrx(bus, p1.ping(p1.BROADCAST_ID)))
    assert [r.id for r in pings] == [1, 2]
    assert txrx(make("AX-12A", [1]), p1.ping(p1.BROADCAST_ID)) == b""  # P1: no broadcast ping


def test_ax_moving_speed_sets_the_move_time() -> None:
    bus = make("AX-12A", [1])
    s = bus.servo(1)
    txrx(bus, p1.write(1, 32, (300).to_bytes(2, "little")))  # 300 x 0.111 rpm = 33.3 rpm
    txrx(bus, p1.write(1, 24, b"\x01"))
    t0 = bus.clock.now()
    bus.write(p1.write(1, 30, (512 + 409).to_bytes(2, "little")))  # 409 steps ~ 120 deg
    steps_per_s = 300 * 0.111 / 60 * 1024 * 360 / 300
    expect = 409 / steps_per_s
    bus.clock.advance(expect * 0.9)
    s.touch(bus.clock.now())
    assert s.raw("Moving") == 1 and s.raw("Present Position") < 921
    bus.clock.advance(expect * 0.1 + 0.01)
    s.touch(bus.clock.now())
    assert s.raw("Present Position") == 921 and s.raw("Moving") == 0
    assert bus.clock.now() - t0 == pytest.approx(expect + 0.01, abs=2e-3)


def test_sts_acceleration_and_goal_speed() -> None:
    """A 1000-step move at 2400 step/s with Acceleration 50 (5000 step/s²): the triangle
    never reaches 2400 (it would need 576 steps each way): 2·sqrt(1000/5000) = 0.894 s."""
    bus = make("STS3215", [1])
    s = bus.servo(1)
    txrx(bus, p1.write(1, 41, bytes((50,))))
    txrx(bus, p1.write(1, 46, (2400).to_bytes(2, "little")))
    bus.write(p1.write(1, 42, (3048).to_bytes(2, "little")))  # a goal turns torque on
    t_move = 2 * math.sqrt(1000 / 5000)
    bus.clock.advance(t_move - 0.02)
    s.touch(bus.clock.now())
    assert 3000 < s.raw("Present Position") < 3048 and s.raw("Torque Enable") == 1
    speed = s.value("Present Speed")
    assert 0 < speed < 2400
    bus.clock.advance(0.04)
    s.touch(bus.clock.now())
    assert s.raw("Present Position") == 3048 and s.value("Present Speed") == 0


def test_sign_magnitude_on_the_wire() -> None:
    bus = make("STS3215", [1])
    txrx(bus, p1.write(1, 55, b"\x00"))
    txrx(bus, p1.write(1, 31, (0x0800 | 48).to_bytes(2, "little")))  # Homing Offset -48
    reply = p1.decode(txrx(bus, p1.read(1, 56, 2)))
    assert int.from_bytes(reply.params, "little") == 2048 + 48
    txrx(bus, p1.write(1, 31, (100).to_bytes(2, "little")))  # +100: reads 1948
    txrx(bus, p1.write(1, 40, b"\x01"))
    # a move towards lower positions reads a negative Present Speed: bit 15 set
    txrx(bus, p1.write(1, 42, (948).to_bytes(2, "little")), 0.05)
    raw = int.from_bytes(p1.decode(txrx(bus, p1.read(1, 58, 2), 0.001)).params, "little")
    assert raw & 0x8000 and 0 < raw & 0x7FFF <= 3072


def test_faults_on_a_feetech_bus() -> None:
    bus = make("STS3215", range(1, 5), faults="drop:id=2,count=1;corrupt:id=3,count=1")
    data = txrx(bus, p1.sync_read(56, 2, range(1, 5)))
    assert [r.id for r in p1.split_status_stream(data)] == [1]  # a silent servo stops the chain
    data = txrx(bus, p1.sync_read(56, 2, range(1, 5)))
    parser = p1.StreamParser()
    assert [None if f is None else f.id for f in parser.feed(data)] == [1, 2, None, 4]
    bus = make("STS3215", [1, 2], faults="torque_off:id=2,at=0.5;hardware_error:id=1,at=0.5,bits=4")
    txrx(bus, p1.write(1, 40, b"\x01"))
    txrx(bus, p1.write(2, 40, b"\x01"))
    bus.clock.advance(1.0)  # type: ignore[attr-defined]
    assert p1.decode(txrx(bus, p1.read(2, 40, 1))).params == b"\x00"
    reply = p1.decode(txrx(bus, p1.read(1, 63, 1)))
    assert reply.code & 4 and reply.params[0] > 70  # overheating: status bit, temperature


def test_one_protocol_per_bus_and_no_watchdog() -> None:
    with pytest.raises(ValueError, match="one protocol per bus"):
        DxlsimUrl.parse("dxlsim://?ids=1-2&model=STS3215,2:AX-12A")
    with pytest.raises(ValueError, match="one protocol per bus"):
        DxlsimUrl.parse("dxlsim://?ids=1-2&model=XM430-W350,2:AX-12A")
    with pytest.raises(ValueError, match="no Bus Watchdog"):
        DxlsimUrl.parse("dxlsim://?ids=1&model=STS3215&faults=watchdog_trip:id=1,at=1").build_bus()
    bus = DxlsimUrl.parse("dxlsim://?ids=1-6&model=sts3215&clock=virtual").build_bus()
    assert isinstance(bus, P1Bus) and [s.id for s in bus.servos] == [1, 2, 3, 4, 5, 6]
    assert str(DxlsimUrl.parse("dxlsim://?ids=1-3&model=ax-12a,3:AX-18A")) == (
        "dxlsim://?ids=1-3&model=AX-12A,3:AX-18A"
    )


@pytest.mark.parametrize(
    "plan",
    [
        "late:id=1,delay=0.05,count=1",
        "truncate:id=1,count=1",
        "garbage:id=1,nbytes=3,count=1",
        "brownout:id=1,at=0.001,duration=0.005",
        "duplicate_id:id=1,at=0.001",
        "unplug:at=0.001",
    ],
)
def test_every_fault_kind_runs_on_a_p1_bus(plan: str) -> None:
    """The X-series fault machinery, unchanged, on a Feetech bus: each kind leaves the host
    a reply it can tell from a good one (or none), and a later read is good again."""
    import serial

    url = f"dxlsim://?ids=1-2&model=STS3215&clock=virtual&faults={plan}"
    port = serial.serial_for_url(url, baudrate=BAUD)
    try:
        bus = port.bus
        bus.clock.advance(0.01)
        if plan.startswith("unplug"):
            with pytest.raises(serial.SerialException):
                port.write(p1.ping(1))
            return
        port.write(p1.read(1, 56, 2))
        bus.clock.advance(0.02)
        first = port.read(port.in_waiting)
        good = p1.encode_status(1, 0, (2048).to_bytes(2, "little"))
        if plan.startswith("duplicate"):
            assert first == good  # twins with the same state: the merged reply is theirs
        elif plan.startswith("brownout"):
            assert first == good  # back at power-up values
        else:
            assert first != good
        port.reset_input_buffer()
        port.write(p1.read(2, 56, 2))
        bus.clock.advance(0.02)
        assert port.read(port.in_waiting) == p1.encode_status(2, 0, (2048).to_bytes(2, "little"))
    finally:
        port.close()


def test_feetech_status_register_reports_latched_errors() -> None:
    bus = make("STS3215", [1], faults="hardware_error:id=1,at=0.001,bits=32")
    bus.clock.advance(0.01)  # type: ignore[attr-defined]
    reply = p1.decode(txrx(bus, p1.read(1, 65, 1)))
    assert reply.code == 32 and reply.params == bytes((32,))


def test_baud_rate_values_and_the_hosts_rate() -> None:
    """Dynamixel Baud Rate 34 runs at 57 142.9 bps, the e-Manual's value for 57 600: a host at
    57 600 is heard. Feetech value 4 is 115 200. A URL without baud takes the host's rate, or
    the factory rate when the model has no value for it."""
    bus = make("MX-28", [1])
    txrx(bus, p1.write(1, 4, bytes((34,))))
    bus.baud = 57_600
    assert txrx(bus, p1.ping(1)) == p1.encode_status(1, 0)
    sts = make("STS3215", [1])
    txrx(sts, p1.write(1, 6, bytes((4,))))
    assert sts.servo(1).baud == 115_200
    url = DxlsimUrl.parse("dxlsim://?ids=1&model=STS3215")
    assert url.build_bus(9600).servos[0].baud == 1_000_000  # no Feetech value for 9600
    assert url.build_bus(500_000).servos[0].baud == 500_000


def test_a_limit_written_between_sync_writes_of_goals_governs_the_next_move() -> None:
    """The emulator keeps a move's limits over Sync Writes of goals alone; a write of Goal
    Speed or a Position Limit in between is used by the next goal, servo by servo."""
    bus = make("STS3215", [1, 2])
    s1, s2 = bus.servo(1), bus.servo(2)

    def goals(tick: int) -> bytes:
        return p1.sync_write(42, 2, {1: tick.to_bytes(2, "little"), 2: tick.to_bytes(2, "little")})

    txrx(bus, goals(3000), wait=1.0)
    for _ in range(3):  # the same goals again: nothing changes
        txrx(bus, goals(3000), wait=0.01)
    assert s1.raw("Present Position") == s2.raw("Present Position") == 3000
    txrx(bus, p1.write(1, 11, (2500).to_bytes(2, "little")))  # Max Position Limit
    txrx(bus, p1.write(1, 46, (500).to_bytes(2, "little")))  # Goal Speed 500 step/s
    bus.write(goals(3500))
    bus.clock.advance(0.5)  # type: ignore[attr-defined]
    s1.touch(bus.clock.now())
    s2.touch(bus.clock.now())
    assert 2650 <= s1.raw("Present Position") <= 2800  # down to its limit at ~500 step/s
    assert s2.raw("Present Position") == 3500  # the other at full speed, long there
    bus.clock.advance(0.6)  # type: ignore[attr-defined]
    s1.touch(bus.clock.now())
    assert s1.raw("Present Position") == 2500 and s1.raw("Moving") == 0
