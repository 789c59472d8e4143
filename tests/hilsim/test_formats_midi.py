"""Standard MIDI Files -> tracks: controller 7 ramps over a tempo change give the hand-computed
targets through ``hilsim tracks``; the tempo map (any track, any tick, SMPTE); 14-bit pairs;
notes; the shipped sample; one line for a bad spec or file; fuzzing. Files are written with
mido (another implementation than the reader's)."""

from __future__ import annotations

import importlib.util
import json
import math
import random
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hilsim.cli import main
from hilsim.targets import SpecError, track_from_spec
from hilsim.targets.formats.common import FormatError
from hilsim.targets.formats.midi_file import read_midi_file

mido = pytest.importorskip("mido")

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("samples_midi", ROOT / "tools" / "samples_midi.py")
gen = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(gen)

RIG = """\
name = "m"
[bus]
port = "dxlsim://?ids=1&model=XM430-W210&rdt_us=0&latency_ms=1"
[loop]
rate_hz = 250
[[joints]]
name = "head"
servo_id = 1
model = "XM430-W210"
min_deg = -40
max_deg = 40
max_speed_deg_s = 300
spring = {{ frequency_hz = 3.0, damping_ratio = 0.9 }}
target = {target}
"""


def deg(track, t: float) -> float:
    return math.degrees(track.sample(t)[0])


def cc(k: int) -> float:
    """A value of controller 7 mapped as degrees = [-30, 30]: 0 -> -30°, 127 -> +30°."""
    return -30 + 60 * k / 127


def track(events, ppqn=480, type=1):
    """A MidiFile of tracks given as [(absolute tick, message), ...] lists."""
    mf = mido.MidiFile(type=type, ticks_per_beat=ppqn)
    mf.tracks += [gen._delta(ev) for ev in events]
    return mf


def tracks_json(tmp_path: Path, target: str, times: str, capsys) -> list[float]:
    rig = tmp_path / "r.toml"
    rig.write_text(RIG.format(target=target))
    assert main(["tracks", str(rig), "--at", times, "--json"]) == 0
    return json.loads(capsys.readouterr().out)["head"]


# ------------------------------------------------------------------ the acceptance
def test_cc7_ramp_over_a_tempo_change_gives_the_hand_calculation(tmp_path, capsys):
    """480 ticks per quarter; 120 bpm (0.5 s a quarter: 1/960 s a tick) to tick 1920 (2.0 s),
    then 60 bpm (1/480 s a tick). Controller 7 on channel 1 is k at tick 30k, k = 0..127.

    held:   t = 1.0 s -> tick 960 -> k = 32 -> -30 + 60·32/127 = -14.882°
            t = 2.5 s -> tick 1920 + 0.5·480 = 2160 -> k = 72 -> 4.016°
            t = 3.0 s -> tick 2400 -> k = 80 -> 7.795°
            t = 6.0 s -> after the last value (127 at tick 3810, 5.9375 s) -> 30°
    linear: t = 3.1 s -> tick 2448 -> k = 81.6 -> 8.551°
            t = 1.99 s -> tick 1910.4 -> k = 63.68 -> 0.0850° (the tempo is still 120 bpm)
    """
    conductor = [(0, mido.MetaMessage("set_tempo", tempo=500_000)),
                 (1920, mido.MetaMessage("set_tempo", tempo=1_000_000))]  # fmt: skip
    ramp = [(30 * k, mido.Message("control_change", control=7, value=k)) for k in range(128)]
    track([conductor, ramp]).save(str(tmp_path / "ramp.mid"))
    spec = '{ type = "midi", file = "ramp.mid", channel = 1, control = 7, degrees = [-30, 30] }'
    held = tracks_json(tmp_path, spec, "1.0,2.5,3.0,6.0", capsys)
    assert held == pytest.approx([cc(32), cc(72), cc(80), 30.0], abs=1e-9)
    assert held == pytest.approx([-14.882, 4.016, 7.795, 30.0], abs=5e-4)
    linear = spec.replace("degrees", 'interpolation = "linear", degrees')
    got = tracks_json(tmp_path, linear, "3.1,1.99", capsys)
    assert got == pytest.approx([cc(81.6), cc(63.68)], abs=1e-9)
    assert got == pytest.approx([8.551, 0.0850], abs=5e-4)


def test_the_shipped_sample_is_the_generator_and_gives_the_hand_numbers(capsys, tmp_path):
    """configs/midi.toml on ramps.mid: the head rises over the tempo change (k at tick 30k) and
    falls after it (127 - k at tick 3840 + 15k, 1/480 s a tick); the jaw is open 0.5-0.75 s and
    3.0-3.5 s. At 7.0 s: tick 1920 + 5·480 = 4320, k = 32, value 95 -> +14.882°; at 3.6 s:
    tick 1920 + 1.6·480 = 2688, k = 89 (2670 <= 2688 < 2700)."""
    gen.write_samples(tmp_path)
    sample = ROOT / "configs" / "animations" / "midi" / "ramps.mid"
    assert sample.read_bytes() == (tmp_path / "ramps.mid").read_bytes()
    assert main(["tracks", str(ROOT / "configs" / "midi.toml"), "--at", "1,3,7,0.6,3.6",
                 "--json"]) == 0  # fmt: skip
    got = capsys.readouterr()
    out = json.loads(got.out)
    assert got.err == (  # one note a file, on stderr: the timing hilsim read
        "hilsim tracks: note: ramps.mid: format 1, 3 tracks, 480 ticks per quarter note, "
        "120 bpm, 60 bpm from 2.000 s; 10.000 s\n"
    )
    assert out["head"] == pytest.approx([cc(32), cc(80), cc(95), cc(19), cc(89)], abs=1e-9)
    assert out["jaw"] == [2.0, 20.0, 2.0, 20.0, 2.0]
    assert read_midi_file(sample).duration_s == 10.0  # End of Track at tick 5760


# ------------------------------------------------------------------ the tempo map
def test_times_are_the_ones_mido_plays_for_tempos_in_any_track(tmp_path):
    """Random tempo changes at random ticks in the second track too: every event's time is the
    one mido's own player gives (mido merges the tracks and honours every set_tempo)."""
    rng = random.Random(29)
    for _ in range(20):
        tempos = [(rng.randrange(0, 5000), mido.MetaMessage("set_tempo",
                   tempo=rng.randrange(100_000, 2_000_000))) for _ in range(rng.randrange(4))]  # fmt: skip
        ccs = [(rng.randrange(0, 6000), mido.Message("control_change", control=7,
                value=rng.randrange(128))) for _ in range(30)]  # fmt: skip
        mf = track([tempos[:1], ccs + tempos[1:]], ppqn=rng.choice([24, 96, 480, 960]))
        path = tmp_path / "t.mid"
        mf.save(str(path))
        want, now = [], 0.0
        for msg in mido.MidiFile(str(path)):
            now += msg.time
            if msg.type == "control_change":
                want.append(now)
        seq = read_midi_file(path)
        got = seq.seconds([e.tick for e in seq.events])
        assert got == pytest.approx(want, rel=1e-12, abs=1e-12)


def test_two_tempos_at_one_tick_the_last_wins(tmp_path):
    first = [(0, mido.MetaMessage("set_tempo", tempo=250_000)),
             (0, mido.MetaMessage("set_tempo", tempo=1_000_000))]  # fmt: skip
    ramp = [(480, mido.Message("control_change", control=7, value=127))]
    track([first, ramp]).save(str(tmp_path / "t.mid"))
    assert read_midi_file(tmp_path / "t.mid").seconds([480])[0] == 1.0


def test_smpte_division_is_absolute_time(tmp_path):
    """Division 0xE728: -25 fps, 40 ticks a frame -> 1000 ticks a second; a tempo moves
    nothing. mido writes only PPQN, so the header's division is patched."""
    ev = [(0, mido.MetaMessage("set_tempo", tempo=123_456)),
          (0, mido.Message("control_change", control=7, value=0)),
          (2500, mido.Message("control_change", control=7, value=127))]  # fmt: skip
    track([ev], type=0).save(str(tmp_path / "s.mid"))
    data = bytearray((tmp_path / "s.mid").read_bytes())
    data[12:14] = bytes([256 - 25, 40])
    (tmp_path / "s.mid").write_bytes(bytes(data))
    seq = read_midi_file(tmp_path / "s.mid")
    assert seq.division == (25.0, 40)
    assert seq.describe() == (
        "format 0, 1 track, SMPTE 25 fps x 40 ticks (tempo events move nothing); 2.500 s"
    )
    t = seq.cc_track(1, 7, (-30, 30), interpolation="linear")
    assert deg(t, 2.5) == pytest.approx(30.0) and deg(t, 1.25) == pytest.approx(0.0, abs=1e-12)
    data[12] = 256 - 29  # 29.97 fps (30 drop-frame): 30000/1001 frames a second
    (tmp_path / "s.mid").write_bytes(bytes(data))
    assert read_midi_file(tmp_path / "s.mid").seconds([2500])[0] == pytest.approx(
        2500 / (40 * 30000 / 1001)
    )


# ------------------------------------------------------------------ values, notes
def test_fine_pairs_as_live_midi_reads_them(tmp_path):
    """Controller 1 is the MSB, 33 the LSB: an LSB before any MSB is ignored, an MSB resets
    the LSB (MIDI 1.0), as hilsim.live.midi does; 0 -> -30°, 16383 -> +30°."""
    ev = [(0, mido.Message("control_change", control=33, value=100)),  # no MSB yet: ignored
          (0, mido.Message("control_change", control=1, value=64)),
          (480, mido.Message("control_change", control=33, value=127)),
          (960, mido.Message("control_change", control=1, value=127)),
          (960, mido.Message("control_change", control=33, value=127))]  # fmt: skip
    track([ev]).save(str(tmp_path / "f.mid"))
    seq = read_midi_file(tmp_path / "f.mid")
    t = seq.cc_track(1, 1, (-30, 30), fine=True)
    fine = lambda raw: -30 + 60 * raw / 16383  # noqa: E731
    assert deg(t, 0.25) == pytest.approx(fine(64 << 7))
    assert deg(t, 0.75) == pytest.approx(fine((64 << 7) | 127))
    assert deg(t, 1.0) == pytest.approx(30.0)  # MSB and LSB at one tick: the pair, no dip
    assert deg(seq.cc_track(1, 1, (-30, 30)), 0.75) == pytest.approx(cc(64))  # 7-bit: MSB only


def test_notes_open_and_close_on_their_channel_only(tmp_path):
    ev = [(480, mido.Message("note_on", channel=9, note=60, velocity=90)),
          (960, mido.Message("note_off", channel=9, note=60)),
          (1440, mido.Message("note_on", channel=9, note=60, velocity=1)),
          (1920, mido.Message("note_on", channel=9, note=60, velocity=0)),
          (0, mido.Message("note_on", channel=0, note=60, velocity=100))]  # fmt: skip
    track([ev]).save(str(tmp_path / "n.mid"))
    spec = {"type": "midi", "file": "n.mid", "channel": 10, "note": 60, "degrees": [0, 20]}
    t = track_from_spec(spec, base_dir=tmp_path, joint_name="jaw")
    assert [deg(t, s) for s in (0.2, 0.6, 1.2, 1.6, 2.2)] == [0, 20, 0, 20, 0]


# ------------------------------------------------------------------ one line per mistake
def _ramp_file(tmp_path: Path) -> Path:
    ev = [(30 * k, mido.Message("control_change", control=7, value=k)) for k in range(8)]
    ev.append((0, mido.Message("note_on", channel=9, note=36, velocity=100)))
    track([ev]).save(str(tmp_path / "ramp.mid"))
    return tmp_path / "ramp.mid"


@pytest.mark.parametrize(
    ("extra", "key", "match"),
    [
        ({"channel": 17, "control": 7}, "channel", "must be a MIDI channel 1-16, got 17"),
        ({"channel": 1}, "control", "give control .* or note"),
        ({"channel": 1, "control": 7, "note": 60}, "control", "give control .* or note"),
        ({"channel": 1, "control": 128}, "control", "must be 0-127, got 128"),
        ({"channel": 1, "control": 40, "fine": True}, "control", r"0-31 \(a 14-bit"),
        ({"channel": 1, "note": 60, "fine": True}, "fine", "with control"),
        ({"channel": 1, "note": 60, "interpolation": "linear"}, "interpolation", "a step"),
        ({"channel": 1, "control": 7, "interpolation": "cubic"}, "interpolation", "hold or"),
        ({"channel": 1, "control": 7, "degrees": [5, 5]}, "degrees", "equal"),
    ],
)
def test_a_bad_spec_is_one_line_naming_the_key(tmp_path, extra, key, match):
    _ramp_file(tmp_path)
    spec = {"type": "midi", "file": "ramp.mid", "degrees": [-30, 30], **extra}
    with pytest.raises(SpecError, match=match) as got:
        track_from_spec(spec, base_dir=tmp_path, joint_name="head")
    assert got.value.key == key


def test_a_controller_or_note_not_in_the_file_lists_what_is(tmp_path):
    path = _ramp_file(tmp_path)
    seq = read_midi_file(path)
    with pytest.raises(FormatError) as got:
        seq.cc_track(2, 7, (0, 1))
    assert str(got.value) == (
        f"{path}: no control change 7 on channel 2; it has ch1 cc 7; ch10 notes 36"
    )
    with pytest.raises(FormatError, match="no note 60 on channel 10; it has ch1 cc 7"):
        seq.note_track(10, 60, (0, 1))


def _good() -> bytes:
    ev = [(0, mido.MetaMessage("set_tempo", tempo=400_000)),
          (0, mido.Message("control_change", control=7, value=1)),
          (10, mido.Message("control_change", control=7, value=2)),
          (20, mido.Message("program_change", program=3))]  # fmt: skip
    return _bytes_of(track([ev], type=0))


def _bytes_of(mf) -> bytes:
    import io

    buf = io.BytesIO()
    mf.save(file=buf)
    return buf.getvalue()


RAMPS = _bytes_of(gen.ramps_file())
GOOD = _good()  # MThd(14) MTrk(8): 00 FF 51 03 .. .. .. | 00 B0 07 01 | 0A 07 02 | 0A C0 03 | ...
TRK = 22  # the first byte of the track's events


@pytest.mark.parametrize(
    ("data", "match"),
    [
        (b"RIFF" + GOOD[4:], r"byte 0: not a Standard MIDI File: .*RIFF \.rmi"),
        (b"MTrk" + GOOD[4:], "byte 0: not a Standard MIDI File"),
        (GOOD[:10], "byte 10: the header chunk is cut short"),
        (GOOD[:8] + b"\x00\x02" + GOOD[10:], "byte 8: format 2 .* is not read"),
        (GOOD[:10] + b"\x00\x02" + GOOD[12:], "byte 10: format 0 with 2 tracks"),
        (GOOD[:12] + b"\x00\x00" + GOOD[14:], "byte 12: 0 ticks per quarter note"),
        (GOOD[:12] + b"\xe5\x00" + GOOD[14:], "byte 12: SMPTE division -27 fps"),
        (GOOD[:-6], r"byte 14: track 1: \d+ bytes said, \d+ left"),
        (GOOD[: TRK + 3] + b"\x02" + GOOD[TRK + 4 :], "Set Tempo must hold 3 bytes, it holds 2"),
        (GOOD[: TRK + 4] + b"\0\0\0" + GOOD[TRK + 7 :], "Set Tempo of 0"),
        (GOOD[: TRK + 7] + b"\x00\x07\x01" + GOOD[TRK + 10 :], "data byte 0x07 with no status"),
        (GOOD[: TRK + 7] + b"\x00\xf4\x01" + GOOD[TRK + 10 :], "status 0xF4 is not an event"),
        (GOOD[: TRK + 7] + b"\x00\xb0\x87" + GOOD[TRK + 10 :], "a data byte over 127"),
        (GOOD[:TRK] + b"\xff\xff\xff\xff\x7f" + GOOD[TRK + 5 :], "longer than 4 bytes"),
    ],
)
def test_a_bad_file_is_one_format_error_naming_file_and_byte(tmp_path, data, match):
    path = tmp_path / "bad.mid"
    path.write_bytes(data)
    with pytest.raises(FormatError, match=match) as got:
        read_midi_file(path)
    assert str(got.value).startswith(f"{path}:byte ")


def test_the_good_file_of_those_reads(tmp_path):
    (tmp_path / "g.mid").write_bytes(GOOD)
    seq = read_midi_file(tmp_path / "g.mid")
    assert [e.value for e in seq.events] == [1, 2] and seq.tempos == [(0, 400_000)]


def test_hilsim_tracks_says_a_bad_file_in_one_line(tmp_path, capsys):
    (tmp_path / "cut.mid").write_bytes(GOOD[:30])
    rig = tmp_path / "r.toml"
    rig.write_text(RIG.format(target='{ type = "midi", file = "cut.mid", channel = 1, '
                                     'control = 7, degrees = [-30, 30] }'))  # fmt: skip
    assert main(["tracks", str(rig), "--at", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cut.mid:byte" in err[0] and "(head)" in err[0]


def test_a_running_status_after_a_meta_event_is_read(tmp_path):
    """Lenient as players are: a writer that keeps running status across a meta event."""
    data = bytearray(GOOD)
    # ... 00 B0 07 01 | 00 FF 01 00 (a text meta) | 0A 07 02 (running status)
    body = (
        b"\x00\xff\x51\x03\x06\x1a\x80\x00\xb0\x07\x01\x00\xff\x01\x00\x0a\x07\x02\x00\xff\x2f\x00"
    )
    data[14:] = b"MTrk" + len(body).to_bytes(4, "big") + body
    (tmp_path / "r.mid").write_bytes(bytes(data))
    assert [e.value for e in read_midi_file(tmp_path / "r.mid").events] == [1, 2]


def _only_format_errors(data: bytes, tmp: Path) -> None:
    path = tmp / "f.mid"
    path.write_bytes(data)
    try:
        seq = read_midi_file(path)
    except FormatError:
        return
    assert np.all(np.isfinite(seq.seconds([e.tick for e in seq.events])))
    for e in seq.events[:3]:
        maker = seq.cc_track if e.kind == 0xB0 else seq.note_track
        maker(e.channel, e.number, (0.0, 1.0))


@given(st.data())
def test_mangled_files_give_a_format_error_or_tracks(tmp_path_factory, draw):
    tmp = tmp_path_factory.mktemp("fuzz")
    data = bytearray(RAMPS if draw.draw(st.booleans()) else GOOD)
    for _ in range(draw.draw(st.integers(1, 4))):
        i = draw.draw(st.integers(0, len(data) - 1))
        op = draw.draw(st.sampled_from(["set", "set", "cut", "insert"]))
        if op == "set":
            data[i] = draw.draw(st.integers(0, 255))
        elif op == "cut":
            del data[i:]
        else:
            data[i:i] = draw.draw(st.binary(min_size=1, max_size=6))
        if not data:
            break
    _only_format_errors(bytes(data), tmp)


@given(st.binary(max_size=120))
def test_random_bytes_give_a_format_error_or_tracks(tmp_path_factory, data):
    tmp = tmp_path_factory.mktemp("fuzz")
    _only_format_errors(data, tmp)
    _only_format_errors(b"MThd\0\0\0\x06\0\0\0\x01\x01\xe0" + data, tmp)
