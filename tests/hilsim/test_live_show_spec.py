"""The show file's clips, sounds, idle, cues and timeline: what is read, and every bad input as
one ValueError line naming the file and the key. Also the trigger grammar and windows."""

from __future__ import annotations

import math
import tomllib
from datetime import datetime
from pathlib import Path

import pytest

from hilsim.live.show_spec import read_runtime
from hilsim.live.triggers import (
    Timers,
    Trigger,
    normalise_key,
    parse_trigger,
    parse_window,
)
from hilsim.targets.spec import track_from_spec

JOINTS = ("jaw", "head_pan")


def make_track(spec: dict, joint: str, where: str):
    try:
        return track_from_spec(spec, joint_name=joint)
    except ValueError as exc:
        raise ValueError(f"show.toml: {where}: {exc}") from None


def read(text: str, tmp_path: Path = Path(".")):
    return read_runtime(tomllib.loads(text), "show.toml", tmp_path, JOINTS, make_track)


BASE = """
[clips.a]
jaw = { type = "keyframes", keys = [[0, 1], [2, 3]] }
head_pan = { type = "sine", amplitude_deg = 5, frequency_hz = 1 }
[clips.b]
jaw = { type = "hold", value_deg = 4 }
[clips.zero]
jaw = { type = "keyframes", keys = [[0, 1]] }
[clips.tiny]
jaw = { type = "keyframes", keys = [[0, 1], [0.01, 2]] }
"""


def test_a_full_show_is_read(tmp_path: Path) -> None:
    (tmp_path / "audio").mkdir()
    (tmp_path / "audio" / "s.wav").write_bytes(b"RIFF")
    spec = read(
        BASE
        + """
[sounds]
a = "audio/s.wav"
b = { file = "audio/s.wav", offset_ms = 120 }
[idle]
clips = ["a", "b"]
order = "random"
seed = 3
[cues.scare]
trigger = ["osc:/trigger/pir", "midi:cc:64", "key:s", "every:30", "daily:19:30"]
clip = "a"
then = "hold"
lockout_s = 10
window = "22:00-02:00"
[cues.other]
clip = "b"
then = "scare"
[[timeline]]
at_s = 0
clip = "b"
[[timeline]]
at_s = 2.5
clip = "a"
loop = true
""",
        tmp_path,
    )
    assert spec.clips["a"].duration == 2.0 and spec.clips["b"].duration is None
    assert set(spec.clips["a"].tracks) == {"jaw", "head_pan"}
    assert spec.sounds["a"].path == tmp_path / "audio" / "s.wav"
    assert spec.sounds["b"].offset_s == pytest.approx(0.12)
    assert spec.idle.clips == ("a", "b") and spec.idle.order == "random" and spec.idle.seed == 3
    scare = spec.cues["scare"]
    assert [t.kind for t in scare.triggers] == ["osc", "midi", "key", "every", "daily"]
    assert scare.then == "hold" and scare.lockout_s == 10.0 and scare.window.text == "22:00-02:00"
    assert spec.cues["other"].triggers == () and spec.cues["other"].then == "scare"
    assert [(e.at_s, e.clip, e.loop) for e in spec.timeline] == [(0, "b", False), (2.5, "a", True)]
    assert spec.trigger_keys == (
        "key:s",
        "midi:cc:64:ch1",
        "osc:/hilsim/cue/other",
        "osc:/hilsim/cue/scare",
        "osc:/trigger/pir",
    )


def test_the_short_idle_form_and_defaults() -> None:
    spec = read('idle = ["a"]\n' + BASE + '[cues.c]\ntrigger = "key:c"\nclip = "b"\n')
    assert spec.idle.clips == ("a",) and spec.idle.order == "sequence" and spec.idle.seed is None
    cue = spec.cues["c"]
    assert (cue.then, cue.lockout_s, cue.window) == ("idle", 0.0, None)


CUE = '[cues.x]\ntrigger = "key:x"\nclip = "a"\n'


@pytest.mark.parametrize(
    ("extra", "key", "words"),
    [
        ('[clips."bad name"]\njaw = { type = "hold", value_deg = 1 }', "clips.bad name", "letters"),
        ("[clips.c]\nneck = { type = 'hold', value_deg = 1 }", "clips.c.neck", "no such joint"),
        ("[clips.c]\njaw = 3", "clips.c.jaw", "target table"),
        ("clips.c = {}", "clips.c", "table of"),
        ("[clips.c]\njaw = { type = 'nope' }", "clips.c.jaw", ""),
        ("[sounds]\nnope = 'x.wav'", "sounds.nope", "no clip"),
        ("[sounds]\na = 'missing.wav'", "sounds.a", "missing.wav"),
        ("[sounds]\na = { file = 'missing.wav' }", "sounds.a.file", "no such sound file"),
        ("[sounds]\na = { offset_ms = 3 }", "sounds.a.file", "missing"),
        ("[sounds]\na = { file = 'x.wav', volume = 3 }", "sounds.a.volume", "unknown key"),
        ("[sounds]\na = 5", "sounds.a", "path"),
        ("[idle]\nclips = ['nope']", "idle.clips[0]", "no clip 'nope'"),
        ("[idle]\nclips = []", "idle.clips", "one or more"),
        ("[idle]\nclips = ['zero']", "idle.clips[0]", "lasts 0 s"),
        ("[idle]\nclips = ['tiny']", "idle.clips[0]", "0.1 s or more"),
        ("[[timeline]]\nat_s = 0\nclip = 'tiny'\nloop = true", "timeline[0].loop", "0.1 s or more"),
        (
            "[cues.x]\nclip = 'zero'\nthen = 'y'\n[cues.y]\nclip = 'tiny'\nthen = 'x'",
            "cues.x.then",
            "x -> y -> x go round",
        ),
        ("[idle]\nclips = ['a']\norder = 'shuffle'", "idle.order", "sequence, random"),
        ("[idle]\nclips = ['a']\nseed = -1", "idle.seed", "integer"),
        ("[idle]\nclips = ['a']\nloop = true", "idle.loop", "unknown key"),
        ("idle = 3", "idle", "table"),
        (CUE + "bogus = 1", "cues.x.bogus", "unknown key"),
        ('[cues.x]\ntrigger = "key:x"', "cues.x.clip", "missing"),
        ('[cues.x]\nclip = "nope"', "cues.x.clip", "no clip 'nope'"),
        (CUE + 'then = "nope"', "cues.x.then", "'idle', 'hold' or a cue"),
        (CUE + "lockout_s = -1", "cues.x.lockout_s", "in 0..604800"),
        (CUE + "lockout_s = 1e300", "cues.x.lockout_s", "in 0..604800"),
        (CUE + "lockout_s = nan", "cues.x.lockout_s", "finite"),
        (CUE + "lockout_s = inf", "cues.x.lockout_s", "finite"),
        (CUE + "lockout_s = true", "cues.x.lockout_s", "number"),
        (CUE + 'window = "18-23"', "cues.x.window", "HH:MM-HH:MM"),
        (CUE + 'window = "18:00-18:00"', "cues.x.window", "empty"),
        (CUE + 'window = "18:00-24:30"', "cues.x.window", "HH:MM-HH:MM"),
        (CUE + 'window = "25:00-02:00"', "cues.x.window", "HH:MM-HH:MM"),
        ('[cues.x]\ntrigger = "osc:nope"\nclip = "a"', "cues.x.trigger", "osc:/address"),
        ('[cues.x]\ntrigger = "midi:note:200"\nclip = "a"', "cues.x.trigger", "0-127"),
        ('[cues.x]\ntrigger = "midi:note:1:ch17"\nclip = "a"', "cues.x.trigger", "ch1-ch16"),
        ('[cues.x]\ntrigger = "midi:pc:1"\nclip = "a"', "cues.x.trigger", "midi:note"),
        ('[cues.x]\ntrigger = "every:0"\nclip = "a"', "cues.x.trigger", "> 0"),
        ('[cues.x]\ntrigger = "at:-1"\nclip = "a"', "cues.x.trigger", ">= 0"),
        ('[cues.x]\ntrigger = "daily:25:00"\nclip = "a"', "cues.x.trigger", "00:00-23:59"),
        ('[cues.x]\ntrigger = "foo:bar"\nclip = "a"', "cues.x.trigger", "unknown trigger"),
        ('[cues.x]\ntrigger = "key:"\nclip = "a"', "cues.x.trigger", "key:<name>"),
        ('[cues.x]\ntrigger = ["key:s", 3]\nclip = "a"', "cues.x.trigger[1]", "a string"),
        ('[cues.x]\ntrigger = 3\nclip = "a"', "cues.x.trigger", "a string or a list"),
        ('[cues.idle]\nclip = "a"', "cues.idle", "`then`"),
        ('[cues."a b"]\nclip = "a"', "cues.a b", "a cue name"),
        ("cues.x = 1", "cues.x", "table"),
        ("[[timeline]]\nat_s = 0\nclip = 'nope'", "timeline[0].clip", "no clip 'nope'"),
        ("[[timeline]]\nclip = 'a'", "timeline[0].at_s", "missing"),
        ("[[timeline]]\nat_s = 0", "timeline[0].clip", "missing"),
        ("[[timeline]]\nat_s = -1\nclip = 'a'", "timeline[0].at_s", "in 0..604800"),
        ("[[timeline]]\nat_s = 1e9\nclip = 'a'", "timeline[0].at_s", "in 0..604800"),
        ("[[timeline]]\nat_s = 0\nclip = 'a'\nloop = 'yes'", "timeline[0].loop", "true or"),
        ("[[timeline]]\nat_s = 0\nclip = 'a'\nspeed = 2", "timeline[0].speed", "unknown key"),
        (
            "[[timeline]]\nat_s = 2\nclip = 'a'\n[[timeline]]\nat_s = 1\nclip = 'b'",
            "timeline[1].at_s",
            "after timeline[0]",
        ),
        ("timeline = 3", "timeline", "[[timeline]]"),
    ],
)
def test_every_bad_input_is_one_line_naming_the_key(tmp_path, extra, key, words) -> None:
    (tmp_path / "x.wav").write_bytes(b"RIFF")
    with pytest.raises(ValueError) as err:
        top = not extra.startswith("[")  # a top-level key goes before the tables
        read(extra + "\n" + BASE if top else BASE + extra + "\n", tmp_path)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith(f"show.toml: {key}: "), msg
    assert words in msg


@pytest.mark.parametrize(
    ("text", "kind", "key", "value"),
    [
        ("osc:/hilsim/cue/scare", "osc", "osc:/hilsim/cue/scare", 0.0),
        ("midi:note:60", "midi", "midi:note:60:ch1", 0.0),
        ("midi:note:060:ch02", "midi", "midi:note:60:ch2", 0.0),
        ("midi:cc:64:ch16", "midi", "midi:cc:64:ch16", 0.0),
        ("key:s", "key", "key:s", 0.0),
        ("key:F1", "key", "key:F1", 0.0),
        ("every:30", "every", "every:30", 30.0),
        ("every:0.5", "every", "every:0.5", 0.5),
        ("at:12.5", "at", "at:12.5", 12.5),
        ("at:0", "at", "at:0", 0.0),
        ("daily:19:30", "daily", "daily:19:30", 19.5 * 3600),
        ("daily:0:05", "daily", "daily:0:05", 300.0),
    ],
)
def test_trigger_grammar(text, kind, key, value) -> None:
    assert parse_trigger(text) == Trigger(kind, key, value)


@pytest.mark.parametrize(
    "text",
    [
        "osc:/a b",
        "osc:/a*",
        "osc:",
        "midi:note:60:ch0",
        "every:nan",
        "every:inf",
        "at:1e400",
        "daily:12:60",
        "daily:24:00",
        "",
        "key:a b",
        "every:soon",
        "at:-1",
        None,
    ],
)
def test_bad_triggers(text) -> None:
    with pytest.raises(ValueError) as info:
        parse_trigger(text)
    # the trigger's own line, naming it; not a ValueError from a conversion inside
    said = str(info.value)
    assert "\n" not in said
    assert said.startswith(f"{text!r}: ") if text is not None else said.endswith("got None")


def test_normalise_key_never_raises() -> None:
    assert normalise_key("midi:note:60") == "midi:note:60:ch1"
    assert normalise_key("midi:garbage") == "midi:garbage"
    assert normalise_key("osc:/x") == "osc:/x"


@pytest.mark.parametrize(
    ("text", "inside", "outside"),
    [
        ("18:00-23:00", ["18:00", "22:59"], ["17:59", "23:00", "00:00"]),
        ("22:00-02:00", ["22:00", "23:59", "00:00", "01:59"], ["02:00", "21:59", "12:00"]),
        ("00:00-24:00", ["00:00", "12:00", "23:59"], []),
        ("23:00-00:00", ["23:30"], ["00:00", "22:59"]),
    ],
)
def test_windows(text, inside, outside) -> None:
    w = parse_window(text)

    def day(hhmm: str) -> float:
        h, m = hhmm.split(":")
        return int(h) * 3600 + int(m) * 60

    assert all(w.contains(day(x)) for x in inside)
    assert not any(w.contains(day(x)) for x in outside)


def test_timers_directly() -> None:
    trig = [parse_trigger(x) for x in ("every:10", "at:5", "daily:00:00", "key:s")]
    timers = Timers(trig, datetime(2024, 2, 28, 23, 59, 50))
    assert timers.due(-math.inf, 0.0) == []
    assert timers.due(0.0, 5.0) == ["at:5"]
    assert timers.due(5.0, 10.0) == ["every:10", "daily:00:00"]
    assert timers.due(10.0, 35.0) == ["every:10"]  # three periods passed: once
    assert timers.due(35.0, 2.0) == []  # time went back
    assert timers.due(2.0, 6.0) == ["at:5"]  # passed again
    with pytest.raises(ValueError, match="wall-clock"):
        Timers(trig, None)
