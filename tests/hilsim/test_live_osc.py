"""OSC input: decoder, joint targets, cues, stop, lost input, network safety; all in show time."""

from __future__ import annotations

import contextlib
import itertools
import math
import socket
import struct
import threading

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from hilsim.live.netguard import GuardConfig, NetGuardError
from hilsim.live.osc import (
    MAX_DEPTH,
    OscDecodeError,
    OscInput,
    OscMessage,
    decode_packet,
    listen,
)

LOCAL = ("127.0.0.1", 50000)
JOINTS = {"jaw": (0.0, 20.0), "head_pan": (-30.0, 30.0)}


def _pad(b: bytes) -> bytes:
    b += b"\0"
    return b + b"\0" * (-len(b) % 4)


def osc(address: str, *args) -> bytes:
    """A message, typed as python-osc types Python values (float -> f, int -> i, str -> s)."""
    tags, data = ",", b""
    for a in args:
        if isinstance(a, float):
            tags, data = tags + "f", data + struct.pack(">f", a)
        elif isinstance(a, int):
            tags, data = tags + "i", data + struct.pack(">i", a)
        elif isinstance(a, str):
            tags, data = tags + "s", data + _pad(a.encode())
        else:
            raise TypeError(a)
    return _pad(address.encode()) + _pad(tags.encode()) + data


def bundle(*elements: bytes) -> bytes:
    out = b"#bundle\0" + struct.pack(">Q", 1)
    for e in elements:
        out += struct.pack(">i", len(e)) + e
    return out


def make(**kw) -> OscInput:
    return OscInput(JOINTS, **kw)


# -- the acceptance of issue 14 --------------------------------------------------------------


def test_jaw_half_is_ten_degrees_at_the_next_poll():
    inp = make()
    assert inp.poll(0.0) == []
    inp.feed(0.001, osc("/hilsim/joint/jaw", 0.5), LOCAL)
    assert inp.target("jaw") is None  # nothing moves between polls
    assert inp.poll(0.004) == []
    assert inp.target("jaw") == 10.0
    assert inp.targets.get("jaw").t == 0.001
    assert inp.target("head_pan") is None


def test_python_osc_messages_decode_the_same():
    builder = pytest.importorskip("pythonosc.osc_message_builder")
    bundle_builder = pytest.importorskip("pythonosc.osc_bundle_builder")
    m = builder.OscMessageBuilder("/hilsim/joint/jaw")
    m.add_arg(0.5)
    assert m.build().dgram == osc("/hilsim/joint/jaw", 0.5)
    b = bundle_builder.OscBundleBuilder(bundle_builder.IMMEDIATELY)
    for args in (("/hilsim/joint/head_pan", 1.0), ("/hilsim/cue/scare",)):
        m = builder.OscMessageBuilder(args[0])
        for a in args[1:]:
            m.add_arg(a)
        b.add_content(m.build())
    m = builder.OscMessageBuilder("/x")
    for a in (7, 2.5, "txt", True, False, None, b"\x01\x02\x03"):
        m.add_arg(a)
    assert decode_packet(m.build().dgram) == [
        OscMessage("/x", (7, 2.5, "txt", True, False, None, b"\x01\x02\x03"))
    ]
    inp = make()
    inp.feed(0.0, b.build().dgram, LOCAL)
    events = inp.poll(0.004)
    assert inp.target("head_pan") == 30.0
    assert [(e.kind, e.detail["cue"]) for e in events] == [("cue", "scare")]


def test_flood_of_malformed_packets_changes_nothing_and_counts_every_drop():
    inp = make(guard=GuardConfig(rate_per_s=1000.0, burst=200))
    inp.feed(0.0, osc("/hilsim/joint/jaw", 0.5), LOCAL)
    inp.poll(0.0)
    bad = [
        b"",
        b"\0\0\0",
        b"/hilsim/joint/jaw",  # no padding
        osc("/hilsim/joint/jaw", 0.9)[:-4],  # truncated argument
        b"#bundle\0" + b"\0" * 8 + struct.pack(">i", 64) + osc("/hilsim/joint/jaw", 0.9),
        osc("/hilsim/joint/jaw", 0.9).replace(b",f", b",q"),  # unknown type tag
        b"\xff" * 24,
    ]
    period, events, bound = 0.004, [], len(JOINTS) + 64 + 1
    t, max_pending = 0.0, 0
    for i in range(10_000):  # 10,000 packets over 2 s of show time: 5,000 a second
        t = 0.0002 * (i + 1)
        inp.feed(t, bad[i % len(bad)], LOCAL)
        max_pending = max(max_pending, inp.pending())
        if i % 20 == 19:  # a 250 Hz loop polls between them
            events += inp.poll(t)
            assert inp.target("jaw") == 10.0
    events += inp.poll(t + period)
    assert inp.target("jaw") == 10.0
    events += inp.poll(t + 1.0)  # the drop lines still owed come a second later
    drops = inp.guard.drops.snapshot()
    assert drops["malformed"] + drops["flood"] == 10_000
    assert drops["flood"] > 0  # 5,000/s against 1,000/s: the bucket acted
    assert inp.guard.drops.total == 10_000
    assert max_pending == 0  # a malformed packet never reaches the hand-over
    assert max_pending <= bound
    assert inp.target("jaw") == 10.0
    lines = [e for e in events if e.kind == "input_dropped"]
    # at most one line per kind per second of show time, and together they tell every drop
    assert len(lines) <= 2 * (math.ceil(t) + 1)
    assert sum(e.detail["new"] for e in lines) == 10_000
    for kind in ("malformed", "flood"):
        ts = [e.t for e in lines if e.detail["reason"] == kind]
        assert all(b - a >= 1.0 for a, b in itertools.pairwise(ts))


def test_a_flood_of_valid_cues_keeps_the_hand_over_bounded():
    inp = make(guard=GuardConfig(rate_per_s=1e6, burst=1_000_000), queue_size=8)
    for i in range(10_000):
        inp.feed(i * 1e-6, osc(f"/hilsim/cue/c{i}"), LOCAL)
        inp.feed(i * 1e-6, osc("/hilsim/joint/jaw", (i % 2) * 1.0), LOCAL)
        assert inp.pending() <= 1 + 8
    events = inp.poll(0.1)
    cues = [e.detail["cue"] for e in events if e.kind == "cue"]
    assert cues == [f"c{i}" for i in range(9992, 10_000)]  # the newest kept, the oldest dropped
    assert inp.guard.drops.by_kind["queue_full"] == 10_000 - 8
    assert inp.target("jaw") == 20.0  # the latest value


def test_sender_outside_the_allow_list_changes_nothing():
    cfg = GuardConfig(interface="0.0.0.0", allow=("192.168.1.20",))
    inp = make(guard=cfg)
    inp.feed(0.0, osc("/hilsim/joint/jaw", 0.5), ("192.168.1.21", 9000))
    inp.feed(0.0, osc("/hilsim/stop"), ("192.168.1.21", 9000))
    events = inp.poll(0.004)
    assert inp.target("jaw") is None
    assert not inp.stop_requested
    assert [(e.kind, e.detail["reason"], e.detail["new"]) for e in events] == [
        ("input_dropped", "sender", 2)
    ]
    inp.feed(0.005, osc("/hilsim/joint/jaw", 0.25), ("192.168.1.20", 9000))
    inp.poll(0.008)
    assert inp.target("jaw") == 5.0


# -- values, cues, stop ---------------------------------------------------------------------


@pytest.mark.parametrize("v", [math.nan, math.inf, -math.inf, -0.001, 1.001, 1e30])
def test_bad_values_are_dropped_and_counted_never_clamped(v):
    inp = make()
    inp.feed(0.0, osc("/hilsim/joint/jaw", 0.25), LOCAL)
    inp.poll(0.0)
    packet = _pad(b"/hilsim/joint/jaw") + _pad(b",d") + struct.pack(">d", v)
    inp.feed(0.001, packet, LOCAL)
    events = inp.poll(0.004)
    assert inp.target("jaw") == 5.0
    assert inp.guard.drops.by_kind["value"] == 1
    assert [e.detail["reason"] for e in events] == ["value"]


def test_ends_and_integer_types_map_to_the_range():
    inp = make()
    inp.feed(0.0, osc("/hilsim/joint/head_pan", 0.0), LOCAL)
    inp.feed(0.0, osc("/hilsim/joint/jaw", 1), LOCAL)  # ,i 1
    inp.poll(0.0)
    assert (inp.target("head_pan"), inp.target("jaw")) == (-30.0, 20.0)


@pytest.mark.parametrize(
    "packet",
    [
        osc("/hilsim/joint/tail", 0.5),  # not a joint of this rig
        osc("/hilsim/joint/jaw"),  # no value
        osc("/hilsim/joint/jaw", 0.5, 0.5),  # two values
        osc("/hilsim/joint/jaw", "0.5"),  # a string
        osc("/hilsim/joint/jaw/x", 0.5),
        osc("/hilsim/cue/"),  # no name
        osc("/hilsim/cue/a/b"),
        osc("/other/thing", 1.0),
    ],
)
def test_unknown_addresses_and_arguments_are_counted(packet):
    inp = make()
    inp.feed(0.0, packet, LOCAL)
    events = inp.poll(0.004)
    assert inp.target("jaw") is None
    assert inp.guard.drops.by_kind["unknown"] == 1
    assert [e.kind for e in events] == ["input_dropped"]


def test_cues_in_order_a_release_ignored_a_stop_once_and_last():
    inp = make(cues={"scare", "bow"})
    inp.feed(0.0, osc("/hilsim/cue/scare", 1.0), LOCAL)
    inp.feed(0.0, osc("/hilsim/cue/scare", 0.0), LOCAL)  # the button's release
    inp.feed(0.0, osc("/hilsim/stop"), LOCAL)
    inp.feed(0.001, osc("/hilsim/cue/bow"), LOCAL)
    inp.feed(0.001, osc("/hilsim/cue/nope"), LOCAL)  # not in the caller's list
    inp.feed(0.002, osc("/hilsim/stop", 0.0), LOCAL)  # a stop's release still stops: harmless
    events = inp.poll(0.004)
    assert [(e.kind, e.t, e.source) for e in events if e.kind != "input_dropped"] == [
        ("cue", 0.0, "osc"),
        ("cue", 0.001, "osc"),
        ("stop", 0.0, "osc"),
    ]
    assert inp.stop_requested
    assert inp.guard.drops.by_kind["unknown"] == 1
    inp.feed(0.005, osc("/hilsim/stop"), LOCAL)
    assert [e.kind for e in inp.poll(0.008)] == []  # the stop is said once


def test_a_bundle_is_applied_whole_or_not_at_all():
    inp = make()
    good = bundle(osc("/hilsim/joint/jaw", 0.5), bundle(osc("/hilsim/joint/head_pan", 0.5)))
    inp.feed(0.0, good, LOCAL)
    inp.poll(0.0)
    assert (inp.target("jaw"), inp.target("head_pan")) == (10.0, 0.0)
    broken = bundle(osc("/hilsim/joint/jaw", 1.0), b"\xff\xff\xff\xff")
    inp.feed(0.001, broken, LOCAL)
    inp.poll(0.004)
    assert inp.target("jaw") == 10.0
    assert inp.guard.drops.by_kind["malformed"] == 1


def test_nesting_and_message_count_are_bounded():
    deep = osc("/hilsim/joint/jaw", 0.5)
    for _ in range(MAX_DEPTH):
        deep = bundle(deep)
    assert len(decode_packet(deep)) == 1
    with pytest.raises(OscDecodeError, match="nested too deep"):
        decode_packet(bundle(deep))
    with pytest.raises(OscDecodeError, match="more than 64 messages"):
        decode_packet(bundle(*[osc("/a")] * 65))


# -- lost input -------------------------------------------------------------------------------


def test_lost_input_holds_and_is_said_once_then_its_return():
    inp = make(lost_after_s=0.5)
    inp.feed(0.0, osc("/hilsim/joint/jaw", 0.5), LOCAL)
    assert inp.poll(0.004) == []
    assert inp.poll(0.5) == []  # exactly the limit: not yet
    (lost,) = inp.poll(0.504)
    assert (lost.kind, lost.detail["joint"], lost.detail["deg"]) == ("input_lost", "jaw", 10.0)
    assert inp.targets.get("jaw").lost
    assert inp.poll(0.6) == [] and inp.poll(3.0) == []  # once per loss
    assert inp.target("jaw") == 10.0  # held
    inp.feed(3.1, osc("/hilsim/joint/jaw", 0.75), LOCAL)
    (back,) = inp.poll(3.104)
    assert (back.kind, back.detail["deg"]) == ("input_returned", 15.0)
    assert inp.target("jaw") == 15.0 and not inp.targets.get("jaw").lost
    (again,) = inp.poll(3.7)
    assert again.kind == "input_lost"


# -- the decoder never raises anything else -----------------------------------------------------

_VALID = [
    osc("/hilsim/joint/jaw", 0.5),
    bundle(osc("/hilsim/joint/jaw", 0.5), osc("/hilsim/cue/x", "s")),
    _pad(b"/b") + _pad(b",bhdTFNI") + struct.pack(">i", 3) + b"abc\0" + b"\0" * 16,
]


@settings(max_examples=1500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=200))
@example(_VALID[0]).via("a message")
@example(_VALID[1]).via("a bundle")
@example(_VALID[2]).via("every type")
def test_fuzz_random_bytes_decode_or_decode_error(data):
    try:
        msgs = decode_packet(data)
    except OscDecodeError:
        return
    # a message is one, a bundle its elements; each address '/' and printable, as in the packet
    assert msgs and (len(msgs) == 1 or data.startswith(b"#bundle\0"))
    for m in msgs:
        assert isinstance(m, OscMessage) and isinstance(m.args, tuple)
        assert m.address.startswith("/") and m.address.isprintable() and " " not in m.address
        assert _pad(m.address.encode("ascii")) in data


@settings(max_examples=2000, deadline=None)
@given(
    st.sampled_from(_VALID),
    st.lists(st.tuples(st.integers(0, 99), st.integers(0, 255)), max_size=6),
    st.integers(0, 60),
)
def test_fuzz_mutated_packets_never_raise_out_of_the_input(base, flips, cut):
    data = bytearray(base)
    for pos, val in flips:
        data[pos % len(data)] = val
    data = bytes(data[: len(data) - cut % len(data)])
    with contextlib.suppress(OscDecodeError):
        decode_packet(data)
    inp = make()
    inp.feed(0.0, data, LOCAL)  # never raises: applied, or counted
    events = inp.poll(0.004)
    dropped = inp.guard.drops.total
    assert inp.guard.drops.by_kind["internal"] == 0
    applied = inp.target("jaw") is not None or any(e.kind == "cue" for e in events)
    assert applied or dropped or inp.stop_requested or decode_packet_is_ignorable(data)


def decode_packet_is_ignorable(data: bytes) -> bool:
    """A well-formed packet that asks nothing (an empty bundle, a cue's release) drops nothing."""
    try:
        msgs = decode_packet(data)
    except OscDecodeError:
        return False
    return all(m.address.startswith("/hilsim/cue/") for m in msgs)


# -- a real socket on 127.0.0.1 -----------------------------------------------------------------


class _Signalled(OscInput):
    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.fed = threading.Semaphore(0)

    def feed(self, t, data, sender):
        super().feed(t, data, sender)
        self.fed.release()


def test_real_udp_socket_end_to_end():
    inp = _Signalled(JOINTS, guard=GuardConfig(max_packet_bytes=256))
    rx = listen(inp, 0, clock=lambda: 1.25)
    try:
        host, port = rx.address
        assert host == "127.0.0.1"
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            tx.sendto(osc("/hilsim/joint/jaw", 0.5), (host, port))
            tx.sendto(b"x" * 1000, (host, port))  # oversized: counted, unread
            tx.sendto(osc("/hilsim/cue/scare"), (host, port))
            for _ in range(3):
                assert inp.fed.acquire(timeout=5.0), "the receiver did not feed the packet"
        events = inp.poll(1.25)
        assert inp.target("jaw") == 10.0
        assert inp.targets.get("jaw").t == 1.25  # stamped with the given clock
        assert [e.kind for e in events] == ["cue", "input_dropped"]
        assert inp.guard.drops.by_kind["oversized"] == 1
    finally:
        rx.close()
    assert not rx._thread.is_alive()


def test_a_port_in_use_is_one_line():
    inp = make()
    rx = listen(inp, 0, clock=lambda: 0.0)
    try:
        with pytest.raises(NetGuardError, match=r"cannot listen on 127\.0\.0\.1 port \d+") as err:
            listen(make(), rx.address[1], clock=lambda: 0.0)
        assert "\n" not in str(err.value)
    finally:
        rx.close()


def test_bad_joint_range_is_refused():
    with pytest.raises(ValueError, match="must be finite, lo < hi"):
        OscInput({"jaw": (20.0, 0.0)})
    with pytest.raises(ValueError, match="lost_after_s"):
        OscInput(JOINTS, lost_after_s=0.0)


def test_lost_input_per_joint_at_its_own_time():
    inp = make(lost_after_s=0.5)
    inp.feed(0.0, osc("/hilsim/joint/jaw", 0.5), LOCAL)
    inp.poll(0.0)
    inp.feed(0.3, osc("/hilsim/joint/head_pan", 0.5), LOCAL)
    assert inp.poll(0.3) == []
    assert [e.detail["joint"] for e in inp.poll(0.51)] == ["jaw"]
    assert inp.poll(0.79) == []  # head_pan's last value is 0.49 s old
    assert [e.detail["joint"] for e in inp.poll(0.81)] == ["head_pan"]
    inp.feed(1.0, osc("/hilsim/joint/jaw", 0.0), LOCAL)
    assert [e.kind for e in inp.poll(1.0)] == ["input_returned"]
    assert inp.poll(1.5) == []
    assert [(e.kind, e.detail["joint"]) for e in inp.poll(1.51)] == [("input_lost", "jaw")]
    assert inp.target("jaw") == 0.0 and inp.target("head_pan") == 0.0
