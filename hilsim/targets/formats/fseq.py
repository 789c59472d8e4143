"""FSEQ sequences, v2 and v1 (xLights, Falcon Player), as tracks in joint radians.

A sequence is frames of one byte per channel, one frame every ``step`` ms. Each frame is held
until the next, as FPP plays them. Version 2 may be compressed (zstd, zlib) and may hold sparse
channel ranges; version 1 is plain. Channels are 1-based, as xLights shows them. A 16-bit
value is a coarse and a fine channel (``fine=``). ``zero="hold"`` (xLights' servo option)
makes a 0 hold the last position.

The rig's use is one call::

    seq = read_fseq(path)
    tracks = seq.tracks({"pan": FseqChannel(1, dmx_unit_map((-90, 90), bits=16), fine=2)})

``zstandard`` (``pip install 'hilsim[fseq]'``) is imported only for a zstd-compressed file.
Every bad input is one :class:`~hilsim.targets.formats.common.FormatError` naming the file and
the position (``byte``, ``block``, ``channel``). No header count is trusted before it is
checked against the file's size. The byte layout and the rules: ``docs/targets.md`` (FSEQ).
"""

from __future__ import annotations

import mmap
import os
import zlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hilsim.targets.formats.common import INTERPOLATIONS, FormatError, SampledTrack, UnitMap

MAGICS = (b"PSEQ", b"FSEQ")  # FPP reads both; the oldest files say FSEQ
HEADER_SIZE, BLOCK_SIZE, RANGE_SIZE = 32, 8, 6
V1_HEADER_SIZE = 28
COMPRESSIONS = {0: "none", 1: "zstd", 2: "zlib"}
ZERO_MODES = ("value", "hold")
#: bytes decompressed at a time (memory stays bounded whatever a header claims)
CHUNK = 1 << 20
#: the most frames read (27.8 h at 10 ms): each is a sample of every track made from the file
MAX_FRAMES = 10_000_000
EXTRA_HINT = "pip install 'hilsim[fseq]'"
#: a file's bytes: read into memory, or a read-only map of the file
Data = bytes | mmap.mmap
#: a FormatError at a place in the file (``"byte 4"``) with its message
_Bad = Callable[[str, str], FormatError]


def dmx_unit_map(degrees: tuple[float, float], bits: int = 16) -> UnitMap:
    """DMX full range -> ``degrees``: 0 -> degrees[0], 255 (8-bit) or 65535 (16-bit) ->
    degrees[1]."""
    if bits not in (8, 16):
        raise ValueError(f"bits must be 8 or 16, got {bits!r}")
    return UnitMap((0, (1 << bits) - 1), degrees, f"DMX {bits}-bit")


@dataclass(frozen=True)
class FseqChannel:
    """Which channel(s) feed a joint and how: ``channel`` (1-based, as xLights shows it) is the
    8-bit value or a 16-bit pair's coarse byte, ``fine`` the pair's fine byte (None: 8-bit);
    ``unit_map`` takes the value (0-255 or 0-65535) to joint degrees; ``zero`` "value" (0 is a
    position) or "hold" (0 holds the last position); ``interpolation`` "hold" or "linear"."""

    channel: int
    unit_map: UnitMap
    fine: int | None = None
    zero: str = "value"
    interpolation: str = "hold"

    def __post_init__(self) -> None:
        for name in ("channel", "fine"):
            value = getattr(self, name)
            if value is None and name == "fine":
                continue
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(
                    f"{name} must be a channel number ≥ 1 (1-based, as xLights shows it), "
                    f"got {value!r}"
                )
        if self.fine == self.channel:
            raise ValueError(f"fine must be another channel than coarse ({self.channel})")
        if self.zero not in ZERO_MODES:
            raise ValueError(f"zero must be one of {', '.join(ZERO_MODES)}, got {self.zero!r}")
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(
                f"interpolation must be one of {', '.join(INTERPOLATIONS)}, "
                f"got {self.interpolation!r}"
            )


@dataclass(frozen=True)
class FseqHeader:
    """The header of a v1 or v2 file, checked against the file's size. ``blocks``: (first frame,
    offset from the start of the file, size) of each used compressed block; ``sparse_ranges``:
    (first channel 0-based, count); ``variables``: (code, data) in file order."""

    major: int
    minor: int
    channel_data_offset: int
    channel_count: int
    frame_count: int
    step_ms: int
    compression: str
    blocks: tuple[tuple[int, int, int], ...]
    sparse_ranges: tuple[tuple[int, int], ...]
    variables: tuple[tuple[str, bytes], ...]
    unique_id: int

    @property
    def duration(self) -> float:
        """The sequence's length (s): frames × step."""
        return self.frame_count * self.step_ms / 1000.0

    @property
    def media_file(self) -> str:
        """The ``mf`` variable (the audio FPP plays with it), or ""."""
        for code, data in self.variables:
            if code == "mf":
                return data.split(b"\0", 1)[0].decode("utf-8", "replace")
        return ""

    def frame_index(self, channel: int) -> int | None:
        """Where 1-based ``channel`` sits in a stored frame; None when the file lacks it."""
        c = channel - 1
        if not self.sparse_ranges:
            return c if 0 <= c < self.channel_count else None
        offset = 0
        for start, count in self.sparse_ranges:
            if start <= c < start + count:
                return offset + c - start
            offset += count
        return None

    def describe_channels(self) -> str:
        """The channels the file holds, 1-based: ``1-4`` or ``101-148, 201-210``."""
        if not self.sparse_ranges:
            return f"1-{self.channel_count}"
        return ", ".join(f"{s + 1}-{s + n}" if n > 1 else f"{s + 1}" for s, n in self.sparse_ranges)


# long on purpose: the header's fields in file order, each checked
def parse_header(data: Data, path: str | Path = "<bytes>") -> FseqHeader:  # noqa: C901, PLR0912
    """The checked header of ``data`` (bytes, or any buffer such as an mmap)."""
    size = len(data)

    def bad(where: str, message: str) -> FormatError:
        return FormatError(path, where, message)

    if size == 0:
        raise bad("", "empty file")
    if data[:4] not in MAGICS:
        if data[:4] == b"ESEQ":
            raise bad("byte 0", "an ESEQ effect sequence, not an FSEQ sequence")
        raise bad("byte 0", f"not an FSEQ file: starts with {bytes(data[:4])!r}, not b'PSEQ'")
    major = data[7] if size > 7 else 2
    fixed = V1_HEADER_SIZE if major == 1 else HEADER_SIZE
    if size < fixed:
        raise bad(f"byte {size}", f"truncated: {size} bytes, the FSEQ header alone is {fixed}")
    if major not in (1, 2):
        raise bad("byte 7", f"FSEQ version {major}.{data[6]}: versions 1 and 2 are read "
                  "(xLights saves v2: open the sequence there and save it again)")  # fmt: skip
    u16: Callable[[int], int]  # the little-endian number at a byte offset
    u32: Callable[[int], int]
    u16, u32 = (lambda o, n=n: int.from_bytes(data[o : o + n], "little") for n in (2, 4))
    minor, offset, channels, frames, step = data[6], u16(4), u32(10), u32(14), data[18]
    ctype = n_ranges = n_blocks = 0  # v1: uncompressed, every channel
    if major == 2:
        ctype, n_ranges = data[20] & 0x0F, data[22]
        n_blocks = ((data[20] & 0xF0) << 4) | data[21]  # v2.1: bits 8-11 in the high nibble
    if ctype not in COMPRESSIONS:
        raise bad("byte 20", f"compression type {ctype}: known are 0 (none), 1 (zstd), 2 (zlib)")
    if frames > MAX_FRAMES:
        raise bad("byte 14", f"{frames} frames ({frames * step / 3.6e6:.1f} h at {step} ms): "
                  f"more than the {MAX_FRAMES:,} frames a track may hold")  # fmt: skip
    for at, value, what in ((10, channels, "0 channels per frame"), (14, frames, "0 frames"),
                            (18, step, "a frame step of 0 ms")):  # fmt: skip
        if value == 0:
            raise bad(f"byte {at}", what)
    tables_end = fixed + n_blocks * BLOCK_SIZE + n_ranges * RANGE_SIZE
    if not tables_end <= offset <= size:
        tables = "block index and sparse ranges" if major == 2 else "v1 header"
        raise bad("byte 4", f"channel data offset {offset} is not between the end of the "
                  f"{tables} ({tables_end}) and the file's end ({size})")  # fmt: skip
    ranges = _ranges(data, fixed + n_blocks * BLOCK_SIZE, n_ranges, bad)
    if ranges and sum(n for _, n in ranges) != channels:
        held = sum(n for _, n in ranges)
        raise bad("byte 10", f"{channels} channels per frame, but the sparse ranges hold {held}")
    variables = _variables(data, tables_end, offset, bad)
    need = frames * channels  # Python ints: a hostile count allocates nothing
    blocks: list[tuple[int, int, int]] = []
    if ctype == 0 and size - offset < need:
        raise bad(f"byte {size}", f"truncated: {frames} frames of {channels} channels need {need} "
                  f"bytes from byte {offset}, the file has {size - offset} (frame "
                  f"{(size - offset) // channels} is incomplete)")  # fmt: skip
    if ctype == 0 and size - offset > need:
        raise bad(f"byte {offset + need}", f"{size - offset - need} bytes after the last of "
                  f"{frames} frames")  # fmt: skip
    if ctype:
        at = offset
        for b in range(n_blocks):
            first, length = u32(HEADER_SIZE + b * BLOCK_SIZE), u32(HEADER_SIZE + b * BLOCK_SIZE + 4)
            where = f"byte {HEADER_SIZE + b * BLOCK_SIZE}"
            if length == 0:
                continue  # an unused index entry
            previous = blocks[-1][0] if blocks else -1
            if first >= frames or first <= previous or (not blocks and first):
                raise bad(where, f"block {b} starts at frame {first}: blocks must start at frame "
                          f"0 and go up, below the frame count {frames}")  # fmt: skip
            if at + length > size:
                raise bad(where, f"truncated: block {b} ({length} bytes at byte {at}) runs past "
                          f"the end of the file ({size} bytes)")  # fmt: skip
            blocks.append((first, at, length))
            at += length
        if not blocks:  # FPP reads such a file as one block of everything after the header
            blocks, at = [(0, offset, size - offset)], size
        if at != size:
            raise bad(f"byte {at}", f"{size - at} bytes after the last compressed block")
    head = (major, minor, offset, channels, frames, step, COMPRESSIONS[ctype], tuple(blocks))
    unique_id = u32(24) | u32(28) << 32 if major == 2 else 0
    return FseqHeader(*head, tuple(ranges), tuple(variables), unique_id)


def _ranges(data: Data, pos: int, n: int, bad: _Bad) -> list[tuple[int, int]]:
    """The sparse ranges (first channel 0-based, count): none empty, none overlapping."""
    ranges: list[tuple[int, int]] = []
    for r in range(n):
        at = pos + r * RANGE_SIZE
        start, count = (int.from_bytes(data[o : o + 3], "little") for o in (at, at + 3))
        if count == 0:
            raise bad(f"byte {at + 3}", f"sparse range {r} holds 0 channels")
        for s, c in ranges:
            if start < s + c and s < start + count:
                raise bad(f"byte {at}", f"sparse range {r} (channels {start + 1}-{start + count})"
                          f" overlaps channels {s + 1}-{s + c}")  # fmt: skip
        ranges.append((start, count))
    return ranges


def _variables(data: Data, start: int, end: int, bad: _Bad) -> list[tuple[str, bytes]]:
    out: list[tuple[str, bytes]] = []
    pos = start
    while pos + 4 <= end:
        length = int.from_bytes(data[pos : pos + 2], "little")
        if length == 0:  # padding to a 4-byte boundary (FPP skips 4 bytes)
            pos += 4
            continue
        if length < 4 or pos + length > end:
            raise bad(f"byte {pos}", f"variable header of {length} bytes does not fit between "
                      f"byte {pos} and the channel data at byte {end}")  # fmt: skip
        code = bytes(data[pos + 2 : pos + 4]).decode("latin-1")
        out.append((code, bytes(data[pos + 4 : pos + length])))
        pos += length
    return out


@dataclass(frozen=True, eq=False)
class FseqFile:
    """A checked file (v1 or v2): its header and its bytes (``data``: bytes or a read-only mmap)."""

    path: str
    header: FseqHeader
    data: Data

    def channel_values(self, channels: Sequence[int]) -> np.ndarray:
        """The raw bytes of 1-based ``channels`` in every frame: uint8 ``(frames, len)``."""
        h = self.header
        cols = []
        for ch in channels:
            if not isinstance(ch, int) or isinstance(ch, bool) or ch < 1:
                raise ValueError(f"channel must be a number ≥ 1 (1-based), got {ch!r}")
            idx = h.frame_index(ch)
            if idx is None:
                where = "outside every sparse range" if h.sparse_ranges else "beyond the file"
                raise FormatError(self.path, f"channel {ch}", f"{where}: it holds channels "
                                  f"{h.describe_channels()} (1-based, as xLights numbers "
                                  "them)")  # fmt: skip
            cols.append(idx)
        wanted = np.array(cols, dtype=np.int64)
        if h.compression == "none":
            n = h.frame_count * h.channel_count
            raw = np.frombuffer(self.data, np.uint8, count=n, offset=h.channel_data_offset)
            return raw.reshape(h.frame_count, h.channel_count)[:, wanted]
        return self._decompressed(wanted)

    def _decompressed(self, idx: np.ndarray) -> np.ndarray:
        """Block by block, a chunk at a time: only the wanted columns are kept (copied out of
        each chunk), so memory is frames × len(idx) bytes whatever the frame's width."""
        h, width = self.header, self.header.channel_count
        columns: list[list[np.ndarray]] = [[] for _ in range(idx.size)]
        for b, (first, at, length) in enumerate(h.blocks):
            end = h.blocks[b + 1][0] if b + 1 < len(h.blocks) else h.frame_count
            expect, got = (end - first) * width, 0
            frames = f"{end - first} frames (frames {first}-{end - 1})"
            for chunk in _chunks(h.compression, bytes(self.data[at : at + length]), self.path, b):
                if got + len(chunk) > expect:
                    raise FormatError(self.path, f"block {b}", f"decompresses to more than its "
                                      f"{frames} of {width} channels")  # fmt: skip
                buf, start = np.frombuffer(chunk, np.uint8), first * width + got
                for j, c in enumerate(idx.tolist()):
                    columns[j].append(buf[(c - start) % width :: width].copy())
                got += len(chunk)
            if got != expect:
                raise FormatError(self.path, f"block {b}", f"truncated: decompresses to {got} "
                                  f"bytes, its {frames} need {expect}")  # fmt: skip
        return np.stack([np.concatenate(col) for col in columns], axis=1)

    def values(self, spec: FseqChannel) -> np.ndarray:
        """The channel's value per frame (float64; 8-bit 0-255 or 16-bit 0-65535), zeros held
        when ``spec.zero == "hold"``."""
        chans = [spec.channel] if spec.fine is None else [spec.channel, spec.fine]
        raw = self.channel_values(chans).astype(np.float64)
        v = raw[:, 0] if spec.fine is None else raw[:, 0] * 256.0 + raw[:, 1]
        return _hold_zeros(v, self.path, spec) if spec.zero == "hold" else v

    def track(self, spec: FseqChannel) -> SampledTrack:
        """One joint's track (radians) from ``spec``."""
        return self._track(spec, self.values(spec))

    def tracks(self, specs: Mapping[str, FseqChannel]) -> dict[str, SampledTrack]:
        """A track per joint, every channel decompressed in one pass."""
        chans = sorted({c for s in specs.values() for c in (s.channel, s.fine) if c is not None})
        if not chans:
            return {}
        raw = self.channel_values(chans).astype(np.float64)
        col = {c: raw[:, i] for i, c in enumerate(chans)}
        out = {}
        for name, s in specs.items():
            v = col[s.channel] if s.fine is None else col[s.channel] * 256.0 + col[s.fine]
            out[name] = self._track(s, _hold_zeros(v, self.path, s) if s.zero == "hold" else v)
        return out

    def _track(self, spec: FseqChannel, values: np.ndarray) -> SampledTrack:
        h = self.header
        times = np.arange(h.frame_count + 1, dtype=np.float64) * (h.step_ms / 1000.0)
        rad = spec.unit_map.to_rad(np.append(values, values[-1]))
        name = f"channel {spec.channel}" + (f"/{spec.fine}" if spec.fine is not None else "")
        return SampledTrack(times, rad, spec.interpolation, source=f"{self.path} {name}")


def read_fseq(path: str | Path) -> FseqFile:
    """Open and check ``path``; the channel data is read (through a read-only mmap, so a large
    file is not copied into memory) when a channel is asked for."""
    p = Path(path)
    try:
        with p.open("rb") as f:
            size = os.fstat(f.fileno()).st_size
            data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
    except (OSError, ValueError) as exc:
        raise FormatError(p, "", f"cannot read: {getattr(exc, 'strerror', None) or exc}") from None
    return parse_fseq(data, p)


def parse_fseq(data: Data, path: str | Path = "<bytes>") -> FseqFile:
    """:func:`read_fseq` on bytes already read."""
    return FseqFile(str(path), parse_header(data, path), data)


# --------------------------------------------------------------------------------- helpers


def _chunks(compression: str, block: bytes, path: str, b: int) -> Iterator[bytes]:
    """Decompressed pieces of one block, at most CHUNK bytes each."""
    if compression == "zlib":
        d = zlib.decompressobj()
        rest = block
        try:
            while rest:
                piece = d.decompress(rest, CHUNK)
                rest = d.unconsumed_tail
                if piece:
                    yield piece
                elif d.eof or not rest:
                    break
            if not d.eof:
                raise FormatError(path, f"block {b}", "truncated: the zlib stream does not end")
        except zlib.error as exc:
            raise FormatError(path, f"block {b}", f"bad zlib data: {exc}") from None
        return
    try:
        import zstandard
    except ImportError:
        raise FormatError(
            path, "", f"zstd-compressed: reading it needs the zstandard package ({EXTRA_HINT})"
        ) from None
    try:
        reader = zstandard.ZstdDecompressor().stream_reader(block, read_across_frames=False)
        while piece := reader.read(CHUNK):
            yield piece
    except zstandard.ZstdError as exc:
        raise FormatError(path, f"block {b}", f"bad zstd data: {exc}") from None


def _hold_zeros(v: np.ndarray, path: str, spec: FseqChannel) -> np.ndarray:
    nz = np.flatnonzero(v != 0)
    if nz.size == 0:
        raise FormatError(
            path,
            f"channel {spec.channel}",
            "is 0 in every frame: with zero = hold there is no position to hold",
        )
    last = np.searchsorted(nz, np.arange(v.size), side="right") - 1
    return v[nz[np.maximum(last, 0)]]
