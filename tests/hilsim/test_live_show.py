"""The show runtime in virtual time: cues with lockout and windows, timers, idle, timeline,
`then`, priorities, sounds; the review's R4 cue-list acceptance. Pure: no clocks, no sleeps."""

from __future__ import annotations

import itertools
import math
import tomllib
from datetime import datetime
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilsim.live.show import MAX_PENDING, ShowRuntime
from hilsim.live.show_spec import read_runtime
from hilsim.targets.spec import track_from_spec
from hilsim.targets.tracks import Hold

JOINTS = ("jaw", "head_pan")
DT = 0.004


def make_track(spec: dict, joint: str, where: str):
    try:
        return track_from_spec(spec, joint_name=joint)
    except ValueError as exc:
        raise ValueError(f"show.toml: {where}: {exc}") from None


def runtime(text: str, tmp_path: Path = Path("."), *, seed: int = 0, wall=None) -> ShowRuntime:
    spec = read_runtime(tomllib.loads(text), "show.toml", tmp_path, JOINTS, make_track)
    base = [Hold(math.radians(-5.0)), Hold(math.radians(-7.0))]
    return ShowRuntime(spec, JOINTS, base, seed=seed, wall_start=wall)


def deg(rt: ShowRuntime, joint: str, t: float) -> float:
    return math.degrees(rt.tracks[JOINTS.index(joint)].sample(t)[0])


def run(rt: ShowRuntime, until: float, triggers: dict[float, str] = {}, dt: float = DT):  # noqa: B006
    """Tick every dt up to ``until``; a trigger at the first tick at or after its time."""
    pending = sorted(triggers.items())
    events = []
    for k in range(round(until / dt) + 1):
        t = k * dt
        while pending and pending[0][0] <= t + 1e-9:
            rt.trigger(pending.pop(0)[1], t)
        events += rt.tick(t)
    return events


def kinds(events, skip=("clip_start",)):
    return [(ev.kind, ev.t) for ev in events if ev.kind not in skip]


R4 = """
[clips.breathe]
jaw = { type = "keyframes", keys = [[0, 10], [1, 12], [2.2, 10]] }
[clips.look_around]
head_pan = { type = "keyframes", keys = [[0, 0], [1.5, 20], [2.5, 0]] }
[clips.scare]
jaw = { type = "keyframes", keys = [[0, 30], [1, 5], [4, 10]] }
[idle]
clips = ["breathe", "look_around"]
order = "random"
seed = 1
[cues.scare]
trigger = "osc:/trigger/pir"
clip = "scare"
then = "idle"
lockout_s = 10
"""


def test_r4_cue_list_acceptance() -> None:
    rt = runtime(R4)
    events = run(rt, 12.0, {5.0: "osc:/trigger/pir", 8.0: "osc:/trigger/pir"})
    got = kinds(events)
    assert [k for k, _ in got] == ["cue_start", "cue_ignored", "cue_end", "idle_resume"]
    for (_, t), want in zip(got, (5.0, 8.0, 9.0, 9.0), strict=True):
        assert want <= t + 1e-9 < want + DT
    ignored = events[[e.kind for e in events].index("cue_ignored")]
    assert ignored.detail["reason"] == "lockout" and ignored.source == "show"
    assert all("message" in e.detail for e in events)
    # the idle clips alternate (random, never the same twice in a row) and resume after
    idle = [
        e.detail["clip"] for e in events if e.kind == "clip_start" and not e.detail.get("resumed")
    ]
    assert len(idle) > 4 and all(a != b for a, b in itertools.pairwise(idle))
    assert any(e.detail.get("resumed") for e in events if e.kind == "clip_start")
    again = runtime(R4)
    assert [(e.kind, e.t, e.detail) for e in run(again, 12.0, {5.0: "osc:/trigger/pir"})][:3] == [
        (e.kind, e.t, e.detail) for e in events
    ][:3]  # the same seed, the same show


def test_scare_starts_at_its_first_pose_on_the_tick_after_the_trigger() -> None:
    rt = runtime(
        R4.replace('"breathe", "look_around"', '"still"')
        + """
[clips.still]
jaw = { type = "hold", value_deg = 10 }
"""
    )
    run(rt, 2.996)
    assert deg(rt, "jaw", 2.996) == pytest.approx(10.0)
    rt.trigger("osc:/trigger/pir", 3.0)
    assert deg(rt, "jaw", 3.0) == pytest.approx(10.0)  # not before the tick
    events = rt.tick(3.0)
    assert events[0].kind == "cue_start" and events[0].t == 3.0
    assert deg(rt, "jaw", 3.0) == pytest.approx(30.0)
    assert deg(rt, "head_pan", 3.0) == pytest.approx(-7.0)  # no clip drives it: its base
    assert rt.now_playing == "cue scare (0.0/4.0 s)"
    run_from(rt, 3.0, 5.0)
    assert rt.now_playing.startswith("cue scare (2.0")
    rt.trigger("osc:/trigger/pir", 5.0)
    assert [e.detail["reason"] for e in rt.tick(5.004)] == ["lockout"]


def run_from(rt: ShowRuntime, t0: float, t1: float, dt: float = DT) -> list:
    events, k = [], 1
    while t0 + k * dt <= t1 + 1e-9:
        events += rt.tick(t0 + k * dt)
        k += 1
    return events


CUES = """
[clips.a]
jaw = { type = "keyframes", keys = [[0, 30], [1, 20]] }
[clips.b]
jaw = { type = "keyframes", keys = [[0, 0], [2, 8]] }
[clips.rest]
jaw = { type = "hold", value_deg = 1 }
[idle]
clips = ["rest"]
[cues.a]
trigger = ["key:a", "midi:note:60"]
clip = "a"
then = "b"
[cues.b]
trigger = "key:b"
clip = "b"
"""


def test_then_another_cue_then_idle() -> None:
    rt = runtime(CUES)
    events = kinds(run(rt, 4.0, {0.5: "key:a"}))
    assert [k for k, _ in events] == ["cue_start", "cue_end", "cue_start", "cue_end", "idle_resume"]
    assert [round(t, 6) for _, t in events] == [0.5, 1.5, 1.5, 3.5, 3.5]
    assert rt.now_playing == "idle rest" and deg(rt, "jaw", 4.0) == pytest.approx(1.0)


def test_midi_note_without_channel_means_channel_1_and_a_cut() -> None:
    rt = runtime(CUES)
    assert "midi:note:60:ch1" in rt.trigger_keys and "osc:/hilsim/cue/b" in rt.trigger_keys
    events = run(rt, 1.0, {0.2: "midi:note:60:ch1", 0.6: "osc:/hilsim/cue/b"})
    cut = [e for e in events if e.kind == "cue_end"]
    assert cut[0].detail["reason"] == "cut" and cut[0].detail["cue"] == "a"
    assert deg(rt, "jaw", 0.6) == pytest.approx(0.0)  # b's first pose
    rt.trigger("midi:note:60", 1.0)  # the short form is the same key
    assert rt.tick(1.004)[-1].detail["cue"] == "a"


def test_then_hold_keeps_the_last_pose_until_the_next_cue() -> None:
    rt = runtime(CUES.replace('then = "b"', 'then = "hold"'))
    run(rt, 3.0, {0.0: "key:a"})
    assert rt.now_playing == "hold a"
    assert rt.tracks[0].sample(2.0) == (pytest.approx(math.radians(20.0)), 0.0)
    rt.trigger("key:b", 3.0)
    events = rt.tick(3.004)
    assert [e.kind for e in events] == ["cue_start"]  # a held cue already ended
    assert deg(rt, "jaw", 3.004) == pytest.approx(0.0)


def test_priority_cue_over_timeline_over_idle_over_base() -> None:
    rt = runtime("""
[clips.idle]
jaw = { type = "hold", value_deg = 1 }
head_pan = { type = "hold", value_deg = 2 }
[clips.song]
head_pan = { type = "hold", value_deg = 3 }
[clips.jab]
jaw = { type = "keyframes", keys = [[0, 4], [1, 4]] }
[idle]
clips = ["idle"]
[cues.jab]
trigger = "key:j"
clip = "jab"
[[timeline]]
at_s = 1
clip = "song"
""")
    run(rt, 0.5)
    assert (deg(rt, "jaw", 0.5), deg(rt, "head_pan", 0.5)) == pytest.approx((1, 2))
    assert rt.now_playing == "idle idle"
    run_from(rt, 0.5, 1.0)
    assert (deg(rt, "jaw", 1.0), deg(rt, "head_pan", 1.0)) == pytest.approx((1, 3))
    assert rt.now_playing == "timeline song"
    rt.trigger("key:j", 1.0)
    run_from(rt, 1.0, 1.5)
    assert (deg(rt, "jaw", 1.5), deg(rt, "head_pan", 1.5)) == pytest.approx((4, 3))
    assert rt.duration is None


def test_timeline_loops_and_a_timeline_only_show_has_an_end() -> None:
    text = """
[clips.ramp]
jaw = { type = "keyframes", keys = [[0, 0], [2, 20]] }
[clips.last]
jaw = { type = "keyframes", keys = [[0, 5], [1.5, 6]] }
[[timeline]]
at_s = 1
clip = "ramp"
loop = true
[[timeline]]
at_s = 10
clip = "last"
"""
    rt = runtime(text)
    run(rt, 0.5)
    assert deg(rt, "jaw", 0.5) == pytest.approx(-5.0)  # before the timeline: the base
    events = rt.tick(0.5) + run_from(rt, 0.5, 10.0)
    rt2 = runtime(text)
    run(rt2, 3.5)
    assert deg(rt2, "jaw", 3.5) == pytest.approx(5.0)  # 2.5 s in, wrapped at 2 s
    starts = [e.t for e in events if e.kind == "clip_start"]
    assert starts == pytest.approx([1.0, 3.0, 5.0, 7.0, 9.0, 10.0], abs=DT)
    assert rt.duration == 11.5
    assert runtime(text.replace("at_s = 10", "at_s = 10\nloop = true")).duration is None


def test_timeline_clip_end_gives_the_front_back_to_idle() -> None:
    rt = runtime("""
[clips.rest]
jaw = { type = "hold", value_deg = 1 }
[clips.song]
jaw = { type = "keyframes", keys = [[0, 9], [1, 9]] }
[idle]
clips = ["rest"]
[[timeline]]
at_s = 2
clip = "song"
""")
    got = kinds(run(rt, 4.0))
    assert got == [("clip_end", 3.0), ("idle_resume", 3.0)]
    assert deg(rt, "jaw", 4.0) == pytest.approx(1.0)


TIMED = """
[clips.c]
jaw = { type = "keyframes", keys = [[0, 3], [0.5, 3]] }
[cues.tick]
trigger = ["every:2", "at:3.5"]
clip = "c"
"""


def test_every_and_at_timers() -> None:
    starts = [e.t for e in run(runtime(TIMED), 7.0) if e.kind == "cue_start"]
    assert starts == pytest.approx([2.0, 3.5, 4.0, 6.0], abs=DT)


def test_daily_trigger_fires_once_a_day_at_its_time() -> None:
    text = TIMED.replace('["every:2", "at:3.5"]', '"daily:19:30"')
    rt = runtime(text, wall=datetime(2024, 6, 1, 19, 29, 58))
    starts = [e.t for e in run(rt, 6.0, dt=0.01) if e.kind == "cue_start"]
    assert starts == pytest.approx([2.0], abs=0.01)
    late = runtime(text, wall=datetime(2024, 6, 1, 19, 31))
    assert late.tick(0.0) == [] and late.tick(86339.0) == []
    assert [e.kind for e in late.tick(86340.0)] == ["cue_start"]  # 19:30 the next day
    assert "cue_start" not in [e.kind for e in late.tick(86341.0)]


@pytest.mark.parametrize(
    ("window", "start", "fires"),
    [
        ("18:00-23:00", (17, 59, 59), [False, True, True, False]),
        ("22:00-02:00", (21, 59, 59), [False, True, True, False]),  # wraps midnight
        ("00:00-24:00", (21, 59, 59), [True, True, True, True]),
    ],
)
def test_cue_window(window, start, fires) -> None:
    text = TIMED.replace('["every:2", "at:3.5"]', '"key:x"') + f'window = "{window}"\n'
    rt = runtime(text, wall=datetime(2024, 12, 31, *start))
    length = 5 * 3600 if window.startswith("18") else 4 * 3600  # to the window's end
    got = []
    for t in (0.0, 2.0, length - 1.0, length + 1.0):
        rt.trigger("key:x", t)
        ev = [e for e in rt.tick(t) if e.kind in ("cue_start", "cue_ignored")]
        got.append(ev[0].kind == "cue_start")
        if ev[0].kind == "cue_ignored":
            assert ev[0].detail["reason"] == "window"
    assert got == fires


def test_sounds_go_with_the_clip_in_front(tmp_path: Path) -> None:
    (tmp_path / "scream.wav").write_bytes(b"RIFF")
    (tmp_path / "hum.wav").write_bytes(b"RIFF")
    rt = runtime(
        """
[clips.hum]
jaw = { type = "keyframes", keys = [[0, 1], [10, 2]] }
[clips.scare]
jaw = { type = "keyframes", keys = [[0, 30], [1, 10]] }
[sounds]
hum = "hum.wav"
scare = { file = "scream.wav", offset_ms = 250 }
[idle]
clips = ["hum"]
[cues.scare]
trigger = "key:s"
clip = "scare"
""",
        tmp_path,
    )
    first = rt.tick(0.0)
    assert first[0].detail["sound"] == str(tmp_path / "hum.wav")
    assert first[0].detail["sound_offset_s"] == 0.0
    events = run_from(rt, 0.0, 0.2)
    rt.trigger("key:s", 0.2)
    events = rt.tick(0.2) + run_from(rt, 0.2, 1.5)
    start = next(e for e in events if e.kind == "cue_start")
    assert start.detail["sound"] == str(tmp_path / "scream.wav")
    assert start.detail["sound_offset_s"] == 0.0  # from the file's start ...
    assert rt.spec.sounds["scare"].offset_s == 0.25  # ... heard 250 ms late (the player's)
    resumed = next(e for e in events if e.kind == "clip_start")
    assert resumed.detail["resumed"] and resumed.t == pytest.approx(1.2)
    assert resumed.detail["sound_offset_s"] == pytest.approx(1.2)  # the hum, 1.2 s in
    assert set(rt.spec.sounds) == {"hum", "scare"}


def test_offset_shifts_clip_time_and_an_endless_idle_plays_on() -> None:
    rt = runtime("""
[clips.wave]
jaw = { type = "sine", amplitude_deg = 10, frequency_hz = 0.25 }
[idle]
clips = ["wave"]
order = "random"
""")
    events = run(rt, 20.0)
    assert [e.kind for e in events] == ["clip_start"]
    assert deg(rt, "jaw", 1.0) == pytest.approx(10.0)
    rt.offset = 1.0
    assert deg(rt, "jaw", 0.0) == pytest.approx(10.0)


def test_unmatched_keys_are_said_once_and_a_flood_is_dropped_and_counted() -> None:
    rt = runtime(CUES)
    rt.trigger("key:zz", 0.0)
    rt.trigger("key:zz", 0.0)
    assert [e.kind for e in rt.tick(0.0)] == ["clip_start", "trigger_unmatched"]
    for _ in range(MAX_PENDING + 36):
        rt.trigger("key:b", 0.1)
    events = rt.tick(0.1)
    dropped = next(e for e in events if e.kind == "triggers_dropped")
    assert dropped.detail["count"] == 36
    assert [e.detail["reason"] for e in events if e.kind == "cue_ignored"] == ["duplicate"] * 63


KEYS = ["key:a", "key:b", "midi:note:60", "osc:/hilsim/cue/b", "key:nope", "osc:/x", "bad"]


@settings(max_examples=150, deadline=None)
@given(
    steps=st.lists(
        st.tuples(
            st.floats(0.0, 3.0, allow_nan=False),
            st.lists(st.sampled_from(KEYS), max_size=4),
        ),
        max_size=40,
    ),
    lockout=st.sampled_from([0, 0.5, 10]),
    then=st.sampled_from(["idle", "hold", "b", "a"]),
)
def test_random_triggers_never_raise_and_events_are_in_time_order(steps, lockout, then) -> None:
    text = CUES.replace('then = "b"', f'then = "{then}"\nlockout_s = {lockout}')
    rt = runtime(text + '\n[[timeline]]\nat_s = 2\nclip = "b"\nloop = true\n')
    t, last = 0.0, -math.inf
    for dt, keys in steps:
        t += dt
        for key in keys:
            rt.trigger(key, t)
        for ev in rt.tick(t):
            assert last <= ev.t <= t
            last = ev.t
        for sub in (t, t + 0.001, t + 0.002):
            assert all(math.isfinite(x) for tr in rt.tracks for x in tr.sample(sub))
        assert isinstance(rt.now_playing, str)
