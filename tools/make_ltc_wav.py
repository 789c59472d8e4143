"""Write SMPTE LTC as a WAV file: a test signal for ``[inputs.ltc]`` (tests, rehearsals).

    python tools/make_ltc_wav.py ltc25.wav --fps 25 --start 01:00:00:00 --seconds 20
    python tools/make_ltc_wav.py gap.wav --fps 29.97df --seconds 10 --gap 4:1  # silent 4..5 s

Our own encoder, written from the published LTC layout (80 bits a frame, biphase mark, BCD
fields least significant bit first, sync word 0x3FFD in bits 64..79): frame 0 starts at
sample 0 with the start code, so frame k ends at sample (k + 1)·rate/fps, where its code + 1
frame is the true time. Drop-frame (29.97df) skips labels 00 and 01 at each minute but every
tenth and sets bit 10. A gap is silence over the signal that keeps running (an unplugged
cable). 16-bit PCM, mono.
"""

from __future__ import annotations

import argparse
import sys
import wave
from pathlib import Path

import numpy as np

#: frame-rate name -> (nominal fps, drop-frame, frames per real second)
RATES = {
    "24": (24, False, 24.0),
    "25": (25, False, 25.0),
    "29.97df": (30, True, 30000 / 1001),
    "30": (30, False, 30.0),
}


def next_label(code: tuple[int, int, int, int], fps: str) -> tuple[int, int, int, int]:
    """The label after ``code`` (h, m, s, f) at ``fps``, drop-frame skipping as SMPTE does."""
    nominal, drop, _ = RATES[fps]
    h, m, s, f = code
    f += 1
    if f == nominal:
        f, s = 0, s + 1
        if s == 60:
            s, m = 0, m + 1
            if m == 60:
                m, h = 0, (h + 1) % 24
    if drop and s == 0 and f < 2 and m % 10:
        f = 2
    return h, m, s, f


def frame_bits(code: tuple[int, int, int, int], fps: str) -> list[int]:
    """The 80 bits of one frame, in the order sent (user bits 0)."""
    nominal, drop, _ = RATES[fps]
    h, m, s, f = code
    bits = [0] * 80

    def put(first: int, n: int, value: int) -> None:
        for k in range(n):
            bits[first + k] = (value >> k) & 1

    put(0, 4, f % 10)
    put(8, 2, f // 10)
    bits[10] = int(drop)
    put(16, 4, s % 10)
    put(24, 3, s // 10)
    put(32, 4, m % 10)
    put(40, 3, m // 10)
    put(48, 4, h % 10)
    put(56, 2, h // 10)
    put(64, 16, int(f"{0x3FFD:016b}"[::-1], 2))  # 0011 1111 1111 1101 as sent
    parity_bit = 59 if nominal == 25 else 27  # the polarity correction bit: zeros even
    if bits.count(0) % 2:
        bits[parity_bit] = 1
    return bits


def ltc_samples(
    fps: str,
    seconds: float,
    rate: int = 48000,
    *,
    start: tuple[int, int, int, int] = (0, 0, 0, 0),
    amplitude: float = 0.5,
    gaps: tuple[tuple[float, float], ...] = (),
    invert: bool = False,
) -> np.ndarray:
    """``seconds`` of LTC at ``fps`` from ``start``, float samples; ``gaps``: (start s,
    length s) of silence."""
    _, _, real_fps = RATES[fps]
    n_frames = int(np.ceil(seconds * real_fps)) + 1
    bits: list[int] = []
    code = start
    for _ in range(n_frames):
        bits += frame_bits(code, fps)
        code = next_label(code, fps)
    # a transition at each bit's start, and halfway through a 1
    tr = np.zeros(2 * len(bits), dtype=np.int64)
    tr[0::2] = 1
    tr[1::2] = bits
    level = np.where(np.cumsum(tr) % 2 == 1, amplitude, -amplitude)  # through each half bit
    if invert:
        level = -level
    # each sample is the wave's mean over [n - 1/2, n + 1/2): an edge between samples shows
    # as a value between the levels, as a band-limited line input gives
    n = round(seconds * rate)
    per = real_fps * 160.0 / rate  # half bits per sample
    area = np.concatenate(([0.0], np.cumsum(level)))  # the integral at half-bit starts
    u = np.clip((np.arange(n + 1) - 0.5) * per, 0.0, None)  # sample bounds in half bits
    h = np.floor(u).astype(np.int64)
    integral = area[h] + level[h] * (u - h)
    x = np.diff(integral) / per
    for g0, glen in gaps:
        x[int(g0 * rate) : int((g0 + glen) * rate)] = 0.0
    return np.asarray(x, dtype=np.float64)


def write_wav(path: str | Path, x: np.ndarray, rate: int, channels: int = 1) -> None:
    """16-bit PCM; ``channels`` > 1 puts ``x`` on the first and silence on the others."""
    pcm = np.clip(np.round(x * 32767), -32768, 32767).astype("<i2")
    if channels > 1:
        pcm = np.column_stack([pcm] + [np.zeros_like(pcm)] * (channels - 1)).ravel()
    with wave.open(str(path), "wb") as w:
        w.setnchannels(channels)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(pcm.tobytes())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("--fps", choices=sorted(RATES), default="25")
    ap.add_argument("--start", default="00:00:00:00", help="HH:MM:SS:FF")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rate", type=int, default=48000, help="sample rate (Hz)")
    ap.add_argument("--gap", action="append", default=[], help="START:LENGTH (s) of silence")
    args = ap.parse_args(argv)
    try:
        h, m, s, f = (int(p) for p in args.start.replace(";", ":").split(":"))
        gaps = tuple(tuple(float(v) for v in g.split(":")) for g in args.gap)
    except ValueError:
        print(f"--start HH:MM:SS:FF and --gap START:LENGTH, got {args.start!r} {args.gap!r}")
        return 2
    x = ltc_samples(args.fps, args.seconds, args.rate, start=(h, m, s, f), gaps=gaps)  # type: ignore[arg-type]
    write_wav(args.out, x, args.rate)
    print(f"{args.out}: {args.seconds:g} s of LTC at {args.fps} fps from {args.start}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
