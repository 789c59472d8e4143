"""The loop's bookkeeping on numbers alone: host stalls, servo silence, following error, health."""

from __future__ import annotations

import math

import pytest

from drivers.servo_bus import HealthPart
from hilsim.show.monitors import (
    MIN_FAILED_READS,
    STALL_ALLOWANCE_S,
    FollowingMonitor,
    HealthSchedule,
    HostStalls,
    SilenceBudget,
)


# ------------------------------------------------------------------ host stalls
def test_a_healthy_tick_is_no_stall():
    stalls = HostStalls()
    for _ in range(100):
        assert stalls.tick_stall(0.0, 50e-6, 0.0) == 0.0
    assert stalls.count == 0 and stalls.total_s == 0.0


def test_a_late_wake_up_is_a_stall():
    stalls = HostStalls()
    assert stalls.tick_stall(0.2, 50e-6, 0.0) == pytest.approx(0.2)
    assert stalls.count == 1 and stalls.max_s == pytest.approx(0.2)


def test_work_far_beyond_its_usual_cost_is_a_stall_but_steady_heavy_work_is_not():
    stalls = HostStalls()
    for _ in range(10):  # 3 ms of integration every tick: cost, not a stall
        assert stalls.tick_stall(0.0, 3e-3, 0.0) == 0.0
    assert stalls.tick_stall(0.0, 3e-3 + 0.06, 0.0) == pytest.approx(0.06)


def test_poll_gaps_are_a_stall_and_the_first_tick_has_no_work_to_judge():
    stalls = HostStalls()
    assert stalls.tick_stall(0.0, None, 0.03) == pytest.approx(0.03)
    assert stalls.tick_stall(0.0, None, STALL_ALLOWANCE_S / 2) == 0.0  # below the noise floor
    assert stalls.as_dict() == {"count": 1, "total_ms": 30.0, "max_ms": 30.0}


# ------------------------------------------------------------------ silence
def test_silence_needs_failed_reads_and_the_budget():
    budget = SilenceBudget(2, budget_s=0.05)
    budget.start(0.0)
    t = 0.0
    for _ in range(MIN_FAILED_READS - 1):  # long but too few failed reads
        t += 0.1
        assert budget.failed(0, t, 0.0, host_late=False) is None
    t += 0.004
    assert budget.failed(0, t, 0.0, host_late=False) == pytest.approx(t)


def test_host_stalls_are_not_silence():
    budget = SilenceBudget(1, budget_s=0.05)
    budget.start(0.0)
    # a 600 ms host stall, then failed reads: silence is the time less the stall
    stall_total = 0.6
    for k in range(1, 6):
        t = 0.6 + 0.004 * k
        assert budget.failed(0, t, stall_total, host_late=False) is None
    assert budget.silent_s(0, 0.62, stall_total) == pytest.approx(0.02)


def test_host_late_reads_do_not_count_as_failed():
    budget = SilenceBudget(1, budget_s=0.01)
    budget.start(0.0)
    for k in range(1, 10):
        assert budget.failed(0, 0.1 * k, 0.0, host_late=True) is None
    assert budget.failed_reads(0) == 0
    budget.ok(0, 1.0, 0.0)
    assert budget.silent_s(0, 1.0, 0.0) == 0.0


# ------------------------------------------------------------------ following error
def test_following_error_after_its_time_not_before():
    period = 0.004
    mon = FollowingMonitor([math.radians(10)] * 2, [0.02, 0.02], period)  # 5 ticks
    far, near = math.radians(30), math.radians(1)
    for _ in range(4):
        assert mon.update([far, near], [0.0, 0.0]) is None
    err = mon.update([far, near], [0.0, 0.0])
    assert err is not None and err.joint == 0 and err.duration_s == pytest.approx(0.02)


def test_following_error_resets_on_a_good_tick_and_ignores_missing_reads():
    mon = FollowingMonitor([0.1], [0.012], 0.004)  # 3 ticks
    assert mon.update([1.0], [0.0]) is None
    assert mon.update([math.nan], [0.0]) is None  # no reading: neither adds nor resets
    assert mon.update([1.0], [0.0]) is None
    assert mon.update([1.0], [0.0]) is not None
    mon.reset(0)
    assert mon.update([1.0], [0.0]) is None
    assert mon.update([0.0], [0.0]) is None  # back within tolerance
    assert mon.update([1.0], [0.0]) is None


# ------------------------------------------------------------------ health schedule
def test_health_reads_go_round_robin_alternating_state_and_watchdog():
    sched = HealthSchedule(3, period_s=0.03)
    taken = []
    t = 0.0
    while len(taken) < 9:
        if sched.due(t):
            taken.append(sched.take(t))
        t += 0.001
    assert [i for i, _ in taken] == [0, 1, 2] * 3
    # the second round (of every CONDITION_EVERY_ROUNDS) reads temperature, voltage, load:
    # inserted, the state and watchdog rounds still alternate
    parts = [HealthPart.STATE, HealthPart.CONDITION, HealthPart.WATCHDOG]
    assert [p for _, p in taken] == [p for p in parts for _ in range(3)]
    assert sched.interval_s == pytest.approx(0.01)
    plain = HealthSchedule(3, period_s=0.03, condition_every=0)  # a P1 bus: none of them
    assert [plain.take(0.0)[1] for _ in range(6)] == [HealthPart.STATE] * 3 + [
        HealthPart.WATCHDOG
    ] * 3
