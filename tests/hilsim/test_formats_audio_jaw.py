"""Audio -> jaw: issue 13's acceptance numbers, review R1's, the lead (given, and from the
spring), every WAV form alike, channels, the band-pass, and bad files (one FormatError each)."""

from __future__ import annotations

import importlib.util
import math
import struct
import sys
import wave
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hilsim import Spring, simulate
from hilsim.targets.formats.audio_jaw import (
    FLOAT_LIMIT,
    RATE_RANGE,
    EnvelopeSettings,
    jaw_envelope,
    jaw_track,
    read_audio,
    spring_lag_s,
)
from hilsim.targets.formats.common import FormatError, UnitMap

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location(
    "samples_audio_jaw", ROOT / "tools" / "samples_audio_jaw.py"
)
gen = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(gen)

JAW = UnitMap((0, 1), (0, 20), "opening")
ISSUE = EnvelopeSettings(window_ms=10, attack_ms=10, release_ms=100, threshold=0.02, full=0.35)


def deg(track, t: float) -> float:
    return math.degrees(track.sample(t)[0])


@pytest.fixture(scope="module")
def acceptance_wav(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("audio") / "acceptance.wav"
    path.write_bytes(gen.wav_bytes(gen.acceptance_signal(44_100), 44_100, bits=16))
    return path


def write(tmp_path: Path, data: bytes, name: str = "x.wav") -> Path:
    path = tmp_path / name
    path.write_bytes(data)
    return path


# ---------------------------------------------------------------------------- acceptance


def test_issue_13_acceptance(acceptance_wav):
    track = jaw_track(acceptance_wav, JAW, ISSUE, lead_s=0.0)
    assert deg(track, 0.49) == 0.0
    assert deg(track, 0.60) == pytest.approx(20.0, abs=0.1)
    after = np.arange(1.5, track.duration + 0.5, 0.001)
    assert np.all(track.sample_array(after)[0] == 0.0)  # back to 0° by 1.5 s, and stays
    led = jaw_track(acceptance_wav, JAW, ISSUE, lead_s=0.050)
    times = np.arange(0.0, 2.2, 0.0005)
    assert np.allclose(led.sample_array(times)[0], track.sample_array(times + 0.050)[0], atol=1e-12)


def test_review_r1_numbers(acceptance_wav):
    """Review R1: 20.0 at 0.55 s, 7.2 ± 0.8 at 1.10 s, < 2.5 at 1.20 s (its simulation: 7.17,
    1.87); lead 50 ms: 20.0 at 0.50 s, 7.2 ± 0.8 at 1.05 s."""
    track = jaw_track(acceptance_wav, JAW, ISSUE)
    assert deg(track, 0.55) == pytest.approx(20.0, abs=0.01)
    assert deg(track, 1.10) == pytest.approx(7.17, abs=0.05)
    assert deg(track, 1.20) == pytest.approx(1.87, abs=0.05)
    assert deg(track, 1.50) == 0.0
    led = jaw_track(acceptance_wav, JAW, ISSUE, lead_s=0.05)
    assert deg(led, 0.50) == pytest.approx(20.0, abs=0.01)
    assert deg(led, 1.05) == pytest.approx(7.2, abs=0.8)


def test_envelope_is_the_documented_follower(acceptance_wav):
    """The RMS of the half-scale sine is 0.5/√2; the release is e·exp(-1 ms/100 ms) per step."""
    env = jaw_envelope(acceptance_wav, ISSUE)
    assert env.times_s[1] - env.times_s[0] == pytest.approx(0.001)
    k = round(0.75 / 0.001)
    assert env.rms[k] == pytest.approx(0.5 / math.sqrt(2), rel=1e-3)
    k1 = round(1.05 / 0.001)  # the window has left the tone: pure release
    assert env.envelope[k1 + 1] / env.envelope[k1] == pytest.approx(math.exp(-0.01), rel=1e-12)
    assert env.audio.encoding == "PCM 16-bit" and env.audio.rate_hz == 44_100


def test_a_line_that_ends_loud_still_closes_the_jaw(tmp_path):
    rate = 8000
    t = np.arange(rate // 2) / rate
    path = write(tmp_path, gen.wav_bytes(0.5 * np.sin(2 * np.pi * 500 * t), rate))
    track = jaw_track(path, JAW, ISSUE)
    assert deg(track, 0.49) == pytest.approx(20.0, abs=0.01)
    assert deg(track, track.duration) == 0.0 and track.duration < 0.5 + 0.35


# ---------------------------------------------------------------------------- the lead


def test_spring_lag_is_c_minus_b_over_k_in_both_forms():
    f, zeta, r = 6.0, 0.9, 0.5
    assert spring_lag_s(Spring.from_animation(f, zeta, r)) == pytest.approx(
        (2 - r) * zeta / (2 * math.pi * f), rel=1e-12
    )
    assert spring_lag_s(Spring(m=1.0, c=0.8, k=25.0, b=0.3)) == pytest.approx(0.5 / 25.0)
    assert spring_lag_s(Spring.from_animation(5.0, 0.7, 2.0)) == pytest.approx(0.0, abs=1e-15)
    assert spring_lag_s(Spring.from_animation(5.0, 0.7, 3.0)) < 0  # feed-forward leads
    with pytest.raises(ValueError, match="bank"):
        spring_lag_s(Spring.stack([Spring(1, 1, 1), Spring(1, 1, 1)]))


@pytest.mark.parametrize(("f", "zeta", "r"), [(6.0, 0.9, 0.5), (3.0, 1.0, 0.0), (2.0, 0.4, 1.0)])
def test_the_spring_follows_a_ramp_exactly_lag_late(f, zeta, r):
    spring = Spring.from_animation(f, zeta, r)
    slope = 0.5  # rad/s
    traj = simulate(spring, 0.0, h=0.001, t_end=6.0, target=lambda t: slope * t,
                    target_rate=lambda t: slope)  # fmt: skip
    late = (slope * traj.t[-1] - traj.x[-1]) / slope
    assert late == pytest.approx(spring_lag_s(spring), rel=1e-6)


@pytest.mark.parametrize(("f", "zeta", "r"), [(6.0, 0.9, 0.5), (3.0, 1.0, 0.0), (10.0, 0.7, 1.0)])
def test_with_the_spring_lag_as_lead_the_commanded_jaw_is_in_time(acceptance_wav, f, zeta, r):
    """Without a lead the spring's jaw crosses half-open (rising) and quarter-open (falling)
    most of the lag after the target; with the lag as lead, within a tenth of the spring's
    period (1/f) and under half the lag - the rest is the spring's rise on a fast edge."""
    spring = Spring.from_animation(f, zeta, r)
    lag = spring_lag_s(spring)
    target = jaw_track(acceptance_wav, JAW, ISSUE)
    u = np.degrees(target.sample_array(np.arange(2001) * 0.001)[0])

    def crossings(y):
        up = np.flatnonzero((y[:-1] < 10) & (y[1:] >= 10))[0]
        down = np.flatnonzero((y[:-1] > 5) & (y[1:] <= 5))[0]
        return np.array([up + (10 - y[up]) / (y[up + 1] - y[up]),
                         down + (y[down] - 5) / (y[down] - y[down + 1])]) * 0.001  # fmt: skip

    near = min(0.1 / f, 0.5 * lag)
    for lead, low, high in ((0.0, 0.75 * lag, 1.5 * lag), (lag, -near, near)):
        track = jaw_track(acceptance_wav, JAW, ISSUE, lead_s=lead)
        traj = simulate(spring, 0.0, h=0.001, t_end=2.0, target=lambda t, tr=track: tr.sample(t)[0],
                        target_rate=lambda t, tr=track: tr.sample(t)[1])  # fmt: skip
        late = crossings(np.degrees(traj.x)) - crossings(u)
        assert np.all((low <= late) & (late <= high)), (lead, late, lag)


def test_bad_lead_is_refused(acceptance_wav):
    for bad in (math.nan, math.inf, 11.0, "50"):
        with pytest.raises(ValueError, match="lead_s"):
            jaw_track(acceptance_wav, JAW, ISSUE, lead_s=bad)


# ---------------------------------------------------------------------------- forms


FORMS = [("pcm", 8, False), ("pcm", 16, False), ("pcm", 24, False), ("pcm", 32, False),
         ("float", 32, False), ("float", 64, False), ("pcm", 16, True), ("float", 32, True)]  # fmt: skip


@pytest.mark.parametrize(("kind", "bits", "ext"), FORMS)
def test_every_wav_form_reads_the_same_samples_and_jaw(tmp_path, acceptance_wav, kind, bits, ext):
    rate = 22_050
    x = gen.acceptance_signal(rate)
    path = write(tmp_path, gen.wav_bytes(x, rate, bits=bits, kind=kind, extensible=ext))
    audio = read_audio(path)
    lsb = 1.0 / 128 if bits == 8 else 1e-4 if kind == "pcm" else 1e-7
    assert audio.rate_hz == rate and np.max(np.abs(audio.samples - x)) <= lsb
    reference = jaw_track(write(tmp_path, gen.wav_bytes(x, rate, bits=64, kind="float"), "r.wav"),
                          JAW, ISSUE)  # fmt: skip
    times = np.arange(0, 2.1, 0.001)
    tol = 0.2 if bits == 8 else 0.005
    diff = np.degrees(jaw_track(path, JAW, ISSUE).sample_array(times)[0])
    assert np.max(np.abs(diff - np.degrees(reference.sample_array(times)[0]))) < tol


@pytest.mark.parametrize("bits", [8, 16, 24, 32])
def test_the_writer_agrees_with_the_stdlib_wave(tmp_path, bits):
    """The samples' files are real WAVs: the stdlib reads the same frames as read_audio."""
    x = np.stack([np.linspace(-1, 0.99, 500), np.linspace(0.5, -0.5, 500)], axis=1)
    path = write(tmp_path, gen.wav_bytes(x, 16_000, bits=bits))
    with wave.open(str(path)) as w:
        assert (w.getnchannels(), w.getsampwidth(), w.getframerate(), w.getnframes()) == (
            2, bits // 8, 16_000, 500)  # fmt: skip
        raw = w.readframes(500)
    assert raw == gen.encode(x, bits)
    assert np.max(np.abs(read_audio(path, "right").samples - x[:, 1])) <= 1 / 128


def test_odd_chunks_before_the_data_are_skipped_with_their_pad_byte(tmp_path):
    x = gen.acceptance_signal(8000)
    plain = gen.wav_bytes(x, 8000)
    fmt_end = 12 + 8 + 16
    extra = b"LIST" + struct.pack("<I", 3) + b"abc" + b"\0"
    path = write(tmp_path, plain[:fmt_end] + extra + plain[fmt_end:])
    assert np.array_equal(
        read_audio(path).samples, read_audio(write(tmp_path, plain, "p.wav")).samples
    )


def test_channels(tmp_path):
    rate = 8000
    x = gen.acceptance_signal(rate)
    stereo = write(tmp_path, gen.wav_bytes(np.stack([np.zeros_like(x), x], axis=1), rate))
    assert jaw_envelope(stereo, ISSUE, "left").opening.max() == 0.0
    assert jaw_envelope(stereo, ISSUE, "right").opening.max() == 1.0
    assert jaw_envelope(stereo, ISSUE, 1).opening.max() == 1.0
    mix = read_audio(stereo, "mix").samples
    assert np.allclose(mix, read_audio(stereo, "right").samples / 2)
    mono = write(tmp_path, gen.wav_bytes(x, rate), "m.wav")
    with pytest.raises(FormatError, match="mono: use mix"):
        read_audio(mono, "right")
    with pytest.raises(FormatError, match=r"0 \.\. 1"):
        read_audio(stereo, 2)
    with pytest.raises(ValueError, match="allowed left, right, mix"):
        read_audio(stereo, "centre")


def test_band_pass_stops_a_hum_and_passes_the_voice_band(tmp_path):
    rate = 16_000
    t = np.arange(2 * rate) / rate
    gate = (t >= 0.5) & (t < 1.0)
    hum = write(tmp_path, gen.wav_bytes(np.where(gate, 0.5 * np.sin(2 * np.pi * 100 * t), 0), rate))
    band = EnvelopeSettings(band_hz=(500.0, 2500.0), band_order=2)
    assert jaw_envelope(hum, ISSUE).opening.max() == 1.0
    assert jaw_envelope(hum, band).opening.max() == 0.0  # 100 Hz: 1/√(1+5⁴) of it passes
    tone = write(tmp_path, gen.wav_bytes(gen.acceptance_signal(rate), rate), "tone.wav")
    track = jaw_track(tone, JAW, band)
    gain = 1 / math.sqrt((1 + (500 / 1000) ** 4) * (1 + (1000 / 2500) ** 4))  # Butterworth edges
    expected = 20 * (0.5 / math.sqrt(2) * gain - 0.02) / (0.35 - 0.02)  # 19.31°: 0.958 of it
    assert deg(track, 0.49) == 0.0 and deg(track, 0.80) == pytest.approx(expected, abs=0.05)
    with pytest.raises(FormatError, match="Nyquist"):
        jaw_envelope(tone, EnvelopeSettings(band_hz=(500.0, 9000.0)))


def test_soundfile_extra_reads_other_formats(tmp_path, acceptance_wav):
    soundfile = pytest.importorskip("soundfile")
    x = gen.acceptance_signal(22_050)
    path = tmp_path / "line.flac"
    soundfile.write(str(path), x, 22_050, subtype="PCM_16")
    assert read_audio(path).encoding == "FLAC PCM_16"
    wav = write(tmp_path, gen.wav_bytes(x, 22_050), "line.wav")
    times = np.arange(0, 2.1, 0.001)
    a, b = (jaw_track(p, JAW, ISSUE).sample_array(times)[0] for p in (path, wav))
    assert np.max(np.abs(np.degrees(a - b))) < 1e-6


@pytest.mark.parametrize("subtype", ["IMA_ADPCM", "ULAW"])
def test_compressed_wav_goes_to_soundfile(tmp_path, subtype):
    soundfile = pytest.importorskip("soundfile")
    path = tmp_path / "c.wav"
    soundfile.write(str(path), gen.acceptance_signal(22_050), 22_050, subtype=subtype)
    track = jaw_track(path, JAW, ISSUE)
    assert read_audio(path).encoding == f"WAV {subtype}"
    assert deg(track, 0.49) == 0.0 and deg(track, 0.60) == pytest.approx(20.0, abs=0.1)
    assert deg(track, 1.10) == pytest.approx(7.17, abs=0.2)


def test_a_float_sample_far_beyond_full_scale_is_refused_through_soundfile_too(tmp_path):
    """One such sample would leave the envelope's running sums too coarse for the quiet
    samples after it (1e9: the jaw shut for the rest of the file), or not finite."""
    soundfile = pytest.importorskip("soundfile")
    path = tmp_path / "loud.aiff"
    soundfile.write(str(path), np.array([0.0, 0.5, 1e9]), 8000, subtype="FLOAT", format="AIFF")
    with pytest.raises(FormatError, match=r"loud\.aiff: sample 2 is 1e\+09, beyond ±1000"):
        read_audio(path)


def test_other_formats_without_soundfile_name_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "soundfile", None)  # import soundfile -> ImportError
    path = write(tmp_path, b"fLaC\0\0\0\x22" + bytes(60), "a.flac")
    with pytest.raises(FormatError, match=r"byte 0: .*pip install 'hilsim\[audio\]'"):
        read_audio(path)


# ---------------------------------------------------------------------------- bad files


def _good() -> bytes:
    return gen.wav_bytes(gen.acceptance_signal(8000)[:800], 8000)


def _patch(data: bytes, offset: int, fmt: str, value) -> bytes:
    out = bytearray(data)
    struct.pack_into(fmt, out, offset, value)
    return bytes(out)


BAD = {
    "empty": (b"", r"empty file"),
    "text": (b"hello, not audio\n" * 4, r"byte 0: not a WAV file"),
    "avi": (b"RIFF\0\0\0\0AVI LIST" + bytes(20), r"byte 8: a RIFF file of form b'AVI '"),
    "header only": (_good()[:12], r"byte 12: no 'fmt ' chunk"),
    "no data chunk": (_good()[:36], r"byte 36: no 'data' chunk"),
    "truncated": (_good()[:300], r"byte 36: the 'data' chunk says 1600 bytes, the file holds 256"),
    "huge data size": (_patch(_good(), 40, "<I", 0xFFFFFFFF), r"says 4294967295 bytes.*truncated"),
    "huge other chunk": (_good()[:12] + b"junk" + struct.pack("<I", 2**31) + bytes(8),
                         r"byte 12: chunk 'junk' says 2147483648 bytes"),
    "data before fmt": (b"RIFF\0\0\0\0WAVEdata\x02\0\0\0\0\0", r"byte 12: a 'data' chunk before"),
    "short fmt": (b"RIFF\0\0\0\0WAVEfmt \x08\0\0\0" + bytes(8), r"'fmt ' chunk of 8 bytes"),
    "adpcm": (_patch(_good(), 20, "<H", 2), r"byte 12: WAV format tag 0x0002 .*hilsim\[audio\]"),
    "12-bit": (_patch(_good(), 34, "<H", 12), r"12-bit PCM; read are \(8, 16, 24, 32\)"),
    "no channels": (_patch(_good(), 22, "<H", 0), r"0 channels"),
    "rate 0": (_patch(_good(), 24, "<I", 0), r"sample rate 0 Hz; allowed 1000"),
    "block align": (_patch(_good(), 32, "<H", 4), r"block align 4, but 1 channels of 16 bits"),
    "empty data": (_good()[:40] + b"\0\0\0\0", r"'data' chunk is empty"),
    "half frame": (_patch(_good()[:47], 40, "<I", 3) + b"\0", r"not whole frames of 2 bytes"),
    "nan sample": (gen.wav_bytes(np.array([0.0, np.nan, 0.0]), 8000, bits=32, kind="float"),
                   r"byte 48: sample 1 is not finite"),
    "huge sample": (gen.wav_bytes(np.array([0.0, 1e200, 0.0]), 8000, bits=64, kind="float"),
                    r"byte 52: sample 1 is 1e\+200, beyond ±1000 \(full scale ±1\)"),
    "loud sample": (gen.wav_bytes(np.array([0.0, 0.5, -2e3]), 8000, bits=32, kind="float"),
                    r"byte 52: sample 2 is -2000, beyond ±1000"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_files_give_one_format_error_naming_file_and_place(tmp_path, case, monkeypatch):
    monkeypatch.setitem(sys.modules, "soundfile", None)
    data, match = BAD[case]
    path = write(tmp_path, data, "bad.wav")
    with pytest.raises(FormatError, match=match) as info:
        jaw_track(path, JAW, ISSUE)
    assert str(info.value).startswith(f"{path}:")
    assert "\n" not in str(info.value)


def test_a_missing_file_is_one_format_error(tmp_path):
    with pytest.raises(FormatError, match="cannot read"):
        read_audio(tmp_path / "nope.wav")


@pytest.mark.parametrize(
    ("kw", "match"),
    [({"window_ms": 0}, "window_ms"), ({"attack_ms": -1}, "attack_ms"),
     ({"release_ms": math.nan}, "release_ms"), ({"threshold": 0.4}, "full"),
     ({"full": 1.5}, "full"), ({"band_hz": (2500.0, 500.0)}, "band_hz"),
     ({"band_hz": (math.nan, 500.0)}, "band_hz"), ({"band_order": 0}, "band_order"),
     ({"step_ms": 0.01}, "step_ms")],
)  # fmt: skip
def test_bad_settings_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        EnvelopeSettings(**kw)


# A fuzz test that asserted nothing once a file was read would pass on any envelope at all:
# each checks what every accepted file gives, and that every refusal is the module's one line.
def _refused(exc: FormatError, path: Path) -> None:
    text = str(exc)
    assert text.startswith(f"{path}:") and exc.detail, text
    assert len(text.splitlines()) == 1 and len(exc.detail) < 400, text


def _accepted(env, path: Path) -> None:
    """The samples finite and within the level read; the envelope on a 1 ms grid from 0 over
    the whole file, finite, RMS and follower >= 0, the opening in 0..1 and shut at the end
    (after 20 release time constants even the loudest sample read is below the threshold);
    and the jaw track within its 0-20° at any time, as long as the envelope."""
    audio = env.audio
    assert RATE_RANGE[0] <= audio.rate_hz <= RATE_RANGE[1] and audio.channels >= 1
    assert audio.samples.size and (np.abs(audio.samples) <= FLOAT_LIMIT).all()
    t, step = env.times_s, ISSUE.step_ms / 1000
    assert t[0] == 0 and np.allclose(np.diff(t), step) and t[-1] >= audio.duration - step
    for curve in (env.rms, env.envelope, env.opening):
        assert curve.shape == t.shape and np.isfinite(curve).all() and (curve >= 0).all()
    assert (env.opening <= 1).all() and env.opening[-1] == 0
    track = jaw_track(path, JAW, ISSUE)
    assert track.duration == t[-1]
    u, du = track.sample_array(np.linspace(-1.0, t[-1] + 1.0, 101))
    assert np.isfinite(du).all() and (np.degrees(u) >= 0).all() and (np.degrees(u) <= 20).all()


def _header(data: bytes) -> tuple[int, int, int] | None:
    """(channels, rate, frames) as the plain 44-byte header says, or None if the file is not
    laid out that way (then the RIFF walk reads it another way, or soundfile does)."""
    tag, channels, rate, _, align, _ = struct.unpack_from("<HHIIHH", data, 20)
    if data[:4] != b"RIFF" or data[8:16] != b"WAVEfmt " or data[36:40] != b"data":
        return None
    if struct.unpack_from("<I", data, 16)[0] != 16 or tag not in (1, 3):
        return None
    return channels, rate, struct.unpack_from("<I", data, 40)[0] // align


_SHORT = gen.wav_bytes(gen.acceptance_signal(8000)[3900:4100], 8000)  # a loud 25 ms


@settings(max_examples=300)
@given(st.binary(max_size=400))
@example(_SHORT).via("a WAV file")
@example(gen.wav_bytes(np.array([0.0, 1e3, -1e3, 0.0]), 1000, bits=64, kind="float")).via("loud")
def test_fuzz_random_bytes_only_format_errors(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("fz") / "f.wav"
    path.write_bytes(data)
    try:
        env = jaw_envelope(path, ISSUE)
    except FormatError as exc:
        _refused(exc, path)
        return
    _accepted(env, path)


@settings(max_examples=300)
@given(st.lists(st.tuples(st.integers(0, 47), st.integers(0, 255)), min_size=1, max_size=6))
@example([(22, 2), (32, 4)]).via("two channels")
@example([(40, 100)]).via("a shorter data chunk")
def test_fuzz_mutated_headers_only_format_errors(tmp_path_factory, edits):
    data = bytearray(gen.wav_bytes(gen.acceptance_signal(8000)[:2000], 8000))
    for offset, value in edits:
        data[offset] = value
    path = tmp_path_factory.mktemp("fz") / "f.wav"
    path.write_bytes(bytes(data))
    try:
        env = jaw_envelope(path, ISSUE)
    except FormatError as exc:
        _refused(exc, path)
        return
    _accepted(env, path)
    if (header := _header(bytes(data))) is not None:  # what the header says is what was read
        assert (env.audio.channels, env.audio.rate_hz, env.audio.samples.size) == header
        assert env.audio.duration == header[2] / header[1]
