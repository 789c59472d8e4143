"""The warm-up before a real-time show's tick 0 (hilsim.show.warm_up): the tick's stages but the
bus run on copies, the show's own parts untouched and its animation never copied, a part
that cannot be copied left out, a failure said, the runs within a budget."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import hilsim.show.warm_up as warm_mod
from hilsim.bench.tick import HilsimTick
from hilsim.safety.filter import SafetyFilter
from hilsim.targets import TargetSet, Track
from hilsim.telemetry.stats import RunStats


def _state(loop) -> dict:
    """What the show keeps that a warm-up could touch."""
    tel = loop.telemetry
    return {
        "arrays": [a.copy() for a in (loop.x, loop.v, loop.cmd, loop.u, loop.present)],
        "safety": (
            loop.safety._tick,
            {kind: list(n) for kind, n in loop.safety._count.items()},
            list(loop.safety._p),
        ),
        "targets_view": loop.targets._pos_view,
        "stats": (tel.stats._i, tel.stats._last_tick),
        "ring": (tel._ring.cursor, tel._ring.tail),
        "held": loop.integrator._held,
    }


def _assert_untouched(loop, before: dict) -> None:
    after = _state(loop)
    for a, b in zip(before["arrays"], after["arrays"], strict=True):
        np.testing.assert_array_equal(a, b)
    assert before["safety"] == after["safety"]
    assert after["targets_view"] is before["targets_view"]
    assert after["stats"] == before["stats"] and after["ring"] == before["ring"]
    assert after["held"] is before["held"]


@pytest.fixture
def tick(tmp_path: Path, monkeypatch):
    # the runs' count is asserted, not their speed: no budget unless a test sets one
    monkeypatch.setattr(warm_mod, "BUDGET_S", 1e9)
    t = HilsimTick(4, tmp_path)
    yield t
    t.close()


def _warm(loop, n: int = warm_mod.WARM_UP_TICKS) -> str | None:
    return warm_mod.warm_up(loop.stepper, loop.map, loop.telemetry, loop.rec, n)


def _spy(monkeypatch, cls, name: str, seen: list, show_part):
    """Count calls of ``cls.name`` (the class's method, as the warm-up calls it), noting
    whether each was on the show's own part."""
    orig = getattr(cls, name)

    def counted(self, *a, **kw):
        seen.append(self is show_part)
        return orig(self, *a, **kw)

    monkeypatch.setattr(cls, name, counted)


def test_every_stage_runs_n_times_on_copies_and_the_show_keeps_nothing(tick, monkeypatch):
    loop = tick.loop
    seen = {k: [] for k in ("filter", "step", "sample", "stats")}
    _spy(monkeypatch, SafetyFilter, "filter", seen["filter"], loop.safety)
    _spy(monkeypatch, type(loop.integrator), "step", seen["step"], loop.integrator)
    _spy(monkeypatch, TargetSet, "sample_into", seen["sample"], loop.targets)
    _spy(monkeypatch, RunStats, "add", seen["stats"], loop.telemetry.stats)
    copied = []
    deepcopy = warm_mod.copy.deepcopy
    monkeypatch.setattr(
        warm_mod.copy, "deepcopy", lambda o, m=None: copied.append(o) or deepcopy(o, m)
    )
    before = _state(loop)
    assert _warm(loop, 7) is None
    assert seen == {k: [False] * 7 for k in seen}  # seven times each, never the show's own
    _assert_untouched(loop, before)
    # the animation is never copied (its size is the show's, not the joints')
    assert not any(o is loop.targets or isinstance(o, Track) for o in copied)


def test_a_part_that_cannot_be_copied_is_left_out_and_the_rest_warmed(tick, monkeypatch):
    loop = tick.loop
    deepcopy, filtered, stepped = warm_mod.copy.deepcopy, [], []

    def refuse_springs(obj, memo=None):
        if obj is loop.integrator:
            raise TypeError("cannot pickle '_thread.lock' object")
        return deepcopy(obj, memo)

    monkeypatch.setattr(warm_mod.copy, "deepcopy", refuse_springs)
    _spy(monkeypatch, SafetyFilter, "filter", filtered, loop.safety)
    _spy(monkeypatch, type(loop.integrator), "step", stepped, loop.integrator)
    before = _state(loop)
    assert _warm(loop, 5) is None
    assert filtered == [False] * 5 and stepped == []
    _assert_untouched(loop, before)


def test_a_shows_targets_are_not_sampled_and_the_springs_follow_a_held_target(tick, monkeypatch):
    loop = tick.loop
    sampled, stepped = [], []
    _spy(monkeypatch, TargetSet, "sample_into", sampled, loop.targets)
    _spy(monkeypatch, type(loop.integrator), "step", stepped, loop.integrator)
    monkeypatch.setattr(loop.stepper, "live_targets", True)  # a show: live inputs behind them
    assert _warm(loop, 3) is None
    assert sampled == [] and stepped == [False] * 3


def test_the_runs_stop_at_the_budget(tick, monkeypatch):
    loop = tick.loop
    filtered = []
    _spy(monkeypatch, SafetyFilter, "filter", filtered, loop.safety)
    monkeypatch.setattr(warm_mod, "BUDGET_S", -1.0)  # past it from the start: one run
    assert _warm(loop, 16) is None
    assert filtered == [False]


def test_a_warm_up_that_fails_does_nothing_and_says_what(tick, monkeypatch):
    loop = tick.loop

    def broken(self, x):
        raise ValueError("3 joint angles for 2 joints")

    monkeypatch.setattr(type(loop.map), "to_servo_list", broken)
    before = _state(loop)
    assert _warm(loop) == "ValueError: 3 joint angles for 2 joints"
    monkeypatch.undo()
    _assert_untouched(loop, before)
