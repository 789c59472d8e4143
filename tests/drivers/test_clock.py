"""The injected clocks: the virtual clock jumps; the real clock sleeps, then spins, and offers
its sleep to other threads as Slack. No test here sleeps: the real clock's sleep is faked."""

from __future__ import annotations

import pytest

import drivers.clock as clock_mod
from drivers.clock import MonotonicClock, Slack, VirtualClock


def test_virtual_clock_jumps_and_never_goes_back():
    c = VirtualClock(1.0)
    assert c.wait_until(3.5) == 3.5
    assert c.wait_until(2.0) == 3.5  # a deadline in the past returns at once
    assert c.advance(0.5) == 4.0
    with pytest.raises(ValueError):
        c.advance(-1.0)


class FakeTime:
    def __init__(self) -> None:
        self.t = 100.0
        self.sleeps: list[tuple[float, bool, float]] = []
        self.slack: Slack | None = None

    def perf_counter(self) -> float:
        self.t += 1e-6  # every look at the clock costs a microsecond
        return self.t

    def sleep(self, dt: float) -> None:
        s = self.slack
        self.sleeps.append((dt, s.is_set() if s else False, s.until if s else float("nan")))
        self.t += dt


@pytest.fixture
def fake(monkeypatch):
    ft = FakeTime()
    monkeypatch.setattr(clock_mod.time, "perf_counter", ft.perf_counter)
    monkeypatch.setattr(clock_mod.time, "sleep", ft.sleep)
    return ft


def test_monotonic_clock_sleeps_then_spins_to_the_deadline(fake):
    c = MonotonicClock(spin_s=200e-6)
    t = c.now() + 0.010
    assert c.wait_until(t) >= t
    ((dt, _, _),) = fake.sleeps
    assert dt == pytest.approx(0.010 - 200e-6, abs=5e-6)  # woke 200 µs early, spun the rest


def test_slack_is_offered_only_while_sleeping_with_its_end(fake):
    c = MonotonicClock(spin_s=200e-6)
    slack = Slack()
    fake.slack = slack
    t = c.now() + 0.005
    c.wait_until(t, slack)
    ((_, was_set, until),) = fake.sleeps
    assert was_set and until == pytest.approx(t - 200e-6)
    assert not slack.is_set()  # cleared before the spin and the tick
    c.wait_until(c.now() - 1.0, slack)  # late already: no sleep, no slack offered
    assert len(fake.sleeps) == 1 and not slack.is_set()


def test_slack_remaining():
    s = Slack()
    assert s.remaining() == float("inf")
    s.until = 0.0
    assert s.remaining() < 0
