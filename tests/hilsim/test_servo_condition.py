"""Each servo's temperature, input voltage and load: read in the health rotation's spare
time on X-series, from every health read on the Protocol 1.0 backend, into one record the
loop keeps; a failed read leaves the last figure with its time."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from drivers.dynamixel import DynamixelBus
from drivers.dynamixel.errors import CommError
from drivers.dynamixel.startup import Expectation
from drivers.servo_bus import HealthPart
from hilsim.rig.joint_map import JointMap
from hilsim.show.monitors import CONDITION_EVERY_ROUNDS, HEALTH_PERIOD_S
from hilsim.show.servo_watch import ServoWatch

PERIOD_S = 0.001  # a 1 kHz loop
SPARE_S = 0.0008  # every tick has time to spare for any health read


def _watch(bus) -> ServoWatch:
    joints = [
        SimpleNamespace(name=f"j{k}", servo_id=sid, tracking_tolerance_rad=0.1, tracking_time_s=1)
        for k, sid in enumerate(bus.ids)
    ]
    n = len(joints)
    return ServoWatch(
        bus,
        joints,
        JointMap([0.0] * n, [1.0] * n),
        period_s=PERIOD_S,
        comm_budget_ms=100,
        watchdog_s=0.0,
        event=lambda *a, **k: None,
        rejoin=lambda i, x: None,
    )


@pytest.fixture(params=["XM430-W350", "XL430-W250"])
def x_show(request):
    model = request.param
    bus = DynamixelBus.open(
        f"dxlsim://?ids=1-2&model={model}&rdt_us=0&clock=virtual",
        baud=1_000_000,
        ids=[1, 2],
        read_mode="fast",
    )
    bus.check([Expectation(1, model), Expectation(2, model)])  # the bus learns the models
    bus.set_torque(True)
    yield SimpleNamespace(bus=bus, watch=_watch(bus), dx=bus.link.port.ser.bus, model=model)
    bus.close()


def _tick(show, ticks: int) -> None:
    clock = show.bus.clock
    for k in range(ticks):
        clock.wait_until(clock.now() + PERIOD_S)
        show.watch.maybe_read_health(SPARE_S, clock.now(), k)


def test_x_series_rotation_reads_temperature_voltage_and_load(x_show):
    rec = x_show.watch.condition
    assert all(math.isnan(x) for x in rec.value["temperature_c"])  # never read: NaN
    x_show.dx.servo(2).set_temperature(47.0, x_show.bus.clock.now())
    # the second round of HEALTH_PERIOD_S reads them (then every CONDITION_EVERY_ROUNDS)
    ticks = round(2 * HEALTH_PERIOD_S / PERIOD_S) + 5
    _tick(x_show, ticks)
    temps, volts = rec.value["temperature_c"], rec.value["voltage_v"]
    assert 10.0 <= temps[0] <= 45.0  # the emulator's ambient, about room temperature
    assert temps[1] == 47.0
    assert all(10.0 <= v <= 13.0 for v in volts)  # the models' 11.1 or 12 V supply
    if x_show.model.startswith("XM"):  # register 126 is Present Current on an XM430
        assert all(math.isnan(x) for x in rec.value["load_pct"])
        assert all(abs(a) < 2.5 for a in rec.value["current_a"])
    else:  # ... and Present Load on an XL430
        assert all(-100.0 <= x <= 100.0 for x in rec.value["load_pct"])
        assert all(math.isnan(a) for a in rec.value["current_a"])
    now = x_show.bus.clock.now()
    for i in range(2):
        assert 0.0 <= now - rec.read_t["temperature_c"][i] <= ticks * PERIOD_S
    assert rec.max_temperature_c == [temps[0], 47.0]
    assert rec.min_voltage_v == volts
    view = rec.view(1, now)
    assert view["temperature_c"] == 47.0 and view["temperature_c_age_s"] >= 0.0
    # about a second later, read again
    x_show.dx.servo(2).set_temperature(52.0, x_show.bus.clock.now())
    _tick(x_show, round(CONDITION_EVERY_ROUNDS * HEALTH_PERIOD_S / PERIOD_S))
    assert temps[1] == 52.0 and rec.max_temperature_c[1] == 52.0


def test_the_condition_read_is_sized_by_its_own_bytes(x_show):
    bus = x_show.bus
    assert bus.condition_read_s > bus.health_read_s  # 21 bytes of data against 7
    # a tick with room for a state read but not a condition read reads the state instead:
    # the checks never wait on the figures
    watch = x_show.watch
    sched = watch.health
    while sched.next_part() is not HealthPart.CONDITION:
        sched.take(-1.0)  # (due at once)
    clock = bus.clock
    room = 1.1 * bus.health_read_s + 150e-6 + 1e-6
    assert 1.1 * bus.condition_read_s + 150e-6 > room
    clock.wait_until(clock.now() + PERIOD_S)
    reads = sched.reads
    watch.maybe_read_health(room, clock.now(), 0)
    assert sched.reads == reads + 1 and sched.deferred == 0
    assert math.isnan(watch.condition.value["temperature_c"][0])
    # with room for it, the next servo's read in that round is its condition
    clock.wait_until(clock.now() + HEALTH_PERIOD_S)
    watch.maybe_read_health(SPARE_S, clock.now(), 1)
    assert math.isfinite(watch.condition.value["temperature_c"][1])


def test_a_failed_read_leaves_the_last_figure_with_its_time(x_show):
    rec = x_show.watch.condition
    ticks = round(CONDITION_EVERY_ROUNDS * HEALTH_PERIOD_S / PERIOD_S) + 10
    _tick(x_show, ticks)
    temp, t_read = rec.value["temperature_c"][0], rec.read_t["temperature_c"][0]
    assert math.isfinite(temp)
    x_show.dx.servo(1).set_temperature(60.0, x_show.bus.clock.now())

    def silent(*args, **kwargs):
        raise CommError("no reply (test)")

    x_show.bus.read_health = silent
    _tick(x_show, 2 * ticks)  # the next condition rounds all fail
    assert rec.value["temperature_c"][0] == temp  # not 60, not NaN, not 0
    assert rec.read_t["temperature_c"][0] == t_read  # its age grows


def test_the_panel_feed_state_carries_the_figures(tmp_path):
    """The feed's state message: each servo's figures and ages with the run's facts (JSON:
    null where never read)."""
    import json

    import numpy as np

    import hilsim
    from drivers.clock import VirtualClock
    from drivers.servo_bus import ConditionRecord, ServoCondition
    from hilsim.show.feed import PanelFeed
    from tests.hilsim.panel_helpers import REPO

    show = hilsim.Show(REPO / "configs/demo.toml", virtual_time=True, out=tmp_path / "run")
    feed = PanelFeed(show, run_dir=tmp_path / "run")
    record = ConditionRecord(2)
    record.update(1, ServoCondition(44.0, 11.8, 7.5), t=2.0)
    clock = VirtualClock()
    clock.advance(3.0)
    zeros = np.zeros(2)
    loop = SimpleNamespace(
        rec=SimpleNamespace(tick=5, t_sched=0.02),
        u=zeros, cmd=zeros, present=zeros,
        reading=SimpleNamespace(status=np.zeros(2, dtype=np.uint8)),
        director=None, overruns=0, stalls=SimpleNamespace(count=0), recent_lateness_us=np.zeros(512),
        watch=SimpleNamespace(comm_errors=0, condition=record),
        stop=SimpleNamespace(command=None, signum=None), clock=clock,
    )  # fmt: skip
    msg = json.loads(feed._line(feed._state_msg(loop)))
    first, second = msg["condition"]
    assert first["temperature_c"] is None and first["temperature_c_age_s"] is None
    assert second["temperature_c"] == 44.0 and second["voltage_v"] == 11.8
    assert second["load_pct"] == 7.5 and second["load_pct_age_s"] == 1.0
