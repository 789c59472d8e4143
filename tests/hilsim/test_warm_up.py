"""The warm-up before a real-time show's tick 0 (hilsim.warm_up): the tick's stages but the
bus run on copies, the show's own parts untouched, a failure skipped and said."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import hilsim.warm_up as warm_mod
from hilsim.bench.tick import HilsimTick
from hilsim.safety import SafetyFilter


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


def test_the_stages_run_n_times_on_copies_and_the_show_keeps_nothing(tmp_path: Path, monkeypatch):
    tick = HilsimTick(4, tmp_path)
    try:
        loop = tick.loop
        calls = []
        filt = SafetyFilter.filter

        def counted(self, desired, out):  # the class's method: the warm-up calls it
            calls.append(self is loop.safety)
            return filt(self, desired, out)

        monkeypatch.setattr(SafetyFilter, "filter", counted)
        loop.safety.filter = lambda *a: (_ for _ in ()).throw(AssertionError("instance spy"))
        before = _state(loop)
        assert warm_mod.warm_up(loop, 7) is None
        after = _state(loop)
        assert calls == [False] * 7  # seven times, never on the show's own filter
        for a, b in zip(before["arrays"], after["arrays"], strict=True):
            np.testing.assert_array_equal(a, b)
        assert before["safety"] == after["safety"]
        assert after["targets_view"] is before["targets_view"]
        assert after["stats"] == before["stats"] and after["ring"] == before["ring"]
        assert after["held"] is before["held"]
    finally:
        tick.close()


def test_parts_that_cannot_be_copied_are_left_out_and_the_rest_warmed(tmp_path: Path, monkeypatch):
    """A show's live targets hold locks: not copied, not sampled; the others still run."""
    tick = HilsimTick(2, tmp_path)
    try:
        loop = tick.loop
        deepcopy, filtered = warm_mod.copy.deepcopy, []

        def refuse_targets(obj, memo=None):
            if obj is loop.targets:
                raise TypeError("cannot pickle '_thread.lock' object")
            return deepcopy(obj, memo)

        filt = SafetyFilter.filter
        monkeypatch.setattr(warm_mod.copy, "deepcopy", refuse_targets)
        monkeypatch.setattr(SafetyFilter, "filter", lambda *a: filtered.append(1) or filt(*a))
        sample = type(loop.targets).sample_into
        monkeypatch.setattr(
            type(loop.targets), "sample_into", lambda *a: pytest.fail("sampled the show's targets")
        )
        before = _state(loop)
        assert warm_mod.warm_up(loop, 5) is None
        monkeypatch.setattr(type(loop.targets), "sample_into", sample)
        assert len(filtered) == 5
        assert _state(loop)["stats"] == before["stats"]
    finally:
        tick.close()


def test_a_warm_up_that_fails_does_nothing_and_says_what(tmp_path: Path, monkeypatch):
    tick = HilsimTick(2, tmp_path)
    try:
        loop = tick.loop

        def broken(self, x):
            raise ValueError("3 joint angles for 2 joints")

        monkeypatch.setattr(type(loop.map), "to_servo_list", broken)
        before = _state(loop)
        assert warm_mod.warm_up(loop) == "ValueError: 3 joint angles for 2 joints"
        after = _state(loop)
        assert after["stats"] == before["stats"] and after["safety"] == before["safety"]
    finally:
        tick.close()
