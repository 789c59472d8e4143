"""LTC: our decoder against our encoder (tools/make_ltc_wav.py), fuzzed; the chase on WAV files
in show time (lock, freewheel, relock, noise); an audio input through a fake sounddevice."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from hilsim.live.ltc import LtcDecoder, LtcError
from hilsim.live.ltc_chase import LtcChase, LtcConfig
from hilsim.live.timecode import Smpte

_spec = importlib.util.spec_from_file_location(
    "make_ltc_wav", Path(__file__).resolve().parents[2] / "tools" / "make_ltc_wav.py"
)
assert _spec is not None and _spec.loader is not None
enc = importlib.util.module_from_spec(_spec)
sys.modules["make_ltc_wav"] = enc
_spec.loader.exec_module(enc)

RATE_CODE = {"24": 0, "25": 1, "29.97df": 2, "30": 3}
TICK = 0.004


def decode_all(x: np.ndarray, rate: int, block: int = 192) -> tuple[list, LtcDecoder]:
    dec = LtcDecoder(rate)
    frames = []
    for i in range(0, len(x), block):
        frames += dec.decode(x[i : i + block])
    return frames, dec


# ------------------------------------------------------------------ the decoder
@pytest.mark.parametrize("fps", ["24", "25", "29.97df", "30"])
@pytest.mark.parametrize("rate", [8000, 44100, 48000, 96000])
def test_every_frame_rate_at_every_sample_rate_decodes_where_it_ends(fps, rate) -> None:
    """Frame k (label start + k) ends at sample (k + 1)·rate/fps; either polarity."""
    real = enc.RATES[fps][2]
    for invert in (False, True):
        x = enc.ltc_samples(fps, 2.0, rate, start=(1, 59, 59, 5), invert=invert)
        frames, dec = decode_all(x, rate)
        assert len(frames) >= int(2.0 * real) - 3 and dec.invalid == 0 and dec.reverse == 0
        label = (1, 59, 59, 5)
        k = 0
        for f in frames:
            while (f.hours, f.minutes, f.seconds, f.frames) != label:  # the first one is lost
                label, k = enc.next_label(label, fps), k + 1
                assert k < 3
            assert f.drop_frame == (fps == "29.97df")
            assert f.end_sample == pytest.approx((k + 1) * rate / real, abs=0.5)
            label, k = enc.next_label(label, fps), k + 1
        assert frames[-1].fps_measured(rate) == pytest.approx(real, rel=0.005)


def test_drop_frame_labels_skip_00_and_01_at_the_minute() -> None:
    x = enc.ltc_samples("29.97df", 1.0, 48000, start=(0, 0, 59, 20))
    labels = [str(f) for f in decode_all(x, 48000)[0]]
    assert "00:00:59;29" in labels and labels[labels.index("00:00:59;29") + 1] == "00:01:00;02"


@pytest.mark.parametrize("block", [1, 7, 160, 10**6])
def test_block_size_changes_nothing(block) -> None:
    x = enc.ltc_samples("25", 0.5, 16000, start=(0, 0, 1, 0))
    ref = [(str(f), f.end_sample) for f in decode_all(x, 16000, 192)[0]]
    got = [(str(f), f.end_sample) for f in decode_all(x, 16000, block)[0]]
    assert len(ref) >= 10 and [g[0] for g in got] == [r[0] for r in ref]
    assert np.allclose([g[1] for g in got], [r[1] for r in ref], atol=1e-6)


def test_low_level_dc_offset_and_varispeed_are_read() -> None:
    """A 5 % level on a DC offset; a signal 8 % slow (written at 52 kHz, read as 48 kHz)."""
    x = 0.3 + enc.ltc_samples("30", 1.0, 48000, amplitude=0.05)
    assert len(decode_all(x, 48000)[0]) >= 27
    slow = enc.ltc_samples("25", 2.0, 52000)
    frames, _ = decode_all(slow, 48000)
    assert len(frames) >= 40
    assert frames[-1].fps_measured(48000) == pytest.approx(25 * 48000 / 52000, rel=0.005)


@pytest.mark.parametrize("fps", ["24", "30"])
def test_a_band_limited_noisy_line_decodes_every_frame(fps) -> None:
    """48 kHz, edges slowed by a 5-sample moving average (~100 us), noise at 12 dB below the
    signal: every frame after the first decodes, none invalid."""
    rng = np.random.default_rng(3)
    x = np.convolve(enc.ltc_samples(fps, 2.0, 48000), np.ones(5) / 5, mode="same")
    x += rng.normal(0.0, 0.5 * 10 ** (-12 / 20), x.size)
    frames, dec = decode_all(x, 48000, 480)
    assert len(frames) >= int(2.0 * enc.RATES[fps][2]) - 2 and dec.invalid == 0


def test_reverse_play_is_counted_not_decoded() -> None:
    x = enc.ltc_samples("25", 1.0, 48000)[::-1].copy()
    frames, dec = decode_all(x, 48000)
    assert frames == [] and dec.reverse >= 20


@pytest.mark.parametrize("rate", [7999, 96001, 48000.0, True, "48000"])
def test_a_bad_sample_rate_is_our_error(rate) -> None:
    with pytest.raises(LtcError, match="sample rate"):
        LtcDecoder(rate)


@pytest.mark.parametrize("samples", [np.zeros((2, 3)), ["a", "b"], [[1], [2, 3]], object()])
def test_samples_that_are_not_one_channel_of_numbers_are_our_error(samples) -> None:
    with pytest.raises(LtcError):
        LtcDecoder(48000).decode(samples)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    data=st.binary(max_size=8192),
    kind=st.sampled_from(["<i2", "<f4", "<f8", "u1"]),
    rate=st.integers(8000, 96000),
    block=st.integers(1, 4096),
)
def test_fuzz_random_bytes_as_samples_never_raise(data, kind, rate, block) -> None:
    """Any bytes as samples (NaN, inf, huge, tiny): frames or nothing, never an exception,
    and every frame a valid code."""
    width = np.dtype(kind).itemsize
    x = np.frombuffer(data[: len(data) // width * width], dtype=kind)
    dec = LtcDecoder(rate)
    for i in range(0, len(x), block):
        for f in dec.decode(x[i : i + block]):
            assert f.frames < 30 and f.seconds < 60 and f.minutes < 60 and f.hours < 24


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    flips=st.integers(1, 200),
    noise=st.floats(0.0, 0.6),
)
def test_fuzz_damaged_ltc_gives_only_valid_frames_in_order(seed, flips, noise) -> None:
    """LTC with samples zeroed or flipped and noise added: whatever comes out is a valid code,
    its end within the signal, in order."""
    rng = np.random.default_rng(seed)
    x = enc.ltc_samples("30", 0.5, 16000)
    at = rng.integers(0, len(x), flips)
    x[at] = -x[at]
    x = x + rng.normal(0.0, noise * 0.5, len(x))
    frames, _ = decode_all(x, 16000, int(rng.integers(1, 500)))
    ends = [f.end_sample for f in frames]
    assert ends == sorted(ends) and all(0 <= e <= len(x) for e in ends)
    assert all(f.frames < 30 and f.seconds < 60 for f in frames)


# ------------------------------------------------------------------ the chase on a WAV
def wav(tmp_path: Path, fps: str, seconds: float, **kw) -> Path:
    rate = kw.pop("rate", 48000)
    path = tmp_path / f"ltc_{fps}.wav"
    enc.write_wav(path, enc.ltc_samples(fps, seconds, rate, **kw), rate)
    return path


def chase_wav(path: Path, until: float, **cfg) -> SimpleNamespace:
    """Poll the chase tick by tick (250 Hz) over the WAV in show time."""
    chase = LtcChase(LtcConfig(source=path, **cfg))
    note = chase.start(lambda: 0.0)
    ts, shows, states, events = [], [], [], []
    for k in range(round(until / TICK) + 1):
        t = k * TICK
        p = chase.poll(t)
        ts.append(t)
        shows.append(math.nan if p.show_time_s is None else p.show_time_s)
        states.append(p.state)
        events += p.events
    chase.close()
    return SimpleNamespace(
        chase=chase, t=np.array(ts), show=np.array(shows), states=states, events=events, note=note
    )


@pytest.mark.parametrize("fps", ["24", "25", "29.97df", "30"])
def test_acceptance_each_frame_rate_locks_within_2_frames_of_the_true_time(tmp_path, fps):
    """LTC from 00:59:58:10 (29.97df crosses a dropped minute): locked within 5 frames, and
    from then on the show time is the true time (code − offset) within 2 frames."""
    start = (0, 59, 58, 10)
    r = chase_wav(wav(tmp_path, fps, 4.0, start=start), 3.9, offset_s=3500.0)
    real = enc.RATES[fps][2]
    true = Smpte(*start, RATE_CODE[fps]).to_seconds() + r.t - 3500.0
    locked = [e for e in r.events if e.kind == "timecode_locked"]
    assert len(locked) == 1 and locked[0].detail["rate"] == fps
    assert locked[0].t <= 5 / real
    on = ~np.isnan(r.show)
    assert on.sum() > 0 and np.all(on[r.t > 5 / real])
    assert np.max(np.abs(r.show[on] - true[on])) <= 2 / real
    assert np.max(np.abs(r.show[on] - true[on])) < 1e-3  # in fact: exact to a sample or so
    assert "offset 3500 s" in locked[0].detail["message"] and "LTC locked at" in str(
        locked[0].detail["message"]
    )
    assert r.chase.status == f"LTC locked {fps} fps"
    assert "played in show time" in r.note


def test_acceptance_a_1_s_dropout_freewheels_and_relocks(tmp_path) -> None:
    """1 s of silence at 2 s: with freewheel_s = 1.5 the show time runs on through it (within
    2 frames of the truth) and the chase relocks as the signal comes back, no jump."""
    r = chase_wav(wav(tmp_path, "25", 5.0, gaps=((2.0, 1.0),)), 4.9, freewheel_s=1.5)
    kinds = [e.kind for e in r.events]
    assert kinds.count("timecode_stopped") == 1 and "timecode_held" not in kinds
    assert kinds.count("timecode_locked") == 2 and "timecode_jump" not in kinds
    stopped = r.events[kinds.index("timecode_stopped")]
    relock = [e for e in r.events if e.kind == "timecode_locked"][1]
    assert 2.0 < stopped.t <= 2.0 + 3 / 25 + TICK
    assert 3.0 < relock.t <= 3.0 + 5 / 25
    free = (r.t > stopped.t) & (r.t < relock.t)
    assert set(np.array(r.states)[free]) == {"freewheel"}
    on = ~np.isnan(r.show)
    assert np.max(np.abs(r.show[on] - r.t[on])) <= 2 / 25


def test_a_dropout_longer_than_the_freewheel_holds_then_relocks_with_a_jump(tmp_path) -> None:
    r = chase_wav(wav(tmp_path, "30", 5.0, gaps=((2.0, 1.0),)), 4.9)  # freewheel 0.5 s
    kinds = [e.kind for e in r.events]
    assert kinds.index("timecode_stopped") < kinds.index("timecode_held")
    held = r.events[kinds.index("timecode_held")]
    assert held.detail["show_time_s"] == pytest.approx(2.5, abs=2 / 30)
    assert "holds at" in held.detail["message"]
    jump = r.events[kinds.index("timecode_jump")]
    assert jump.detail["from_s"] == pytest.approx(2.5, abs=2 / 30)
    after = r.t > 3.3
    assert np.max(np.abs(r.show[after] - r.t[after])) <= 2 / 30
    assert r.states[-1] == "locked"


def not_ltc(kind: str, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(48000 * 6) / 48000
    if kind == "gaussian":
        return np.clip(rng.normal(0, 0.3, t.size), -1, 1)
    if kind == "uniform":
        return rng.uniform(-1, 1, t.size)
    if kind == "tone":  # 1 kHz: transitions at LTC's own spacing, but never a sync word
        return 0.5 * np.sin(2 * np.pi * 1000 * t)
    # random bits, biphase-mark coded at 25 fps's bit rate: LTC's shape without its frames
    bits = rng.integers(0, 2, 2000 * 6 + 1)
    tr = np.zeros(2 * bits.size, np.int64)
    tr[0::2], tr[1::2] = 1, bits
    level = np.cumsum(tr) % 2
    return np.where(level[(t * 4000).astype(np.int64)] == 1, 0.5, -0.5)


@pytest.mark.parametrize(
    ("kind", "seed"), [("gaussian", 7), ("uniform", 8), ("tone", 0), ("random_bits", 9)]
)
def test_acceptance_noise_never_locks_and_says_so_once(tmp_path, kind, seed) -> None:
    path = tmp_path / "noise.wav"
    enc.write_wav(path, not_ltc(kind, seed), 48000)
    r = chase_wav(path, 5.9)
    assert set(r.states) == {"waiting"} and np.all(np.isnan(r.show))
    said = [e for e in r.events if e.kind == "timecode_none"]
    assert len(said) == 1 and said[0].t == pytest.approx(2.0)
    assert "no timecode locked in 2 s from noise.wav" in said[0].detail["message"]
    assert [e.kind for e in r.events] == ["timecode_none"]
    assert r.chase.status == "LTC waiting"


def test_a_fixed_fps_that_the_signal_does_not_run_at_is_said_once(tmp_path) -> None:
    r = chase_wav(wav(tmp_path, "25", 2.0), 1.9, fps="30")
    said = [e for e in r.events if e.kind == "timecode_rate_mismatch"]
    assert len(said) == 1 and said[0].detail["measured"] == "25"
    assert "fps = 30 but the signal runs at 25.00 fps" in said[0].detail["message"]


def test_reverse_play_is_said_once_and_not_chased(tmp_path) -> None:
    path = tmp_path / "rev.wav"
    enc.write_wav(path, enc.ltc_samples("25", 3.0, 48000)[::-1].copy(), 48000)
    r = chase_wav(path, 2.9)
    assert [e.kind for e in r.events].count("timecode_reverse") == 1
    assert set(r.states) == {"waiting"}


def test_a_24_bit_stereo_wav_is_read_on_its_channel(tmp_path) -> None:
    import wave

    x = enc.ltc_samples("24", 1.5, 44100)
    pcm = np.round(x * (2**23 - 1)).astype("<i4")
    b = pcm.view(np.uint8).reshape(-1, 4)[:, :3]  # the low three bytes, little-endian
    stereo = np.zeros((len(x), 2, 3), np.uint8)
    stereo[:, 1] = b  # LTC on the second channel, silence on the first
    path = tmp_path / "s24.wav"
    with wave.open(str(path), "wb") as w:
        w.setnchannels(2)
        w.setsampwidth(3)
        w.setframerate(44100)
        w.writeframes(stereo.tobytes())
    assert chase_wav(path, 1.4, channel=2).states[-1] == "locked"
    assert set(chase_wav(path, 1.4, channel=1).states) == {"waiting"}


# ------------------------------------------------------------------ an audio input
class FakeStream:
    latency = 0.005

    def __init__(self, **kw):
        self.kw, self.started, self.closed = kw, False, False

    def start(self):
        self.started = True

    def stop(self):
        pass

    def close(self):
        self.closed = True


class FakeSd:
    """sounddevice as the reader uses it: one input at 48 kHz, or none."""

    def __init__(self, present: bool = True):
        self.present, self.stream = present, None

    def query_devices(self, device, kind):
        if not self.present:
            raise ValueError(f"No input device matching {device!r}")
        return {"default_samplerate": 48000.0}

    def InputStream(self, **kw):  # sounddevice's name
        self.stream = FakeStream(**kw)
        return self.stream


def test_an_audio_input_is_decoded_in_its_own_thread_and_locks() -> None:
    sd = FakeSd()
    chase = LtcChase(LtcConfig(source="Scarlett", offset_s=10.0))
    chase.sd = sd
    clock = [0.0]
    note = chase.start(lambda: clock[0])
    assert "LTC from audio input 'Scarlett' (48000 Hz, channel 1)" in note
    assert sd.stream.started and sd.stream.kw["blocksize"] == 480
    x = enc.ltc_samples("25", 1.0, 48000, start=(0, 0, 10, 0)).astype(np.float32)
    callback = sd.stream.kw["callback"]
    no_time = SimpleNamespace(currentTime=0.0, inputBufferAdcTime=0.0)
    states = []
    for i in range(0, len(x), 480):
        clock[0] = (i + 480) / 48000  # the callback comes as the block ends
        callback(x[i : i + 480, None], 480, no_time, SimpleNamespace(input_overflow=False))
        chase.audio._q.join()  # the thread has decoded it (no sleep)
        p = chase.poll(clock[0])
        states.append(p.state)
        if p.state == "locked":  # within a block (10 ms) of the true time: code + 1 frame
            assert p.show_time_s == pytest.approx(clock[0], abs=0.011)
    assert states[-1] == "locked" and states.index("locked") <= 20
    assert "freewheel" not in states
    assert chase.summary()["blocks_dropped"] == 0
    chase.close()


def test_a_stalled_decoder_drops_blocks_counts_them_and_says_so_once_a_second() -> None:
    from hilsim.live.ltc_audio import QUEUE_BLOCKS, AudioLtcReader

    chase = LtcChase(LtcConfig(source="default"))
    reader = AudioLtcReader(chase, chase.config, lambda: 0.0, sd=FakeSd())
    reader.rate = 48000  # not opened: no thread takes the blocks
    block = np.zeros((480, 1), np.float32)
    for _ in range(QUEUE_BLOCKS + 8):
        reader._callback(block, 480, SimpleNamespace(), SimpleNamespace())
    assert reader._q.qsize() == QUEUE_BLOCKS and reader.dropped == 8
    first = reader.take_events(5.0)
    assert len(first) == 1 and first[0].detail["dropped"] == 8
    reader._callback(block, 480, SimpleNamespace(), SimpleNamespace())
    assert reader.take_events(5.5) == [] and len(reader.take_events(6.0)) == 1


def test_no_audio_device_is_one_warning_and_no_chase() -> None:
    chase = LtcChase(LtcConfig(source="Nope"))
    chase.sd = FakeSd(present=False)
    note = chase.start(lambda: 0.0)
    assert note.startswith("warning: LTC: no audio input 'Nope' (No input device matching")
    assert "\n" not in note
    first = chase.poll(0.004)
    assert [e.kind for e in first.events] == ["input_unavailable"]
    assert first.state == "waiting" and first.show_time_s is None
    assert [e.kind for e in chase.poll(0.008).events] == []
    assert [e.kind for e in chase.poll(5.0).events] == []  # no second line (timecode_none)
    assert "no audio input" in chase.summary()["error"]


def test_without_sounddevice_an_audio_input_is_one_warning() -> None:
    if importlib.util.find_spec("sounddevice") is not None:
        pytest.skip("sounddevice is installed here")
    chase = LtcChase(LtcConfig(source="default"))
    note = chase.start(lambda: 0.0)
    assert "LTC from an audio input needs" in note and "hilsim[live]" in note


# ------------------------------------------------------------------ the show file, the loop
def test_through_the_loop_the_jaw_follows_the_chased_time(tmp_path) -> None:
    """hilsim's loop in virtual time with [inputs.ltc] on a 29.97df WAV from 00:00:02;00: the
    jaw's rig keyframes (2 deg/s) are sampled at the chased time, within 2 frames."""
    from tests.hilsim.test_live_run import PERIOD, deg, show

    wav(tmp_path, "29.97df", 3.0, start=(0, 0, 2, 0))
    text = '[inputs.ltc]\nsource = "ltc_29.97df.wav"\nfps = "29.97df"\n'
    r = show(tmp_path, text, duration=2.5, open_inputs=True)
    target = deg(r.run, "target", 1)
    t = np.arange(len(target)) * PERIOD
    after = t > 5 / 29.97
    true = 2.0 * (Smpte(0, 0, 2, 0, 2).to_seconds() + t[after])
    assert np.max(np.abs(target[after] - true)) <= 2.0 * 2 / 29.97
    kinds = [e["kind"] for e in r.run.events]
    assert kinds.count("timecode_locked") == 1
    assert r.director.now_playing.endswith("LTC locked 29.97df fps")
    assert r.director.close(None)["ltc"]["rate"] == "29.97df"


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ('source = "missing.wav"', "inputs.ltc.source: "),
        ('source = "bad.wav"', "not a PCM WAV file we can read"),
        ('source = "ok.wav"\nfps = 29', "inputs.ltc.fps: one of auto, 24, 25"),
        ('source = "ok.wav"\nchannel = 2', "channel 2, but the file has 1"),
        ('source = "ok.wav"\nsample_rate = 48000', "a WAV file has its own"),
        ("source = -1", "an audio input's index is >= 0"),
        ('source = "ok.wav"\nofset_s = 1', "unknown key(s) ofset_s in inputs.ltc"),
        ('source = "ok.wav"\n[inputs.mtc]', "inputs.ltc: inputs.mtc sets the show time too"),
    ],
)
def test_a_show_file_mistake_in_inputs_ltc_is_one_line(tmp_path, text, words) -> None:
    from hilsim.live.showfile import load_show
    from hilsim.rig import RigError, load_rig
    from tests.hilsim.test_live_run import RIG

    (tmp_path / "rig.toml").write_text(RIG)
    enc.write_wav(tmp_path / "ok.wav", enc.ltc_samples("25", 0.2, 48000), 48000)
    (tmp_path / "bad.wav").write_bytes(b"RIFF\x00\x00\x00\x00WAVEjunk")
    (tmp_path / "show.toml").write_text("[inputs.ltc]\n" + text + "\n")
    with pytest.raises(RigError) as info:
        load_show(tmp_path / "show.toml", load_rig(tmp_path / "rig.toml"), lambda *a: None)
    assert words in str(info.value) and "\n" not in str(info.value)


def test_an_audio_input_in_the_show_file_is_read_as_such(tmp_path) -> None:
    from hilsim.live.showfile import load_show
    from hilsim.rig import load_rig
    from tests.hilsim.test_live_run import RIG

    (tmp_path / "rig.toml").write_text(RIG)
    (tmp_path / "show.toml").write_text(
        '[inputs.ltc]\nsource = "Scarlett 2i2"\nchannel = 2\nfps = 25\noffset_s = 3600\n'
        "sample_rate = 44100\n"
    )
    spec = load_show(tmp_path / "show.toml", load_rig(tmp_path / "rig.toml"), lambda *a: None)
    assert spec.ltc == LtcConfig(
        source="Scarlett 2i2", channel=2, fps="25", offset_s=3600.0, sample_rate=44100
    )
    assert not spec.ltc.is_wav and spec.midi is None


def test_live_md_example_is_what_the_reader_takes(tmp_path) -> None:
    """docs/live.md's [inputs.ltc] block, with its WAV made and its commented key on."""
    import tomllib

    from hilsim.live.ltc_chase import read_ltc
    from hilsim.rig.reader import Reader

    text = (Path(__file__).resolve().parents[2] / "docs" / "live.md").read_text(encoding="utf-8")
    block = text.split("### SMPTE LTC", 1)[1].split("```toml", 1)[1].split("```", 1)[0]
    enc.write_wav(tmp_path / "show_ltc.wav", enc.ltc_samples("25", 0.2, 48000), 48000)
    wav_cfg = read_ltc(Reader(tmp_path / "s.toml", tomllib.loads(block)["inputs"]["ltc"],
                              "inputs.ltc"), tmp_path)  # fmt: skip
    assert wav_cfg.is_wav and wav_cfg.offset_s == 3600 and wav_cfg.fps == "auto"
    device = block.replace('source = "show_ltc.wav"', 'source = "Scarlett 2i2"')
    device = device.replace("# sample_rate", "sample_rate")
    cfg = read_ltc(Reader(tmp_path / "s.toml", tomllib.loads(device)["inputs"]["ltc"],
                          "inputs.ltc"), tmp_path)  # fmt: skip
    assert cfg.source == "Scarlett 2i2" and cfg.sample_rate == 48000


@settings(
    max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    body=st.binary(max_size=200),
    fmt=st.integers(0, 4),
    channels=st.integers(0, 3),
    width=st.integers(0, 5),
    rate=st.integers(0, 200000),
)
@example(body=bytes(range(100)), fmt=1, channels=1, width=5, rate=48000)  # 40-bit "PCM"
@example(body=bytes(range(99)), fmt=1, channels=3, width=3, rate=8000)
def test_fuzz_a_damaged_wav_is_one_valueerror_or_reads(tmp_path, body, fmt, channels, width, rate):
    """A RIFF/WAVE header with random fields and data: the WAV reader raises ValueError (one
    line) or reads samples; nothing else leaves it."""
    import struct

    from hilsim.live.ltc_chase import WavSource

    fmt_chunk = struct.pack(
        "<HHIIHH", fmt, channels, rate, rate * channels * width, channels * width, 8 * width
    )
    data = b"fmt " + struct.pack("<I", 16) + fmt_chunk + b"data" + struct.pack("<I", len(body))
    path = tmp_path / "f.wav"
    path.write_bytes(b"RIFF" + struct.pack("<I", 4 + len(data) + len(body)) + b"WAVE" + data + body)
    try:
        src = WavSource(path, 1)
    except ValueError as exc:
        assert "\n" not in str(exc)
        return
    with src:
        while not src.done:
            x = src.read(64)
            assert x.ndim == 1


def test_a_wav_that_cannot_be_read_on_is_said_and_the_chase_lets_go(tmp_path) -> None:
    """A read error mid-file (a disk gone): one ltc_read_error, then freewheel and hold, never
    an exception in the loop's tick."""
    chase = LtcChase(LtcConfig(source=wav(tmp_path, "25", 3.0)))
    chase.start(lambda: 0.0)
    for k in range(250):
        chase.poll(k * TICK)
    assert chase.state == "locked"

    def broken(n):
        raise OSError("Input/output error")

    chase._wav._w.readframes = broken
    kinds = []
    for k in range(250, 750):
        kinds += [e.kind for e in chase.poll(k * TICK).events]
    assert kinds == ["ltc_read_error", "timecode_stopped", "timecode_held"]
    assert chase.state == "held"


def test_an_audio_input_under_virtual_time_is_refused_in_one_line(tmp_path) -> None:
    """Real-time audio cannot be chased by a show on the virtual clock: refused before anything
    moves, saying what to do (it used to run, chasing audio against jumping time)."""
    import hilsim
    from hilsim.show.session import ShowRefusedError
    from tests.hilsim.test_live_run import RIG

    (tmp_path / "rig.toml").write_text(RIG)
    (tmp_path / "show.toml").write_text('[inputs.ltc]\nsource = "default"\n')
    show = hilsim.Show(tmp_path / "rig.toml", show=tmp_path / "show.toml", virtual_time=True)
    with pytest.raises(ShowRefusedError) as exc:
        show.open()
    message = str(exc.value)
    assert "\n" not in message and "an audio input runs in real time" in message
    assert "make_ltc_wav.py" in message
    show.close()
