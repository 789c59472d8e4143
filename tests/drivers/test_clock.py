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


def test_the_clocks_own_slack_serves_every_wait_that_names_none(fake):
    # a loop sets its writer's Slack on the clock: an emulator's wait inside a tick (which
    # names no slack) is then free time too, with its end
    c = MonotonicClock(spin_s=100e-6)
    slack = Slack()
    fake.slack = c.idle = slack
    t = c.now() + 0.0006
    c.wait_until(t)
    ((_, was_set, until),) = fake.sleeps
    assert was_set and until == pytest.approx(t - 100e-6)
    assert not slack.is_set()
    c.idle = None
    c.wait_until(c.now() + 0.001)
    assert fake.sleeps[-1][1] is False  # none set: no free time offered


def test_slack_remaining():
    s = Slack()
    assert s.remaining() == float("inf")
    s.until = 0.0
    assert s.remaining() < 0


# -- precise timers: the thread's timer slack, set for a block and restored
linux_slack = pytest.mark.skipif(
    clock_mod.timer_slack_ns() is None, reason="no per-thread timer slack (not Linux)"
)


@linux_slack
def test_precise_timers_set_the_threads_slack_and_restore_it():
    before = clock_mod.timer_slack_ns()
    assert before > clock_mod.PRECISE_SLACK_NS  # the OS default (50 µs) or what was set
    with clock_mod.precise_timers() as ok:
        assert ok and clock_mod.timer_slack_ns() == clock_mod.PRECISE_SLACK_NS
    assert clock_mod.timer_slack_ns() == before
    with pytest.raises(RuntimeError), clock_mod.precise_timers():
        raise RuntimeError("a show that crashed")
    assert clock_mod.timer_slack_ns() == before  # restored on the way out, too


@linux_slack
def test_precise_timers_are_the_calling_threads_only():
    import threading

    seen = []
    with clock_mod.precise_timers():
        t = threading.Thread(target=lambda: seen.append(clock_mod.timer_slack_ns()))
        t.start()
        t.join()
        here = clock_mod.timer_slack_ns()
    # a thread started inside the block inherits the slack at its creation (Linux), and
    # changing it there does not change it here
    assert here == clock_mod.PRECISE_SLACK_NS and seen == [clock_mod.PRECISE_SLACK_NS]
    other = []

    def elsewhere() -> None:
        with clock_mod.precise_timers(7):
            other.append(clock_mod.timer_slack_ns())

    before = clock_mod.timer_slack_ns()
    t = threading.Thread(target=elsewhere)
    t.start()
    t.join()
    assert other == [7] and clock_mod.timer_slack_ns() == before


def test_precise_timers_where_the_os_refuses_change_nothing(monkeypatch):
    monkeypatch.setattr(clock_mod, "set_timer_slack_ns", lambda ns: False)
    with clock_mod.precise_timers() as ok:
        assert ok is False
    monkeypatch.setattr(clock_mod, "timer_slack_ns", lambda: None)  # not Linux
    calls = []
    monkeypatch.setattr(clock_mod, "set_timer_slack_ns", lambda ns: calls.append(ns))
    with clock_mod.precise_timers() as ok:
        assert ok is False
    assert calls == []


def test_the_default_spin_window_is_what_a_clock_gets(fake):
    c = MonotonicClock()
    assert c.spin_s == clock_mod.DEFAULT_SPIN_S
    t = c.now() + 0.004
    c.wait_until(t)
    ((dt, _, _),) = fake.sleeps
    assert dt == pytest.approx(0.004 - clock_mod.DEFAULT_SPIN_S, abs=5e-6)


class LateWakes(FakeTime):
    """A host whose sleeps wake ``late_s`` after their time."""

    def __init__(self, late_s: float) -> None:
        super().__init__()
        self.late_s = late_s

    def sleep(self, dt: float) -> None:
        super().sleep(dt)
        self.t += self.late_s


def _waits(ft: FakeTime, c: MonotonicClock, n: int, period: float = 0.004) -> list[float]:
    """``n`` deadlines ``period`` apart; how late each wait returned (s)."""
    late, t = [], c.now()
    for _ in range(n):
        t += period
        late.append(c.wait_until(t) - t)
    return late


@pytest.fixture
def late30(monkeypatch):
    ft = LateWakes(30e-6)
    monkeypatch.setattr(clock_mod.time, "perf_counter", ft.perf_counter)
    monkeypatch.setattr(clock_mod.time, "sleep", ft.sleep)
    return ft


def test_the_spin_window_shrinks_to_how_late_this_host_wakes(late30):
    # a host that wakes every sleep 30 µs late: the window learns ~30 µs instead of spinning
    # the 100 µs allowed, and the deadlines are still met by the spin
    c = MonotonicClock(spin_s=100e-6)
    assert c.window_s == 100e-6  # until it has seen a sleep, the whole allowance
    late = _waits(late30, c, 3000)
    assert 30e-6 <= c.window_s <= 33e-6  # the latest wake-up (+ the fake's clock reads)
    dt = late30.sleeps[-1][0]
    assert dt == pytest.approx(0.004 - c.window_s, abs=5e-6)  # sleeps to ~35 µs before
    assert max(late[-500:]) < 3e-6  # on time (the clock's reads cost the fake 1 µs each)
    late30.late_s = 80e-6  # one later wake-up: the window takes it at once, and holds it
    _waits(late30, c, 1)
    assert c.window_s == pytest.approx(81e-6, abs=2e-6)
    late30.late_s = 30e-6
    _waits(late30, c, 100)
    assert c.window_s == pytest.approx(76e-6, abs=2e-6)  # coming down 0.05 µs a sleep


def test_the_learned_window_never_passes_spin_us(monkeypatch):
    ft = LateWakes(500e-6)  # later than the allowance: spin it all, as a fixed window does
    monkeypatch.setattr(clock_mod.time, "perf_counter", ft.perf_counter)
    monkeypatch.setattr(clock_mod.time, "sleep", ft.sleep)
    c = MonotonicClock(spin_s=100e-6)
    late = _waits(ft, c, 200)
    assert c.window_s == 100e-6
    assert min(late) == pytest.approx(400e-6, abs=5e-6)  # late by the excess only
    z = MonotonicClock(spin_s=0.0)  # sleep only: nothing to learn
    _waits(ft, z, 50)
    assert z.window_s == 0.0


def test_a_fixed_window_is_kept_when_not_learning(late30):
    c = MonotonicClock(spin_s=100e-6, learn=False)
    _waits(late30, c, 500)
    assert c.window_s == 100e-6
    assert late30.sleeps[-1][0] == pytest.approx(0.004 - 100e-6, abs=5e-6)


def test_a_host_whose_p99_wake_up_is_later_than_spin_us_keeps_the_whole_window(monkeypatch):
    # 30 µs late but one sleep in 25 300 µs late: wake-ups past the 100 µs allowed every few
    # sleeps, so the window stays 100 µs throughout, as a fixed one (lateness p99 as ever)
    ft = LateWakes(30e-6)
    n = [0]

    def sleep(dt: float) -> None:
        n[0] += 1
        ft.late_s = 300e-6 if n[0] % 25 == 0 else 30e-6
        LateWakes.sleep(ft, dt)

    monkeypatch.setattr(clock_mod.time, "perf_counter", ft.perf_counter)
    monkeypatch.setattr(clock_mod.time, "sleep", sleep)
    c = MonotonicClock(spin_s=100e-6)
    windows = []
    t = c.now()
    for _ in range(2000):
        t += 0.004
        c.wait_until(t)
        windows.append(c.window_s)
    assert set(windows[-1000:]) == {100e-6}
