"""A health read in a tick's spare time is sized by what health reads have cost, not only
by the wire model: on a host where a read costs more than its bus time (the SDK, an
in-process emulator), a tick without that much to spare does not take one."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from drivers.dynamixel import DynamixelBus
from hilsim.rig.joint_map import JointMap
from hilsim.show.servo_watch import (
    HEALTH_COST_MEMORY_S,
    HEALTH_FLOOR_S,
    HEALTH_MARGIN,
    HEALTH_SPARE_S,
    ServoWatch,
)

EXTRA_S = 0.003  # what each health read costs beyond its bus time (virtual clock)


@pytest.fixture
def slow_health():
    bus = DynamixelBus.open(
        "dxlsim://?ids=1-2&rdt_us=0&clock=virtual", baud=1_000_000, ids=[1, 2], read_mode="fast"
    )
    joints = [
        SimpleNamespace(name=f"j{i}", servo_id=i + 1, tracking_tolerance_rad=0.1, tracking_time_s=1)
        for i in range(2)
    ]
    watch = ServoWatch(
        bus,
        joints,
        JointMap([0.0, 0.0], [1.0, 1.0]),
        period_s=0.001,
        comm_budget_ms=100,
        watchdog_s=0.0,
        event=lambda *a, **k: None,
        rejoin=lambda i, x: None,
    )
    bus.set_torque(True)  # a healthy figure: the reads find nothing wrong
    read = bus.read_health
    extra = [EXTRA_S]

    def slow(*args, **kwargs):
        out = read(*args, **kwargs)
        bus.clock.advance(extra[0])
        return out

    bus.read_health = slow
    yield SimpleNamespace(bus=bus, watch=watch, extra=extra)
    bus.close()


def _reads(show, spare_s: float, ticks: int, period_s: float = 0.001) -> int:
    watch, clock = show.watch, show.bus.clock
    before = watch.health.reads
    for k in range(ticks):
        clock.wait_until(clock.now() + period_s)
        watch.maybe_read_health(spare_s, clock.now(), k)
    return watch.health.reads - before


def test_a_read_that_cost_more_than_its_bus_time_sizes_the_next(slow_health):
    model = slow_health.bus.health_read_s
    enough_for_the_model = HEALTH_MARGIN * model + HEALTH_SPARE_S + 1e-6
    assert _reads(slow_health, enough_for_the_model, 1) == 1  # nothing known yet: the model
    # it took EXTRA_S more: ticks with only the model's time to spare take no more reads
    assert _reads(slow_health, enough_for_the_model, 500) == 0
    assert slow_health.watch.health.deferred > 0
    # a tick with the measured time to spare does
    measured = model + EXTRA_S
    assert _reads(slow_health, HEALTH_MARGIN * measured + HEALTH_SPARE_S + 1e-6, 1) == 1


def test_a_slow_spell_is_forgotten(slow_health):
    model = slow_health.bus.health_read_s
    enough_for_the_model = HEALTH_MARGIN * model + HEALTH_SPARE_S + 1e-6
    assert _reads(slow_health, enough_for_the_model, 1) == 1  # slow: the next ones wait
    slow_health.extra[0] = 0.0  # the reads are quick again
    # the floor's reads measure them quick; once the slow one is forgotten
    # (HEALTH_COST_MEMORY_S), every due read fits again: a round of 2 every 40 ms
    ticks = int((HEALTH_COST_MEMORY_S + 3.0) / 0.001)
    assert _reads(slow_health, enough_for_the_model, ticks) > 100
    assert slow_health.watch.health.forced <= HEALTH_COST_MEMORY_S / HEALTH_FLOOR_S + 1


def test_one_slow_read_among_quick_ones_does_not_stop_the_reads(slow_health):
    # the first read of a show is the likely slow one (cold caches); the floor's next read
    # is quick, and from then on each due read that fits is taken, not one a second
    model = slow_health.bus.health_read_s
    enough = HEALTH_MARGIN * model + HEALTH_SPARE_S + 1e-6
    assert _reads(slow_health, enough, 1) == 1  # slow
    slow_health.extra[0] = 0.0
    forced = slow_health.watch.health.forced
    ticks = int(1.5 * HEALTH_FLOOR_S / 0.001)
    assert _reads(slow_health, enough, ticks) > 10  # a round of 2 every 40 ms after the floor
    assert slow_health.watch.health.forced == forced + 1


def test_a_bus_with_no_time_to_spare_still_gets_a_read_a_second(slow_health):
    watch = slow_health.watch
    # 10 s of ticks that never have the time: one read a HEALTH_FLOOR_S, each counted forced
    reads = _reads(slow_health, 0.0, 10_000)
    assert reads == watch.health.forced == pytest.approx(10.0 / HEALTH_FLOOR_S, abs=1)
    assert watch.health.deferred > 9_000
