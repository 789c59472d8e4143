"""Protocol 2.0 framing: golden packets from the e-Manual, stuffing, CRC, stream resync."""

from __future__ import annotations

import json
import pathlib

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.dxlsim.protocol import (
    HEADER,
    Instruction,
    PacketError,
    StreamParser,
    crc16,
    decode,
    encode_fast_status,
    encode_instruction,
    encode_status,
    parse_fast_status,
    stuff,
    unstuff,
)

GOLDEN_PATH = pathlib.Path(__file__).parent / "golden_packets.json"
GOLDEN = {
    k: bytes.fromhex(v)
    for k, v in json.loads(GOLDEN_PATH.read_text()).items()
    if not k.startswith("_")
}
PLAIN = {k: v for k, v in GOLDEN.items() if k != "fast_sync_read_status_ids_3_7_4"}


@pytest.mark.parametrize("name", sorted(PLAIN))
def test_golden_packet_round_trips(name):
    frame = GOLDEN[name]
    packet = decode(frame)
    assert packet.encode() == frame


def test_golden_packet_contents():
    ping = decode(GOLDEN["ping_id1_status_model1030_fw38"])
    assert (ping.id, ping.error, ping.params) == (1, 0, bytes([0x06, 0x04, 38]))
    read = decode(GOLDEN["read_id1_present_position_instruction"])
    assert (read.instruction, read.params) == (Instruction.READ, bytes([132, 0, 4, 0]))
    sync = decode(GOLDEN["sync_write_addr116_len4_id1_150_id2_170"])
    assert sync.params == bytes([116, 0, 4, 0, 1, 150, 0, 0, 0, 2, 170, 0, 0, 0])


def test_golden_fast_sync_read_reply():
    frame = GOLDEN["fast_sync_read_status_ids_3_7_4"]
    blocks = parse_fast_status(frame, [4, 4, 4])
    assert [(e, i, int.from_bytes(d, "little"), ok) for e, i, d, ok in blocks] == [
        (0, 3, 166, True),
        (0, 7, 2079, True),
        (0, 4, 1023, True),
    ]
    assert encode_fast_status([(e, i, d) for e, i, d, _ in blocks]) == frame
    assert len(frame) == 8 + 3 * (4 + 4)  # Fast Sync Read reply: 8 + N(X+4) bytes


def test_fast_reply_block_crc_detects_corruption():
    frame = bytearray(GOLDEN["fast_sync_read_status_ids_3_7_4"])
    frame[18] ^= 0x01  # second block's data
    blocks = parse_fast_status(bytes(frame), [4, 4, 4])
    assert [ok for *_, ok in blocks] == [True, False, False]


def test_crc_known_value():
    body = GOLDEN["ping_id1_instruction"]
    assert crc16(body[:-2]) == body[-2] | body[-1] << 8 == 0x4E19


def test_stuffing_example_and_lengths():
    # -131073 as int32 little endian is FF FF FD FF: needs stuffing (FF FF FD -> FF FF FD FD).
    params = bytes([116, 0]) + (-131073).to_bytes(4, "little", signed=True)
    frame = encode_instruction(1, Instruction.WRITE, params)
    assert b"\xff\xff\xfd\xfd" in frame[7:]
    assert frame[5] | frame[6] << 8 == 1 + len(params) + 1 + 2  # INST + params + stuffed byte + CRC
    assert decode(frame).params == params


@given(st.binary(max_size=64))
def test_stuff_unstuff_round_trip(body):
    stuffed = stuff(body)
    assert unstuff(stuffed) == body
    assert b"\xff\xff\xfd" not in stuffed.replace(b"\xff\xff\xfd\xfd", b"")


@given(
    st.integers(0, 252),
    st.sampled_from([i for i in Instruction if i != Instruction.STATUS]),
    st.binary(max_size=40),
)
def test_any_instruction_round_trips(pid, inst, params):
    frame = encode_instruction(pid, inst, params)
    packet = decode(frame)
    assert (packet.id, packet.instruction, packet.params) == (pid, inst, params)


@given(st.integers(0, 252), st.integers(0, 255), st.binary(max_size=40))
def test_status_round_trips(pid, err, params):
    packet = decode(encode_status(pid, err, params))
    assert (packet.id, packet.error, packet.params) == (pid, err, params)


def test_decode_rejects_bad_crc_and_length():
    frame = bytearray(GOLDEN["ping_id1_instruction"])
    frame[-1] ^= 0xFF
    with pytest.raises(PacketError, match="CRC"):
        decode(bytes(frame))
    with pytest.raises(PacketError, match="length"):
        decode(GOLDEN["ping_id1_instruction"] + b"\x00")
    with pytest.raises(PacketError, match="header"):
        decode(b"\x00" * 12)


def test_parser_resyncs_after_garbage_and_split_feeds():
    a, b = GOLDEN["ping_id1_instruction"], GOLDEN["reboot_id1"]
    stream = b"\x00\xff\xff\xfd\x12" + a + b"\xff\xff" + b
    parser = StreamParser()
    frames = []
    for i in range(0, len(stream), 3):  # arbitrary split points
        frames += parser.feed(stream[i : i + 3])
    assert [f.raw for f in frames] == [a, b]
    assert frames[1].end == len(stream)
    assert all(f.crc_ok for f in frames)


def test_parser_reports_crc_failure_with_id():
    frame = bytearray(GOLDEN["write_id1_goal_position_512"])
    frame[10] ^= 0x40
    (f,) = StreamParser().feed(bytes(frame))
    assert (f.crc_ok, f.packet, f.id) == (False, None, 1)


def test_parser_reset_drops_partial_packet():
    a = GOLDEN["ping_id1_instruction"]
    parser = StreamParser()
    assert parser.feed(a[:6]) == []
    parser.reset()
    assert parser.feed(a[6:]) == []
    assert [f.raw for f in parser.feed(a)] == [a]


@given(st.binary(max_size=300))
def test_parser_never_raises_and_frames_are_consistent(data):
    parser = StreamParser()
    for f in parser.feed(data):
        assert f.raw.startswith(HEADER)
        assert len(f.raw) == 7 + (f.raw[5] | f.raw[6] << 8)
        if f.crc_ok:
            assert decode(f.raw).instruction == f.packet.instruction


@given(st.binary(max_size=300))
def test_the_shared_crc_is_the_sdks(data):
    """drivers.protocol2.crc (the emulator's codec and the driver's Fast Sync Read parser both
    use it) computes what dynamixel-sdk computes."""
    import dynamixel_sdk as sdk

    from drivers.protocol2.crc import crc16

    assert crc16(data) == sdk.PacketHandler(2.0).updateCRC(0, list(data), len(data))
