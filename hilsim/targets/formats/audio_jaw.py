"""Audio -> jaw: a sound file through an envelope follower, as a jaw track.

The louder the line, the wider the jaw. Computed once, from the file:

1. an optional band-pass;
2. a trailing RMS over ``window_ms``, every ``step_ms``;
3. an attack/release follower (it runs on past the file's end, so the jaw closes);
4. an opening 0..1 between ``threshold`` and ``full``, mapped to degrees by the rig's
   :class:`~hilsim.targets.formats.common.UnitMap`.

``lead_s`` shifts the track earlier; :func:`spring_lag_s` (the spring's lag, ``(c - b)/k``)
as the lead puts the *commanded* jaw in time with the sound::

    track = jaw_track(path, UnitMap((0, 1), (closed_deg, open_deg), "opening"),
                      EnvelopeSettings(window_ms=..., ...), channel="right",
                      lead_s=spring_lag_s(joint.spring))

:func:`jaw_envelope` gives the envelope itself, for plots. WAV is read here; other formats
need ``soundfile`` (``pip install 'hilsim[audio]'``). The pipeline, the lead's derivation and
the files read: ``docs/targets.md`` (Audio -> jaw).
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hilsim._types import FloatArray, IntArray
from hilsim.dynamics.springs import Spring
from hilsim.targets.formats.common import (
    AUDIO_JAW_SOURCE,
    FormatError,
    SampledTrack,
    UnitMap,
    read_bytes,
)

#: channel choices besides a 0-based index
CHANNELS = ("left", "right", "mix")
#: sample rates read (Hz): below, a 1 ms grid is coarser than the audio; above, no audio file
RATE_RANGE = (1000, 768_000)
#: the largest float sample read (full scale is ±1): beyond, the envelope's running sums of
#: squares lose the quieter samples after it (or overflow), so such a file is refused
FLOAT_LIMIT = 1000.0
#: WAVE format tags: PCM, IEEE float, extensible (the sub-format's tag is in its GUID)
_PCM, _FLOAT, _EXTENSIBLE = 0x0001, 0x0003, 0xFFFE
AUDIO_EXTRA = "pip install 'hilsim[audio]'"


@dataclass(frozen=True)
class EnvelopeSettings:
    """The envelope follower's settings (times in ms; levels as RMS normalised to full scale,
    so a full-scale sine is 0.707). ``band_hz``: None, or (low, high) for a band-pass with
    Butterworth edges of ``band_order`` (low 0: no high-pass; high ``inf``: no low-pass).
    ValueError names a setting out of range."""

    window_ms: float = 10.0
    attack_ms: float = 10.0
    release_ms: float = 100.0
    threshold: float = 0.02
    full: float = 0.35
    band_hz: tuple[float, float] | None = None
    band_order: int = 2
    step_ms: float = 1.0

    def __post_init__(self) -> None:
        def check(name: str, ok: bool, allowed: str) -> None:
            if not ok:
                raise ValueError(f"{name} = {getattr(self, name)!r}: must be {allowed}")

        num = (int, float)
        for name in ("window_ms", "attack_ms", "release_ms", "threshold", "full", "step_ms"):
            value = getattr(self, name)
            check(name, isinstance(value, num) and math.isfinite(value), "a finite number")
        check("window_ms", 0 < self.window_ms <= 10_000, "> 0 and <= 10000 ms")
        check("step_ms", 0.1 <= self.step_ms <= 100, "within 0.1 .. 100 ms")
        check("attack_ms", 0 <= self.attack_ms <= 10_000, "within 0 .. 10000 ms")
        check("release_ms", 0 <= self.release_ms <= 10_000, "within 0 .. 10000 ms")
        check("threshold", 0 <= self.threshold < 1, ">= 0 and < 1 (RMS, full scale)")
        check("full", self.threshold < self.full <= 1, f"> threshold ({self.threshold}) and <= 1")
        check("band_order", isinstance(self.band_order, int) and 1 <= self.band_order <= 8, "1..8")
        if self.band_hz is not None:
            band = self.band_hz
            ok = (
                len(band) == 2
                and all(isinstance(x, num) and not math.isnan(x) for x in band)
                and 0 <= band[0] < band[1]
                and math.isfinite(band[0])
            )
            check("band_hz", ok, "None or (low, high) Hz with 0 <= low < high (high may be inf)")


@dataclass(frozen=True)
class Audio:
    """One channel of a sound file: ``samples`` (float64, full scale ±1), ``rate_hz``, and
    what was read (``channels`` in the file, ``encoding`` such as ``"PCM 16-bit"``)."""

    samples: np.ndarray
    rate_hz: int
    channels: int
    encoding: str

    @property
    def duration(self) -> float:
        return self.samples.size / self.rate_hz


@dataclass(frozen=True)
class JawEnvelope:
    """The follower's curves on its grid ``times_s`` (k·step, before any lead): ``rms``,
    ``envelope`` (after attack/release) and ``opening`` (0..1)."""

    times_s: np.ndarray
    rms: np.ndarray
    envelope: np.ndarray
    opening: np.ndarray
    audio: Audio


# ------------------------------------------------------------------------------ the lead


def spring_lag_s(spring: Spring) -> float:
    """How late a joint's spring follows a slow target (s): ``(c - b)/k``, its group delay at
    0 Hz; ``(2 - r)·ζ/(2π·f)`` for ``Spring.from_animation(f, ζ, r)``. Negative when the
    feed-forward leads (r > 2). Pass it as ``lead_s`` to put the commanded jaw in time."""
    if spring.shape != ():
        raise ValueError(f"one spring, not a bank of {spring.n}")
    return float((spring.c - spring.b) / spring.k)


# ------------------------------------------------------------------------------ reading


def read_audio(path: str | Path, channel: str | int = "mix") -> Audio:
    """One channel of a sound file, normalised to full scale.

    ``channel``: ``"left"`` (the first), ``"right"`` (the second; a mono file has none),
    ``"mix"`` (the mean of all) or a 0-based index. Raises FormatError.
    """
    path = Path(path)
    data = read_bytes(path)
    if not data:
        raise FormatError(path, "", "empty file: no audio")
    try:
        if data[:4] != b"RIFF" or data[8:12] != b"WAVE":
            raise _NotPcmWav("byte 0", f"not a WAV file (starts {data[:4]!r})")
        frames, rate, encoding = _read_wav(path, data)
    except _NotPcmWav as why:
        frames, rate, encoding = _read_other(path, data, *why.args)
    return Audio(_pick(path, frames, channel), rate, frames.shape[1], encoding)


def _read_wav(path: Path, data: bytes) -> tuple[np.ndarray, int, str]:
    """(frames × channels float64 array, rate, encoding) from a RIFF/WAVE file's bytes."""
    fmt: tuple[int, int, int, int, int] | None = None
    pos = 12
    while pos + 8 <= len(data):
        cid, size = data[pos : pos + 4], struct.unpack_from("<I", data, pos + 4)[0]
        body = pos + 8
        if cid != b"data" and size > len(data) - body:
            raise FormatError(
                path,
                f"byte {pos}",
                f"chunk {cid.decode('latin-1')!r} says {size} bytes, more than the file holds",
            )
        if cid == b"fmt ":
            fmt = _fmt_chunk(path, data, pos, size)
        elif cid == b"data":
            if fmt is None:
                raise FormatError(path, f"byte {pos}", "a 'data' chunk before any 'fmt ' chunk")
            if size > len(data) - body:
                raise FormatError(
                    path,
                    f"byte {pos}",
                    f"the 'data' chunk says {size} bytes, the file holds {len(data) - body} "
                    "after it: truncated (or written by a streaming tool that left the size "
                    "unset; rewrite it, e.g. with sox)",
                )
            return _decode(path, memoryview(data)[body : body + size], body, fmt)
        pos = body + size + (size & 1)  # chunks are padded to an even length
    if fmt is None:
        raise FormatError(path, f"byte {len(data)}", "no 'fmt ' chunk: truncated WAV")
    raise FormatError(path, f"byte {len(data)}", "no 'data' chunk: truncated WAV, no audio")


def _fmt_chunk(path: Path, data: bytes, pos: int, size: int) -> tuple[int, int, int, int, int]:
    """(tag, channels, rate, block_align, bits) of a 'fmt ' chunk at ``pos``, checked."""
    at = f"byte {pos}"
    if size < 16 or pos + 8 + 16 > len(data):
        raise FormatError(path, at, f"'fmt ' chunk of {size} bytes; a WAV's has at least 16")
    tag, channels, rate, _, align, bits = struct.unpack_from("<HHIIHH", data, pos + 8)
    if tag == _EXTENSIBLE:
        if size < 40 or pos + 8 + 40 > len(data):
            raise FormatError(path, at, "WAVE_FORMAT_EXTENSIBLE 'fmt ' chunk shorter than 40 bytes")
        tag = struct.unpack_from("<H", data, pos + 8 + 24)[0]  # the sub-format GUID's first word
    kinds = {_PCM: (8, 16, 24, 32), _FLOAT: (32, 64)}
    if tag not in kinds:
        raise _NotPcmWav(at, f"WAV format tag {tag:#06x} (compressed audio)")
    if bits not in kinds[tag]:
        kind = "PCM" if tag == _PCM else "float"
        raise FormatError(path, at, f"{bits}-bit {kind}; read are {kinds[tag]} bits")
    if not 1 <= channels <= 256:
        raise FormatError(path, at, f"{channels} channels; allowed 1 .. 256")
    if not RATE_RANGE[0] <= rate <= RATE_RANGE[1]:
        raise FormatError(
            path, at, f"sample rate {rate} Hz; allowed {RATE_RANGE[0]} .. {RATE_RANGE[1]} Hz"
        )
    if align != channels * bits // 8:
        raise FormatError(
            path,
            at,
            f"block align {align}, but {channels} channels of {bits} bits need "
            f"{channels * bits // 8}",
        )
    return tag, channels, rate, align, bits


def _decode(
    path: Path, raw: bytes | memoryview, at: int, fmt: tuple[int, int, int, int, int]
) -> tuple[np.ndarray, int, str]:
    tag, channels, rate, align, bits = fmt
    if not raw:
        raise FormatError(path, f"byte {at}", "the 'data' chunk is empty: no audio")
    if len(raw) % align:
        raise FormatError(
            path,
            f"byte {at + len(raw) - len(raw) % align}",
            f"the 'data' chunk's {len(raw)} bytes are not whole frames of {align} bytes",
        )
    if tag == _FLOAT:
        x = np.frombuffer(raw, dtype="<f4" if bits == 32 else "<f8").astype(np.float64)
        bad = np.flatnonzero(~(np.abs(x) <= FLOAT_LIMIT))  # NaN too
        if bad.size:
            i = int(bad[0])
            raise FormatError(path, f"byte {at + i * bits // 8}", f"sample {i} {_loud(x[i])}")
        encoding = f"float {bits}-bit"
    elif bits == 8:
        x = (np.frombuffer(raw, dtype=np.uint8).astype(np.float64) - 128.0) / 128.0
        encoding = "PCM 8-bit"
    elif bits == 24:
        b = np.frombuffer(raw, dtype=np.uint8).reshape(-1, 3).astype(np.int32)
        v = b[:, 0] | (b[:, 1] << 8) | (b[:, 2] << 16)
        x = ((v ^ 0x800000) - 0x800000).astype(np.float64) / float(1 << 23)
        encoding = "PCM 24-bit"
    else:
        x = np.frombuffer(raw, dtype=f"<i{bits // 8}").astype(np.float64)
        x *= 1.0 / float(1 << (bits - 1))  # in place: a long file is one float64 copy
        encoding = f"PCM {bits}-bit"
    return x.reshape(-1, channels), rate, encoding


class _NotPcmWav(Exception):  # noqa: N818 - a signal inside this module, never raised out
    """(where, what): a file the RIFF reader does not decode; soundfile's turn."""


def _read_other(path: Path, data: bytes, at: str, what: str) -> tuple[np.ndarray, int, str]:
    """A file the WAV reader does not decode, through soundfile (an optional extra)."""
    if data[:4] == b"RIFF" and data[8:12] != b"WAVE":
        raise FormatError(path, "byte 8", f"a RIFF file of form {data[8:12]!r}, not WAVE")
    try:
        import soundfile
    except ImportError:
        raise FormatError(
            path,
            at,
            f"{what}: read here is PCM or float WAV; other audio needs the optional "
            f"soundfile library: {AUDIO_EXTRA}",
        ) from None
    import io

    try:
        frames, rate = soundfile.read(io.BytesIO(data), dtype="float64", always_2d=True)
        info = soundfile.info(io.BytesIO(data))
    except Exception as exc:
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        text = re.sub(r"Error opening <_io\.BytesIO object at 0x[0-9a-f]+>: ", "", text)
        raise FormatError(path, "", f"{what}, and not readable as audio ({text})") from None
    if frames.size == 0:
        raise FormatError(path, "", "no audio samples")
    if not RATE_RANGE[0] <= rate <= RATE_RANGE[1]:
        raise FormatError(
            path, "", f"sample rate {rate} Hz; allowed {RATE_RANGE[0]} .. {RATE_RANGE[1]} Hz"
        )
    if (bad := np.flatnonzero(~(np.abs(frames) <= FLOAT_LIMIT))).size:
        raise FormatError(path, "", f"sample {int(bad[0])} {_loud(frames.flat[bad[0]])}")
    return frames, int(rate), f"{info.format} {info.subtype}"


def _loud(x: float) -> str:
    if not math.isfinite(x):
        return "is not finite"
    return f"is {x:g}, beyond ±{FLOAT_LIMIT:g} (full scale ±1)"


def _pick(path: Path, frames: np.ndarray, channel: str | int) -> np.ndarray:
    n = frames.shape[1]
    if channel == "mix":
        return frames.mean(axis=1) if n > 1 else frames.reshape(-1)
    index = {"left": 0, "right": 1}.get(channel, channel) if isinstance(channel, str) else channel
    if isinstance(index, bool) or not isinstance(index, int):
        raise ValueError(f"channel {channel!r}: allowed {', '.join(CHANNELS)} or a 0-based index")
    if not 0 <= index < n:
        raise FormatError(
            path,
            "",
            f"channel {channel!r} asked for, the file has {n} channel"
            f"{'s' if n > 1 else ''} ({'mono: use mix' if n == 1 else f'0 .. {n - 1}'})",
        )
    return np.ascontiguousarray(frames[:, index])


# ------------------------------------------------------------------------------ the envelope


def band_pass(x: np.ndarray, rate: int, band: tuple[float, float], order: int = 2) -> np.ndarray:
    """``x`` through a zero-phase band-pass: a linear-phase FIR whose magnitude is the
    Butterworth edges' 1/√(1 + (low/f)^2n) · 1/√(1 + (f/high)^2n), applied by FFT overlap-add
    and re-centred (no delay). A FIR, so a long file costs time in proportion, not memory."""
    low, high = band
    n_fft = 1 << max(10, min(17, math.ceil(math.log2(8.0 * rate / max(low, 20.0)))))
    f = np.fft.rfftfreq(n_fft, 1.0 / rate)
    with np.errstate(divide="ignore", over="ignore"):
        mag = np.ones_like(f)
        if low > 0:
            mag /= np.sqrt(1.0 + (low / np.maximum(f, 1e-300)) ** (2 * order))
        if math.isfinite(high):
            mag /= np.sqrt(1.0 + (f / high) ** (2 * order))
    h = np.roll(np.fft.irfft(mag, n_fft), n_fft // 2) * np.blackman(n_fft)
    delay = n_fft // 2
    block = 1 << 16
    size = 1 << math.ceil(math.log2(block + n_fft - 1))
    hf = np.fft.rfft(h, size)
    out = np.zeros(x.size + n_fft - 1)
    for start in range(0, x.size, block):
        seg = x[start : start + block]
        y = np.fft.irfft(np.fft.rfft(seg, size) * hf, size)[: seg.size + n_fft - 1]
        out[start : start + y.size] += y
    return out[delay : delay + x.size]


def jaw_envelope(
    path: str | Path, settings: EnvelopeSettings | None = None, channel: str | int = "mix"
) -> JawEnvelope:
    """The envelope follower over one channel of ``path`` (see the module's docstring)."""
    s = settings or EnvelopeSettings()
    audio = read_audio(path, channel)
    rate, x = audio.rate_hz, audio.samples
    if s.band_hz is not None:
        nyquist = rate / 2
        if s.band_hz[0] >= nyquist or (math.isfinite(s.band_hz[1]) and s.band_hz[1] >= nyquist):
            raise FormatError(
                path,
                "",
                f"band-pass {s.band_hz[0]:g}..{s.band_hz[1]:g} Hz reaches the file's "
                f"Nyquist frequency {nyquist:g} Hz (sample rate {rate} Hz)",
            )
        x = band_pass(x, rate, s.band_hz, s.band_order)
    n = x.size
    width = max(1, round(s.window_ms * rate / 1000.0))
    step_us = round(s.step_ms * 1000.0)
    step = step_us / 1e6
    k = np.arange((n - 1 + width) * 1_000_000 // (rate * step_us) + 2, dtype=np.int64)
    end = k * (step_us * rate) // 1_000_000  # the last sample at or before t_k, exactly
    rms = np.sqrt(_window_sums(x, end, width) / width)
    env = _follow(rms.tolist(), step, s)
    times = k * step
    tail = _tail(env[-1], step, s)
    if tail:
        times = np.concatenate([times, times[-1] + step * np.arange(1, len(tail) + 1)])
        rms = np.concatenate([rms, np.zeros(len(tail))])
        env = env + tail
    envelope = np.asarray(env)
    opening = np.clip((envelope - s.threshold) / (s.full - s.threshold), 0.0, 1.0)
    return JawEnvelope(times, rms, envelope, opening, audio)


def _window_sums(x: np.ndarray, ends: IntArray, width: int) -> FloatArray:
    """Σ x² over samples (end - width, end] for each of the ascending ``ends`` (outside the
    file: silence), from running sums taken a chunk at a time (no second file-long array)."""
    n = x.size
    want = np.clip(np.concatenate([ends, ends - width]), -1, n - 1)  # prefix sums needed
    order = np.argsort(want, kind="stable")
    pos = want[order]
    prefix: FloatArray = np.zeros(want.size)  # want = -1: the empty prefix, 0
    carry, chunk = 0.0, 1 << 20
    for start in range(0, n, chunk):
        run = np.cumsum(np.square(x[start : start + chunk]))
        run += carry
        lo, hi = np.searchsorted(pos, [start, start + chunk])
        prefix[order[lo:hi]] = run[pos[lo:hi] - start]
        carry = float(run[-1])
    return np.maximum(prefix[: ends.size] - prefix[ends.size :], 0.0)


def _alpha(tau_ms: float, step: float) -> float:
    return 1.0 if tau_ms == 0 else 1.0 - math.exp(-step * 1000.0 / tau_ms)


def _follow(rms: list[float], step: float, s: EnvelopeSettings) -> list[float]:
    up, down = _alpha(s.attack_ms, step), _alpha(s.release_ms, step)
    out: list[float] = []
    e = 0.0
    append = out.append
    for r in rms:
        e += (up if r > e else down) * (r - e)
        append(e)
    return out


def _tail(e: float, step: float, s: EnvelopeSettings) -> list[float]:
    """The follower over silence after the file, until the jaw is shut (at most 20 τ)."""
    down = _alpha(s.release_ms, step)
    limit = max(1, math.ceil(20 * s.release_ms / 1000.0 / step))
    out: list[float] = []
    while e > s.threshold and len(out) < limit and down > 0:
        e -= down * e
        out.append(e)
    return out


def jaw_track(
    path: str | Path,
    jaw: UnitMap,
    settings: EnvelopeSettings | None = None,
    *,
    channel: str | int = "mix",
    lead_s: float = 0.0,
) -> SampledTrack:
    """The jaw's target from a sound file: the opening (0..1) through ``jaw`` to degrees,
    linear between steps, the whole curve ``lead_s`` earlier (negative: later). Samples wholly
    before show time 0 are dropped (the one just before is kept, so u(0) is exact)."""
    if not (isinstance(lead_s, int | float) and math.isfinite(lead_s) and abs(lead_s) <= 10.0):
        raise ValueError(f"lead_s = {lead_s!r}: must be a finite number of seconds within ±10")
    env = jaw_envelope(path, settings, channel)
    times = env.times_s - float(lead_s)
    first = max(0, int(np.searchsorted(times, 0.0, side="right")) - 1)
    values = jaw.to_rad(env.opening[first:])
    return SampledTrack(times[first:], values, "linear", source=f"{path} {AUDIO_JAW_SOURCE}")
