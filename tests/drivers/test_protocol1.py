"""drivers.protocol1: packets against the reference note's vectors, and the encodings' laws.

Vectors: PING, READ and SYNC READ as worked out by hand from the framing rules (LEN = params + 2,
CHK = ~sum & 0xFF); the cycle arithmetic of 12 servos at 1 Mbit/s likewise.
"""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.protocol1 import packet as p1
from drivers.protocol1.control_table import (
    AX_12A,
    FEETECH_SCS,
    FEETECH_STS,
    MX_64,
    SCS0009,
    STS3215,
    TABLES,
    table_for,
)
from drivers.protocol1.encoding import (
    decode_word,
    encode_word,
    from_sign_magnitude,
    to_sign_magnitude,
)
from drivers.protocol1.wire_time import ReadMethod, cycle_time_s, sync_read_time_s


def test_reference_vectors() -> None:
    assert p1.ping(1) == bytes.fromhex("FF FF 01 02 01 FB")
    assert p1.read(1, 56, 2) == bytes.fromhex("FF FF 01 04 02 38 02 BE")
    assert p1.sync_read(56, 2, [1, 2]) == bytes.fromhex("FF FF FE 06 82 38 02 01 02 3C")


def test_status_and_group_packets() -> None:
    # AX-12A ID 1 answering a 2-byte read of 512: FF FF 01 04 00 00 02 ~(1+4+0+0+2)
    assert p1.encode_status(1, 0, b"\x00\x02") == bytes.fromhex("FF FF 01 04 00 00 02 F8")
    sw = p1.sync_write(30, 2, {1: b"\x00\x02", 2: b"\xff\x03"})
    assert sw == bytes.fromhex("FF FF FE 0A 83 1E 02 01 00 02 02 FF 03") + bytes((sw[-1],))
    assert sw[-1] == ~sum(sw[2:-1]) & 0xFF
    assert p1.parse_sync_write(p1.decode(sw).params) == (30, {1: b"\x00\x02", 2: b"\xff\x03"})
    br = p1.bulk_read([(1, 36, 2), (2, 36, 2)])
    assert br[:7] == bytes.fromhex("FF FF FE 09 92 00 02")
    assert p1.parse_bulk_read(p1.decode(br).params) == [(1, 36, 2), (2, 36, 2)]
    assert p1.parse_sync_read(p1.decode(p1.sync_read(56, 2, [1, 2])).params) == (56, 2, [1, 2])


def test_decode_refuses_bad_checksum_and_length() -> None:
    good = p1.ping(3)
    with pytest.raises(p1.PacketError, match="checksum"):
        p1.decode(good[:-1] + bytes((good[-1] ^ 1,)))
    with pytest.raises(p1.PacketError, match="LEN"):
        p1.decode(good + b"\x00")


def test_stream_parser_resynchronises() -> None:
    parser = p1.StreamParser()
    stream = b"\x00\xff" + p1.ping(1) + b"\xff" + p1.read(2, 36, 2)
    frames = [decoded for _, decoded in parser.feed_decoded(stream[:7])]
    frames += [decoded for _, decoded in parser.feed_decoded(stream[7:])]
    assert [(f[1], f[2], f[3]) for f in frames] == [(1, True, 1), (2, True, 2)]
    bad = bytearray(p1.ping(4))
    bad[-1] ^= 0xFF
    assert parser.feed(bytes(bad)) == [None]


def test_status_stream_split() -> None:
    stream = p1.encode_status(1, 0, b"\x10\x00") + p1.encode_status(6, 0x20, b"\x11\x00")
    assert [(pk.id, pk.code, pk.params) for pk in p1.split_status_stream(stream)] == [
        (1, 0, b"\x10\x00"),
        (6, 0x20, b"\x11\x00"),
    ]


@given(st.integers(0, 0xFD), st.sampled_from(list(p1.Inst)), st.binary(max_size=40))
def test_frame_round_trip(pid: int, inst: int, params: bytes) -> None:
    frame = p1.encode_instruction(pid, inst, params)
    assert frame[3] == len(params) + 2
    assert (sum(frame[2:]) & 0xFF) == 0xFF  # the checksum makes the body sum to FF
    assert p1.decode(frame) == p1.Packet(pid, inst, params)


@given(st.integers(-32767, 32767))
def test_sign_magnitude_round_trip_bit15(v: int) -> None:
    raw = to_sign_magnitude(v, 15)
    assert 0 <= raw <= 0xFFFF and (raw >> 15) == (v < 0)
    assert from_sign_magnitude(raw, 15) == v


@given(st.integers(-2047, 2047))
def test_sign_magnitude_round_trip_bit11(v: int) -> None:
    assert from_sign_magnitude(to_sign_magnitude(v, 11), 11) == v


def test_sign_magnitude_is_not_twos_complement() -> None:
    assert to_sign_magnitude(-1, 15) == 0x8001
    assert STS3215.item("Present Position").encode(-5) == b"\x05\x80"
    assert STS3215.item("Homing Offset").encode(-5) == b"\x05\x08"
    assert from_sign_magnitude(0x8000, 15) == 0  # "-0"
    with pytest.raises(ValueError, match="sign bit"):
        to_sign_magnitude(4096, 11)


@given(st.integers(0, 0xFFFF))
def test_words_big_and_little(v: int) -> None:
    assert encode_word(v, 2, big_endian=True) == v.to_bytes(2, "big")
    assert encode_word(v, 2) == v.to_bytes(2, "little")
    assert decode_word(encode_word(v, 2, True), True) == v


def test_scs_is_big_endian_and_sts_little() -> None:
    assert SCS0009.item("Goal Position").encode(513) == b"\x02\x01"
    assert STS3215.item("Goal Position").encode(513) == b"\x01\x02"
    assert AX_12A.item("Goal Position").encode(513) == b"\x01\x02"
    assert FEETECH_SCS.big_endian and not FEETECH_STS.big_endian


def test_tables_facts() -> None:
    assert table_for("sts3215").model_number == 777
    assert table_for("ST3215") is STS3215
    assert table_for("AX-12A").model_number == 12
    assert (AX_12A.item("Goal Position").addr, AX_12A.item("Present Position").addr) == (30, 36)
    assert (STS3215.item("Goal Position").addr, STS3215.item("Present Position").addr) == (42, 56)
    assert (STS3215.item("Lock").addr, SCS0009.item("Lock").addr) == (55, 48)
    assert MX_64.item("Current").addr == 68 and not AX_12A.has("Current")
    assert not any(t.family.bus_watchdog for t in TABLES.values())
    assert FEETECH_STS.sync_read and not FEETECH_SCS.sync_read and MX_64.family.bulk_read
    with pytest.raises(ValueError, match="known: AX-12A"):
        table_for("XM430-W350")
    for table in TABLES.values():  # no two items overlap
        spans = sorted((i.addr, i.end) for i in table.items)
        assert all(a_end <= b for (_, a_end), (b, _) in itertools.pairwise(spans))


def test_wire_time_matches_the_reference_arithmetic() -> None:
    # 12 servos, 1 Mbit/s, 2-byte data, no delays: the byte counts times 10 µs
    assert cycle_time_s(12, 1e6, ReadMethod.SYNC_READ, turnaround_s=0) == pytest.approx(1.60e-3)
    assert sync_read_time_s(12, 1e6, turnaround_s=0) == pytest.approx(1.16e-3)
    assert cycle_time_s(12, 1e6, "bulk_read", turnaround_s=0) == pytest.approx(0.44e-3 + 1.39e-3)
    assert cycle_time_s(12, 1e6, "single", turnaround_s=0) == pytest.approx(0.44e-3 + 1.92e-3)
    # single reads pay the adapter's latency per servo read
    assert cycle_time_s(12, 1e6, "single", turnaround_s=0, latency_s=1e-3, reads=2) == (
        pytest.approx(0.44e-3 + 2 * 0.16e-3 + 2e-3)
    )


def test_family_read_methods_and_units() -> None:
    from drivers.protocol1.control_table import MX_28, table_for_number

    assert [t.family.read_method for t in (STS3215, MX_28, AX_12A, SCS0009)] == [
        "sync_read",
        "bulk_read",
        "single",
        "single",
    ]
    assert AX_12A.deg_per_step == pytest.approx(0.293, abs=1e-3)
    assert STS3215.steps_per_rev == 4096
    assert table_for_number(777) is STS3215 and table_for_number(1020) is None
    assert FEETECH_STS.baud_code(115_200) == 4 and AX_12A.family.baud_code(57_600) == 34
