"""Write sample FSEQ v2 sequences into configs/animations/fseq/.

Written by this project's own writer from the published layout (FPP's FSEQFile.cpp and the
fseq-file-format notes): a 32-byte header, the compressed-block index (FPP reserves a few
unused entries of size 0), sparse ranges, variable headers, padding to a multiple of 4, then the
channel data - raw, or in blocks of whole frames each compressed on its own (the first block
holds 10 frames, as FPP writes it so playback starts fast).

* ``r51.fseq`` (uncompressed), ``r51_zstd.fseq``, ``r51_zlib.fseq``: issue 13's worked
  sequence - 4 channels, 50 frames, 20 ms; channel 1 (xLights numbering; the file's index 0)
  = 5·frame, channel 2 = 0, so channels 1-2 as a 16-bit pair over -90...+90° give -90.0° at
  t = 0 and -2.108° at 0.500 s (frame 25: 125·256 = 32000); channel 3 a jaw that is 0
  ("hold") between its moves; channel 4 = 255 - 5·frame.
* ``sparse.fseq``: the same frames stored as two sparse ranges, channels 1-2 and 4 (xLights
  numbering), with an ``sp`` variable header.

    python tools/samples_fseq.py [OUTPUT_DIR]
    python tools/samples_fseq.py --bench      # time the reader on a show-sized sequence

Deterministic (the unique ID is fixed; the compressed files are the same bytes for the same
zlib and zstd builds). The zstd file needs the ``zstandard`` package.
Tests import its functions.
"""

from __future__ import annotations

import argparse
import zlib
from pathlib import Path

import numpy as np

UNIQUE_ID = 0x0005_F000_0000_0000


def r51_frames() -> np.ndarray:
    """The worked sequence's 50 × 4 channel bytes."""
    k = np.arange(50)
    jaw = np.zeros(50, dtype=np.int64)
    jaw[5:10], jaw[20:23], jaw[30:40] = 200, 60, 120  # 0 between: "hold" under zero = hold
    return np.stack([5 * k, np.zeros(50, int), jaw, 255 - 5 * k], axis=1).astype(np.uint8)


def _compress(kind: str, raw: bytes) -> bytes:
    if kind == "zlib":
        return zlib.compress(raw, 6)
    import zstandard  # the writer needs it for zstd, as the reader does

    # FPP streams each block, so its zstd frames carry no content size; neither do these
    return zstandard.ZstdCompressor(level=3, write_content_size=False).compress(raw)


def fseq_bytes(
    frames: np.ndarray,
    step_ms: int = 20,
    *,
    compression: str = "none",
    sparse_ranges: list[tuple[int, int]] | None = None,
    variables: list[tuple[str, bytes]] | None = None,
    frames_per_block: int = 16,
    spare_blocks: int = 2,
    minor: int = 0,
) -> bytes:
    """An FSEQ v2 file of ``frames`` (uint8, frames × stored channels; with ``sparse_ranges``
    (0-based first channel, count) the stored channels are the ranges' in order)."""
    frames = np.ascontiguousarray(frames, dtype=np.uint8)
    n_frames, width = frames.shape
    ranges = list(sparse_ranges or [])
    if ranges:
        assert sum(n for _, n in ranges) == width, "the ranges must hold the stored channels"
    ctype = {"none": 0, "zstd": 1, "zlib": 2}[compression]
    blocks: list[tuple[int, bytes]] = []
    if ctype:
        starts = [0, *range(min(10, n_frames), n_frames, frames_per_block)]
        starts = sorted(set(s for s in starts if s < n_frames))
        for i, s in enumerate(starts):
            e = starts[i + 1] if i + 1 < len(starts) else n_frames
            blocks.append((s, _compress(compression, frames[s:e].tobytes())))
    n_index = len(blocks) + spare_blocks if ctype else 0
    var_bytes = b"".join(  # size counts its own 4 header bytes; the data NUL-terminated
        (4 + len(data) + 1).to_bytes(2, "little") + code.encode() + data + b"\0"
        for code, data in (variables or [])
    )
    header_len = 32 + 8 * n_index + 6 * len(ranges) + len(var_bytes)
    offset = header_len + (-header_len) % 4
    head = bytearray(32)
    head[0:4] = b"PSEQ"
    head[4:6] = offset.to_bytes(2, "little")
    head[6], head[7] = minor, 2
    head[8:10] = offset.to_bytes(2, "little")
    head[10:14] = width.to_bytes(4, "little")
    head[14:18] = n_frames.to_bytes(4, "little")
    head[18] = step_ms
    head[20] = ctype | ((n_index >> 8) << 4)
    head[21] = n_index & 0xFF
    head[22] = len(ranges)
    head[24:32] = UNIQUE_ID.to_bytes(8, "little")
    index = b"".join(s.to_bytes(4, "little") + len(d).to_bytes(4, "little") for s, d in blocks)
    index += bytes(8 * (n_index - len(blocks)))
    rng = b"".join(s.to_bytes(3, "little") + n.to_bytes(3, "little") for s, n in ranges)
    body = b"".join(d for _, d in blocks) if ctype else frames.tobytes()
    out = bytes(head) + index + rng + var_bytes
    return out + bytes(offset - len(out)) + body


def sparse_frames() -> tuple[np.ndarray, list[tuple[int, int]]]:
    """r51's channels 1-2 and 4 (xLights numbering) as two sparse ranges."""
    full = r51_frames()
    return full[:, [0, 1, 3]], [(0, 2), (3, 1)]


def write_samples(out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    frames = r51_frames()
    sparse, ranges = sparse_frames()
    files = {
        "r51.fseq": fseq_bytes(frames),
        "r51_zlib.fseq": fseq_bytes(frames, compression="zlib"),
        "r51_zstd.fseq": fseq_bytes(frames, compression="zstd"),
        "sparse.fseq": fseq_bytes(
            sparse, sparse_ranges=ranges, variables=[("sp", b"hilsim tools/samples_fseq.py")]
        ),
    }
    written = []
    for name, data in files.items():
        path = out_dir / name
        path.write_bytes(data)
        written.append(path)
    return written


def bench(repeat: int = 5) -> None:
    """Time the reader on a show-sized sequence: 5 min at 20 ms (15,000 frames) of 2,048
    channels, half of them changing every frame (random), four joints (two 16-bit pairs, two
    8-bit channels, one with zero = hold), from bytes in memory; min and median of ``repeat``."""
    import statistics
    import time

    from hilsim.targets.formats.fseq import FseqChannel, dmx_unit_map, parse_fseq

    rng = np.random.default_rng(1)
    frames = rng.integers(0, 256, (15000, 2048), dtype=np.uint8)
    frames[:, :1024] = (np.arange(15000)[:, None] // 7 % 256).astype(np.uint8)
    specs = {
        "pan": FseqChannel(1, dmx_unit_map((-90, 90)), fine=2),
        "tilt": FseqChannel(3, dmx_unit_map((-30, 30)), fine=4),
        "jaw": FseqChannel(1500, dmx_unit_map((0, 30), 8), zero="hold"),
        "tail": FseqChannel(2048, dmx_unit_map((-40, 40), 8)),
    }
    for kind in ("none", "zlib", "zstd"):
        data = fseq_bytes(frames, 20, compression=kind, frames_per_block=200)
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            parse_fseq(data, "bench.fseq").tracks(specs)
            times.append(time.perf_counter() - t0)
        print(
            f"fseq {kind:4s}: 15000 frames x 2048 channels ({len(data) / 1e6:.1f} MB), 4 tracks: "
            f"min {min(times) * 1e3:.0f} ms, median {statistics.median(times) * 1e3:.0f} ms"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parent.parent / "configs" / "animations" / "fseq"
    parser.add_argument("out_dir", nargs="?", type=Path, default=default)
    parser.add_argument("--bench", action="store_true", help="time the reader, write nothing")
    args = parser.parse_args()
    if args.bench:
        bench()
        return
    for path in write_samples(args.out_dir):
        print(f"{path} ({path.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
