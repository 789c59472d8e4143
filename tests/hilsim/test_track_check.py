"""Load-time track checks: targets beyond a joint's limits or speed are found and worded."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from hilsim.rig import load_rig
from hilsim.show.parts import build_targets
from hilsim.targets import Hold, Keyframes, Sine, TargetSet
from hilsim.targets.check import TrackWarning, _sample, check_tracks
from hilsim.targets.csv_file import CsvCurve

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
PERIOD = 1.0 / 64.0  # exact in binary: tick times k/64 are exact, so the counts are too
rad = math.radians


@dataclass
class Joint:
    name: str
    min_rad: float = rad(-30.0)
    max_rad: float = rad(30.0)
    max_speed_rad_s: float = rad(60.0)


def check(*tracks, **kw) -> list[TrackWarning]:
    names = [f"j{i}" for i in range(len(tracks))]
    return check_tracks(TargetSet(tracks, names), [Joint(n) for n in names], PERIOD, **kw)


def test_targets_within_every_limit_give_no_warning():
    # on the limits, and exactly at the speed limit (60°/s): rounding is not reported
    assert check(Keyframes([0, 1, 2, 3], [0.0, rad(30.0), rad(-30.0), 0.0])) == []
    assert check(Keyframes([0.0, 1.0], [0.0, rad(30.0)]), Hold(rad(-30.0))) == []


def test_keyframe_beyond_max_first_worst_and_total():
    # 0 → 60° → 0 over 2 s: beyond 30° for t in (0.5, 1.5): ticks 33..95 of 1/64 s
    (w,) = check(Keyframes([0, 1, 2], [0.0, rad(60.0), 0.0]), **{"horizon_s": 1.0})
    assert (w.joint, w.kind, w.limit) == ("j0", "max", rad(30.0))
    assert w.first_t == 33 / 64 and w.first_value == pytest.approx(rad(60.0 * 33 / 64))
    assert w.worst_t == 1.0 and w.worst_value == pytest.approx(rad(60.0))
    assert w.total_s == 63 / 64 and w.checked_s is None
    assert str(w) == (
        "j0: target 30.9° at t = 0.516 s is beyond max_deg 30° "
        "(worst 60° at t = 1.00 s; 0.984 s beyond in all)"
    )


def test_below_min_and_a_value_just_beyond_is_printed_beyond():
    (w,) = check(Hold(rad(-30.004)), duration_s=2.0)
    assert w.kind == "min" and w.first_t == 0.0 and w.total_s == 129 / 64  # ticks 0..128
    assert (
        str(w) == "j0: target -30.004° at t = 0.00 s is beyond min_deg -30° (2.02 s beyond in all)"
    )


def test_speed_too_fast_and_jumps():
    # 0 → 30° in 0.25 s: 120°/s for 16 ticks; then a step easing jumps to 10° at t = 1
    track = Keyframes([0.0, 0.25, 1.0, 2.0], [0.0, rad(30.0), rad(10.0), rad(10.0)],
                      ["linear", "step", "linear"])  # fmt: skip
    (w,) = check(track)
    assert w.kind == "speed" and w.limit == rad(60.0)
    assert w.first_t == 0.0 and w.first_value == pytest.approx(rad(120.0))
    # the jump: -20° in the tick from 63/64 to 1 s, -1280°/s
    assert w.worst_t == 63 / 64 and w.worst_value == pytest.approx(rad(-20.0) * 64)
    assert w.total_s == 17 / 64
    assert str(w) == (
        "j0: target speed 120°/s at t = 0.00 s exceeds max_speed_deg_s 60°/s "
        "(worst 1280°/s at t = 0.984 s; 0.266 s faster in all): raise max_speed_deg_s "
        "(within the servo's), slow the animation, or accept it (the safety filter holds the "
        "joint to its limit)"
    )


def test_the_show_runs_past_the_last_key_holding_its_value():
    # ends at 40° at t = 1; the show lasts 10 s: beyond from t = 0.75 + to the end, tick 640
    (w,) = check(Keyframes([0.0, 1.0], [0.0, rad(40.0)]), duration_s=10.0)
    first = math.floor(0.75 * 64) + 1
    assert w.first_t == first / 64 and w.total_s == (640 - first + 1) / 64
    # and a shorter show than the animation stops the check where the show stops
    (w,) = check(Keyframes([0.0, 1.0], [0.0, rad(40.0)]), duration_s=0.875)
    assert w.total_s == (56 - first + 1) / 64


def test_endless_generators_are_checked_over_the_horizon_and_say_so():
    sine = Sine(rad(45.0), 0.2)  # beyond ±30° part of each 5 s period; 56.5°/s at most
    ws = check(sine, horizon_s=8.0)
    assert [w.kind for w in ws] == ["min", "max"]
    assert all(w.checked_s == 8.0 for w in ws)
    assert str(ws[1]).endswith("of the first 8.00 s)")
    # a show of a known length (here the keyframes' 8 s) checks the generator over all of it
    ws = check(sine, Keyframes([0.0, 8.0], [0.0, 0.0]), horizon_s=2.0)
    assert [(w.joint, w.kind, w.checked_s) for w in ws] == [
        ("j0", "min", None),
        ("j0", "max", None),
    ]


def test_chunks_join_up(monkeypatch):
    # the speed across a chunk border is the one between the chunks' samples
    import hilsim.targets.check as tc

    track = Keyframes([0.0, 2.0, 2.0 + PERIOD, 4.0], [0.0, 0.0, rad(20.0), rad(20.0)])
    (whole,) = check(track)
    monkeypatch.setattr(tc, "CHUNK_TICKS", 7)
    assert check(track) == [whole]
    assert whole.kind == "speed" and whole.first_t == 2.0 and whole.total_s == PERIOD


def test_csv_tracks_are_sampled_as_the_loop_samples_them():
    times = np.array([0.0, 0.3, 0.31, 2.0])
    curve = CsvCurve(times, np.array([0.0, 0.2, -0.1, 0.4]))
    t = np.arange(200) * PERIOD
    np.testing.assert_array_equal(_sample(curve, t), [curve.sample(float(x))[0] for x in t])
    single = CsvCurve([0.5], [0.1])
    np.testing.assert_array_equal(_sample(single, t), 0.1)


def test_demo_and_hardware_example_are_within_their_limits():
    for name in ("demo.toml", "hardware_example.toml"):
        rig = load_rig(CONFIGS / name)
        assert check_tracks(build_targets(rig), rig.joints, rig.loop.period_s) == [], name


def test_arguments_are_checked():
    targets = TargetSet([Hold(0.0)], ["a"])
    with pytest.raises(ValueError, match="2 joints for 1 tracks"):
        check_tracks(targets, [Joint("a"), Joint("b")], PERIOD)
    for kw, match in (
        ({"period_s": 0.0}, "period_s"),
        ({"period_s": PERIOD, "horizon_s": math.inf}, "horizon_s"),
        ({"period_s": PERIOD, "duration_s": -1.0}, "duration_s"),
    ):
        with pytest.raises(ValueError, match=match):
            check_tracks(targets, [Joint("a")], **kw)
