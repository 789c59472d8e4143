"""A show's loop thread runs with precise timers (issue 12: waiting costs nothing): inside
``hilsim.show.realtime.realtime`` the thread's timer slack is 1 ns, so its sleep can end close to
the deadline and the clock's spin window can be short; afterwards it is what it was, also
when the block raises. Where the OS has no timer slack the show runs as before."""

from __future__ import annotations

import pytest

import drivers.clock as clock_mod
import hilsim.show.realtime as rt


@pytest.mark.skipif(clock_mod.timer_slack_ns() is None, reason="no timer slack (not Linux)")
def test_realtime_sets_precise_timers_for_the_show_and_restores_them():
    before = clock_mod.timer_slack_ns()
    with rt.realtime(None, None) as sched:
        assert sched == "SCHED_OTHER"
        assert clock_mod.timer_slack_ns() == clock_mod.PRECISE_SLACK_NS
    assert clock_mod.timer_slack_ns() == before
    with pytest.raises(KeyboardInterrupt), rt.realtime(None, None):
        raise KeyboardInterrupt
    assert clock_mod.timer_slack_ns() == before


def test_realtime_runs_where_timer_slack_cannot_be_set(monkeypatch):
    calls = []
    monkeypatch.setattr(clock_mod, "timer_slack_ns", lambda: None)
    monkeypatch.setattr(clock_mod, "set_timer_slack_ns", lambda ns: calls.append(ns))
    with rt.realtime(None, None) as sched:
        assert sched == "SCHED_OTHER"
    assert calls == []
