"""Sound files played in sync with their clips: what is *heard* lines up with the motion.

A show file's ``[sounds]`` names a file per clip (``offset_ms`` delays it) and the output
``device``. Needs ``pip install 'hilsim[live]'`` (sounddevice, and the PortAudio library);
FLAC, Ogg and the rest need soundfile (``pip install 'hilsim[audio]'``). Without sounddevice or
PortAudio, or without an output device at the start, the show runs silent after one warning
line (and one ``audio_error`` event) -- unless ``[sounds] required = true``: then it is refused
in one line, before anything moves.

* :meth:`AudioOut.preload` decodes every file at show load into float32 frames at one rate and
  one or two channels. During the show nothing is read or decoded.
* :meth:`AudioOut.play` is told the show time the clip started and the show time now. It
  places the first sample by the stream's DAC time, so the sound is in sync from the first
  sample heard. A late play starts later in the file; an early one waits in silence.
* One sound at a time: a new ``play`` replaces the one playing; :meth:`AudioOut.stop` silences it.
* The audio callback only copies frames from memory: no locks, no waits, no allocation.

Audio is not a safety matter: a device missing at the start or failing mid-show is one
``audio_error`` event, and the show goes on in silence. :meth:`AudioOut.poll` reports
underflows; :meth:`AudioOut.close` stops the stream. The timing rule and the clock drift:
``docs/live.md`` (Sounds).
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from hilsim.live.inbox import LiveEvent
from hilsim.live.midi import EXTRA_HINT, LiveExtraError

#: the line a missing PortAudio library gets
PORTAUDIO_HINT = "apt install libportaudio2"
#: most output channels (a file with more gives its first ones)
MAX_CHANNELS = 2
#: what a refusal adds when the show file asks for its sound
REQUIRED = "[sounds] required = true: the show does not start without its sound"


class AudioUnavailableError(LiveExtraError, ValueError):
    """sounddevice or PortAudio is missing (one line naming what to install). A ValueError too,
    so a show-file loader that reports ValueErrors as one line reports this one."""


def require_sounddevice() -> Any:
    """Import sounddevice lazily; missing (or PortAudio missing) -> AudioUnavailableError."""
    try:
        import sounddevice
    except ImportError:
        raise AudioUnavailableError(
            f"sounds need the optional package sounddevice: {EXTRA_HINT}"
        ) from None
    except OSError as exc:  # sounddevice is there, the PortAudio library is not
        raise AudioUnavailableError(
            f"sounds need the PortAudio library ({exc}): {PORTAUDIO_HINT}"
        ) from None
    return sounddevice


@dataclass(frozen=True)
class Sound:
    """A decoded sound: ``frames`` (n × channels, float32, full scale ±1) at ``rate_hz``."""

    path: str
    frames: np.ndarray
    rate_hz: int
    offset_ms: float = 0.0

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])


class Backend(Protocol):
    """An output stream. ``latency_s`` and ``time()`` are valid after ``open``; ``start`` and
    ``stop`` are called from the loop and must not block."""

    latency_s: float  #: the stream's reported output latency (s)
    underflows: int  #: buffers the device asked for too late, in all

    def open(self, rate_hz: int, channels: int) -> str:
        """Open and start the stream (silence); return a note naming the device."""

    def time(self) -> float:
        """The stream's clock (s), the one its DAC times are on."""

    def start(self, sound: Sound, start_frame: int, at: float) -> None:
        """Play ``sound`` from ``start_frame``, that frame heard at stream time ``at``."""

    def stop(self) -> None: ...

    def problem(self) -> str | None:
        """Why the stream no longer plays (a device lost), or None."""

    def close(self) -> None: ...


class SilentBackend:
    """No device: sounds are scheduled and logged as usual, nothing is heard (virtual time,
    tests, a show run without speakers). Needs no optional package."""

    latency_s = 0.0
    underflows = 0

    def open(self, rate_hz: int, channels: int) -> str:
        return "audio: silent (no output device; sound_start events are still logged)"

    def time(self) -> float:
        return 0.0

    def start(self, sound: Sound, start_frame: int, at: float) -> None: ...

    def stop(self) -> None: ...

    def problem(self) -> str | None:
        return None

    def close(self) -> None: ...


class Voice:
    """One sound scheduled on a stream: the callback's only state (``pos`` once started)."""

    __slots__ = ("at", "frames", "pos", "start_frame", "started")

    def __init__(self, frames: np.ndarray, start_frame: int, at: float) -> None:
        self.frames, self.start_frame, self.at = frames, start_frame, at
        self.started = False
        self.pos = start_frame


def fill(voice: Voice | None, out: np.ndarray, dac_time: float, rate_hz: int) -> None:
    """Fill ``out`` (frames × channels) with ``voice``'s frames, the first frame of ``out``
    heard at ``dac_time`` (stream time, s). The callback's whole work: copies, no allocation."""
    frames = out.shape[0]
    if voice is None:
        out.fill(0.0)
        return
    if not voice.started:
        lead = round((voice.at - dac_time) * rate_hz)  # silent frames before the start
        if lead >= frames:
            out.fill(0.0)
            return
        voice.started = True
        if lead < 0:  # the buffer is later than planned: skip ahead, stay in sync
            voice.pos = voice.start_frame - lead
            lead = 0
        else:
            voice.pos = voice.start_frame
            out[:lead] = 0.0
    else:
        lead = 0
    src = voice.frames
    pos = voice.pos
    n = max(0, min(frames - lead, src.shape[0] - pos))
    out[lead : lead + n] = src[pos : pos + n]
    out[lead + n :] = 0.0
    voice.pos = pos + n


class SoundDeviceBackend:
    """The real backend: a sounddevice.OutputStream whose callback runs :func:`fill`.

    Args:
        device: sounddevice's device (a name or index); ``None``: the default output.
        latency: PortAudio's suggested latency (``"low"``, ``"high"`` or seconds).
        sd: the sounddevice module (tests pass a fake); ``None``: imported here.
    """

    def __init__(self, device: Any = None, *, latency: Any = "low", sd: Any = None) -> None:
        self._sd = sd if sd is not None else require_sounddevice()
        self.device, self.latency_hint = device, latency
        self.latency_s = 0.0
        self.underflows = 0
        self.rate_hz = 0
        self._stream: Any = None
        self._voice: Voice | None = None
        self._finished = False
        self._closing = False

    def open(self, rate_hz: int, channels: int) -> str:
        try:
            stream = self._sd.OutputStream(
                samplerate=rate_hz,
                channels=channels,
                dtype="float32",
                device=self.device,
                latency=self.latency_hint,
                callback=self._callback,
                finished_callback=self._on_finished,
            )
            stream.start()
        except Exception as exc:  # PortAudioError, ValueError (no such device)
            raise OSError(f"cannot open the audio output {self._name}: {exc}") from None
        self._stream, self.rate_hz = stream, rate_hz
        self.latency_s = float(stream.latency)
        return (
            f"audio out: {self._name}, {rate_hz} Hz, {channels} ch, "
            f"latency {self.latency_s * 1000:.0f} ms"
        )

    @property
    def _name(self) -> str:
        return "default device" if self.device is None else str(self.device)

    def _callback(self, outdata: Any, frames: int, time: Any, status: Any) -> None:
        if getattr(status, "output_underflow", False):
            self.underflows += 1
        dac = float(getattr(time, "outputBufferDacTime", 0.0) or 0.0)
        if dac <= 0.0:  # a host API that gives no DAC time
            dac = float(time.currentTime) + self.latency_s
        fill(self._voice, outdata, dac, self.rate_hz)

    def _on_finished(self) -> None:
        self._finished = True

    def time(self) -> float:
        return float(self._stream.time)

    def start(self, sound: Sound, start_frame: int, at: float) -> None:
        self._voice = Voice(sound.frames, start_frame, at)  # one reference swap

    def stop(self) -> None:
        self._voice = None

    def problem(self) -> str | None:
        if self._stream is None or self._closing:
            return None
        if self._finished or not self._stream.active:
            return "the audio stream stopped (device unplugged or failed)"
        return None

    def close(self) -> None:
        self._closing = True
        self._voice = None
        stream, self._stream = self._stream, None
        if stream is not None:
            try:
                stream.abort()
            finally:
                stream.close()


def _num(x: object) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


class AudioOut:
    """Sounds played in sync with their clips (see the module docstring).

    Args:
        backend: the output stream; ``None``: :class:`SoundDeviceBackend` on ``device``.
        source: the events' ``source``.
        device: the output (a name or index, as sounddevice takes it); None: the default.
        required: no sounddevice/PortAudio (here) or no device (at :meth:`start`) raises,
            naming what is missing; otherwise the show goes on silent, after one warning.
    """

    def __init__(
        self,
        backend: Backend | None = None,
        *,
        source: str = "audio",
        device: str | int | None = None,
        required: bool = False,
    ) -> None:
        self.required = required
        #: why no sound can be played (sounddevice or PortAudio missing), said at start
        self.unavailable: str | None = None
        if backend is None:
            try:
                backend = SoundDeviceBackend(device)
            except AudioUnavailableError as exc:
                if required:
                    raise AudioUnavailableError(f"{exc} ({REQUIRED})") from None
                self.unavailable = str(exc)
                backend = SilentBackend()
        self.backend: Backend = backend
        self.source = source
        self.sounds: dict[str, Sound] = {}
        self.rate_hz: int | None = None
        self.channels = 1
        self.opened = False
        self.failed: str | None = None
        self.playing: str | None = None
        self.counts = {"played": 0, "skipped": 0, "errors": 0}
        self._underflows_seen = 0
        self._pending: list[LiveEvent] = []  # events from stop(), reported by poll()

    # ------------------------------------------------------------------ show load
    def preload(self, items: Iterable[Any], offsets_ms: Mapping[str, float] | None = None) -> None:
        """Decode every sound now. ``items``: paths, or objects with ``.path`` and optionally
        ``.offset_ms`` (a show file's sounds); ``offsets_ms``: path -> ms. Raises ValueError
        (one line naming the file) for a missing, unreadable or not-audio file."""
        from hilsim.targets.formats.audio_jaw import read_audio

        offsets = dict(offsets_ms or {})
        loaded = []
        for item in items:
            path = os.fspath(getattr(item, "path", item))
            off = getattr(item, "offset_ms", None)
            off = offsets.get(path, 0.0 if off is None else off)
            if not _num(off):
                raise ValueError(f"{path}: offset_ms must be a finite number, got {off!r}")
            first = read_audio(path, 0)  # FormatError (a ValueError) names the file
            chans = [first.samples]
            for c in range(1, min(first.channels, MAX_CHANNELS)):
                chans.append(read_audio(path, c).samples)
            loaded.append((path, float(off), first.rate_hz, chans))
        for _, _, rate, chans in loaded:
            if self.rate_hz is None:
                self.rate_hz = rate
            self.channels = max(self.channels, len(chans))
        for path, off, rate, chans in loaded:
            frames = _frames(chans, rate, self.rate_hz or rate, self.channels)
            sound = Sound(path, frames, self.rate_hz or rate, off)
            self.sounds[path] = sound
            self.sounds.setdefault(str(Path(path).resolve()), sound)

    def start(self, now: Any = None) -> str | None:
        """Open the output stream (before the show); return a line to show the operator. No
        output (no device, no PortAudio): a warning line, the show silent, an ``audio_error``
        event at the first :meth:`poll`; with ``required``, OSError with one line instead."""
        if self.opened or self.failed is not None or not self.sounds or self.rate_hz is None:
            return None
        why = self.unavailable
        if why is None:
            try:
                note = self.backend.open(self.rate_hz, self.channels)
            except OSError as exc:
                if self.required:
                    raise OSError(f"{exc} ({REQUIRED})") from None
                why = str(exc)
            else:
                self.opened = True
                return note
        self._pending.append(self._fail(math.nan, why, "no audio output, the show goes on silent"))
        return f"warning: no sound: {why}; the show runs silent (audio_error in events.jsonl)"

    # ------------------------------------------------------------------ the show
    def play(
        self,
        path: str | os.PathLike[str],
        file_offset_s: float,
        at_show_t: float,
        now_show_t: float,
        *,
        offset_ms: float | None = None,
    ) -> list[LiveEvent]:
        """Play the preloaded ``path`` so that its position ``file_offset_s`` is heard at show
        time ``at_show_t`` + offset_ms (the sound's own unless given); called at show time
        ``now_show_t``. Replaces the sound playing. Never raises, never blocks."""
        t = float(now_show_t)
        name = os.fspath(path)
        sound = self.sounds.get(name) or self.sounds.get(str(Path(name).resolve()))
        if sound is None:
            return [self._skip(t, name, f"sound {name!r} was not preloaded: not played")]
        if self.failed is not None:
            self.counts["skipped"] += 1
            return []
        if not self.opened:
            return [self._skip(t, name, f"sound {name!r}: the audio output is not open")]
        off_s = (sound.offset_ms if offset_ms is None else offset_ms) / 1000.0
        try:
            self.backend.stop()
            b_now = self.backend.time()
            latency = self.backend.latency_s
            heard_at = b_now + (at_show_t + off_s - t)
            start_s = float(file_offset_s)
            earliest = b_now + latency
            if heard_at < earliest:  # late call, or the latency: start later in the file
                start_s += earliest - heard_at
                heard_at = earliest
            frame = max(0, round(start_s * sound.rate_hz))
            if frame >= sound.n_frames:
                self.playing = None
                return [self._skip(t, name, f"sound {name!r}: its end has passed: not played")]
            self.backend.start(sound, frame, heard_at)
        except Exception as exc:  # a device failing mid-show: audio is not a safety matter
            return [self._fail(t, f"{type(exc).__name__}: {exc}")]
        self.playing = name
        self.counts["played"] += 1
        delay_ms = (heard_at - b_now) * 1000.0
        where = f"from {frame / sound.rate_hz:.3f} s, heard in {delay_ms:.0f} ms"
        return [self._event(t, "sound_start", f"sound {Path(name).name} {where}", sound=name,
                            start_frame=frame, heard_at_s=t + delay_ms / 1000.0,
                            latency_ms=latency * 1000.0)]  # fmt: skip

    def stop(self) -> None:
        """Silence the sound playing (a cut to a clip without a sound). Never raises."""
        self.playing = None
        if self.opened and self.failed is None:
            try:
                self.backend.stop()
            except Exception as exc:
                self._pending.append(self._fail(math.nan, f"{type(exc).__name__}: {exc}"))

    def poll(self, t: float) -> list[LiveEvent]:
        """Once per tick (or less): a device lost mid-show, underflows since the last poll."""
        events = [LiveEvent(t, e.kind, e.source, e.detail) for e in self._pending]
        self._pending.clear()
        if not self.opened or self.failed is not None:
            return events
        problem = self.backend.problem()
        if problem is not None:
            return [*events, self._fail(t, problem)]
        n, seen = self.backend.underflows, self._underflows_seen
        if n > seen:
            message = f"audio output underflow ({n - seen} buffers late): a click"
            events.append(self._event(t, "audio_underflow", message, count=n - seen, total=n))
            self._underflows_seen = n
        return events

    def close(self) -> None:
        """Stop and close the stream (Ctrl-C, the end of the show). Never raises."""
        self.playing = None
        if self.opened:
            self.opened = False
            with contextlib.suppress(Exception):  # closing never stops the exit path
                self.backend.close()

    def summary(self) -> dict[str, Any]:
        return {
            **self.counts,
            "sounds": len({id(s) for s in self.sounds.values()}),
            "underflows": self.backend.underflows if self.opened else self._underflows_seen,
            "error": self.failed,
        }

    # ------------------------------------------------------------------ helpers
    def _event(self, t: float, kind: str, message: str, **detail: Any) -> LiveEvent:
        return LiveEvent(t, kind, self.source, {"message": message, **detail})

    def _skip(self, t: float, name: str, message: str) -> LiveEvent:
        self.counts["skipped"] += 1
        return self._event(t, "sound_skipped", message, sound=name)

    def _fail(
        self, t: float, why: str, what: str = "audio output failed, the show goes on"
    ) -> LiveEvent:
        self.failed = why
        self.playing = None
        self.counts["errors"] += 1
        with contextlib.suppress(Exception):
            self.backend.stop()
        return self._event(t, "audio_error", f"{what}: {why}")


def _frames(chans: list[np.ndarray], rate: int, to_rate: int, channels: int) -> np.ndarray:
    """(n × channels) float32 at ``to_rate``: mono copied to every channel, resampled
    linearly when the rates differ."""
    if rate != to_rate:
        n = chans[0].size
        m = max(1, round(n * to_rate / rate))
        src_t = np.arange(n) / rate
        dst_t = np.arange(m) / to_rate
        chans = [np.interp(dst_t, src_t, c) for c in chans]
    out = np.zeros((chans[0].size, channels), dtype=np.float32)
    for c in range(channels):
        out[:, c] = chans[c] if c < len(chans) else (chans[0] if len(chans) == 1 else 0.0)
    return out
