"""Other tools' animation files as rig targets (hilsim.targets.sources): the issue's acceptance
numbers through the rig and ``hilsim tracks``, every form of a format alike, the unit maps the
rig gives, the lead from the spring, and one clear line for a bad spec or file."""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from hilsim.cli import main
from hilsim.dynamics.springs import Spring
from hilsim.targets import SpecError, track_from_spec
from hilsim.targets.formats.common import FormatError

REPO = Path(__file__).resolve().parents[2]
ANIM = REPO / "configs" / "animations"
_spec = importlib.util.spec_from_file_location(
    "samples_audio_jaw", REPO / "tools" / "samples_audio_jaw.py"
)
samples_audio = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(samples_audio)
_spec = importlib.util.spec_from_file_location("samples_fseq", REPO / "tools" / "samples_fseq.py")
samples_fseq = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(samples_fseq)


def deg(track, t: float) -> float:
    return math.degrees(track.sample(t)[0])


def build(spec: dict, base: Path = ANIM, spring: Spring | None = None):
    return track_from_spec(spec, base_dir=base, joint_name="jaw", csv_cache={}, spring=spring)


# ------------------------------------------------------------------ Bottango
@pytest.mark.parametrize(
    "file", ["bottango/GeneratedCodeAnimations.cpp", "bottango/sd", "bottango/commands.json"]
)
def test_bottango_acceptance_from_every_form(file):
    track = build(
        {"type": "bottango", "file": file, "animation": 0, "effector": "0", "degrees": [0, 40]}
    )
    assert deg(track, 1.0) == pytest.approx(29.97, abs=0.025)  # 1749.33 us of 1000-2000
    for t, want in ((0.0, 20.00), (2.0, 34.72), (2.25, 30.92), (3.0, 11.12)):
        assert deg(track, t) == pytest.approx(want, abs=0.02)  # the review's R3 numbers


def test_bottango_signal_and_movement_maps():
    base = {"type": "bottango", "file": "bottango/sd", "effector": "0"}
    by_range = build({**base, "degrees": [0, 40]})
    by_signal = build({**base, "signal": [1000, 2000], "degrees": [0, 40]})
    by_movement = build({**base, "movement": [0, 1], "degrees": [0, 40]})
    for t in (0.3, 1.0, 2.6):
        assert deg(by_signal, t) == pytest.approx(deg(by_range, t))
        assert deg(by_movement, t) == pytest.approx(deg(by_range, t))
    # the I2C servo is registered 2000 -> 1000 us: its range maps reversed
    rev = build({**base, "effector": "643", "degrees": [-45, 45], "animation": 0})
    assert deg(rev, 1.5) == pytest.approx(45.0)  # the curve's end, 1000 us
    assert deg(rev, 0.0) == pytest.approx(0.0)  # parked at its start signal, 1500 us


@pytest.mark.parametrize("extra", [{}, {"movement": [0, 1]}, {"signal": [1000, 2000]}])
@pytest.mark.parametrize("file", ["bottango/GeneratedCodeAnimations.cpp", "bottango/sd"])
def test_a_wrong_bottango_effector_is_named_first_with_the_ones_there_are(file, extra):
    """Not advice about signal ranges or curves: the effector is not in the export at all."""
    spec = {"type": "bottango", "file": file, "effector": "9", "degrees": [0, 40], **extra}
    with pytest.raises(FormatError) as got:
        build(spec)
    assert got.value.detail == "no effector '9' in this export; it has 0, 643"
    assert got.value.path == str(ANIM / file)  # the file named as the reader names it


def test_bottango_start_and_speed_limit_through_hilsim_tracks(tmp_path, capsys):
    """configs/bottango.toml on an export whose first curves start after 0 ms: the jaw (pin
    servo 0, start 1200 µs, 500 µs/s) waits at its start signal, then moves at its limit;
    one note says where the limit keeps the signal off the curves."""
    spec = importlib.util.spec_from_file_location("sb", REPO / "tools" / "samples_bottango.py")
    sb = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("sb", sb)
    spec.loader.exec_module(sb)
    setup = ["rSVPin,0,1000,2000,500,1200", "rSVI2C,64,3,2000,1000,3000,1500"]
    talk = sb.Anim("Talk", ["sC,0,1000,400,4096,0,0,8192,0,0", "sC,643,500,500,4096,0,0,0,0,0"])
    export = sb.write_code(tmp_path / "g.cpp", setup, [talk])
    rig = (REPO / "configs" / "bottango.toml").read_text()
    path = tmp_path / "r.toml"
    path.write_text(rig.replace("animations/bottango/GeneratedCodeAnimations.cpp", str(export)))
    assert main(["tracks", str(path), "--at", "0,0.9,1.4,2.0,2.6", "--json"]) == 0
    out, err = capsys.readouterr()
    # 1200 µs (8°) until 1.0 s; then 500 µs/s: 1400 µs (16°) at 1.4 s, 2000 µs (40°) at 2.6 s
    assert json.loads(out)["jaw"] == pytest.approx([8.0, 8.0, 16.0, 28.0, 40.0])
    # 643 (2000 -> 1000 µs is -45..45°): 1500 µs until 0.5 s, then 1000 µs/s (within its
    # 3000) to 2000 µs at 1.0 s: 1900 µs (-36°) at 0.9 s
    assert json.loads(out)["head_pan"] == pytest.approx([0.0, -36.0, -45.0, -45.0, -45.0])
    notes = [ln for ln in err.splitlines() if "speed limit" in ln]
    assert len(notes) == 1 and 'animation 0 "Talk" effector 0' in notes[0]
    assert "(500 us/s) keeps the driver's signal off the curves once (1.000-2.600 s)" in notes[0]


def test_acceptance_through_hilsim_tracks(capsys):
    assert main(["tracks", str(REPO / "configs" / "bottango.toml"), "--at", "1.0", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["jaw"][0] == pytest.approx(29.97, abs=0.025)
    lips = REPO / "configs" / "lipsync.toml"
    assert main(["tracks", str(lips), "--at", "0.02,0.10,0.29,0.35,0.45", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["jaw"] == pytest.approx([0, 20, 10, 4, 0])
    assert main(["tracks", str(REPO / "configs" / "fseq.toml"), "--at", "0,0.5", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["pan"] == pytest.approx([-90.0, -2.108], abs=1e-3)


# ------------------------------------------------------------------ Blender, FSEQ
@pytest.mark.parametrize("file", ["r53.json", "r53.bin", "r53.h"])
def test_blender_servo_forms_and_the_reviews_numbers(file):
    spec = {"type": "blender_servo", "file": f"blender_servo/{file}", "servo": 0,
            "position": [544, 2400], "degrees": [0, 180]}  # fmt: skip
    if file.endswith(".bin"):
        spec["fps"] = 30
    assert deg(build(spec), 0.5) == pytest.approx(151.487, abs=1e-3)
    assert deg(build(spec), 1.25) == pytest.approx(149.838, abs=1e-3)  # held: 2089 us
    linear = build({**spec, "interpolation": "linear"})
    assert deg(linear, 1.25) == pytest.approx(147.705, abs=1e-3)  # 2067 us


def test_fseq_forms_and_zero_hold():
    spec = {"type": "fseq", "channel": 1, "fine": 2, "degrees": [-90, 90]}
    plain = build({**spec, "file": "fseq/r51.fseq"})
    zlib = build({**spec, "file": "fseq/r51_zlib.fseq"})
    for t in (0.0, 0.5, 0.73):
        assert deg(zlib, t) == deg(plain, t)
    assert deg(plain, 0.5) == pytest.approx(-2.108, abs=1e-3)
    eight = build({"type": "fseq", "file": "fseq/r51.fseq", "channel": 1, "degrees": [0, 255]})
    assert deg(eight, 0.5) == pytest.approx(125.0)  # frame 25: 5 * 25, 8-bit full range


def test_fseq_channels_of_a_sparse_file_are_absolute_as_the_rig_doc_says(tmp_path):
    """A file storing only show channels 501-502 (one sparse range): the rig names 502, not 2;
    channel 1 is outside the file, and docs/rig.md says so on the channel key."""
    k = np.arange(10)
    frames = np.stack([5 * k, 255 - 5 * k], axis=1).astype(np.uint8)  # channels 501, 502
    (tmp_path / "s.fseq").write_bytes(samples_fseq.fseq_bytes(frames, sparse_ranges=[(500, 2)]))
    spec = {"type": "fseq", "file": "s.fseq", "degrees": [0, 255]}
    assert deg(build({**spec, "channel": 502}, tmp_path), 0.1) == pytest.approx(230.0)  # frame 5
    with pytest.raises(FormatError, match=r"s\.fseq:channel 2: outside every sparse range: it "
                       r"holds channels 501-502"):  # fmt: skip
        build({**spec, "channel": 2}, tmp_path)
    section = (REPO / "docs" / "rig.md").read_text(encoding="utf-8").split('`type = "fseq"`')[1]
    row = next(line for line in section.splitlines() if line.startswith("| `channel` |"))
    assert "Absolute in a sparse file too" in row and "has channel 501, not 1" in row


# ------------------------------------------------------------------ audio, lip-sync
def test_audio_acceptance_and_the_lead(tmp_path):
    (tmp_path / "line.wav").write_bytes(
        samples_audio.wav_bytes(samples_audio.acceptance_signal(), 44_100)
    )
    spec = {"type": "audio", "file": "line.wav", "degrees": [0, 20], "window_ms": 10,
            "attack_ms": 10, "release_ms": 100, "threshold": 0.02, "full": 0.35}  # fmt: skip
    jaw = build(spec, tmp_path)
    assert deg(jaw, 0.49) == 0.0
    assert deg(jaw, 0.60) == pytest.approx(20.0, abs=0.1)
    assert deg(jaw, 1.5) == 0.0
    led = build({**spec, "lead_ms": 50}, tmp_path)
    for t in (0.52, 0.6, 1.05, 1.2):
        assert deg(led, t - 0.05) == pytest.approx(deg(jaw, t), abs=1e-9)
    spring = Spring.from_animation(8.0, 0.7, 0.0)
    auto = build({**spec, "lead_ms": "auto"}, tmp_path, spring)
    lag = 2 * 0.7 / (2 * math.pi * 8.0)
    for t in (0.6, 1.1):
        assert deg(auto, t - lag) == pytest.approx(deg(jaw, t), abs=1e-6)


@pytest.mark.parametrize("file", ["hi.tsv", "hi.json", "hi.xml", "hi.pgo", "hi.dat"])
def test_lipsync_forms_give_the_same_jaw(file):
    shapes = {"X": 0, "A": 0, "B": 0.2, "C": 0.5, "D": 1.0, "E": 0.6, "F": 0.3, "G": 0.1, "H": 0.4}
    spec = {"type": "lipsync", "file": f"lipsync/{file}", "degrees": [0, 20], "shapes": shapes}
    if file.endswith(".dat"):
        spec["fps"] = 100
    track = build(spec)
    reference = build({**spec, "file": "lipsync/hi.tsv"})
    frame = 1 / 24 if file.endswith(".pgo") else 0.01
    times = np.arange(0, 0.5, 0.0005)
    ours = np.array([deg(track, t) for t in times])
    ref = np.array([deg(reference, t) for t in times])
    differ = times[np.abs(ours - ref) > 1e-9]
    # where they differ, the reference takes the same value within one source frame
    for t in differ:
        near = [deg(reference, s) for s in np.arange(t - frame, t + frame + 1e-9, 0.0005)]
        assert any(abs(v - deg(track, t)) < 1e-9 for v in near), t


# ------------------------------------------------------------------ bad specs and files
@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ({"type": "bottango", "file": "bottango/sd", "effector": "0"}, "degrees: missing"),
        ({"type": "bottango", "file": "nope.cpp", "effector": "0", "degrees": [0, 1]},
         "file: no such file"),
        ({"type": "bottango", "file": "bottango/sd", "effector": "0", "degrees": [0]},
         "degrees: must be two finite numbers"),
        ({"type": "bottango", "file": "bottango/sd", "effector": "0", "degrees": [0, 40],
          "signal": [1000, 1000]}, "signal: the two source points are equal"),
        ({"type": "bottango", "file": "bottango/sd", "effector": "0", "degrees": [0, 40],
          "signal": [1, 2], "movement": [0, 1]}, "movement: give signal or movement"),
        ({"type": "bottango", "file": "bottango/sd", "effector": True, "degrees": [0, 40]},
         "effector: must be"),
        ({"type": "fseq", "file": "fseq/r51.fseq", "channel": 0, "degrees": [0, 40]},
         "channel: channel must be a channel number"),
        ({"type": "audio", "file": "audio_jaw/line.wav", "degrees": [0, 20], "lead_ms": "soon"},
         "lead_ms: must be a number of ms"),
        ({"type": "audio", "file": "audio_jaw/line.wav", "degrees": [0, 20], "lead_ms": "auto"},
         "lead_ms: \"auto\" needs"),
        ({"type": "audio", "file": "audio_jaw/line.wav", "degrees": [0, 1e5]},
         "degrees: key [0-9]+: value [0-9.]+° is beyond ±92160°"),
        ({"type": "lipsync", "file": "lipsync/hi.dat", "degrees": [0, 20], "shapes": {"A": 0}},
         "fps: a Moho .dat file holds no frame rate"),
        ({"type": "lipsync", "file": "lipsync/hi.tsv", "degrees": [0, 20], "shapes": {"Q": 1}},
         "shapes: rhubarb: 'Q' is not a Rhubarb shape"),
        ({"type": "blender_servo", "file": "blender_servo/r53.json", "servo": 0,
          "degrees": [0, 1]}, "position: missing"),
        ({"type": "blender_servo", "file": "blender_servo/r53.bin", "servo": 0,
          "position": [544, 2400], "degrees": [0, 1], "fps": 10**9}, "fps: must be a whole 1"),
        ({"type": "lipsync", "file": "lipsync/hi.dat", "degrees": [0, 20], "shapes": {"A": 0},
          "fps": 1e-300}, "fps: must be 1 .. 1000"),
        ({"type": "lipsync", "file": "lipsync/hi.tsv", "degrees": [0, 20], "shapes": {"A": 0},
          "names": ["a"]}, "names: must be a vocabulary's name"),
        ({"type": "lipsync", "file": "lipsync/hi.pgo", "degrees": [0, 20], "shapes": {"A": 0},
          "voice": {"a": 1}}, "voice: must be a voice's name or index"),
    ],
)  # fmt: skip
def test_bad_specs_name_the_key(spec, match):
    with pytest.raises(SpecError, match=match):
        build(spec)


def test_a_file_the_reader_refuses_names_file_and_position(tmp_path):
    (tmp_path / "cut.fseq").write_bytes((ANIM / "fseq" / "r51.fseq").read_bytes()[:40])
    with pytest.raises(FormatError, match=r"cut\.fseq:"):
        build({"type": "fseq", "file": "cut.fseq", "channel": 1, "degrees": [0, 1]}, tmp_path)
    (tmp_path / "shapes.tsv").write_text("0.00\tX\n0.10\tQ\n0.20\tX\n")
    spec = {"type": "lipsync", "file": "shapes.tsv", "degrees": [0, 20], "shapes": {"X": 0}}
    with pytest.raises(FormatError, match=r"shapes\.tsv:line 2:"):
        build(spec, tmp_path)


def test_hilsim_tracks_says_a_bad_file_in_one_line(tmp_path, capsys):
    (tmp_path / "cut.fseq").write_bytes(b"PSEQ" + bytes(10))
    rig = (
        (REPO / "configs" / "fseq.toml")
        .read_text()
        .replace("animations/fseq/r51.fseq", str(tmp_path / "cut.fseq"))
    )
    path = tmp_path / "r.toml"
    path.write_text(rig)
    assert main(["tracks", str(path), "--at", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cut.fseq" in err[0] and "joints[0].target (pan)" in err[0]


def test_what_the_files_say_is_reported(capsys):
    """Bottango's start/idle/loop/trigger settings and a Blender export's held frames are
    printed (stderr: the JSON on stdout stays clean), by hilsim tracks and hilsim run."""
    assert main(["tracks", str(REPO / "configs" / "bottango.toml"), "--at", "0", "--json"]) == 0
    out, err = capsys.readouterr()
    json.loads(out)
    assert 'animation 0 "Talk": trigger on input 10, rising (HIGH), no loop' in err
    assert 'animation 1 "Idle": idle animation' in err
    assert main(["tracks", str(REPO / "configs" / "blender_servo.toml"), "--at", "0"]) == 0
    assert "cannot tell an unchanged position from one Blender dropped" in capsys.readouterr().err


def test_a_marker_byte_the_arduino_library_misreads_is_said_once(tmp_path, capsys):
    """Both joints of configs/blender_servo.toml on r53.bin, whose servo 10 has ID 0x0A: one
    line on stderr, naming servo and frame; the values are the file's records."""
    rig = (REPO / "configs" / "blender_servo.toml").read_text()
    bin_file = (ANIM / "blender_servo" / "r53.bin").as_posix()
    path = tmp_path / "r.toml"
    path.write_text(rig.replace('animations/blender_servo/r53.json"', f'{bin_file}", fps = 30'))
    assert main(["tracks", str(path), "--at", "0.5", "--json"]) == 0
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if "0x0a" in ln]
    assert len(lines) == 1 and "r53.bin: servo 10 in frame 0: its ID is 0x0a" in lines[0]
    assert lines[0].startswith("hilsim tracks: note: ") and "reads the 5-byte records" in lines[0]
    assert json.loads(out)["arm"] == pytest.approx([151.487 - 90], abs=1e-3)
