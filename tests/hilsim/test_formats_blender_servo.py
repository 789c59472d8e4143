"""blender-servo-animation exports (.json, .bin, .h) -> tracks: issue 13's worked numbers, the
three forms alike, 0x0A inside a record, held frames, the add-on's unit map, bad inputs."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from hilsim.targets.formats.blender_servo import (
    BoneSettings,
    parse_blender_servo,
    read_blender_servo,
)
from hilsim.targets.formats.common import FormatError, UnitMap

ROOT = Path(__file__).resolve().parents[2]


def _tool(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


gen = _tool("samples_blender_servo")
FRAMES = gen.skip_unchanged(gen.sample_positions())
FORMS = {"json": gen.json_bytes(FRAMES), "bin": gen.bin_bytes(FRAMES), "h": gen.h_bytes(FRAMES)}
BONE = BoneSettings(
    servo_id=0, position_min=544, position_max=2400, rotation_range=180, neutral_angle=90
)


def load(form: str, data: bytes | None = None, **kw):
    if form == "bin":
        kw.setdefault("fps", 30)
    return parse_blender_servo(FORMS[form] if data is None else data, form, f"x.{form}", **kw)


def deg(track, t: float) -> float:
    return math.degrees(track.sample(t)[0])


@pytest.mark.parametrize("form", ["json", "bin", "h"])
def test_review_numbers_from_each_form(form):
    """Servo angle 151.487° at t = 0.500 s; linear 147.705° at 1.25 s (2067 µs); held there,
    2089 µs -> 149.838°; as the bone's rotation, -61.487° at 0.500 s."""
    anim = load(form)
    assert anim.fps == 30 and len(anim.frames) == 100 and anim.servo_ids == (0, 10)
    held = anim.track_for(BONE, angle="servo")
    linear = anim.track_for(BONE, angle="servo", interpolation="linear")
    assert deg(held, 0.500) == pytest.approx(151.487, abs=5e-4)
    assert deg(linear, 1.25) == pytest.approx(147.705, abs=5e-4)
    assert deg(held, 1.25) == pytest.approx(149.838, abs=5e-4)
    assert deg(anim.track_for(BONE, angle="bone"), 0.500) == pytest.approx(-61.487, abs=5e-4)
    assert anim.positions(0)[37] == 2089 and anim.positions(0)[38] == 2045
    assert held.duration == pytest.approx(100 / 30)


def test_the_three_forms_give_identical_tracks():
    times = np.linspace(-0.5, 4.0, 901)
    unit = UnitMap((150, 600), (0, 180), "ticks")
    results = []
    for form in FORMS:
        anim = load(form)
        results.append(
            [
                anim.track(sid, unit, interpolation=i).sample_array(times)
                for sid in (0, 10)
                for i in ("hold", "linear")
            ]
        )
        assert [dict(f) for f in anim.frames] == FRAMES
    for other in results[1:]:
        for (p0, v0), (p1, v1) in zip(results[0], other, strict=True):
            assert np.array_equal(p0, p1) and np.array_equal(v0, v1)


def test_the_shipped_samples_are_the_generators():
    for path in (ROOT / "configs" / "animations" / "blender_servo").iterdir():
        assert path.read_bytes() == FORMS[path.suffix[1:]], path


def test_0x0a_inside_a_record_is_data_not_a_frame_end():
    # servo 10 (0x0A) at 266 (0x010A), then an empty frame, then servo 10 at 2570 (0x0A0A)
    data = bytes([0x3C, 0x0A, 0x01, 0x0A, 0x3E, 0x0A, 0x0A, 0x3C, 0x0A, 0x0A, 0x0A, 0x3E, 0x0A])
    anim = parse_blender_servo(data, "bin", "x.bin", fps=10)
    assert [dict(f) for f in anim.frames] == [{10: 266}, {}, {10: 2570}]
    assert anim.positions(10).tolist() == [266, 266, 2570]
    assert data.count(0x0A) == 8  # a reader splitting on 0x0A would see 8 frames, not 3


def _arduino_form(form: str, frames: list[dict[int, int]]):
    return load(form, gen.bin_bytes(frames) if form == "bin" else gen.h_bytes(frames))


@pytest.mark.parametrize("form", ["bin", "h"])
def test_a_marker_byte_inside_a_record_is_one_note_naming_servo_and_frame(form):
    """The add-on's Arduino library (2.0.0) ends a frame at any 0x0A and restarts a record at
    any 0x3C: one line per file says where first, hilsim still reads the records right."""
    frames = [{0: 1000}, {0: 1001, 10: 300}, {0: 1290}, {0: 572}]  # 10, 0x050A, 0x023C
    anim = _arduino_form(form, frames)
    assert [dict(f) for f in anim.frames] == frames
    note = anim.misread_note()
    assert note.startswith(f"x.{form}: servo 10 in frame 1: its ID is 0x0a, which the add-on's")
    assert "as a frame end" in note and "(1 of 3 such records here;" in note
    assert anim.notes(0)[0] == anim.notes(10)[0] == note  # the same line: printed once
    last = _arduino_form(form, frames[3:]).misread_note()
    assert "servo 0 in frame 0: its position's low byte is 0x3c" in last
    assert "as a record start" in last and "the only such record here" in last
    assert _arduino_form(form, frames[:1]).misread_note() is None


def test_a_json_export_is_not_the_arduino_librarys_and_gets_no_marker_note():
    anim = load("json", gen.json_bytes([{10: 10}], fps=10))
    assert anim.misread_note() is None and anim.notes(10) == ()


def test_a_missing_servo_holds_and_the_notes_say_why_that_may_be_wrong():
    frames = [{0: 1000, 1: 300}, {1: 310}, {}, {0: 1100}]
    anim = load("json", gen.json_bytes(frames, fps=10))
    assert anim.positions(0).tolist() == [1000, 1000, 1000, 1100]
    assert anim.held_frames(0) == (1, 2)
    (note,) = anim.notes(0)
    assert "servo 0: 2 of 4 frames" in note and "cannot tell an unchanged position" in note
    late = load("json", gen.json_bytes([{0: 5}, {0: 6, 3: 400}, {}], fps=10))
    assert late.positions(3).tolist() == [400, 400, 400]
    assert any("no position before frame 1" in n for n in late.notes(3))
    assert load("json", gen.json_bytes([{0: 5}, {0: 6}], fps=10)).notes(0) == ()
    track = anim.track(0, UnitMap((1000, 2000), (0, 40), "us"))
    assert deg(track, 0.25) == pytest.approx(0.0) and deg(track, 0.35) == pytest.approx(4.0)


def test_bone_settings_reverse_and_multiplier():
    bone = BoneSettings(1, 150, 600, 180, 90, multiplier=2.0, reverse_direction=True)
    # the add-on: angle = 90 - s·2·rotation, s = -1 -> rotation = (angle - 90)/2
    assert bone.unit_map("bone").to_deg(375) == pytest.approx(0.0)
    assert bone.unit_map("bone").to_deg(600) == pytest.approx(45.0)
    assert bone.unit_map("servo").to_deg(600) == pytest.approx(180.0)
    with pytest.raises(ValueError, match="angle must be one of servo, bone"):
        bone.unit_map("joint")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"position_min": 600, "position_max": 150}, "below position_max"),
        ({"rotation_range": 0}, "rotation_range"),
        ({"neutral_angle": math.nan}, "neutral_angle must be a finite"),
        ({"servo_id": 256}, "servo_id"),
        ({"multiplier": 0}, "multiplier"),
        ({"reverse_direction": "yes"}, "reverse_direction"),
    ],
)
def test_impossible_bone_settings_are_refused(kwargs, match):
    args = (
        dict(servo_id=0, position_min=150, position_max=600, rotation_range=180, neutral_angle=90)
        | kwargs
    )
    with pytest.raises(ValueError, match=match):
        BoneSettings(**args)


def test_a_position_outside_the_bones_range_means_the_settings_are_not_the_exports():
    narrow = BoneSettings(0, 544, 2000, 180, 90)
    with pytest.raises(FormatError, match=r"x\.json:frame 13: servo 0 at 2016, outside"):
        load("json").track_for(narrow, angle="servo")


def test_fps_is_the_callers_for_bin_and_checked_for_the_others(tmp_path):
    with pytest.raises(FormatError, match=r"x\.bin: a \.bin export does not say its fps"):
        parse_blender_servo(FORMS["bin"], "bin", "x.bin")
    with pytest.raises(FormatError, match="the file says 30 fps, not the 25 given"):
        load("json", fps=25)
    assert load("bin", fps=60).track(0, BONE.unit_map("servo")).duration == pytest.approx(100 / 60)
    path = tmp_path / "a.h"
    path.write_bytes(FORMS["h"])
    assert read_blender_servo(path).scene == "Skull"
    assert load("h", gen.h_bytes(FRAMES, namespace=False)).scene == ""
    decimal = FORMS["h"].replace(b"0x3c", b"60").replace(b"0x0a,", b"/* end */ 10,")
    assert load("h", decimal).frames == load("h").frames  # decimal bytes and comments read too
    with pytest.raises(FormatError, match=r"a\.anim: unknown form '\.anim'"):
        read_blender_servo(tmp_path / "a.anim")
    with pytest.raises(FormatError, match="cannot read"):
        read_blender_servo(tmp_path / "missing.json")


def test_servo_not_in_the_file_is_named():
    with pytest.raises(FormatError, match=r"x\.json:servo 3: not in the file \(servos: 0, 10\)"):
        load("json").track(3, BONE.unit_map("servo"))


def _json(**changes) -> bytes:
    doc = json.loads(FORMS["json"]) | changes
    return json.dumps(doc).encode()


H = FORMS["h"].decode()

BAD = [
    ("json", b"", r"x\.json: empty file"),
    ("json", b"\x3c\x00\x05\xc0\x3e\x0a", r"x\.json:byte 1: a NUL byte: binary, not text"),
    ("json", b'{"fps": \xff}', r"x\.json:byte 8: not UTF-8"),
    ("json", b'{\n"fps": 30,\n"positions": [}', r"x\.json:line 3: not JSON"),
    ("json", b"[1, 2]", "no top-level 'positions' list"),
    ("json", b'{"fps": NaN, "positions": []}', "NaN is not a JSON number"),
    ("json", b"[" * 100000, "not JSON"),
    ("json", _json(fps=0), r"x\.json:fps: must be a whole number"),
    ("json", _json(fps=29.97), r"x\.json:fps: must be a whole number"),
    ("json", _json(fps=True), r"x\.json:fps: must be a whole number"),
    ("json", _json(frames=99), r"x\.json:frames: says 99 but 'positions' holds 100"),
    ("json", _json(positions={"0": 1}), "must be a list of frames"),
    ("json", _json(positions=[{"0": 1}, [1]], frames=2), r"x\.json:frame 1: must be an object"),
    ("json", _json(positions=[{"x": 1}], frames=1), r"frame 0: servo ID 'x' is not 0-255"),
    ("json", _json(positions=[{"256": 1}], frames=1), "servo ID '256' is not 0-255"),
    ("json", _json(positions=[{"0": -1}], frames=1), "position -1 is not an integer 0-65535"),
    ("json", _json(positions=[{"0": 65536}], frames=1), "position 65536 is not an integer"),
    ("json", _json(positions=[{"0": 1.5}], frames=1), "position 1.5 is not an integer"),
    ("json", _json(positions=[], frames=0), r"x\.json: no frames"),
    ("json", _json(positions=[{}, {}], frames=2), "2 frames, none with a position"),
    ("bin", b"\x3c\x00\x05", r"x\.bin:byte 0: truncated: a record starts here but only 3"),
    ("bin", b"\x3c\x00\x05\xc0\x3f\x0a", r"x\.bin:byte 4: 0x3f where a record ends with 0x3e"),
    ("bin", b"\x0a\x0a\x41", r"x\.bin:byte 2: 0x41 where a record .* must start \(frame 2\)"),
    ("bin", b"\x0a\x3c\x00\x05\xc0\x3e", r"x\.bin:byte 6: truncated: frame 1 has positions"),
    ("bin", b"", r"x\.bin: empty file"),
    ("h", H.replace("const byte FPS = 30;", "").encode(), "no 'const ... FPS = N;'"),
    ("h", H.replace("LENGTH = 585", "LENGTH = 584").encode(), r"line 20: LENGTH is 584 but"),
    ("h", H.replace("FRAMES = 100", "FRAMES = 99").encode(), "FRAMES is 99 but the array holds"),
    ("h", H.replace("0x3e, 0x0a, ", "0x3e, 0xzz, ", 1).encode(), r"line 21: '0xzz' is not a byte"),
    ("h", H.replace("0x3e, 0x0a, ", "0x3e, 0x1ff, ", 1).encode(), r"line 21: 0x1ff is not a byte"),
    (
        "h",
        H.replace("0xc0, 0x3e", "0xc0, 0x3f", 1).encode(),
        r"x\.h:line 21 \(array byte 4\): 0x3f where a record ends",
    ),
    ("h", H.replace("0x3e, 0x0a, ", "0x3e, 0x0 a, ", 1).encode(), r"line 21: '0x0 a' is not a"),
    ("h", H.replace("ANIMATION_DATA", "DATA").encode(), "no 'ANIMATION_DATA"),
    ("h", (H + H[H.index("const byte PROGMEM") :]).encode(), "2 'ANIMATION_DATA"),
    ("h", H.replace("FPS = 30", "FPS = 0").encode(), "FPS is 0"),
    # hostile repetitions a backtracking pattern would take minutes over (linear here)
    ("h", b"/* " * 30000, "no 'const ... FPS = N;'"),
    (
        "h",
        H[: H.index("const byte PROGMEM")].encode() + b"ANIMATION_DATA[1]={" * 30000,
        "no 'ANIMATION_DATA",
    ),
]


@pytest.mark.parametrize(("form", "data", "match"), BAD)
def test_bad_input_is_one_format_error_naming_file_and_position(form, data, match):
    with pytest.raises(FormatError, match=match) as info:
        load(form, data)
    assert str(info.value).startswith(f"x.{form}:")
    assert "\n" not in str(info.value)


def _only_format_errors(form: str, data: bytes) -> None:
    """A FormatError of one line naming the file, or an export whose every servo gives a
    track: a position per frame, finite and within the map's 0-180° at any time, frames
    ascending from 0, as long as the file's frames at its fps."""
    path = f"f.{form}"
    try:
        anim = parse_blender_servo(data, form, path, fps=30 if form == "bin" else None)
    except FormatError as exc:
        text = str(exc)
        assert text.startswith(path) and len(text.splitlines()) == 1 and len(text) < 400, text
        return
    assert anim.form == form and anim.fps >= 1 and anim.n_frames >= 1 and anim.servo.size
    assert (np.diff(anim.frame_of) >= 0).all() and anim.frame_of[0] >= 0
    assert anim.frame_of[-1] < anim.n_frames
    for sid in anim.servo_ids:
        assert 0 <= sid <= 255
        assert anim.positions(sid).shape == (anim.n_frames,)
        for how in ("hold", "linear"):
            track = anim.track(sid, UnitMap((0, 65535), (0, 180)), interpolation=how)
            assert track.duration == pytest.approx(anim.n_frames / anim.fps)
            u, du = track.sample_array(np.linspace(-1.0, track.duration + 1.0, 50))
            assert np.isfinite(du).all() and (np.degrees(u) >= -1e-9).all()
            assert (np.degrees(u) <= 180 + 1e-9).all()


@given(st.sampled_from(["json", "bin", "h"]), st.binary(max_size=300))
@example("json", FORMS["json"]).via("an export")
@example("bin", FORMS["bin"]).via("an export")
@example("h", FORMS["h"]).via("an export")
def test_random_bytes_give_a_format_error_or_tracks(form, data):
    _only_format_errors(form, data)


@given(st.sampled_from(["json", "bin", "h"]), st.data())
def test_mangled_exports_give_a_format_error_or_tracks(form, draw):
    data = bytearray(FORMS[form])
    for _ in range(draw.draw(st.integers(1, 4))):
        i = draw.draw(st.integers(0, len(data) - 1))
        op = draw.draw(st.sampled_from(["set", "cut", "insert"]))
        if op == "set":
            data[i] = draw.draw(st.integers(0, 255))
        elif op == "cut":
            del data[i:]
        else:
            data[i:i] = draw.draw(st.binary(min_size=1, max_size=6))
        if not data:
            break
    _only_format_errors(form, bytes(data))
