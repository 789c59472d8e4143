"""The summary counts the safety filter's interventions per joint, in one place."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hilsim.safety import COUNTER_KINDS, SafetyFilter
from hilsim.telemetry.stats import RunStats
from tests.hilsim.tick_rows import stats_record

NAMES = ("pan", "tilt", "jaw")


def _stats_with_ticks(n: int = 3) -> RunStats:
    stats = RunStats(NAMES, servo_ids=[1, 2, 3])
    for i in range(n):
        stats.add(stats_record(i * 0.002, 0.0, False, 1.0, 1.0, 1.0, 1.0, [0, 0, 0], i))
    return stats


def test_the_filters_counters_land_in_safety_limits_every_joint_listed():
    f = SafetyFilter([-1.0] * 3, [1.0] * 3, 1.0, 1e6, 0.002, soft_start_s=0.0, joint_names=NAMES)
    f.start(np.zeros(3))
    out = np.empty(3)
    for _ in range(10):
        f.filter(np.array([5.0, 0.0, 0.0]), out)  # pan: clamped, then speed-limited
    c = f.counters
    stats = _stats_with_ticks()
    stats.set_safety_counts(c.by_kind(), ticks=c.ticks, held_ticks=c.fault_ticks)
    s = stats.summary()
    limits = s["safety_limits"]
    assert list(limits) == list(COUNTER_KINDS)
    assert limits["position"] == {"pan": 10, "tilt": 0, "jaw": 0}  # zeros shown, not omitted
    assert limits["speed"] == {"pan": 10, "tilt": 0, "jaw": 0}
    assert all(set(per) == set(NAMES) for per in limits.values())
    assert s["safety_ticks"] == {"filtered": 10, "held": 0}
    json.dumps(s)


def test_missing_joints_are_zero_and_a_later_call_replaces_the_counts():
    stats = _stats_with_ticks()
    stats.set_safety_counts({"position": {"jaw": 4}}, ticks=3)
    assert stats.summary()["safety_limits"] == {"position": {"pan": 0, "tilt": 0, "jaw": 4}}
    stats.set_safety_counts({"speed": {"pan": np.int64(2)}}, ticks=5, held_ticks=1)
    s = stats.summary()
    assert s["safety_limits"] == {"speed": {"pan": 2, "tilt": 0, "jaw": 0}}
    assert type(s["safety_limits"]["speed"]["pan"]) is int
    assert s["safety_ticks"] == {"filtered": 5, "held": 1}


def test_never_reported_is_null_not_zero():
    s = _stats_with_ticks().summary()
    assert s["safety_limits"] is None and s["safety_ticks"] is None


@pytest.mark.parametrize(
    "counts, kw, match",
    [
        ({"position": {"elbow": 1}}, {"ticks": 1}, "unknown joint 'elbow'"),
        ({"position": {"pan": -1}}, {"ticks": 1}, "negative"),
        ({}, {"ticks": -1}, "tick counts"),
    ],
)
def test_bad_counts_are_refused(counts, kw, match):
    with pytest.raises(ValueError, match=match):
        _stats_with_ticks().set_safety_counts(counts, **kw)
