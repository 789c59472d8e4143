"""SMPTE linear timecode (LTC) from audio samples: our own biphase-mark decoder (numpy).

LTC is an audio signal: 80 bits per video frame, biphase-mark coded. Every bit starts with a
transition; a 1 has a second one halfway. So only the *intervals* between transitions count,
never the polarity: a whole bit period is a 0, two half periods a 1. The bit period is taken
from the signal: a guess in the middle of 24..30 fps tells long from short at any rate, and
each decoded frame then sets it (80 bits over the frame's own length), so a varispeed signal
is tracked. Transitions are found with hysteresis about a running centre (a DC offset and
any level from a line input work) and placed between samples by linear interpolation.

A frame ends with the sync word 0x3FFD (bits 64..79 as sent). Its fields are BCD, least
significant bit first: frame units 0-3, tens 8-9, drop-frame flag 10; seconds 16-19 / 24-26;
minutes 32-35 / 40-42; hours 48-51 / 56-57. User bits and flags are ignored. Each
:class:`LtcFrame` carries the sample index where its last bit ended (the start of the next
frame): the instant its code + 1 frame is on the wire, so time is exact to a fraction of a
sample. A sync word read backwards (0xBFFC: reverse play) is counted in ``reverse``, not
decoded. Samples in any sample rate 8 kHz..96 kHz, floats about ±1 (any level above
``min_level``). Nothing but :class:`LtcError` leaves this module.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

SYNC_WORD = 0x3FFD  #: bits 64..79 in the order sent, bit 64 the most significant
SYNC_REVERSED = 0xBFFC  #: the same sync word played backwards
_MASK80 = (1 << 80) - 1
#: bit rates (bits/s) the decoder accepts: 24 fps ·80 = 1920 .. 30 fps ·80 = 2400, ±15 %
MIN_BIT_RATE, MAX_BIT_RATE = 1920 * 0.85, 2400 * 1.15
_GUESS_BIT_RATE = 2160.0  # between 24 and 30 fps: long and short are told apart at either
MIN_SAMPLE_RATE, MAX_SAMPLE_RATE = 8000, 96000


class LtcError(ValueError):
    """The decoder's one error: a bad setting or samples that are not audio."""


@dataclass(frozen=True)
class LtcFrame:
    """One decoded frame: HH:MM:SS:FF as labelled, the drop-frame flag, the sample index
    (fractional) where its last bit ended, and its bit period (samples per bit)."""

    hours: int
    minutes: int
    seconds: int
    frames: int
    drop_frame: bool
    end_sample: float
    bit_period: float

    def fps_measured(self, sample_rate: float) -> float:
        """Frames per second this frame's length gives (80 bits a frame)."""
        return sample_rate / (80.0 * self.bit_period)

    def __str__(self) -> str:
        sep = ";" if self.drop_frame else ":"
        return f"{self.hours:02d}:{self.minutes:02d}:{self.seconds:02d}{sep}{self.frames:02d}"


class LtcDecoder:
    """A streaming decoder: :meth:`decode` each block of samples in order; frames come out as
    their sync words complete. State (the bit period, a half bit pending) carries over blocks.

    Args:
        sample_rate: samples per second, an integer 8000..96000.
        min_level: below this peak amplitude (full scale 1.0) the input is silence.
    """

    def __init__(self, sample_rate: int, *, min_level: float = 0.01) -> None:
        if (
            isinstance(sample_rate, bool)
            or not isinstance(sample_rate, int)
            or not MIN_SAMPLE_RATE <= sample_rate <= MAX_SAMPLE_RATE
        ):
            raise LtcError(
                f"LTC: sample rate must be an integer {MIN_SAMPLE_RATE}..{MAX_SAMPLE_RATE} Hz, "
                f"got {sample_rate!r}"
            )
        if not (isinstance(min_level, int | float) and 0 < min_level < 1):
            raise LtcError(f"LTC: min_level must be a number in (0, 1), got {min_level!r}")
        self.sample_rate = sample_rate
        self.min_level = float(min_level)
        self._guess = sample_rate / _GUESS_BIT_RATE
        self._lo_period = sample_rate / MAX_BIT_RATE
        self._hi_period = sample_rate / MIN_BIT_RATE
        self._period = self._guess  # samples per bit, now
        self._n = 0  # samples consumed
        self._hi = 0.0  # peak envelopes (their mean is the centre)
        self._lo = 0.0
        self._state = 0  # the hysteresis state: +1, -1, 0 (none yet)
        self._side_pos, self._side_x = 0, 0.0  # the last sample outside the dead zone
        self._last_edge: float | None = None
        self._half: float | None = None  # the first half of a 1 (its length), pending
        self._reg = 0
        self._nbits = 0  # bits since sync was lost
        self._ends: deque[float] = deque(maxlen=81)  # where the last 81 bits ended
        self._since_frame = 0  # bits since the last good frame
        self.frames = 0  #: frames decoded
        self.invalid = 0  #: sync words whose fields were not a valid code
        self.reverse = 0  #: sync words read backwards (reverse play)
        self.resyncs = 0  #: intervals no bit could be (noise, a dropout): sync lost

    @property
    def samples(self) -> int:
        """Samples consumed so far (the next block's first sample index)."""
        return self._n

    def decode(self, samples: Any) -> list[LtcFrame]:
        """Decode the next block (a 1-D array of numbers); the frames completed in it."""
        try:
            x = np.asarray(samples, dtype=np.float64)
        except (TypeError, ValueError, OverflowError) as exc:
            raise LtcError(f"LTC: samples must be numbers: {exc}") from None
        if x.ndim != 1:
            raise LtcError(f"LTC: samples must be one channel (1-D), got shape {x.shape}")
        if x.size == 0:
            return []
        if not np.isfinite(x).all():  # a NaN or inf is no level: silence there
            x = np.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0)
        edges = self._edges(x)
        self._n += x.size
        out: list[LtcFrame] = []
        for p in edges:
            frame = self._edge(float(p))
            if frame is not None:
                out.append(frame)
        return out

    def _edges(self, x: np.ndarray) -> np.ndarray:
        """The transitions in ``x`` (global sample positions, fractional), with hysteresis."""
        n = x.size
        decay = math.exp(-n / (0.05 * self.sample_rate))  # the envelope forgets in ~50 ms
        if self._n == 0:  # the first block sets the envelopes
            self._hi = self._lo = float(x[0])
        centre = 0.5 * (self._hi + self._lo)
        self._hi = max(float(x.max()), centre + (self._hi - centre) * decay)
        self._lo = min(float(x.min()), centre + (self._lo - centre) * decay)
        centre = 0.5 * (self._hi + self._lo)
        amp = 0.5 * (self._hi - self._lo)
        if amp < self.min_level:  # silence: no transitions, and sync is lost
            self._state = 0
            self._lose_sync()
            self._last_edge = None
            return np.empty(0)
        h = 0.3 * amp
        st = np.zeros(n, dtype=np.int8)
        st[x > centre + h] = 1
        st[x < centre - h] = -1
        idx = np.where(st != 0, np.arange(n), -1)
        np.maximum.accumulate(idx, out=idx)
        filled = np.where(idx >= 0, st[np.maximum(idx, 0)], self._state).astype(np.int8)
        prev = np.empty(n, dtype=np.int8)
        prev[0] = self._state
        prev[1:] = filled[:-1]
        where = np.flatnonzero((filled != prev) & (prev != 0))
        # the crossing of the centre between the last sample on the old side and this one
        j = np.empty(n, dtype=np.int64)
        j[0] = -1
        j[1:] = idx[:-1]
        jw = j[where]
        old = jw < 0  # the old side's last sample is in an earlier block
        j_pos = np.where(old, self._side_pos - self._n, jw).astype(np.float64)
        a = np.where(old, self._side_x, x[np.maximum(jw, 0)]) - centre
        b = x[where] - centre
        span = where - j_pos
        frac = np.where(a != b, a / np.where(a != b, a - b, 1.0), 1.0)
        pos = self._n + j_pos + span * np.clip(frac, 0.0, 1.0)
        if idx[-1] >= 0:
            self._side_pos, self._side_x = self._n + int(idx[-1]), float(x[idx[-1]])
        self._state = int(filled[-1])
        return pos

    def _lose_sync(self) -> None:
        if self._nbits:
            self.resyncs += 1
        self._half = None
        self._nbits = 0
        self._ends.clear()
        self._period = self._guess

    def _edge(self, p: float) -> LtcFrame | None:
        last, self._last_edge = self._last_edge, p
        if last is None:
            return None
        d = p - last
        t = self._period
        if d < 0.3 * t or d > 1.5 * t:  # no bit is this long or short: noise, or a dropout
            self._lose_sync()
            return None
        if d > 0.75 * t:  # a whole bit: 0 (a lone half before it was a misaligned start)
            self._half = None
            return self._bit(0, p)
        if self._half is None:
            self._half = d
            return None
        self._half = None
        return self._bit(1, p)

    def _bit(self, bit: int, p: float) -> LtcFrame | None:
        self._reg = ((self._reg << 1) | bit) & _MASK80
        self._ends.append(p)
        self._nbits += 1
        self._since_frame += 1
        if self._since_frame > 160:  # two frames with none decoded: back to the guess
            self._period = self._guess
        low = self._reg & 0xFFFF
        if self._nbits >= 16 and low == SYNC_REVERSED:
            self.reverse += 1
        if self._nbits < 80 or low != SYNC_WORD or len(self._ends) < 81:
            return None
        period = (p - self._ends[0]) / 80.0
        frame = self._frame(p, period)
        if frame is None or not self._lo_period <= period <= self._hi_period:
            self.invalid += 1
            return None
        self._period = period  # adaptive: the next bits are judged by this frame's own
        self._since_frame = 0
        self.frames += 1
        return frame

    def _frame(self, end: float, period: float) -> LtcFrame | None:
        reg = self._reg

        def field(first: int, n: int) -> int:
            return sum(((reg >> (79 - (first + k))) & 1) << k for k in range(n))

        units = (field(0, 4), field(16, 4), field(32, 4), field(48, 4))
        if max(units) > 9:
            return None
        frames = field(8, 2) * 10 + units[0]
        seconds = field(24, 3) * 10 + units[1]
        minutes = field(40, 3) * 10 + units[2]
        hours = field(56, 2) * 10 + units[3]
        if frames > 29 or seconds > 59 or minutes > 59 or hours > 23:
            return None
        return LtcFrame(hours, minutes, seconds, frames, bool(field(10, 1)), end, period)
