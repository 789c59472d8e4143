"""P1ServoBus, the host side of Feetech STS/SCS and Dynamixel AX/MX (Protocol 1.0), on the
P1 stub bus (tests/p1_stub.py) and the virtual clock: the tick's packets, each reply checked
on its own, the rotation's rate, the start-up table, the exit policy, EEPROM writes."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.dxlsim import register_bus, unregister_bus
from drivers.dynamixel.errors import ExitNotConfirmed, StartupMismatch
from drivers.p1bus import table
from drivers.p1bus.bus import P1ServoBus
from drivers.p1bus.health import write_eeprom
from drivers.p1bus.link import _whole_chain, encode
from drivers.p1bus.startup import P1Expectation
from drivers.protocol1 import packet
from drivers.protocol1.control_table import TABLES
from drivers.servo_bus import PresentReading, ReadStatus
from tests.p1_stub import P1StubBus

OK, STALE, ERROR, ALERT, UNREAD = (int(s) for s in ReadStatus)
_names = itertools.count()


@pytest.fixture
def p1():
    """``p1(models={id: model})`` -> (P1ServoBus, P1StubBus), checked against the servos."""
    opened: list[tuple[P1ServoBus, str]] = []

    def make(models: dict[int, str], *, check: bool = True, period_s: float = 0.004):
        stub = P1StubBus(models)
        name = f"p1-{next(_names)}"
        bus = P1ServoBus.open(
            register_bus(name, stub), baud=1_000_000, ids=list(models), models=list(models.values())
        )
        opened.append((bus, name))
        bus.plan(period_s)
        if check:
            bus.check(expect(models))
        return bus, stub

    yield make
    for bus, name in opened:
        bus.close()
        unregister_bus(name)


def expect(models: dict[int, str], **kw) -> list[P1Expectation]:
    kw.setdefault("position_range_rad", (-1.0, 1.0))
    kw.setdefault("return_delay_us_max", 100.0)
    return [P1Expectation(sid, m, **kw) for sid, m in models.items()]


STS6 = {i: "STS3215" for i in range(1, 7)}


def test_the_host_table_agrees_with_the_shared_control_tables():
    """Every register the host uses is the shared table's item: address, size, sign bit, order."""
    fields = [
        f for f in table.Family.__dataclass_fields__ if isinstance(getattr(table.STS, f), table.Reg)
    ]
    for model, tab in TABLES.items():
        fam = table.family_of(model)
        assert fam is not None and fam.models[model] == tab.model_number
        assert fam.big_endian == tab.family.big_endian
        assert (fam.read is table.ReadMethod.SYNC) == tab.family.sync_read
        assert (fam.read is table.ReadMethod.BULK) == tab.family.bulk_read
        assert fam.status_return_all == tab.family.srl_all
        assert fam.baud_codes == tab.family.baud_rates
        assert fam.ticks_per_turn == pytest.approx(tab.resolution * 360 / tab.range_deg)
        for f in fields:
            reg = getattr(fam, f)
            if reg is None:
                continue
            (item,) = [i for i in tab.items if i.addr == reg.addr]
            assert (item.size, item.sign_bit) == (reg.size, reg.sign_bit), (model, f)


def test_sync_read_is_one_request_and_each_reply_is_checked_on_its_own(p1):
    bus, stub = p1(STS6)
    stub.servos[2].set("Present Position", 2048 + 100)
    stub.servos[3].corrupt = 1
    stub.servos[5].silent = True
    since = len(stub.sent)
    r = bus.read_present()
    assert r.status.tolist() == [OK, OK, STALE, OK, STALE, OK]
    assert math.isnan(r.positions[2]) and math.isnan(r.positions[4])
    assert r.positions[1] == pytest.approx(100 * 2 * math.pi / 4096)
    assert r.positions[0] == 0.0
    (req,) = stub.instructions(since)
    assert req.encode() == packet.sync_read(56, 2, range(1, 7))
    assert bus.corrupt_sample is not None
    stub.servos[5].silent = False
    assert bus.read_present(r).status.tolist() == [OK] * 6  # the next tick reads all again


def test_sync_read_request_is_the_reference_vector(p1):
    bus, stub = p1({1: "STS3215", 2: "STS3215"})
    since = len(stub.sent)
    bus.read_present()
    assert len(stub.sent) == since + 1
    assert stub.sent[-1][1] == bytes.fromhex("FF FF FE 06 82 38 02 01 02 3C")


def test_goals_are_one_sync_write_in_each_familys_encoding(p1):
    bus, stub = p1({1: "STS3215", 2: "STS3215"})
    bus.set_torque(True)
    since = len(stub.sent)
    bus.write_goals(np.array([0.5, -0.25]))
    (sw,) = stub.instructions(since)
    addr, data = packet.parse_sync_write(sw.params)
    assert sw.code == packet.Inst.SYNC_WRITE and addr == 42
    t1, t2 = round(0.5 * 4096 / (2 * math.pi)) + 2048, round(-0.25 * 4096 / (2 * math.pi)) + 2048
    assert data == {1: t1.to_bytes(2, "little"), 2: t2.to_bytes(2, "little")}
    scs, sstub = p1({4: "SCS0009"})
    scs.set_torque(True)
    since = len(sstub.sent)
    scs.write_goals(np.array([0.1]))
    (sw,) = sstub.instructions(since)
    tick = round(0.1 * 1024 * 360 / 300 / (2 * math.pi)) + 512
    assert packet.parse_sync_write(sw.params)[1] == {4: tick.to_bytes(2, "big")}  # big-endian
    sstub.servos[4].set("Present Position", 700)
    assert scs.read_present().positions[0] == pytest.approx(188 / (1024 * 360 / 300) * 2 * math.pi)


def test_a_goal_beyond_the_angle_limits_is_refused_before_the_wire(p1):
    bus, stub = p1({1: "AX-12A"}, period_s=0.01)
    stub.sent.clear()
    with pytest.raises(ValueError, match=r"servo 1: tick .* not in 0\.\.1023"):
        bus.write_goals(np.array([math.radians(160)]))  # AX: 300 degrees, +-150
    assert stub.sent == []


def test_error_bits_a_hardware_bit_is_alert_with_its_reading_an_instruction_bit_error(p1):
    bus, stub = p1({1: "STS3215", 2: "STS3215"})
    stub.servos[1].err = 0x04  # overheating: the reading is still the servo's position
    r = bus.read_present()
    assert r.status.tolist() == [ALERT, OK] and r.positions[0] == 0.0 and r.errors[0] == 4
    ax, astub = p1({1: "AX-12A"}, period_s=0.01)
    astub.servos[1].err = 0x40  # instruction error: the data is no answer
    r = ax.read_present()
    assert r.status.tolist() == [ERROR] and math.isnan(r.positions[0])


def test_mx_reads_by_one_bulk_read(p1):
    models = {i: "MX-28" for i in (3, 4, 7)}
    bus, stub = p1(models)
    assert bus.read_mode is table.ReadMethod.BULK
    since = len(stub.sent)
    assert bus.read_present().status.tolist() == [OK] * 3
    (req,) = stub.instructions(since)
    assert req.encode() == packet.bulk_read([(i, 36, 2) for i in (3, 4, 7)])


def test_ax_reads_in_rotation_each_servo_at_the_rate_it_states(p1):
    models = {i: "AX-12A" for i in range(1, 13)}
    bus, _ = p1(models, period_s=0.01)
    assert bus.read_mode is table.ReadMethod.ROTATION
    k = bus.per_tick
    assert 1 <= k < 12
    reads = np.zeros(12)
    reading = PresentReading.empty(bus.ids)
    ticks = 12 * 10
    for _ in range(ticks):
        bus.read_present(reading)
        reads += reading.status == OK
        assert set(reading.status.tolist()) <= {OK, UNREAD}
        assert (reading.status == OK).sum() == k
        assert np.isnan(reading.positions[reading.status == UNREAD]).all()
    rate = bus.read_rate_hz(100.0)
    assert reads / (ticks / 100.0) == pytest.approx(np.full(12, rate), rel=0.1)
    assert bus.stats.consecutive_bad.tolist() == [0] * 12  # not asked is no failure


def test_startup_check_names_every_difference_in_one_table(p1):
    models = {1: "STS3215", 2: "STS3215", 3: "STS3215", 4: "STS3215"}
    bus, stub = p1(models, check=False)
    stub.servos[1].set("Return Delay Time", 250)
    stub.servos[1].set("Response Status Level", 0)
    stub.servos[2].set("Phase", 0x1C)
    stub.servos[3].set("Model Number", 1284)
    stub.servos[4].silent = True
    with pytest.raises(StartupMismatch) as info:
        bus.check(expect({**models, 3: "ST3215"}))  # (another name of the STS3215)
    rows = {(r.servo_id, r.item) for r in info.value.rows}
    assert rows == {
        (1, "Return Delay Time"),
        (1, "Response Status Level"),
        (2, "Phase"),
        (3, "model"),
        (4, "answers Ping"),
    }
    text = str(info.value)
    assert "SCS0009 (Feetech SCS)" in text and "Lock, addr 55 := 0" in text
    assert not [p for p in stub.instructions() if p.code in (packet.Inst.WRITE, 0x83)]  # read-only


def test_startup_check_says_there_is_no_bus_watchdog(p1):
    bus, _ = p1(STS6, check=False)
    report = bus.check(expect(STS6))
    assert bus.has_watchdog is False
    assert any("no Bus Watchdog" in n for n in report.notes)


def test_arming_a_watchdog_writes_nothing(p1):
    bus, stub = p1(STS6)
    stub.sent.clear()
    bus.arm_watchdog(0.1)
    assert stub.sent == []


def test_exit_policy_hold_and_relax_are_read_back(p1):
    bus, stub = p1(STS6)
    bus.set_torque(True)
    stub.servos[2].set("Present Position", 2100)
    report = bus.apply_exit_policy("hold")
    assert report.ok and report.confirmed == tuple(range(1, 7))
    assert any("no Bus Watchdog" in n for n in report.notes)
    assert stub.servos[2].get("Goal Position") == 2100
    assert bus.apply_exit_policy("relax").ok
    assert all(s.get("Torque Enable") == 0 for s in stub.servos.values())


def test_exit_policy_that_cannot_be_confirmed_names_the_servos(p1):
    bus, stub = p1(STS6)
    bus.set_torque(True)
    stub.servos[3].silent = True
    stub.servos[5].torque_sticks_off = True
    stub.servos[5].set("Torque Enable", 0)
    with pytest.raises(ExitNotConfirmed) as info:
        bus.apply_exit_policy("hold", retries=1)
    why = dict(info.value.report.unconfirmed)
    assert set(why) == {3, 5}
    assert "no reply" in why[3] and "torque is off" in why[5]


def test_eeprom_writes_unlock_then_relock_a_feetech_servo(p1):
    bus, stub = p1({1: "STS3215"})
    since = len(stub.sent)
    write_eeprom(bus.link, bus.fams[0], 1, bus.fams[0].return_delay, 0)
    writes = [(p.params[0], p.params[1:]) for p in stub.instructions(since) if p.code == 3]
    assert writes == [(55, b"\x00"), (7, b"\x00"), (55, b"\x01")]
    assert stub.servos[1].get("Lock") == 1 and stub.servos[1].get("Return Delay Time") == 0


def test_one_protocol_per_bus():
    with pytest.raises(ValueError, match="one protocol per bus"):
        P1ServoBus(None, [1, 2], ["STS3215", "AX-12A"], 0)  # type: ignore[arg-type]
    assert table.protocol_of("MX-28") is table.Protocol.DXL1
    assert table.protocol_of("MX-28-P2") is table.Protocol.DXL2
    assert table.protocol_of("xm430-w350-t") is table.Protocol.DXL2
    assert table.protocol_of("sts3215") is table.Protocol.FEETECH
    assert table.family_of("ST3215") is table.STS and table.family_of("AX-12") is table.AX
    assert table.protocol_of("HS-485HB") is None


def test_scan_pings_each_id_and_names_model_and_family():
    from drivers.p1bus.scan import scan1

    stub = P1StubBus({1: "STS3215", 2: "STS3215", 5: "SCS0009"})
    name = f"p1-{next(_names)}"
    try:
        found = scan1(register_bus(name, stub), [1_000_000], range(8), table.Protocol.FEETECH)
    finally:
        unregister_bus(name)
    assert [(f.id, f.model_name, f.family, f.model_number) for f in found] == [
        (1, "STS3215", "Feetech STS", 777),
        (2, "STS3215", "Feetech STS", 777),
        (5, "SCS0009", "Feetech SCS", 1284),  # its big-endian Model Number read right
    ]
    pings = [p.id for p in stub.instructions() if p.code == packet.Inst.PING]
    assert pings == list(range(8))  # one Ping per ID: no broadcast Ping is relied on


def test_scan_cli_finds_an_ax_figure_on_protocol_1(capsys):
    from hilsim.cli import main

    stub = P1StubBus({1: "AX-12A", 7: "MX-64"})
    name = f"p1-{next(_names)}"
    try:
        url = register_bus(name, stub)
        assert (
            main(["scan", "--port", url, "--protocol", "1.0", "--ids", "0-9", "--baud", "1M"]) == 0
        )
        out = capsys.readouterr().out
        assert "ID   1 @ 1000000 bit/s: AX-12A (Dynamixel AX; model 12" in out
        assert "ID   7 @ 1000000 bit/s: MX-64 (Dynamixel MX (Protocol 1.0); model 310" in out
        assert main(["scan", "--port", url, "--ids", "0-3", "--baud", "1M"]) == 1  # X series
        assert "--protocol feetech or --protocol 1.0" in capsys.readouterr().err
    finally:
        unregister_bus(name)


@settings(
    max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3))
def test_the_goal_frame_is_the_packet_builders_sync_write(p1, rads):
    """The tick's Sync Write, rewritten in place, is byte for byte what
    :func:`packet.sync_write` makes of each family's encoding (STS and SCS on one bus)."""
    bus, stub = p1({1: "STS3215", 2: "SCS0009", 3: "STS3215"})
    since = len(stub.sent)
    bus.write_goals(np.array(rads))
    ticks = [round(g * t) + c for g, t, c in zip(rads, bus._tpr, bus._center, strict=True)]
    want = packet.sync_write(
        42,
        2,
        {
            sid: encode(fam, fam.goal_position, tk)
            for sid, fam, tk in zip(bus.ids, bus.fams, ticks, strict=True)
        },
    )
    assert stub.sent[since][1] == want


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.integers(0, 253), min_size=1, max_size=12, unique=True),
    st.integers(0, 255),
    st.binary(min_size=24, max_size=24),
    st.integers(0, 200),
    st.integers(0, 255),
)
def test_a_whole_chain_reads_as_the_stream_parser_reads_it(ids, err, words, at, flip):
    """The tick's shortcut for a Sync Read chain that came whole gives what the stream
    parser gives, or stands aside (a damaged byte anywhere)."""
    data = bytearray(
        b"".join(packet.encode_status(i, err, words[2 * k : 2 * k + 2]) for k, i in enumerate(ids))
    )
    data[at % len(data)] ^= flip
    want = set(ids)
    fast = _whole_chain(bytes(data), want, 8)
    got: dict[int, tuple[int, bytes]] = {}
    corrupt = []
    for _, (raw, fid, ok, code, params) in packet.StreamParser().feed_decoded(bytes(data)):
        if not ok or len(params) != 2:
            corrupt.append(raw)
        elif fid in want and fid not in got:
            got[fid] = (code, params)
    if fast is not None:
        assert fast == got and not corrupt
    else:
        assert flip != 0  # an intact chain always takes the shortcut
