"""Start-up check and exit policy of DynamixelBus, on the emulated bus (virtual clock)."""

from __future__ import annotations

import dynamixel_sdk as sdk
import numpy as np
import pytest

from drivers.clock import VirtualClock
from drivers.dxlsim import DxlBus, VirtualServo
from drivers.dynamixel.errors import ExitNotConfirmed, StartupMismatch
from drivers.dynamixel.startup import Expectation, ReadMode, check_servo
from drivers.protocol2 import control_table as ct
from drivers.servo_bus import ExitPolicy
from tests.drivers.conftest import asked
from tests.drivers.test_dynamixel_bus import bus_opener

BAUD = 1_000_000
open_bus = pytest.fixture(bus_opener)


def servo(id_: int, model: str = "XM430-W350", rdt_us: float = 0.0, **kw) -> VirtualServo:
    return VirtualServo(model, id_, baud=BAUD, return_delay_us=rdt_us, t=0.0, **kw)


def expect(ids, **kw) -> list[Expectation]:
    return [Expectation(i, model="XM430-W350", position_range_rad=(-1.0, 1.0), **kw) for i in ids]


# ------------------------------------------------------------------ check
def test_every_mismatch_lands_in_one_table(open_bus):
    servos = [
        servo(1),
        servo(2, "XL430-W250"),
        servo(3, operating_mode=4),
        servo(4, min_position_limit=1500, max_position_limit=2500),
        servo(5, rdt_us=500),
        servo(6, status_return_level=0),
        servo(7),
        servo(8, torque_enable=1),
        # 9 is missing
        servo(10, status_return_level=1),
        servo(11, torque_enable=1),
        servo(12, torque_enable=1),
    ]
    servos[6].inject_hardware_error(0x24, 0.0)
    servos[7].trip_watchdog(0.0)
    dx = DxlBus(servos, baud=BAUD, clock=VirtualClock())
    ids = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]
    bus, _ = open_bus(dx, ids=ids, read_mode="plain")
    exps = [*expect(ids[:-1]), Expectation(12, model="XM430-W350", allow_torque_on=False)]
    with pytest.raises(StartupMismatch) as info:
        bus.check(exps)
    exc = info.value
    rows = {r.servo_id: r for r in exc.rows}
    assert sorted(rows) == [2, 3, 4, 5, 6, 7, 8, 9, 10, 12]  # exactly one row each
    assert (rows[2].item, rows[2].found) == ("model", "XL430-W250 (1060)")
    assert (rows[3].item, rows[3].found) == ("Operating Mode", "extended_position (4)")
    assert rows[4].item == "position range" and "[1500, 2500]" in rows[4].found
    assert (rows[5].item, rows[5].found) == ("Return Delay Time", "500 us")
    assert rows[6].item == "Status Return Level" and "answers Ping, not Read" in rows[6].found
    assert rows[7].item == "Hardware Error Status" and "overheating, overload" in rows[7].found
    assert (rows[8].item, rows[8].found) == ("Bus Watchdog", "tripped (-1)")
    assert (rows[9].item, rows[9].found) == ("answers Ping", "no (timeout)")
    assert (rows[10].item, rows[10].found) == ("Status Return Level", "1")
    assert (rows[12].item, rows[12].found) == ("Torque Enable", "on")
    text = str(exc)
    assert text.count("\n") == 2 + len(rows)  # title, header, rule, one line per row
    assert exc.servo_ids == (2, 3, 4, 5, 6, 7, 8, 9, 10, 12)


def test_passing_check_reports_the_servos(open_bus):
    dx = DxlBus(
        [servo(1), servo(2, torque_enable=1, present_position=3072)],
        baud=BAUD,
        clock=VirtualClock(),
    )
    bus, _ = open_bus(dx, read_mode="auto")
    report = bus.check(expect([1, 2]))
    assert report.read_mode is ReadMode.FAST
    assert report.torque_on_ids == (2,)
    np.testing.assert_allclose(report.positions_rad, [0.0, np.pi / 2])
    assert [s.model_name for s in report.servos] == ["XM430-W350"] * 2
    assert any("servo 2: torque already on" in n for n in report.notes)
    assert "servo 2: XM430-W350 fw 46" in str(report)


def test_check_servo_returns_its_findings_and_changes_nothing(open_bus):
    dx = DxlBus(
        [servo(1, rdt_us=100, min_position_limit=1000, max_position_limit=3000), servo(2)],
        baud=BAUD,
        clock=VirtualClock(),
    )
    bus, _ = open_bus(dx, read_mode="plain")
    found = check_servo(bus.link, Expectation(1, "XM430-W350"), attempts=1, fast_required=True)
    assert found.state is not None and found.state.position_limits == (1000, 3000)
    assert found.goal_range == (1000, 3000)
    assert found.return_delay_s == pytest.approx(100e-6)
    assert [r.item for r in found.rows] == ["Return Delay Time"]
    silent = check_servo(bus.link, Expectation(9), attempts=2, fast_required=False)
    assert silent.state is None and silent.goal_range is None and silent.return_delay_s is None
    assert [(r.item, r.found) for r in silent.rows] == [("answers Ping", "no (timeout)")]


def test_auto_mode_falls_back_to_plain_for_old_firmware(open_bus):
    dx = DxlBus([servo(1), servo(2, firmware=44)], baud=BAUD, clock=VirtualClock())
    bus, _ = open_bus(dx, read_mode="auto")
    report = bus.check(expect([1, 2]))
    assert report.read_mode is ReadMode.PLAIN and bus.read_mode is ReadMode.PLAIN
    assert any("servo(s) [2]" in n for n in report.notes)
    assert bus.read_present().all_ok


def test_fast_mode_requires_fast_firmware(open_bus):
    dx = DxlBus([servo(1, "XL330-M288", firmware=45), servo(2)], baud=BAUD, clock=VirtualClock())
    bus, _ = open_bus(dx, read_mode="fast")
    with pytest.raises(StartupMismatch) as info:
        bus.check([Expectation(1, "XL330-M288"), Expectation(2)])
    (row,) = info.value.rows
    assert (row.servo_id, row.item, row.expected, row.found) == (
        1,
        "firmware (Fast Sync Read)",
        ">= 46",
        "45",
    )


def test_check_wants_one_expectation_per_servo(open_bus):
    bus, _ = open_bus()
    with pytest.raises(ValueError, match=r"missing \[4\], not on this bus \[7\]"):
        bus.check([Expectation(i) for i in (1, 2, 3, 7)])


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"model": "XM999"}, "unknown servo model"),
        ({"position_range_rad": (1.0, -1.0)}, "lo <= hi"),
        ({"position_range_rad": (0.0, float("nan"))}, "finite"),
        ({"id": 300}, "0..252"),
        ({"return_delay_us_max": -1}, ">= 0"),
        ({"operating_mode": 2}, "OperatingMode"),
    ],
)
def test_expectation_validates(kw, match):
    with pytest.raises(ValueError, match=match):
        Expectation(**{"id": 1, **kw})


def test_plain_read_allows_for_return_delays_the_sdk_timeout_ignores(open_bus):
    """8 servos with the factory 500 us Return Delay Time: the chain takes 5.6 ms, longer
    than the SDK's own packet timeout on an ideal (0 ms latency) adapter."""
    ids = list(range(1, 9))
    bus, _ = open_bus(ids, read_mode="plain", rdt_us=500.0)
    bus.check(expect(ids, return_delay_us_max=500))
    reading = bus.read_present()
    assert reading.all_ok
    assert reading.t_done - reading.t == pytest.approx(
        (14 + 8) * 10e-6 + 8 * (500 + 20 + 150) * 1e-6  # request, then 8 x (RDT, turnaround, reply)
    )
    reader = sdk.GroupSyncRead(bus.link.port, bus.link.ph, 132, 4)
    for i in ids:
        reader.addParam(i)
    assert reader.txRxPacket() == sdk.COMM_RX_TIMEOUT  # the SDK alone gives up


# ------------------------------------------------------------------ exit policy
def _moved(open_bus, **kw):
    bus, dx = open_bus(**kw)
    bus.set_torque(True)
    bus.write_goals(np.array([0.4, -0.4, 0.8, -0.8]))
    dx.clock.advance(0.05)  # mid-move
    return bus, dx


def _reg(dx, addr, size=1):
    t = dx.clock.now()
    return [int.from_bytes(s.read(addr, size, t)[1], "little", signed=True) for s in dx.servos]


def test_hold_is_confirmed(open_bus):
    bus, dx = _moved(open_bus)
    report = bus.apply_exit_policy("hold")
    assert report.ok and report.confirmed == (1, 2, 3, 4) and report.policy is ExitPolicy.HOLD
    assert _reg(dx, 64) == [1] * 4
    assert _reg(dx, 98) == [5] * 4  # 0.1 s default
    dx.clock.advance(0.5)  # goal = where it was: it stays there
    assert _reg(dx, 116, 4) == _reg(dx, 132, 4)


def test_hold_uses_the_armed_watchdog_period_and_clears_a_trip(open_bus):
    bus, dx = _moved(open_bus, faults="watchdog_trip:id=1,at=0.06")
    bus.arm_watchdog(0.2)
    dx.clock.advance(0.05)
    assert bus.link.read_item(1, ct.BUS_WATCHDOG) == -1
    assert bus.apply_exit_policy(ExitPolicy.HOLD).ok
    assert _reg(dx, 98) == [10] * 4


def test_relax_is_confirmed(open_bus):
    bus, dx = _moved(open_bus)
    report = bus.apply_exit_policy("relax", retries=0)
    assert report.ok and str(report) == "exit policy 'relax': 4 servo(s) confirmed"
    assert _reg(dx, 64) == [0] * 4


@pytest.mark.parametrize("policy", ["hold", "relax"])
def test_a_silent_servo_is_named_and_the_rest_confirmed(open_bus, policy):
    bus, dx = _moved(open_bus, faults="drop:id=3,at=0.04")
    t0 = dx.clock.now()
    with pytest.raises(ExitNotConfirmed) as info:
        bus.apply_exit_policy(policy, retries=2)
    report = info.value.report
    assert report.confirmed == (1, 2, 4) and info.value.servo_ids == (3,)
    assert "servo 3:" in str(info.value) and "no reply" in str(info.value)
    expected = {"hold": 1, "relax": 0}[policy]
    assert [_reg(dx, 64)[i] for i in (0, 1, 3)] == [expected] * 3
    assert dx.clock.now() - t0 < 0.5  # bounded: a few packet timeouts, no hang


def test_hold_needs_torque(open_bus):
    bus, _ = _moved(open_bus, faults="torque_off:id=2,at=0.06")
    bus.clock.advance(0.02)
    with pytest.raises(ExitNotConfirmed, match="servo 2: torque is off: cannot hold"):
        bus.apply_exit_policy("hold")


def test_transient_failures_are_retried(open_bus):
    bus, dx = _moved(open_bus, faults="drop:id=2,at=0.04,count=2", trace=True)
    before = len(dx.trace)
    assert bus.apply_exit_policy("relax", retries=2).ok
    # the retries happened: servo 2's write went unanswered, so the next try read first (a
    # write whose status packet is lost may have taken): unanswered too; the third found
    # torque off (the write had taken: only its reply was dropped), so nothing is rewritten
    tries = [(a.id, a.instruction, a.address, len(a.replies)) for a in asked(dx, before)]
    write, read = sdk.INST_WRITE, sdk.INST_READ
    assert [t for t in tries if t[0] == 2] == [
        (2, write, 64, 0), (2, read, 64, 0), (2, read, 64, 1)
    ]  # fmt: skip
    assert [t for t in tries if t[0] != 2] == [
        (i, inst, 64, 1) for i in (1, 3, 4) for inst in (write, read)
    ]


def test_exit_policy_after_an_interrupted_transaction(open_bus):
    bus, _ = _moved(open_bus)
    bus.link.port.is_using = True  # KeyboardInterrupt inside the SDK leaves this
    assert bus.apply_exit_policy("relax").ok


def test_exit_policy_arguments_are_checked(open_bus):
    bus, _ = open_bus()
    with pytest.raises(ValueError, match="'stay'"):
        bus.apply_exit_policy("stay")
    with pytest.raises(ValueError, match="retries"):
        bus.apply_exit_policy("relax", retries=-1)


def test_a_retry_first_waits_out_the_failed_transactions_late_reply(open_bus):
    from drivers.dynamixel.errors import CommTimeout
    from drivers.dynamixel.read_order import LATE_BLOCK_S
    from drivers.dynamixel.startup import retry

    calls, settled = [], []

    def fails_twice():
        calls.append(1)
        if len(calls) < 3:
            raise CommTimeout("no reply", servo_id=1, what="Ping")
        return "ok"

    assert retry(3, fails_twice, settle=lambda: settled.append(len(calls))) == "ok"
    assert settled == [1, 2]  # before each retry, never after the last try
    bus, _ = open_bus()
    port, t = bus.link.port, bus.clock.now()
    bus.link.settle()  # the next transmit waits the late window and the adapter's latency
    assert port._quiet_at == pytest.approx(t + LATE_BLOCK_S + bus.link.latency_timer_ms * 1e-3)


class _FlakyLink:
    """A Link whose writes fail ``fails`` times (no reply), then succeed; reads echo."""

    def __init__(self, fails: int) -> None:
        self.fails, self.settled, self.value = fails, 0, None

    def write_item(self, sid, item, value) -> None:
        from drivers.dynamixel.errors import CommTimeout

        if self.fails:
            self.fails -= 1
            raise CommTimeout("no reply", servo_id=sid, what="Write")
        self.value = value

    def read_item(self, sid, item) -> int:
        return self.value

    def settle(self) -> None:
        self.settled += 1

    def recover(self) -> None:
        pass


def test_the_exit_waits_out_late_replies_between_tries_but_a_tick_never_does():
    from drivers.dynamixel import health

    link = _FlakyLink(fails=2)
    health._confirm(link, 1, ct.GOAL_POSITION, 2000, attempts=3)
    assert link.settled == 2  # before each retry, not after the last try
    link = _FlakyLink(fails=3)
    with pytest.raises(health._UnconfirmedError):
        health._confirm(link, 1, ct.GOAL_POSITION, 2000, attempts=3)
    assert link.settled == 2
    link = _FlakyLink(fails=2)  # a watchdog recovery runs inside a tick: no waiting
    health.recover_watchdog(link, 1, 2000, None, attempts=3)
    assert link.settled == 0
