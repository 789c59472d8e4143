"""LTC chase: SMPTE linear timecode on an audio line (or in a WAV file) -> show time, per tick.

``[inputs.ltc]`` names a ``source``: a ``.wav`` file (relative to the show file) or an audio
input (a device name, part of one, or its index; ``"default"``), read on ``channel``. The
frames :mod:`hilsim.live.ltc` decodes drive the same lock, freewheel, hold and relock as the
MTC chase (:class:`~hilsim.live.timecode.TimecodeChase`): a frame ends where its code + 1
frame is on the wire, so each one re-anchors the show time exactly (code + 1 frame −
``offset_s``). A frame is used only when the frame before it continues into it (its code one
frame on, 80 bits later): noise that happens to look like one frame never locks or jumps.

The rate is ``fps`` (24, 25, "29.97df", 30) or, with ``"auto"``, inferred: the drop-frame flag
gives 29.97df, else the measured frame length (24, 25 or 30), moved up by a frame number the
rate cannot have. A WAV file plays in show time: sample ``n`` is at ``n / rate`` s, decoded
ahead in 20 ms chunks (so ``--virtual-time`` chases it deterministically). An audio input is
read by :mod:`hilsim.live.ltc_audio` in a thread of its own. Events: ``timecode_locked``
(with ``rate`` and ``show_time_s``), ``timecode_stopped``, ``timecode_held``,
``timecode_jump``, ``timecode_invalid``; once each: ``timecode_none`` (nothing locked in 2 s),
``timecode_reverse``, ``timecode_rate_mismatch``, ``input_unavailable`` (no audio input),
``ltc_read_error`` (the WAV cannot be read on). Keys and a show-controller set-up:
``docs/live.md`` (LTC).
"""

from __future__ import annotations

import math
import wave
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hilsim.live.inbox import LiveEvent
from hilsim.live.ltc import MAX_SAMPLE_RATE, MIN_SAMPLE_RATE, LtcDecoder, LtcError, LtcFrame
from hilsim.live.timecode import RATE_NAMES, ChasePoll, Smpte, TimecodeChase
from hilsim.rig import RigError
from hilsim.rig.reader import Reader

#: ``fps`` in the show file -> the MTC rate code (``None``: inferred)
FPS_CODES: dict[str, int | None] = {"auto": None, "24": 0, "25": 1, "29.97df": 2, "30": 3}
#: nothing locked this long after the start (s): said once
NO_LOCK_AFTER_S = 2.0
#: a WAV file is read and decoded this far at a time (s)
WAV_CHUNK_S = 0.02


@dataclass(frozen=True)
class LtcConfig:
    #: a WAV file (Path) or an audio input (name, part of one, or index)
    source: Path | str | int
    channel: int = 1
    fps: str = "auto"
    offset_s: float = 0.0
    freewheel_s: float = 0.5
    jump_s: float = 0.1
    #: an audio input's sample rate (Hz; None: the device's own)
    sample_rate: int | None = None

    @property
    def is_wav(self) -> bool:
        return isinstance(self.source, Path)


def read_ltc(r: Reader, base: Path) -> LtcConfig:
    """``[inputs.ltc]`` from the show file (paths relative to ``base``). Raises RigError."""
    source = r.get("source", (str, int), allowed="a .wav file, or an audio input's name or index")
    fps = r.get("fps", (str, int, float), "auto")
    fps_name = {24: "24", 25: "25", 30: "30", "29.97": "29.97df"}.get(fps, str(fps))
    if fps_name not in FPS_CODES or isinstance(fps, bool):
        raise r.fail("fps", f'one of auto, 24, 25, "29.97df", 30; got {fps!r}')
    channel = r.integer("channel", 1, lo=1, hi=64)
    if isinstance(source, str) and source.lower().endswith((".wav", ".wave")):
        src: Path | str | int = (base / source).resolve()
        assert isinstance(src, Path)
        try:
            with WavSource(src, channel):
                pass
        except ValueError as exc:
            raise r.fail("source", str(exc)) from None
    elif isinstance(source, int) and source < 0:
        raise r.fail("source", f"an audio input's index is >= 0, got {source}")
    else:
        src = source
    out = LtcConfig(
        source=src,
        channel=channel,
        fps=fps_name,
        offset_s=r.number(
            "offset_s", 0.0, at_least=-86400.0, at_most=86400.0, why="a timecode is within a day"
        ),
        freewheel_s=r.number("freewheel_s", 0.5, nonnegative=True, at_most=3600),
        jump_s=r.number("jump_s", 0.1, positive=True, at_most=3600),
        sample_rate=r.integer("sample_rate", None, lo=MIN_SAMPLE_RATE, hi=MAX_SAMPLE_RATE),
    )
    r.finish()
    if out.is_wav and out.sample_rate is not None:
        raise RigError(f"{r.path}: {r.key('sample_rate')}: a WAV file has its own; drop the key")
    return out


class WavSource:
    """One channel of a PCM WAV file (8, 16, 24 or 32 bits), read a block at a time as floats
    about ±1. Raises ValueError (one line) on a file it cannot read."""

    def __init__(self, path: Path, channel: int = 1) -> None:
        self.path = path
        try:
            self._w = wave.open(str(path), "rb")  # noqa: SIM115 (kept open: read per chunk)
        except FileNotFoundError:
            raise ValueError(f"{path}: no such file") from None
        except (wave.Error, EOFError, OSError) as exc:
            raise ValueError(f"{path}: not a PCM WAV file we can read ({exc})") from None
        self.rate = self._w.getframerate()
        self.channels = self._w.getnchannels()
        self.width = self._w.getsampwidth()
        if channel > self.channels:
            self.close()
            raise ValueError(f"{path}: channel {channel}, but the file has {self.channels}")
        if not MIN_SAMPLE_RATE <= self.rate <= MAX_SAMPLE_RATE:
            self.close()
            raise ValueError(
                f"{path}: {self.rate} Hz; LTC is read at {MIN_SAMPLE_RATE}..{MAX_SAMPLE_RATE} Hz"
            )
        if self.width not in (1, 2, 3, 4):
            self.close()
            raise ValueError(f"{path}: {8 * self.width}-bit samples; PCM is 8, 16, 24 or 32 bits")
        self.channel = channel
        self.done = False

    def read(self, n: int) -> np.ndarray:
        """The next ``n`` samples (fewer at the end of the file; ``done`` then)."""
        try:
            raw = self._w.readframes(n)
        except (wave.Error, EOFError, OSError) as exc:
            self.done = True
            raise ValueError(f"{self.path}: cannot read on ({exc})") from None
        w, ch = self.width, self.channels
        count = len(raw) // (w * ch)
        if count < n:
            self.done = True
        if count == 0:
            return np.empty(0)
        raw = raw[: count * w * ch]
        if w == 1:
            x = (np.frombuffer(raw, np.uint8).astype(np.float64) - 128.0) / 128.0
        elif w == 3:  # little-endian 24-bit: widen to 32 with the sign in the top byte
            b = np.frombuffer(raw, np.uint8).reshape(-1, 3)
            x = (b[:, 0].astype(np.int32) << 8 | b[:, 1].astype(np.int32) << 16
                 | b[:, 2].astype(np.int8).astype(np.int32) << 24) / 2.0**31  # fmt: skip
        else:
            x = np.frombuffer(raw, f"<i{w}").astype(np.float64) / float(2 ** (8 * w - 1))
        return np.asarray(x[self.channel - 1 :: ch], dtype=np.float64)

    def close(self) -> None:
        self._w.close()

    def __enter__(self) -> WavSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LtcChase(TimecodeChase):
    """``[inputs.ltc]``: decoded LTC frames -> show time (see the module docstring).

    :meth:`start` opens the source (a WAV file, or an audio input through
    :mod:`hilsim.live.ltc_audio`); :meth:`poll` is the loop's, once a tick. Tests hand frames
    in with :meth:`feed_frame`, or samples with :meth:`feed_samples`.
    """

    name = "LTC"
    alive_key = "last_frame_t"

    def __init__(self, config: LtcConfig, *, source: str = "ltc") -> None:
        super().__init__(
            freewheel_s=config.freewheel_s,
            jump_s=config.jump_s,
            offset_s=config.offset_s,
            source=source,
        )
        self.config = config
        self._fixed_rate = FPS_CODES[config.fps]
        self.rate: int | None = self._fixed_rate
        self.latency_s = 0.0  # how late frames may reach the inbox (an audio input's blocks)
        self._wav: WavSource | None = None
        self.decoder: LtcDecoder | None = None
        self._prev: tuple[float, Smpte] | None = None  # the last frame decoded (t, code)
        self._max_label = 0
        self._said: set[str] = set()
        self._pending: list[LiveEvent] = []  # said by the source before a poll
        self.audio: Any = None  # the audio input's reader (hilsim.live.ltc_audio)
        self.sd: Any = None  # the sounddevice module to use (tests: a fake); None: imported
        self.error: str | None = None  #: why there is no chase (no audio input)
        self.frames = 0  #: frames handed to the chase
        self._last_put = -math.inf

    # ------------------------------------------------------------------ the source
    def start(self, now: Any) -> str:
        """Open the source; the one line to say. An audio input that cannot be opened is a
        warning and no chase (the show time waits at 0), never a refusal."""
        cfg = self.config
        if isinstance(cfg.source, Path):
            self._wav = WavSource(cfg.source, cfg.channel)
            self.decoder = LtcDecoder(self._wav.rate)
            return (
                f"LTC from {cfg.source.name} ({self._wav.rate} Hz, channel {cfg.channel}), "
                f"fps {cfg.fps}, offset {cfg.offset_s:g} s: played in show time"
            )
        from hilsim.live.ltc_audio import open_audio_input

        try:
            self.audio = open_audio_input(self, cfg, now, sd=self.sd)
        except (OSError, RuntimeError, ValueError, ImportError) as exc:
            self.error = f"LTC: no audio input {cfg.source!r} ({exc}): no chase, show time 0"
            self._pending.append(LiveEvent(0.0, "input_unavailable", self.source,
                                           {"message": self.error}))  # fmt: skip
            return f"warning: {self.error}"
        return str(self.audio.describe())

    def close(self) -> None:
        if self._wav is not None:
            self._wav.close()
        if self.audio is not None:
            self.audio.close()

    def feed_samples(self, samples: Any, t_first: float) -> None:
        """Decode a block whose first sample is at local time ``t_first``; its frames go to the
        inbox stamped where they ended (an audio input's thread, or a test)."""
        dec = self.decoder
        assert dec is not None  # start() or the audio input made it
        n0 = dec.samples
        for frame in dec.decode(samples):
            self.feed_frame(frame, t_first + (frame.end_sample - n0) / dec.sample_rate)

    def feed_frame(self, frame: LtcFrame, t: float) -> None:
        """A decoded frame that ended at local time ``t`` (never before the previous one)."""
        self.inbox.put(max(t, self._last_put), frame)
        self._last_put = max(t, self._last_put)

    def _pump(self, t: float) -> None:
        """Decode the WAV file up to show time ``t`` (a chunk ahead at most)."""
        wav, dec = self._wav, self.decoder
        if wav is None or dec is None or wav.done:
            return
        chunk = max(1, round(WAV_CHUNK_S * wav.rate))
        while not wav.done and dec.samples < t * wav.rate:
            try:
                block = wav.read(chunk)
            except ValueError as exc:  # a file cut short on disk: the signal ends here
                self._pending.append(
                    LiveEvent(t, "ltc_read_error", self.source, {"message": str(exc)})
                )
                return
            self.feed_samples(block, dec.samples / wav.rate)

    # ------------------------------------------------------------------ the loop's side
    def poll(self, t: float) -> ChasePoll:
        """Decode what is due at ``t``, chase it, advance the state; never waits."""
        events, self._pending = self._pending, []
        self._pump(t)
        drops = self.inbox.take_drops()
        if drops:
            events.append(LiveEvent(t, "inbox_overflow", self.source,
                                    {"dropped": drops, "total": self.inbox.dropped}))  # fmt: skip
        if self.audio is not None:
            events += self.audio.take_events(t)
        for tm, frame in self.inbox.take_due(t):
            self._frame(tm, frame, events)
        self._advance(t, events)
        self._once_notes(t, events)
        return ChasePoll(self.show_time(t), self.state, self.timecode, events)

    def _stale_s(self) -> float:
        return 2 * self._frame_s + self.latency_s

    def _frame(self, tm: float, frame: LtcFrame, events: list[LiveEvent]) -> None:
        self.frames += 1
        rate = self._rate_of(frame, tm, events)
        code = Smpte(frame.hours, frame.minutes, frame.seconds, frame.frames, rate)
        prev, self._prev = self._prev, (tm, code)
        if code.problem() is not None:  # said once per run by _new_code
            self._new_code(tm, code, 1.0, "ltc", events)
            return
        fps = code.fps
        if prev is None or prev[1].problem() is not None:
            return
        step = code.to_seconds() - prev[1].to_seconds()
        if abs(step * fps - 1) > 0.01 or abs((tm - prev[0]) * fps - 1) > 0.2:
            self.rejected += 1  # not one frame on from the last: wait for one that continues
            return
        self._new_code(tm, code, 1.0, "ltc", events)

    def _rate_of(self, frame: LtcFrame, tm: float, events: list[LiveEvent]) -> int:
        """The MTC rate code of ``frame``: ``fps``, or inferred (``auto``)."""
        dec = self.decoder
        measured = frame.fps_measured(dec.sample_rate) if dec is not None else None
        self._max_label = max(self._max_label, frame.frames)
        if frame.drop_frame:
            guess = 2
        elif measured is None:
            guess = 3 if self._max_label >= 25 else 1 if self._max_label >= 24 else 0
        else:
            guess = min((0, 1, 3), key=lambda c: abs(measured - (24, 25, 0, 30)[c]))
            if self._max_label >= 24 and guess == 0:
                guess = 1
            if self._max_label >= 25:
                guess = 3
        if self._fixed_rate is None:
            self.rate = guess
            return guess
        if guess != self._fixed_rate and "rate" not in self._said:
            self._said.add("rate")
            got = f"{measured:.2f} fps" if measured is not None else RATE_NAMES[guess]
            drop = ", drop-frame flag set" if frame.drop_frame else ""
            fps = self.config.fps
            message = f"LTC: fps = {fps} but the signal runs at {got}{drop}; read at {fps}"
            detail = {"message": message, "measured": RATE_NAMES[guess]}
            events.append(LiveEvent(tm, "timecode_rate_mismatch", self.source, detail))
        return self._fixed_rate

    def _once_notes(self, t: float, events: list[LiveEvent]) -> None:
        dec = self.decoder
        if self.error is not None:  # no input: said once already (input_unavailable)
            return
        if self.state == "waiting" and t >= NO_LOCK_AFTER_S and "none" not in self._said:
            self._said.add("none")
            seen = "" if dec is None else f" ({dec.frames} frames decoded, {dec.invalid} invalid)"
            message = (
                f"LTC: no timecode locked in {NO_LOCK_AFTER_S:g} s from "
                f"{self.describe_source()}{seen}: the show time waits at 0"
            )
            events.append(LiveEvent(t, "timecode_none", self.source, {"message": message}))
        if dec is not None and dec.reverse >= 4 and "reverse" not in self._said:
            self._said.add("reverse")
            message = "LTC played backwards is not chased: freewheel, then hold"
            events.append(LiveEvent(t, "timecode_reverse", self.source, {"message": message}))

    # ------------------------------------------------------------------ reports
    def describe_source(self) -> str:
        src = self.config.source
        return src.name if isinstance(src, Path) else f"audio input {src!r}"

    @property
    def status(self) -> str:
        """The status line's part: ``LTC locked 25 fps`` (the rate once known)."""
        rate = "" if self.rate is None or self.state == "waiting" else f" {RATE_NAMES[self.rate]}"
        return f"LTC {self.state}{rate}" + (" fps" if rate else "")

    def summary(self) -> dict[str, Any]:
        dec = self.decoder
        out: dict[str, Any] = {
            "source": self.describe_source(),
            "state": self.state,
            "rate": None if self.rate is None else RATE_NAMES[self.rate],
            "offset_s": self.offset_s,
            "frames": self.frames,
            "codes": self.codes,
            "rejected": self.rejected,
        }
        if dec is not None:
            out.update(invalid=dec.invalid, reverse=dec.reverse, resyncs=dec.resyncs)
        if self.audio is not None:
            out.update(self.audio.summary())
        if self.error is not None:
            out["error"] = self.error
        return out


__all__ = ["LtcChase", "LtcConfig", "LtcError", "WavSource", "read_ltc"]
