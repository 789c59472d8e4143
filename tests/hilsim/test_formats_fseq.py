"""FSEQ -> tracks: the worked 16-bit numbers, uncompressed / zlib / zstd / sparse alike,
8-bit channels, "0 means hold", the extended block count, v1 files, bad inputs, fuzzing."""

from __future__ import annotations

import importlib.util
import math
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hilsim.targets.formats.common import FormatError, UnitMap
from hilsim.targets.formats.fseq import (
    FseqChannel,
    dmx_unit_map,
    parse_fseq,
    read_fseq,
)

ROOT = Path(__file__).resolve().parents[2]


def _tool(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


gen = _tool("samples_fseq")
R51 = gen.r51_frames()
PLAIN = gen.fseq_bytes(R51)
ZLIB = gen.fseq_bytes(R51, compression="zlib")
SPARSE_FRAMES, RANGES = gen.sparse_frames()
SPARSE = gen.fseq_bytes(SPARSE_FRAMES, sparse_ranges=RANGES, variables=[("mf", b"jaw.wav")])
PAN = FseqChannel(1, dmx_unit_map((-90, 90), bits=16), fine=2)


#: the shipped zstd sample (the generator needs zstandard to write it; reading it needs it too)
ZSTD = (ROOT / "configs" / "animations" / "fseq" / "r51_zstd.fseq").read_bytes()


def has_zstd() -> bool:
    return importlib.util.find_spec("zstandard") is not None


def zstd_file() -> bytes:
    pytest.importorskip("zstandard")
    return ZSTD


def deg(track, t: float) -> float:
    return math.degrees(track.sample(t)[0])


def test_review_numbers_16_bit_pan():
    """4 channels, 50 frames, 20 ms; channel 1 (xLights; index 0) = 5·frame, channel 2 = 0:
    -90.0° at t = 0, -2.108° at 0.500 s (frame 25: 125·256 = 32000)."""
    seq = parse_fseq(PLAIN, "r51.fseq")
    h = seq.header
    assert (h.channel_count, h.frame_count, h.step_ms, h.compression) == (4, 50, 20, "none")
    assert h.channel_data_offset == 32 and h.duration == 1.0
    track = seq.track(PAN)
    assert deg(track, 0.0) == pytest.approx(-90.0, abs=1e-9)
    assert deg(track, 0.500) == pytest.approx(-2.108, abs=5e-4)
    assert deg(track, 0.519) == deg(track, 0.500)  # frames are held
    assert track.duration == 1.0 and deg(track, 5.0) == deg(track, 0.99)
    linear = seq.track(FseqChannel(1, PAN.unit_map, fine=2, interpolation="linear"))
    assert deg(linear, 0.51) == pytest.approx((deg(track, 0.50) + deg(track, 0.52)) / 2)


def test_every_storage_gives_identical_tracks():
    forms = {"plain": PLAIN, "zlib": ZLIB, "sparse": SPARSE} | (
        {"zstd": ZSTD} if has_zstd() else {}
    )
    times = np.linspace(-0.1, 1.2, 651)
    specs = {
        "pan": PAN,
        "tail": FseqChannel(4, dmx_unit_map((0, 90), bits=8), interpolation="linear"),
    }
    ref = parse_fseq(PLAIN).tracks(specs)
    for name, data in forms.items():
        seq = parse_fseq(data, name)
        assert np.array_equal(seq.channel_values([1, 2, 4]), R51[:, [0, 1, 3]]), name
        for joint, track in seq.tracks(specs).items():
            for a, b in zip(track.sample_array(times), ref[joint].sample_array(times), strict=True):
                assert np.array_equal(a, b), (name, joint)
    assert [b[0] for b in parse_fseq(ZLIB).header.blocks] == [0, 10, 26, 42]  # FPP's first: 10
    assert np.array_equal(parse_fseq(b"FSEQ" + PLAIN[4:]).channel_values([1]), R51[:, [0]])


def test_the_shipped_samples_are_the_generators():
    """Uncompressed samples byte for byte; compressed ones by content (another zlib or zstd
    build may compress the same frames to other bytes). Without zstandard the zstd sample's
    header is checked, not its frames."""
    sparse = gen.fseq_bytes(
        SPARSE_FRAMES, sparse_ranges=RANGES, variables=[("sp", b"hilsim tools/samples_fseq.py")]
    )
    assert {p.name for p in (ROOT / "configs" / "animations" / "fseq").iterdir()} == {
        "r51.fseq", "r51_zlib.fseq", "r51_zstd.fseq", "sparse.fseq"
    }  # fmt: skip
    sample = ROOT / "configs" / "animations" / "fseq"
    assert (sample / "r51.fseq").read_bytes() == PLAIN
    assert (sample / "sparse.fseq").read_bytes() == sparse
    ref = parse_fseq(PLAIN).track(PAN).sample(0.5)
    for name in ("r51.fseq", "r51_zlib.fseq", "sparse.fseq") + (("r51_zstd.fseq",) * has_zstd()):
        seq = read_fseq(sample / name)
        assert np.array_equal(seq.channel_values([1, 2, 4]), R51[:, [0, 1, 3]]), name
        assert seq.track(PAN).sample(0.5) == ref
    zstd = read_fseq(sample / "r51_zstd.fseq").header
    assert (zstd.compression, zstd.frame_count, zstd.channel_count) == ("zstd", 50, 4)


# ------------------------------------------------------------------------------ v1
def v1_bytes(frames: np.ndarray, step_ms: int = 25, media: bytes = b"", magic=b"PSEQ") -> bytes:
    """An FSEQ v1 file written field by field from the published v1 layout: a 28-byte fixed
    header (flags 0, no universes, gamma 1, colour encoding 2 as xLights wrote them), an
    optional ``mf`` variable header, zeros to a multiple of 4, then the raw frames."""
    n, width = frames.shape
    var = struct.pack("<H2s", 4 + len(media) + 1, b"mf") + media + b"\0" if media else b""
    offset = -(-(28 + len(var)) // 4) * 4
    head = struct.pack(
        "<4sHBBHIIBBHHBB2x", magic, offset, 0, 1, 28, width, n, step_ms, 0, 0, 0, 1, 2
    )
    assert len(head) == 28
    return head + var + bytes(offset - 28 - len(var)) + frames.astype(np.uint8).tobytes()


#: 40 frames of 25 ms, 3 channels: 1 = 6·frame, 2 = 100 (a 16-bit pair), 3 = 250 - 5·frame
K40 = np.arange(40)
V1_FRAMES = np.stack([6 * K40, np.full(40, 100), 250 - 5 * K40], axis=1)
V1 = v1_bytes(V1_FRAMES, media=b"skull.mp3")


def test_v1_file_is_read_with_the_hand_computed_numbers():
    """Frame 20 (0.5 s): 120·256 + 100 = 30820 over -90..+90° -> -5.3491°; channel 3 at frame 8
    (0.2 s) is 210 -> 74.1176° over 0..90°; 40 frames of 25 ms last 1.0 s."""
    seq = parse_fseq(V1, "old.fseq")
    h = seq.header
    assert (h.major, h.minor, h.compression, h.sparse_ranges, h.unique_id) == (1, 0, "none", (), 0)
    assert (h.channel_count, h.frame_count, h.step_ms, h.duration) == (3, 40, 25, 1.0)
    assert h.channel_data_offset == 44 and h.media_file == "skull.mp3"  # 28 + 14, padded to 44
    pan = seq.track(PAN)
    assert deg(pan, 0.5) == pytest.approx(-5.3491, abs=5e-4)
    assert deg(pan, 0.524) == deg(pan, 0.5)  # held for its 25 ms
    tail = seq.track(FseqChannel(3, dmx_unit_map((0, 90), bits=8)))
    assert deg(tail, 0.2) == pytest.approx(74.1176, abs=5e-4)
    assert seq.values(FseqChannel(3, dmx_unit_map((0, 90), bits=8)))[39] == 55  # 250 - 195


def test_v1_and_v2_of_the_same_frames_give_identical_tracks(tmp_path):
    v2 = parse_fseq(gen.fseq_bytes(V1_FRAMES.astype(np.uint8), 25))
    (tmp_path / "old.fseq").write_bytes(v1_bytes(V1_FRAMES, magic=b"FSEQ"))  # the oldest magic
    v1 = read_fseq(tmp_path / "old.fseq")
    assert v1.header.media_file == ""
    times = np.linspace(-0.1, 1.2, 261)
    for spec in (PAN, FseqChannel(3, dmx_unit_map((0, 90), bits=8), interpolation="linear")):
        for a, b in zip(v1.track(spec).sample_array(times), v2.track(spec).sample_array(times),
                        strict=True):  # fmt: skip
            assert np.array_equal(a, b)
    with pytest.raises(FormatError, match=r"old\.fseq:channel 4: beyond the file: it holds "
                       r"channels 1-3"):  # fmt: skip
        v1.track(FseqChannel(4, PAN.unit_map))


def test_8_bit_channel_and_zero_means_hold():
    seq = parse_fseq(PLAIN)
    tail_map = dmx_unit_map((0, 90), bits=8)
    tail = seq.track(FseqChannel(4, tail_map))
    assert seq.values(FseqChannel(4, tail_map))[10] == 205  # 255 - 5·10
    assert deg(tail, 0.0) == pytest.approx(90.0)
    assert deg(tail, 0.2) == pytest.approx(90 * 205 / 255)
    jaw = UnitMap((0, 255), (0, 30), "DMX")
    as_value = seq.values(FseqChannel(3, jaw))
    held = seq.values(FseqChannel(3, jaw, zero="hold"))
    assert as_value[12] == 0 and held[12] == 200  # 0 between moves holds the last position
    assert held[:5].tolist() == [200] * 5  # before the first non-zero frame: that frame's value
    assert held[45] == 120 and np.all(held > 0)
    with pytest.raises(FormatError, match=r"x:channel 2: is 0 in every frame: with zero = hold"):
        parse_fseq(PLAIN, "x").track(FseqChannel(2, jaw, zero="hold"))


def test_a_channel_beyond_the_file_or_outside_every_sparse_range_is_named():
    with pytest.raises(FormatError, match=r"a\.fseq:channel 5: beyond the file: it holds "
                       r"channels 1-4 \(1-based, as xLights numbers them\)$"):  # fmt: skip
        parse_fseq(PLAIN, "a.fseq").track(FseqChannel(1, PAN.unit_map, fine=5))
    with pytest.raises(FormatError, match=r"s:channel 3: outside every sparse range: it holds "
                       r"channels 1-2, 4 \(1-based"):  # fmt: skip
        parse_fseq(SPARSE, "s").track(FseqChannel(3, PAN.unit_map))
    seq = parse_fseq(SPARSE)
    assert seq.header.media_file == "jaw.wav"
    assert seq.header.frame_index(4) == 2 and seq.header.frame_index(3) is None


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"channel": 0}, "channel must be a channel number ≥ 1"),
        ({"channel": True}, "channel must be"),
        ({"fine": 1}, "fine must be another channel"),
        ({"zero": "skip"}, "zero must be one of value, hold"),
        ({"interpolation": "cubic"}, "interpolation must be one of"),
    ],
)
def test_impossible_channel_specs_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        FseqChannel(**({"channel": 1, "unit_map": PAN.unit_map} | kwargs))
    with pytest.raises(ValueError, match="bits must be 8 or 16"):
        dmx_unit_map((0, 1), bits=12)


def test_extended_block_count_past_255_blocks():
    frames = np.tile(np.arange(300, dtype=np.uint8)[:, None], (1, 3))
    data = gen.fseq_bytes(frames, 25, compression="zlib", frames_per_block=1, minor=1)
    assert data[20] >> 4 == 1  # bits 8-11 of the count in the compression byte's high nibble
    seq = parse_fseq(data)
    assert len(seq.header.blocks) == 291 and seq.header.compression == "zlib"
    assert np.array_equal(seq.channel_values([3]), frames[:, [2]])


def test_zstd_without_the_package_says_which_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "zstandard", None)
    with pytest.raises(
        FormatError, match=r"z\.fseq: zstd-compressed: .*\(pip install 'hilsim\[fseq\]'\)$"
    ):
        parse_fseq(ZSTD, "z.fseq").track(PAN)


def patch(data: bytes, at: int, new: bytes) -> bytes:
    return data[:at] + new + data[at + len(new) :]


def u32(x: int) -> bytes:
    return x.to_bytes(4, "little")


Z_BLOCK0, *_, Z_LAST = parse_fseq(ZLIB).header.blocks  # (first frame, offset, size) each
BAD = [
    (b"", r"x: empty file"),
    (b"RIFF" + PLAIN[4:], r"x:byte 0: not an FSEQ file: starts with b'RIFF', not b'PSEQ'"),
    (b"ESEQ" + PLAIN[4:], r"x:byte 0: an ESEQ effect sequence"),
    (PLAIN[:20], r"x:byte 20: truncated: 20 bytes, the FSEQ header alone is 32"),
    (PLAIN[:6], r"x:byte 6: truncated: 6 bytes, the FSEQ header alone is 32"),
    (patch(PLAIN, 7, b"\x03"), r"x:byte 7: FSEQ version 3\.0: versions 1 and 2 are read"),
    (V1[:27], r"x:byte 27: truncated: 27 bytes, the FSEQ header alone is 28"),
    (
        patch(V1, 4, b"\x18\x00"),
        r"x:byte 4: channel data offset 24 is not between the end "
        r"of the v1 header \(28\) and the file's end \(164\)",
    ),
    (patch(V1, 10, u32(0)), r"x:byte 10: 0 channels per frame"),
    (patch(V1, 18, b"\x00"), r"x:byte 18: a frame step of 0 ms"),
    (
        V1[:-2],
        r"x:byte 162: truncated: 40 frames of 3 channels need 120 bytes from byte 44, "
        r"the file has 118 \(frame 39 is incomplete\)",
    ),
    (V1 + b"\0" * 3, r"x:byte 164: 3 bytes after the last of 40 frames"),
    (patch(V1, 28, b"\x40\x00"), r"x:byte 28: variable header of 64 bytes does not fit"),
    (patch(PLAIN, 20, b"\x03"), r"x:byte 20: compression type 3"),
    (patch(PLAIN, 10, u32(0)), r"x:byte 10: 0 channels per frame"),
    (patch(PLAIN, 14, u32(0)), r"x:byte 14: 0 frames"),
    (patch(PLAIN, 18, b"\x00"), r"x:byte 18: a frame step of 0 ms"),
    (patch(PLAIN, 4, b"\xff\x00"), r"x:byte 4: channel data offset 255 is not between"),
    (patch(PLAIN, 22, b"\x05"), r"x:byte 4: channel data offset 32 is not between .* \(62\)"),
    (
        PLAIN[:-3],
        r"x:byte 229: truncated: 50 frames of 4 channels need 200 bytes .*\(frame 49 is incomplete\)",
    ),
    (PLAIN + b"\0", r"x:byte 232: 1 bytes after the last of 50 frames"),
    (
        patch(PLAIN, 14, u32(0xFFFFFFFF)),
        r"byte 14: 4294967295 frames \(23860\.9 h at 20 ms\): "
        r"more than the 10,000,000",
    ),
    (patch(PLAIN, 14, u32(10_000_000)), r"truncated: 10000000 frames of 4 channels"),
    (patch(PLAIN, 10, u32(0xFFFFFFFF)), r"truncated: 50 frames of 4294967295 channels"),
    (patch(SPARSE, 10, u32(4)), r"x:byte 10: 4 channels per frame, but the sparse ranges hold 3"),
    (patch(SPARSE, 35, b"\x00\x00\x00"), r"x:byte 35: sparse range 0 holds 0 channels"),
    (patch(SPARSE, 38, b"\x01\x00\x00"), r"x:byte 38: sparse range 1 \(channels 2-2\) overlaps"),
    (patch(SPARSE, 44, b"\xff\x00"), r"x:byte 44: variable header of 255 bytes does not fit"),
    (patch(SPARSE, 44, b"\x02\x00"), r"x:byte 44: variable header of 2 bytes"),
    # (the compressed sizes are this zlib build's: the messages are built from them)
    (
        ZLIB[:-1],
        rf"x:byte 56: truncated: block 3 \({Z_LAST[2]} bytes at byte {Z_LAST[1]}\) runs "
        r"past the end",
    ),
    (ZLIB + b"\0\0", rf"x:byte {len(ZLIB)}: 2 bytes after the last compressed block"),
    (
        patch(ZLIB, 40, u32(0)),
        r"x:byte 40: block 1 starts at frame 0: blocks must start at frame 0 and go up",
    ),
    (patch(ZLIB, 32, u32(3)), r"x:byte 32: block 0 starts at frame 3"),
    (patch(ZLIB, 56, u32(60)), r"x:byte 56: block 3 starts at frame 60"),
    (patch(ZLIB, 40, u32(9)), r"x:block 0: decompresses to more than its 9 frames \(frames 0-8\)"),
    (patch(ZLIB, 40, u32(11)), r"x:block 0: truncated: decompresses to 40 bytes, its 11 frames"),
    (patch(ZLIB, 14, u32(10_000_000)), r"x:block 3: truncated: decompresses to 32 bytes"),
    (patch(ZLIB, Z_BLOCK0[1], b"\xff\xff"), r"x:block 0: bad zlib data"),
    (patch(ZLIB, Z_BLOCK0[1] + Z_BLOCK0[2] - 8, b"\0" * 8), r"x:block 0: bad zlib data"),
]


@pytest.mark.parametrize(("data", "match"), BAD)
def test_bad_input_is_one_format_error_naming_file_and_position(data, match):
    with pytest.raises(FormatError, match=match) as info:
        parse_fseq(data, "x").channel_values([1])
    assert str(info.value).startswith("x:") and "\n" not in str(info.value)


def test_bad_zstd_data_is_named_by_block():
    data = zstd_file()
    _first, at, _size = parse_fseq(data).header.blocks[1]
    with pytest.raises(FormatError, match=r"x:block 1: bad zstd data"):
        parse_fseq(patch(data, at, b"\0\0\0\0"), "x").channel_values([1])
    with pytest.raises(FormatError, match=r"x:block 3: truncated: decompresses to 32 bytes, its"):
        parse_fseq(patch(data, 14, u32(51)), "x").channel_values([1])


def test_a_file_without_block_index_is_one_block_as_fpp_reads_it():
    body = zlib.compress(R51.tobytes())
    data = gen.fseq_bytes(R51[:0].reshape(0, 4), compression="none")  # header shape only
    data = bytearray(data[:32])
    data[14:18] = u32(50)
    data[20] = 2
    assert np.array_equal(parse_fseq(bytes(data) + body).channel_values([1, 2, 3, 4]), R51)


def test_read_fseq_names_a_missing_file(tmp_path):
    with pytest.raises(FormatError, match=r"nope\.fseq: cannot read"):
        read_fseq(tmp_path / "nope.fseq")


def _only_format_errors(data: bytes) -> None:
    """Parse and read the first channel the file holds: a FormatError or values, nothing else."""
    try:
        seq = parse_fseq(data, "f.fseq")
        first = seq.header.sparse_ranges[0][0] + 1 if seq.header.sparse_ranges else 1
        assert seq.channel_values([first]).shape == (seq.header.frame_count, 1)
    except FormatError:
        return


@given(st.binary(max_size=200))
def test_random_bytes_give_a_format_error_or_values(data):
    _only_format_errors(data)
    _only_format_errors(b"PSEQ" + data)


@given(st.sampled_from(["plain", "zlib", "sparse", "v1"]), st.data())
def test_mangled_files_give_a_format_error_or_values(form, draw):
    data = bytearray({"plain": PLAIN, "zlib": ZLIB, "sparse": SPARSE, "v1": V1}[form])
    for _ in range(draw.draw(st.integers(1, 4))):
        i = draw.draw(st.integers(0, len(data) - 1))
        op = draw.draw(st.sampled_from(["set", "set", "cut", "insert"]))
        if op == "set":
            data[i] = draw.draw(st.integers(0, 255))
        elif op == "cut":
            del data[i:]
        else:
            data[i:i] = draw.draw(st.binary(min_size=1, max_size=6))
        if not data:
            break
    _only_format_errors(bytes(data))


@given(st.data())
def test_mangled_zstd_gives_a_format_error_or_values(draw):
    data = bytearray(zstd_file())
    i = draw.draw(st.integers(32, len(data) - 1))
    data[i] = draw.draw(st.integers(0, 255))
    _only_format_errors(bytes(data))
