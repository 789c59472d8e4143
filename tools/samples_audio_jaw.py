"""Write sample sound files for the audio -> jaw reader into configs/animations/audio_jaw/.

Every sample is synthesised here (tone bursts, no recorded speech), written by this script's
own RIFF/WAVE writer:

* ``line.wav``: 8 kHz, 8-bit mono, 1.2 s: three "syllables" (a 300 Hz buzz with a 1.2 kHz
  overtone, each with its own loudness and a soft onset), the shape of a short spoken line.
* ``tone_track.wav``: 8 kHz, 8-bit stereo, 0.8 s: the talking-skull "tone track" layout -
  the left channel carries the dialogue (a buzz), the right one steady 1 kHz bursts where the
  jaw should open; read it with ``channel = "right"``.

The issue's acceptance signal (0.5 s silence, 0.5 s of a 1 kHz sine at half full scale, 1 s
silence; 44.1 kHz 16-bit) is :func:`acceptance_signal`; the tests write it themselves.

    python tools/samples_audio_jaw.py [OUTPUT_DIR]
    python tools/samples_audio_jaw.py --bench SECONDS [--band]   # time jaw_track, 3 runs

Deterministic. Tests import its functions. ``--bench`` writes a SECONDS-long 44.1 kHz 16-bit
mono "speech" file to a temporary directory, times :func:`jaw_track` on it three times and
prints the memory a fourth run allocates at its peak (tracemalloc, numpy's arrays included);
it writes nothing into the repository.
"""

from __future__ import annotations

import argparse
import struct
from pathlib import Path

import numpy as np

#: the sub-format GUID's tail of WAVE_FORMAT_EXTENSIBLE (after the 2-byte format tag)
_GUID_TAIL = b"\x00\x00\x00\x00\x10\x00\x80\x00\x00\xaa\x00\x38\x9b\x71"


def encode(frames: np.ndarray, bits: int, kind: str = "pcm") -> bytes:
    """Samples (n × channels, full scale ±1) as little-endian WAV sample bytes."""
    x = np.asarray(frames, dtype=np.float64)
    if kind == "float":
        return x.astype("<f4" if bits == 32 else "<f8").tobytes()
    if bits == 8:
        return np.clip(np.round(x * 128.0 + 128.0), 0, 255).astype(np.uint8).tobytes()
    top = float(1 << (bits - 1))
    v = np.clip(np.round(x * top), -top, top - 1).astype(np.int64)
    if bits == 24:
        b = (v & 0xFFFFFF).astype("<u4").view(np.uint8).reshape(-1, 4)[:, :3]
        return b.tobytes()
    return v.astype(f"<i{bits // 8}").tobytes()


def wav_bytes(
    frames: np.ndarray, rate: int, bits: int = 16, kind: str = "pcm", extensible: bool = False
) -> bytes:
    """A whole RIFF/WAVE file: ``frames`` (n, or n × channels) as PCM or IEEE float."""
    x = np.asarray(frames, dtype=np.float64)
    x = x.reshape(-1, 1) if x.ndim == 1 else x
    channels = x.shape[1]
    data = encode(x, bits, kind)
    tag = 3 if kind == "float" else 1
    align = channels * bits // 8
    fmt = struct.pack("<HHIIHH", 0xFFFE if extensible else tag, channels, rate, rate * align,
                      align, bits)  # fmt: skip
    if extensible:
        fmt += struct.pack("<HHI", 22, bits, 0) + struct.pack("<H", tag) + _GUID_TAIL
    chunks = b"fmt " + struct.pack("<I", len(fmt)) + fmt
    chunks += b"data" + struct.pack("<I", len(data)) + data + (b"\0" if len(data) & 1 else b"")
    return b"RIFF" + struct.pack("<I", 4 + len(chunks)) + b"WAVE" + chunks


def acceptance_signal(rate: int = 44_100) -> np.ndarray:
    """Issue 13: 0.5 s silence, 0.5 s of a 1 kHz sine at half full scale, 1 s silence."""
    t = np.arange(2 * rate) / rate
    return np.where((t >= 0.5) & (t < 1.0), 0.5 * np.sin(2 * np.pi * 1000.0 * t), 0.0)


def _buzz(t: np.ndarray) -> np.ndarray:
    return 0.7 * np.sin(2 * np.pi * 300.0 * t) + 0.3 * np.sin(2 * np.pi * 1200.0 * t)


def _bursts(t: np.ndarray, bursts: list[tuple[float, float, float]]) -> np.ndarray:
    """A loudness curve: (start, end, level) bursts, each with 15 ms raised-cosine edges."""
    out = np.zeros_like(t)
    for start, end, level in bursts:
        rise = np.clip((t - start) / 0.015, 0, 1)
        fall = np.clip((end - t) / 0.015, 0, 1)
        out += level * (0.5 - 0.5 * np.cos(np.pi * np.minimum(rise, fall)))
    return out


def line_signal(rate: int = 8000) -> np.ndarray:
    t = np.arange(int(1.2 * rate)) / rate
    return _buzz(t) * _bursts(t, [(0.10, 0.30, 0.6), (0.38, 0.55, 0.35), (0.62, 0.95, 0.8)])


def tone_track_signal(rate: int = 8000) -> np.ndarray:
    t = np.arange(int(0.8 * rate)) / rate
    words = [(0.10, 0.32, 0.7), (0.45, 0.70, 0.6)]
    left = _buzz(t) * _bursts(t, words)
    right = 0.5 * np.sin(2 * np.pi * 1000.0 * t) * _bursts(t, [(a, b, 1.0) for a, b, _ in words])
    return np.stack([left, right], axis=1)


def write_samples(out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    files = {
        "line.wav": wav_bytes(line_signal(), 8000, bits=8),
        "tone_track.wav": wav_bytes(tone_track_signal(), 8000, bits=8),
    }
    written = []
    for name, data in files.items():
        (out / name).write_bytes(data)
        written.append(out / name)
    return written


def bench(seconds: float, band: bool) -> None:
    import tempfile
    import time
    import tracemalloc

    from hilsim.targets.formats.audio_jaw import EnvelopeSettings, jaw_track
    from hilsim.targets.formats.common import UnitMap

    rate = 44_100
    t = np.arange(int(seconds * rate)) / rate
    noise = np.random.default_rng(1).standard_normal(t.size)
    x = 0.3 * np.sin(2 * np.pi * 300 * t) * (0.5 + 0.5 * np.sin(2 * np.pi * 3 * t)) + 0.01 * noise
    settings = EnvelopeSettings(band_hz=(500.0, 2500.0)) if band else EnvelopeSettings()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.wav"
        path.write_bytes(wav_bytes(x, rate))
        del t, noise, x
        times = []
        for _ in range(3):
            start = time.perf_counter()
            jaw_track(path, UnitMap((0, 1), (0, 20), "opening"), settings)
            times.append(time.perf_counter() - start)
        tracemalloc.start()  # a fourth, untimed run: the memory it allocates at its peak
        jaw_track(path, UnitMap((0, 1), (0, 20), "opening"), settings)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
    size = seconds * rate * 2 / 2**20
    runs = ", ".join(f"{s * 1000:.0f} ms" for s in times)
    print(
        f"jaw_track, {seconds:g} s of 44.1 kHz 16-bit mono ({size:.1f} MB), band-pass {band}: "
        f"{runs}; peak allocated {peak:.0f} MB"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parent.parent / "configs" / "animations" / "audio_jaw"
    parser.add_argument("out", nargs="?", type=Path, default=default)
    parser.add_argument("--bench", type=float, metavar="SECONDS", help="time jaw_track instead")
    parser.add_argument("--band", action="store_true", help="with --bench: a 500-2500 Hz band")
    args = parser.parse_args()
    if args.bench:
        bench(args.bench, args.band)
        return
    for path in write_samples(args.out):
        print(f"{path} ({path.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
