"""Sounds in sync with clips: the offset arithmetic (late start, latency, offset_ms), a cut, load
errors, the callback feeding the right frames (a fake sounddevice stream), a device failing
mid-show, and the optional extra. No audio device is used: PortAudio is not needed here."""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys
import types
import wave
from dataclasses import dataclass

import numpy as np
import pytest

from hilsim.live.audio_out import (
    AudioOut,
    AudioUnavailableError,
    SilentBackend,
    SoundDeviceBackend,
    Voice,
    fill,
    require_sounddevice,
)

RATE = 8000  # Hz: 0.05 s = 400 frames


def write_wav(path, n_frames: int, rate: int = RATE, channels: int = 1) -> str:
    """A 16-bit WAV whose frame i holds the code i (channel c: i + c·10000): a ramp to check
    which frames were played."""
    codes = np.arange(n_frames, dtype=np.int16)
    data = np.stack([codes + np.int16(c * 10000) for c in range(channels)], axis=1)
    with wave.open(str(path), "wb") as w:
        w.setnchannels(channels)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(data.astype("<i2").tobytes())
    return str(path)


class FakeBackend:
    """Records what it was asked to play: (file, start frame, stream time heard)."""

    def __init__(self, latency_s: float = 0.05, now: float = 100.0) -> None:
        self.latency_s, self.now = latency_s, now
        self.underflows = 0
        self.starts: list[tuple[str, int, float]] = []
        self.stops = 0
        self.opened: tuple[int, int] | None = None
        self.fail: str | None = None
        self.broken: str | None = None
        self.closed = False

    def open(self, rate_hz, channels):
        self.opened = (rate_hz, channels)
        return "fake audio out"

    def time(self):
        if self.fail:
            raise OSError(self.fail)
        return self.now

    def start(self, sound, start_frame, at):
        self.starts.append((sound.path, start_frame, at))

    def stop(self):
        self.stops += 1

    def problem(self):
        return self.broken

    def close(self):
        self.closed = True


@dataclass
class SoundItem:  # a show file's [sounds] entry as the show runtime holds it
    path: str
    offset_ms: float = 0.0


def audio(tmp_path, seconds: float = 3.0, latency_s: float = 0.05, offset_ms: float = 0.0):
    path = write_wav(tmp_path / "scream.wav", int(seconds * RATE))
    backend = FakeBackend(latency_s)
    out = AudioOut(backend)
    out.preload([SoundItem(path, offset_ms)])
    assert out.start(lambda: 0.0) == "fake audio out"
    assert backend.opened == (RATE, 1)
    return out, backend, path


# -- the offset arithmetic -------------------------------------------------------------------


def test_on_time_play_skips_the_latency_into_the_file(tmp_path) -> None:
    out, backend, path = audio(tmp_path, latency_s=0.05)
    (ev,) = out.play(path, 0.0, 3.0, 3.0)
    # nothing written now is heard before now + 50 ms: start 50 ms in, heard then: in sync
    assert backend.starts == [(path, 400, pytest.approx(100.05))]
    assert ev.kind == "sound_start" and ev.detail["start_frame"] == 400
    assert ev.detail["heard_at_s"] == pytest.approx(3.05)


def test_offset_ms_larger_than_the_latency_delays_the_sound(tmp_path) -> None:
    out, backend, path = audio(tmp_path, latency_s=0.05, offset_ms=120)
    out.play(path, 0.0, 3.0, 3.0)
    assert backend.starts == [(path, 0, pytest.approx(100.12))]  # from the top, 120 ms later


def test_offset_ms_smaller_than_the_latency_skips_the_difference(tmp_path) -> None:
    out, backend, path = audio(tmp_path, latency_s=0.05, offset_ms=30)
    out.play(path, 0.0, 3.0, 3.0)
    assert backend.starts == [(path, 160, pytest.approx(100.05))]  # 20 ms in


def test_a_late_play_starts_later_in_the_file_by_the_lateness(tmp_path) -> None:
    out, backend, path = audio(tmp_path, latency_s=0.05)
    out.play(path, 0.0, 3.0, 3.2)  # the call came 200 ms after the clip started
    assert backend.starts == [(path, 2000, pytest.approx(100.05))]  # 0.2 + 0.05 s in
    out.play(path, 1.0, 3.0, 3.2)  # the clip's sound starts 1 s into the file
    assert backend.starts[-1] == (path, 10000, pytest.approx(100.05))


def test_offset_given_to_play_overrides_the_sounds_own(tmp_path) -> None:
    out, backend, path = audio(tmp_path, latency_s=0.01, offset_ms=500)
    out.play(path, 0.0, 3.0, 3.0, offset_ms=-40)  # earlier: skip 40 + 10 ms
    assert backend.starts == [(path, 400, pytest.approx(100.01))]


def test_a_sound_whose_end_has_passed_is_not_played(tmp_path) -> None:
    out, backend, path = audio(tmp_path, seconds=1.0)
    (ev,) = out.play(path, 0.0, 3.0, 5.0)
    assert ev.kind == "sound_skipped" and "end has passed" in ev.detail["message"]
    assert backend.starts == [] and out.playing is None


def test_a_cut_stops_the_previous_sound(tmp_path) -> None:
    out, backend, path = audio(tmp_path)
    other = write_wav(tmp_path / "laugh.wav", RATE)
    out.preload([other])
    out.play(path, 0.0, 1.0, 1.0)
    stops = backend.stops
    out.play(other, 0.0, 2.0, 2.0)
    assert backend.stops == stops + 1 and backend.starts[-1][0] == other
    assert out.playing == other
    out.stop()
    assert out.playing is None and backend.stops == stops + 2


def test_a_sound_not_preloaded_is_an_event_not_a_read(tmp_path) -> None:
    out, backend, _ = audio(tmp_path)
    (ev,) = out.play(tmp_path / "nope.wav", 0.0, 1.0, 1.0)
    assert ev.kind == "sound_skipped" and "not preloaded" in ev.detail["message"]
    assert backend.starts == []


def test_the_silent_backend_logs_sounds_in_virtual_time_without_a_device(tmp_path) -> None:
    path = write_wav(tmp_path / "scream.wav", RATE)
    out = AudioOut(SilentBackend())
    out.preload([SoundItem(path, 100)])
    assert "silent" in out.start(lambda: 0.0)
    (ev,) = out.play(path, 0.0, 3.0, 3.0)
    assert ev.kind == "sound_start" and ev.detail["start_frame"] == 0
    assert ev.detail["heard_at_s"] == pytest.approx(3.1)
    assert ev.detail["message"] == "sound scream.wav from 0.000 s, heard in 100 ms"
    out.close()


def test_a_play_before_the_output_is_open_is_skipped(tmp_path) -> None:
    path = write_wav(tmp_path / "a.wav", RATE)
    out = AudioOut(FakeBackend())
    out.preload([path])
    (ev,) = out.play(path, 0.0, 1.0, 1.0)
    assert ev.kind == "sound_skipped" and "not open" in ev.detail["message"]


# -- load errors -----------------------------------------------------------------------------


def test_a_missing_file_is_one_line_at_load(tmp_path) -> None:
    out = AudioOut(FakeBackend())
    with pytest.raises(ValueError, match=r"gone\.wav") as err:
        out.preload([str(tmp_path / "gone.wav")])
    assert "\n" not in str(err.value)


def test_a_file_that_is_not_audio_is_one_line_at_load(tmp_path) -> None:
    bad = tmp_path / "notes.wav"
    bad.write_text("this is not a sound\n")
    with pytest.raises(ValueError, match=r"notes\.wav") as err:
        AudioOut(FakeBackend()).preload([str(bad)])
    assert "\n" not in str(err.value)


def test_a_bad_offset_is_one_line_at_load(tmp_path) -> None:
    path = write_wav(tmp_path / "a.wav", 100)
    with pytest.raises(ValueError, match="offset_ms"):
        AudioOut(FakeBackend()).preload([SoundItem(path, float("nan"))])


def test_mono_is_copied_to_both_channels_and_rates_are_made_one(tmp_path) -> None:
    stereo = write_wav(tmp_path / "st.wav", 800, channels=2)
    mono = write_wav(tmp_path / "mono.wav", 400, rate=4000)
    out = AudioOut(FakeBackend())
    out.preload([stereo, mono])
    assert (out.rate_hz, out.channels) == (RATE, 2)
    st, mo = out.sounds[stereo].frames, out.sounds[mono].frames
    assert st.shape == (800, 2) and st.dtype == np.float32
    assert st[5, 0] == pytest.approx(5 / 32768) and st[5, 1] == pytest.approx(10005 / 32768)
    assert mo.shape == (800, 2) and np.array_equal(mo[:, 0], mo[:, 1])  # resampled 2x
    assert mo[10, 0] == pytest.approx(5 / 32768)


# -- the callback, through a fake sounddevice stream ------------------------------------------


class FakeStream:
    latency = 0.02

    def __init__(self, **kw) -> None:
        self.kw = kw
        self.callback = kw["callback"]
        self.time = 50.0
        self.active = False
        self.closed = False

    def start(self):
        self.active = True

    def abort(self):
        self.active = False

    def close(self):
        self.closed = True


def fake_sd(fail: Exception | None = None):
    sd = types.SimpleNamespace(streams=[])

    def OutputStream(**kw):
        if fail is not None:
            raise fail
        s = FakeStream(**kw)
        sd.streams.append(s)
        return s

    sd.OutputStream = OutputStream
    return sd


def times(dac: float, current: float = 0.0):
    return types.SimpleNamespace(outputBufferDacTime=dac, currentTime=current)


NO_FLAGS = types.SimpleNamespace(output_underflow=False)


def real_backend(tmp_path, offset_ms=50.0):
    path = write_wav(tmp_path / "ramp.wav", 2000)
    sd = fake_sd()
    out = AudioOut(SoundDeviceBackend(sd=sd))
    out.preload([SoundItem(path, offset_ms)])
    assert "8000 Hz" in out.start(lambda: 0.0)
    (stream,) = sd.streams
    assert stream.kw["samplerate"] == RATE and stream.kw["channels"] == 1 and stream.active
    return out, stream, path


def codes(buf: np.ndarray) -> list[int]:
    return [round(x * 32768) for x in buf[:, 0]]


def test_the_callback_places_the_first_frame_at_its_dac_time_then_plays_on(tmp_path) -> None:
    out, stream, path = real_backend(tmp_path, offset_ms=50)
    out.play(path, 0.0, 1.0, 1.0)  # heard at stream time 50.05: frame 0
    buf = np.full((256, 1), 9.0, dtype=np.float32)
    stream.callback(buf, 256, times(dac=50.02), NO_FLAGS)  # this buffer is heard from 50.02
    assert codes(buf) == [0] * 240 + list(range(16))  # 30 ms of silence, then the file
    stream.callback(buf, 256, times(dac=50.052), NO_FLAGS)
    assert codes(buf) == list(range(16, 272))
    for _ in range(6):
        stream.callback(buf, 256, times(dac=0.0), NO_FLAGS)
    assert codes(buf) == list(range(1552, 1808))
    stream.callback(buf, 256, times(dac=0.0), NO_FLAGS)  # the end of the 2000 frames
    assert codes(buf) == list(range(1808, 2000)) + [0] * 64


def test_a_first_buffer_later_than_planned_skips_ahead_to_stay_in_sync(tmp_path) -> None:
    out, stream, path = real_backend(tmp_path, offset_ms=50)
    out.play(path, 0.0, 1.0, 1.0)  # frame 0 heard at 50.05
    buf = np.zeros((64, 1), dtype=np.float32)
    stream.callback(buf, 64, times(dac=50.06), NO_FLAGS)  # 10 ms late: start at frame 80
    assert codes(buf) == list(range(80, 144))


def test_without_a_dac_time_the_callback_adds_the_latency(tmp_path) -> None:
    out, stream, path = real_backend(tmp_path, offset_ms=50)
    out.play(path, 0.0, 1.0, 1.0)
    buf = np.zeros((256, 1), dtype=np.float32)
    stream.callback(buf, 256, times(dac=0.0, current=50.0), NO_FLAGS)  # heard from 50.02
    assert codes(buf) == [0] * 240 + list(range(16))


def test_a_cut_through_the_real_backend_switches_frames_and_stop_is_silence(tmp_path) -> None:
    out, stream, path = real_backend(tmp_path, offset_ms=0)
    other = write_wav(tmp_path / "other.wav", 2000)
    out.preload([other])
    buf = np.zeros((32, 1), dtype=np.float32)
    out.play(path, 0.0, 1.0, 1.0)  # 20 ms latency skipped: frame 160 at 50.02
    stream.callback(buf, 32, times(dac=50.02), NO_FLAGS)
    assert codes(buf) == list(range(160, 192))
    out.play(other, 0.1, 1.0, 1.0)  # the cut: other's frame 800 + 160
    stream.callback(buf, 32, times(dac=50.02), NO_FLAGS)
    assert codes(buf) == list(range(960, 992))
    out.stop()
    stream.callback(buf, 32, times(dac=50.024), NO_FLAGS)
    assert not buf.any()


def test_fill_without_a_voice_is_silence_and_a_far_start_waits() -> None:
    buf = np.ones((16, 2), dtype=np.float32)
    fill(None, buf, 0.0, RATE)
    assert not buf.any()
    voice = Voice(np.ones((100, 2), dtype=np.float32), 0, at=1.0)
    buf[:] = 5.0
    fill(voice, buf, 0.0, RATE)  # 8000 frames away: all silence, not started
    assert not buf.any() and not voice.started


def test_a_device_that_fails_to_open_is_one_warning_and_a_silent_show(tmp_path) -> None:
    """Sound is not a safety matter: no device at the start is a warning line, one
    audio_error event at the first poll, and plays skipped; the show goes on."""
    path = write_wav(tmp_path / "a.wav", 100)
    out = AudioOut(SoundDeviceBackend("USB Audio", sd=fake_sd(ValueError("No such device"))))
    out.preload([path])
    note = out.start(lambda: 0.0)
    assert note == (
        "warning: no sound: cannot open the audio output USB Audio: No such device; the show "
        "runs silent (audio_error in events.jsonl)"
    )
    (ev,) = out.poll(0.0)
    assert ev.kind == "audio_error" and ev.t == 0.0
    assert ev.detail["message"].startswith("no audio output, the show goes on silent: ")
    assert out.poll(0.004) == [] and out.play(path, 0.0, 1.0, 1.0) == []
    assert out.summary()["error"] == "cannot open the audio output USB Audio: No such device"


def test_a_required_device_that_fails_to_open_is_one_oserror_line(tmp_path) -> None:
    path = write_wav(tmp_path / "a.wav", 100)
    backend = SoundDeviceBackend("USB Audio", sd=fake_sd(ValueError("No such device")))
    out = AudioOut(backend, required=True)
    out.preload([path])
    with pytest.raises(OSError, match=r"USB Audio: No such device \(\[sounds\] required = true"):
        out.start(lambda: 0.0)


def test_device_index_0_is_named_as_itself_not_as_the_default(tmp_path) -> None:
    sd = fake_sd()
    out = AudioOut(SoundDeviceBackend(0, sd=sd))
    out.preload([write_wav(tmp_path / "a.wav", 100)])
    assert out.start(lambda: 0.0).startswith("audio out: 0, 8000 Hz")
    assert sd.streams[0].kw["device"] == 0


# -- faults mid-show: events, the show goes on -----------------------------------------------


def test_a_device_failing_mid_show_is_one_event_and_later_plays_are_silent(tmp_path) -> None:
    out, backend, path = audio(tmp_path)
    backend.fail = "PortAudio: Device unavailable"
    (ev,) = out.play(path, 0.0, 1.0, 1.0)
    assert ev.kind == "audio_error" and "the show goes on" in ev.detail["message"]
    assert out.play(path, 0.0, 2.0, 2.0) == []  # no new event, no exception
    assert out.poll(3.0) == []
    assert out.summary()["errors"] == 1 and out.summary()["skipped"] == 1
    out.close()
    assert backend.closed


def test_a_stream_that_stopped_is_reported_by_poll_once(tmp_path) -> None:
    out, backend, path = audio(tmp_path)
    assert out.poll(1.0) == []
    backend.broken = "the audio stream stopped (device unplugged or failed)"
    (ev,) = out.poll(2.0)
    assert ev.kind == "audio_error" and ev.t == 2.0 and "unplugged" in ev.detail["message"]
    assert out.poll(3.0) == []
    assert out.play(path, 0.0, 4.0, 4.0) == []


def test_the_real_backend_notices_its_stream_finished_and_counts_underflows(tmp_path) -> None:
    out, stream, _path = real_backend(tmp_path)
    buf = np.zeros((8, 1), dtype=np.float32)
    stream.callback(buf, 8, times(1.0), types.SimpleNamespace(output_underflow=True))
    (ev,) = out.poll(1.0)
    assert ev.kind == "audio_underflow" and ev.detail["count"] == 1
    stream.kw["finished_callback"]()  # PortAudio ended the stream: the device is gone
    (ev,) = out.poll(2.0)
    assert ev.kind == "audio_error"
    out.close()
    assert stream.closed


# -- the optional extra ----------------------------------------------------------------------


def test_without_sounddevice_a_show_runs_silent_after_one_warning(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "sounddevice", None)
    out = AudioOut()
    out.preload([write_wav(tmp_path / "a.wav", 100)])
    assert out.start(lambda: 0.0).startswith(
        "warning: no sound: sounds need the optional package sounddevice: pip install"
    )
    assert [e.kind for e in out.poll(0.0)] == ["audio_error"]


def test_without_sounddevice_a_show_that_requires_sound_is_refused(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "sounddevice", None)
    with pytest.raises(AudioUnavailableError, match=r"pip install 'hilsim\[live\]'") as err:
        AudioOut(required=True)
    assert isinstance(err.value, ValueError)  # a show loader's one line
    assert "required = true" in str(err.value)


class _NoPortAudio(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """sounddevice found, its import failing as it does without the PortAudio library."""

    def find_spec(self, name, path=None, target=None):
        if name == "sounddevice":
            return importlib.machinery.ModuleSpec(name, self)
        return None

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        raise OSError("PortAudio library not found")


def test_without_portaudio_the_line_names_the_package_to_install(monkeypatch) -> None:
    monkeypatch.delitem(sys.modules, "sounddevice", raising=False)
    monkeypatch.setattr(sys, "meta_path", [_NoPortAudio(), *sys.meta_path])
    with pytest.raises(AudioUnavailableError, match="apt install libportaudio2"):
        require_sounddevice()
