"""Each fault kind, and what the unmodified SDK sees when it strikes."""

from __future__ import annotations

import dynamixel_sdk as sdk
import pytest
import serial

from drivers.dxlsim import unregister_bus
from drivers.dxlsim.faults import Fault, FaultKind, FaultPlan, FaultSpecError, parse_fault_plan
from tests.drivers.conftest import make_bus, open_session

OK = sdk.COMM_SUCCESS
ADDR_TORQUE, ADDR_LED, ADDR_HW_ERROR, ADDR_WATCHDOG = 64, 65, 70, 98
ADDR_GOAL_POS, ADDR_PRESENT_POS = 116, 132


@pytest.fixture
def faulty():
    opened = []

    def _open(faults: str, ids=(1, 2), seed=0, rdt_us=0.0):
        bus = make_bus(ids, faults=faults, seed=seed, trace=True, rdt_us=rdt_us)
        s = open_session(bus)
        opened.append(s)
        return s

    yield _open
    for s in opened:
        s.port.closePort()
    unregister_bus("test-bus")


def test_drop_is_a_timeout(faulty):
    s = faulty("drop:id=1,count=1")
    assert s.ph.ping(s.port, 1)[1] == sdk.COMM_RX_TIMEOUT
    assert s.ph.ping(s.port, 1)[1] == OK  # count=1: only once
    assert s.ph.ping(s.port, 2)[1] == OK


def test_drop_in_sync_read_breaks_the_chain(faulty):
    s = faulty("drop:id=1", ids=(1, 2))
    reader = sdk.GroupSyncRead(s.port, s.ph, ADDR_PRESENT_POS, 4)
    reader.addParam(2)
    reader.addParam(1)
    assert reader.txRxPacket() == sdk.COMM_RX_TIMEOUT
    rx = [r for r in s.bus.trace if r.direction == "rx"]
    assert [r.note for r in rx] == ["id=2"]  # ID 2 answered, ID 1 did not


def test_corrupt_is_a_crc_error(faulty):
    s = faulty("corrupt:id=1,count=1")
    assert s.ph.ping(s.port, 1)[1] == sdk.COMM_RX_CORRUPT


def test_truncate_is_corrupt(faulty):
    s = faulty("truncate:id=1,count=1")
    assert s.ph.read4ByteTxRx(s.port, 1, ADDR_PRESENT_POS)[1] == sdk.COMM_RX_CORRUPT


def test_garbage_before_header_is_skipped_by_the_sdk(faulty):
    s = faulty("garbage:id=1,nbytes=9")
    model, result, _ = s.ph.ping(s.port, 1)
    assert (model, result) == (1020, OK)


def test_late_reply_lands_in_the_next_transaction(faulty):
    """The classic field bug: a late status is taken as the answer to the next request."""
    s = faulty("", rdt_us=500.0)
    assert s.ph.write1ByteTxRx(s.port, 1, ADDR_LED, 1) == (OK, 0)
    s.bus.faults = FaultPlan((Fault(FaultKind.LATE, frozenset({1}), delay=0.040, count=1),))
    t_ping = s.bus.clock.now()
    assert s.ph.ping(s.port, 1)[1] == sdk.COMM_RX_TIMEOUT  # SDK gives up at 34 ms
    # The ping's status starts 0.62 + 40 ms after t_ping. A Read sent at 40.3 ms would be
    # answered at 40.96 ms: the stale ping status arrives first, after the Read cleared
    # the input buffer, and the SDK takes it (same ID, valid CRC) as the Read's answer.
    s.bus.clock.wait_until(t_ping + 0.0403)
    data, result, _ = s.ph.readTxRx(s.port, 1, ADDR_LED, 1)
    assert result == OK
    assert data == [1020 & 0xFF]  # the model number's low byte, not the LED


def test_duplicate_id_collides(faulty):
    s = faulty("duplicate_id:id=1,at=0.5")
    assert s.ph.write1ByteTxRx(s.port, 1, ADDR_LED, 1) == (OK, 0)
    s.bus.clock.advance(1.0)
    _, result, _ = s.ph.read1ByteTxRx(s.port, 1, ADDR_LED)  # original says 1, twin says 0
    assert result == sdk.COMM_RX_CORRUPT


def test_brownout_silences_then_resets_ram(faulty):
    s = faulty("brownout:id=1,at=0.1,duration=0.3")
    assert s.ph.write1ByteTxRx(s.port, 1, ADDR_TORQUE, 1) == (OK, 0)
    s.bus.clock.wait_until(0.2)
    assert s.ph.ping(s.port, 1)[1] == sdk.COMM_RX_TIMEOUT
    assert s.ph.ping(s.port, 2)[1] == OK
    s.bus.clock.wait_until(0.5)
    assert s.ph.read1ByteTxRx(s.port, 1, ADDR_TORQUE) == (0, OK, 0)


def test_hardware_error_sets_alert_and_cuts_torque(faulty):
    s = faulty("hardware_error:id=2,at=0.1,bits=overload")
    assert s.ph.write1ByteTxRx(s.port, 2, ADDR_TORQUE, 1) == (OK, 0)
    s.bus.clock.wait_until(0.2)
    value, result, error = s.ph.read1ByteTxRx(s.port, 2, ADDR_HW_ERROR)
    assert (value, result) == (0x20, OK)
    assert error & 0x80  # Alert bit
    assert s.ph.read1ByteTxRx(s.port, 2, ADDR_TORQUE)[0] == 0  # overload is in Shutdown (52)
    assert s.ph.reboot(s.port, 2)[0] == OK
    assert s.ph.read1ByteTxRx(s.port, 2, ADDR_HW_ERROR) == (0, OK, 0)


def test_torque_silently_cut(faulty):
    s = faulty("torque_off:id=1,at=0.1")
    assert s.ph.write1ByteTxRx(s.port, 1, ADDR_TORQUE, 1) == (OK, 0)
    s.bus.clock.wait_until(0.2)
    assert s.ph.read1ByteTxRx(s.port, 1, ADDR_TORQUE) == (0, OK, 0)


def test_watchdog_trip_rejects_goals(faulty):
    s = faulty("watchdog_trip:id=1,at=0.1")
    assert s.ph.write1ByteTxRx(s.port, 1, ADDR_TORQUE, 1) == (OK, 0)
    s.bus.clock.wait_until(0.2)
    assert s.ph.read1ByteTxRx(s.port, 1, ADDR_WATCHDOG)[0] == 0xFF  # -1
    result, error = s.ph.write4ByteTxRx(s.port, 1, ADDR_GOAL_POS, 1000)
    assert result == OK and error & 0x7F == 4  # Data Range Error
    assert s.ph.write1ByteTxRx(s.port, 1, ADDR_WATCHDOG, 0) == (OK, 0)
    assert s.ph.write4ByteTxRx(s.port, 1, ADDR_GOAL_POS, 1000) == (OK, 0)


def test_unplug_raises_serial_exception_and_frees_the_port(faulty):
    s = faulty("unplug:at=0.1")
    assert s.ph.ping(s.port, 1)[1] == OK
    s.bus.clock.wait_until(0.2)
    with pytest.raises(serial.SerialException):
        s.ph.ping(s.port, 1)
    assert s.port.is_using is False  # the adapter released it; the SDK alone would not


def test_reply_faults_by_rate_are_reproducible():
    def run(seed):
        bus = make_bus((1,), faults="drop:rate=0.3", seed=seed)
        s = open_session(bus, name="rate-bus")
        results = [s.ph.ping(s.port, 1)[1] for _ in range(40)]
        unregister_bus("rate-bus")
        return results

    a, b, c = run(7), run(7), run(8)
    assert a == b
    assert a != c
    assert 3 <= a.count(sdk.COMM_RX_TIMEOUT) <= 25


def test_fault_windows_respect_at_and_until(faulty):
    s = faulty("drop:id=1,at=0.5,until=1.0")
    assert s.ph.ping(s.port, 1)[1] == OK
    s.bus.clock.wait_until(0.6)
    assert s.ph.ping(s.port, 1)[1] == sdk.COMM_RX_TIMEOUT
    s.bus.clock.wait_until(1.1)
    assert s.ph.ping(s.port, 1)[1] == OK


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("explode:id=1", "unknown fault kind"),
        ("drop:rate=2", "rate"),
        ("drop:colour=red", "unknown key"),
        ("brownout:at=1", "give id=N"),
        ("drop:rate=abc", "bad value"),
        (
            "unplug:id=2,at=3",
            r"unplug: the USB adapter goes for every servo; it takes no id= \(got id=2\)$",
        ),
    ],
)
def test_bad_fault_specs_say_what_is_wrong(text, message):
    with pytest.raises(FaultSpecError, match=message):
        parse_fault_plan(text)


def test_fault_spec_parses_every_kind():
    plan = parse_fault_plan(
        "drop:id=1-2,rate=0.5;corrupt;truncate:count=3;late:delay=0.1;garbage:nbytes=4;"
        "brownout:id=1,at=2,duration=0.5;hwerr:id=1,bits=0x04;torque_off:id=2,at=1;"
        "watchdog:id=1,at=3;duplicate_id:id=2,at=4;unplug:at=5"
    )
    assert [f.kind for f in plan.faults] == list(FaultKind)
    assert plan.faults[0].ids == frozenset({1, 2})
