"""sACN (E1.31) and Art-Net in: packets built by other implementations (the ``sacn`` package's
DataPacket/SyncPacket, stupidArtnet's sender) read by our parsers, the per-universe rules
(priority, sequence, sync, data loss, 0 = hold), a virtual-time show on the emulator, and a
real loopback socket. No wall-clock figure is asserted."""

from __future__ import annotations

import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import hilsim
from hilsim.live.dmx_config import DmxConfig, DmxJoint
from hilsim.live.dmx_input import DmxInput, listen
from hilsim.live.dmx_packets import DmxData, DmxDecodeError, DmxSync, parse_artnet, parse_e131
from hilsim.live.netguard import GuardConfig
from hilsim.rig import load_rig
from hilsim.show.parts import build_parts, with_show
from hilsim.show.session import open_bus, open_telemetry, port_for, run_show
from hilsim.show.stop import StopFlag
from hilsim.telemetry.reader import read_run

data_packet = pytest.importorskip("sacn.messages.data_packet")
sync_packet = pytest.importorskip("sacn.messages.sync_packet")

CID_A = tuple(range(16))
CID_B = tuple(range(100, 116))
SENDER = ("127.0.0.1", 5568)
PERIOD = 0.004
SPEED = 200.0


def e131(cid=CID_A, universe=1, slots=(0x80, 0x00), priority=100, sequence=0, **kw) -> bytes:
    """An E1.31 data packet as the ``sacn`` package builds it."""
    p = data_packet.DataPacket(cid, "console", universe, tuple(slots), priority, sequence, **kw)
    return bytes(p.getBytes())


def joint16(**kw) -> DmxJoint:
    return DmxJoint("head_pan", 1, 1, 16, -50.0, 10.0, 50.0, **kw)


def sacn_input(*joints: DmxJoint, **kw) -> DmxInput:
    return DmxInput(DmxConfig("sacn", joints or (joint16(),), **kw))


def values(inp: DmxInput, t: float) -> dict[str, float]:
    return {j: d for j, d, _ in inp.poll(t).values}


# ------------------------------------------------------------------------------ parsers
def test_an_e131_packet_built_by_sacn_is_read_field_by_field():
    p = parse_e131(e131(universe=513, slots=(1, 2, 3), priority=150, sequence=7, sync_universe=9))
    assert isinstance(p, DmxData)
    assert (p.universe, p.slots[:4], p.priority, p.sequence, p.sync_address) == (
        513, b"\x01\x02\x03\x00", 150, 7, 9)  # fmt: skip
    assert len(p.slots) == 512  # sacn sends a whole universe
    assert p.source == bytes(CID_A).hex() and p.name == "console" and not p.terminated
    assert parse_e131(e131(streamTerminated=True)).terminated  # type: ignore[union-attr]
    assert parse_e131(e131(previewData=True)) is None  # preview: not for a figure
    s = parse_e131(bytes(sync_packet.SyncPacket(CID_A, 9, 3).getBytes()))
    assert s == DmxSync(bytes(CID_A).hex(), 9, 3)


def test_an_artdmx_packet_built_by_stupidartnet_is_read():
    stupid = pytest.importorskip("stupidArtnet")
    a = stupid.StupidArtnet("127.0.0.1", universe=0x1234 & 0x7FFF, packet_size=4)
    a.set([0x80, 0x00, 7, 9])
    raw = bytes(a.packet_header) + bytes(a.buffer)
    a.close()
    p = parse_artnet(raw, "127.0.0.1")
    assert isinstance(p, DmxData)
    assert (p.universe, p.slots, p.priority) == (0x1234, b"\x80\x00\x07\x09", 100)
    a2 = stupid.StupidArtnet("127.0.0.1", universe=0, artsync=True)
    assert parse_artnet(bytes(a2.artsync_header), "h") == DmxSync("h", 0)
    a2.close()


# ------------------------------------------------------------------------------ mapping
@pytest.mark.parametrize(
    ("bits", "v", "deg"),
    [(16, 0x8000, 10.0), (16, 1, -50.0), (16, 0xFFFF, 50.0), (8, 128, 10.0), (8, 255, 50.0),
     (8, 1, -50.0), (16, 0x4000, -50.0 + 60.0 * (0x4000 - 1) / 32767)],
)  # fmt: skip
def test_scaled_mapping_min_center_max(bits, v, deg):
    j = DmxJoint("head_pan", 1, 1, bits, -50.0, 10.0, 50.0)
    assert j.degrees(v) == pytest.approx(deg)


def test_zero_holds_by_default_and_the_other_zero_kinds():
    assert joint16().degrees(0) is None
    assert joint16(zero="center").degrees(0) == 10.0
    assert joint16(zero="min").degrees(0) == -50.0
    inp = sacn_input(joint16(zero="release"))
    inp.feed(0.0, e131(slots=(0, 0)), SENDER)
    assert inp.poll(0.0).releases == ["head_pan"]


# ------------------------------------------------------------------------------ the rules
def test_a_higher_priority_source_takes_over_and_the_lower_one_after_it_goes_silent():
    inp = sacn_input()
    inp.feed(0.0, e131(CID_A, slots=(0x80, 0)), SENDER)
    assert values(inp, 0.0) == {"head_pan": 10.0}
    inp.feed(0.1, e131(CID_B, slots=(0xFF, 0xFF), priority=150), SENDER)
    inp.feed(0.11, e131(CID_A, slots=(0x01, 0), sequence=1), SENDER)  # not the winner: unheard
    p = inp.poll(0.12)
    assert {j: d for j, d, _ in p.values} == {"head_pan": 50.0}
    assert [e.kind for e in p.events] == ["dmx_source"]
    t = 0.11
    for k in range(1, 40):  # A goes on at 10 Hz; B said nothing since 0.1
        t = 0.11 + 0.1 * k
        inp.feed(t, e131(CID_A, slots=(0x80, 0), sequence=1 + k), SENDER)
    assert inp.sources(1)[0] == bytes(CID_A).hex()  # B left after 2.5 s; A is heard again
    assert values(inp, t) == {"head_pan": 10.0}


def test_late_packets_are_dropped_and_counted():
    inp = sacn_input()
    inp.feed(0.0, e131(slots=(0x80, 0), sequence=250), SENDER)
    inp.feed(0.01, e131(slots=(0xFF, 0xFF), sequence=249), SENDER)  # one behind: late
    inp.feed(0.02, e131(slots=(0xFF, 0xFF), sequence=250), SENDER)  # the same again: late
    p = inp.poll(0.02)
    assert [(j, d) for j, d, _ in p.values] == [("head_pan", 10.0)]
    assert [e.detail["reason"] for e in p.events if e.kind == "input_dropped"] == ["late"]
    inp.feed(0.03, e131(slots=(0xFF, 0xFF), sequence=4), SENDER)  # 10 ahead (it wrapped)
    assert values(inp, 0.03) == {"head_pan": 50.0}
    assert inp.guard.drops.by_kind["late"] == 2


def test_data_with_a_sync_address_waits_for_its_sync_packet():
    inp = sacn_input()
    sync = bytes(sync_packet.SyncPacket(CID_A, 7, 0).getBytes())
    inp.feed(0.0, sync, SENDER)
    inp.feed(0.01, e131(slots=(0xFF, 0xFF), sync_universe=7), SENDER)
    assert values(inp, 0.01) == {}  # waits
    inp.feed(0.02, sync, SENDER)
    assert values(inp, 0.02) == {"head_pan": 50.0}
    # no sync for longer than lost_after_s: the data is applied as it comes
    inp.feed(3.0, e131(slots=(0x80, 0), sync_universe=7, sequence=1), SENDER)
    assert values(inp, 3.0) == {"head_pan": 10.0}


def test_a_universe_without_data_for_2_5_s_holds_and_says_so_once():
    inp = sacn_input()
    inp.feed(0.0, e131(), SENDER)
    inp.poll(0.0)
    assert inp.poll(2.5).events == []
    (ev,) = inp.poll(2.504).events
    assert ev.kind == "input_lost" and ev.detail["joints"] == ["head_pan"]
    assert "2.5 s" in ev.detail["message"] and "hold" in ev.detail["message"]
    assert inp.poll(3.0).events == []
    inp.feed(3.1, e131(sequence=1), SENDER)
    assert [e.kind for e in inp.poll(3.1).events] == ["input_returned"]


def test_a_stream_terminated_leaves_at_once():
    inp = sacn_input()
    inp.feed(0.0, e131(), SENDER)
    inp.feed(0.1, e131(sequence=1, streamTerminated=True), SENDER)
    assert [e.kind for e in inp.poll(0.1).events] == ["input_lost"]


def test_senders_outside_the_allow_list_and_garbage_are_dropped_and_counted():
    inp = sacn_input()
    inp.feed(0.0, e131(), ("192.168.1.9", 5568))
    inp.feed(0.0, b"\x00" * 40, SENDER)
    inp.feed(0.0, e131()[:-1], SENDER)
    assert inp.guard.drops.by_kind["sender"] == 1
    assert inp.guard.drops.by_kind["malformed"] == 2
    assert values(inp, 0.0) == {}
    off = GuardConfig(interface="10.0.0.2", allow=("10.0.0.9",))
    far = DmxInput(DmxConfig("sacn", (joint16(),), guard=off))
    far.feed(0.0, e131(), ("10.0.0.9", 5568))
    assert values(far, 0.0) == {"head_pan": 10.0}


# ------------------------------------------------------------------------------ a show
RIG = f"""
name = "dmx"
[bus]
port = "dxlsim://?ids=1&rdt_us=0&latency_ms=1"
[loop]
rate_hz = 250
[safety]
soft_start_s = 0.1
[[joints]]
name = "head_pan"
servo_id = 1
min_deg = -60
max_deg = 60
max_speed_deg_s = {SPEED}
max_accel_deg_s2 = 5000
spring = {{ frequency_hz = 4.0, damping_ratio = 1.0, response = 0.0 }}
target = {{ type = "hold", value_deg = 0 }}
"""
SHOW = """
[inputs.sacn]
[inputs.sacn.joints.head_pan]
universe = 1
channel = 1
bits = 16
degrees = [-50, 10, 50]
"""


def run_show_with(tmp_path: Path, duration: float, sends) -> SimpleNamespace:
    """The show in virtual time; ``sends(k)``: the datagrams arriving during tick k."""
    (tmp_path / "rig.toml").write_text(RIG)
    (tmp_path / "show.toml").write_text(SHOW)
    rig = load_rig(tmp_path / "rig.toml")
    parts = with_show(build_parts(rig), str(tmp_path / "show.toml"), False, virtual=True)
    director = parts.director
    real_tick = director.tick

    def tick(k, t, present):
        real_tick(k, t, present)
        for data in sends(k):
            director.dmx[0].feed(k * PERIOD, data, SENDER)

    director.tick = tick
    bus = open_bus(rig, port_for(rig, True))
    tel = open_telemetry(rig, tmp_path / "run", True)
    try:
        result = run_show(parts, bus, tel, duration_s=duration, stop=StopFlag())
    finally:
        bus.close()
    return SimpleNamespace(result=result, run=read_run(tmp_path / "run"))


def test_a_show_follows_priority_holds_on_zero_and_on_silence(tmp_path):
    """A sends the middle (0x80 0x00 -> 10 deg) at 25 Hz; B at priority 150 sends the top
    (50 deg) from 1 s to 2 s and goes silent; A is heard again 2.5 s later; A sends 0 from 5 s
    (held); from 6 s nothing: still held, and input_lost said 2.5 s later."""
    seq = {"a": 0, "b": 0}

    def sends(k):
        t = k * PERIOD
        out = []
        if k % 10 == 0 and t < 6.0:
            seq["a"] += 1
            slots = (0, 0) if t >= 5.0 else (0x80, 0)
            out.append(e131(CID_A, slots=slots, sequence=seq["a"] % 256))
        if k % 10 == 5 and 1.0 <= t < 2.0:
            seq["b"] += 1
            out.append(e131(CID_B, slots=(0xFF, 0xFF), priority=150, sequence=seq["b"]))
        return out

    r = run_show_with(tmp_path, 9.0, sends)
    target = np.degrees(r.run.joint("target")[:, 0])
    cmd = np.degrees(r.run.joint("cmd")[:, 0])
    at = lambda s: target[round(s / PERIOD)]  # noqa: E731
    assert at(0.9) == pytest.approx(10.0)  # coarse 0x80 fine 0x00: the middle
    assert at(1.9) == pytest.approx(50.0)  # B, priority 150, took over
    assert at(4.0) == pytest.approx(50.0)  # B silent < 2.5 s: held
    assert at(4.8) == pytest.approx(10.0)  # A heard again
    assert at(5.9) == pytest.approx(10.0)  # 0 holds
    assert at(8.9) == pytest.approx(10.0)  # silence holds
    assert np.max(np.abs(np.diff(cmd))) / PERIOD <= SPEED * (1 + 1e-9)
    assert cmd[int(1.9 / PERIOD)] == pytest.approx(50.0, abs=0.5)  # the spring got there
    ev = [(e["kind"], round(e["t"], 2)) for e in r.run.events
          if e["kind"] in ("dmx_source", "input_lost", "live_take")]  # fmt: skip
    kinds = [k for k, _ in ev]
    assert kinds == ["live_take", "dmx_source", "dmx_source", "input_lost"]
    lost_t = ev[-1][1]
    assert lost_t == pytest.approx(5.96 + 2.5, abs=0.02)  # A's last packet + 2.5 s


# ------------------------------------------------------------------------------ real sockets
def test_stupidartnet_over_a_real_loopback_socket_moves_a_joint_value():
    stupid = pytest.importorskip("stupidArtnet")
    fed = threading.Semaphore(0)

    class Signalled(DmxInput):
        def feed(self, t, data, sender):
            super().feed(t, data, sender)
            fed.release()

    cfg = DmxConfig("artnet", (DmxJoint("head_pan", 0, 1, 16, -50.0, 10.0, 50.0),), port=0)
    inp = Signalled(cfg)
    rx = listen(inp, lambda: 1.0)
    try:
        a = stupid.StupidArtnet("127.0.0.1", universe=0, packet_size=2, port=rx.address[1])
        a.set([0x80, 0x00])
        a.show()
        assert fed.acquire(timeout=5.0), "the receiver did not feed the packet"
        assert values(inp, 1.0) == {"head_pan": 10.0}
        a.close()
    finally:
        rx.close()


def test_a_show_file_section_is_read_and_a_mistake_is_one_line(tmp_path):
    (tmp_path / "rig.toml").write_text(RIG)
    (tmp_path / "show.toml").write_text(SHOW)
    with hilsim.Show(tmp_path / "rig.toml", virtual_time=True, show=tmp_path / "show.toml",
                     duration=0.01) as show:  # fmt: skip
        assert show is not None
    bad = SHOW.replace("channel = 1", "channel = 512")
    (tmp_path / "show.toml").write_text(bad)
    with pytest.raises(hilsim.RigError, match=r"channel: must be <= 511"):
        hilsim.Show(tmp_path / "rig.toml", virtual_time=True, show=tmp_path / "show.toml")
    off = SHOW.replace("[inputs.sacn]\n", '[inputs.sacn]\ninterface = "10.1.2.3"\n')
    (tmp_path / "show.toml").write_text(off)
    with pytest.raises(hilsim.RigError, match="allow"):
        hilsim.Show(tmp_path / "rig.toml", virtual_time=True, show=tmp_path / "show.toml")
    for section in ("inputs.sacn", "inputs.multisync"):  # one line: the file named once
        text = SHOW if section == "inputs.sacn" else "[inputs.multisync]\n"
        (tmp_path / "show.toml").write_text(
            text.replace(f"[{section}]\n", f"[{section}]\nrate_per_s = -1\n")
        )
        with pytest.raises(hilsim.RigError) as err:
            hilsim.Show(tmp_path / "rig.toml", virtual_time=True, show=tmp_path / "show.toml")
        assert str(err.value).count("show.toml") == 1, str(err.value)
        assert f"{section}.rate_per_s: must be > 0" in str(err.value)


# ------------------------------------------------------------------------------ fuzzing
def _mutated(base: bytes):
    return st.tuples(
        st.lists(st.tuples(st.integers(0, len(base) - 1), st.integers(0, 255)), max_size=6),
        st.integers(0, len(base)),
    ).map(lambda m: _apply(base, *m))


def _apply(base: bytes, edits: list[tuple[int, int]], cut: int) -> bytes:
    b = bytearray(base)
    for i, v in edits:
        b[i] = v
    return bytes(b[:cut])


_E131 = e131(slots=(0x80, 0, 5))
_SYNC = bytes(sync_packet.SyncPacket(CID_A, 7, 0).getBytes())
_ARTDMX = b"Art-Net\0\x00\x50\x00\x0e\x01\x00\x00\x00\x00\x04\x80\x00\x01\x02"
_PACKETS = st.one_of(st.binary(max_size=700), _mutated(_E131), _mutated(_SYNC), _mutated(_ARTDMX))


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_PACKETS)
def test_nothing_but_their_own_error_leaves_the_parsers(data):
    for parse in (parse_e131, lambda d: parse_artnet(d, "h")):
        try:
            p = parse(data)
        except DmxDecodeError:
            continue
        assert p is None or isinstance(p, DmxData | DmxSync)
        if isinstance(p, DmxData):
            assert len(p.slots) <= 512


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_PACKETS, max_size=20))
def test_a_stream_of_anything_never_breaks_an_input(stream):
    for proto in ("sacn", "artnet"):
        inp = DmxInput(DmxConfig(proto, (DmxJoint("head_pan", 1, 1, 16, -50.0, 10.0, 50.0),)))
        for i, data in enumerate(stream):
            inp.feed(i * 0.01, data, SENDER)
        p = inp.poll(len(stream) * 0.01)
        assert inp.guard.drops.by_kind["internal"] == 0
        assert all(-50.0 <= d <= 50.0 for _, d, _ in p.values)


def test_multicast_joins_each_universes_group_on_the_interface():
    """E1.31 multicast (239.255.0.1 for universe 1), sent on loopback by a socket of ours
    carrying a packet the sacn package built; the receiver joined the group."""
    import socket

    from hilsim.live.netguard import NetGuardError

    fed = threading.Semaphore(0)

    class Signalled(DmxInput):
        def feed(self, t, data, sender):
            super().feed(t, data, sender)
            fed.release()

    cfg = DmxConfig("sacn", (joint16(),), port=0, multicast=True,
                    guard=GuardConfig(interface="127.0.0.1"))  # fmt: skip
    inp = Signalled(cfg)
    try:
        rx = listen(inp, lambda: 1.0)
    except NetGuardError as exc:  # a host without multicast on loopback
        pytest.skip(str(exc))
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
        s.sendto(e131(slots=(0xFF, 0xFF)), ("239.255.0.1", rx.address[1]))
        assert fed.acquire(timeout=5.0), "the receiver did not feed the packet"
        assert values(inp, 1.0) == {"head_pan": 50.0}
    finally:
        s.close()
        rx.close()


def test_release_after_s_is_read_for_sacn_and_artnet(tmp_path):
    from hilsim.live.director import release_after
    from hilsim.live.showfile import load_show

    (tmp_path / "rig.toml").write_text(RIG)
    text = SHOW.replace("[inputs.sacn]\n", "[inputs.sacn]\nrelease_after_s = 4\n")
    text += SHOW.replace("sacn", "artnet").replace("universe = 1", "universe = 0")
    (tmp_path / "show.toml").write_text(text)
    spec = load_show(tmp_path / "show.toml", load_rig(tmp_path / "rig.toml"), lambda *a: None)
    got = release_after(spec)
    assert (got["sacn"], got["artnet"]) == (4.0, None)
    assert spec.artnet is not None and spec.artnet.port == 6454 and not spec.artnet.multicast


def test_two_sacn_senders_over_loopback_the_higher_priority_wins_and_its_end_hands_back():
    """The sacn package's own senders (their CIDs, sequence numbers and stream-terminated
    packets) unicast to 127.0.0.1:5568, where sacn always sends. No wall-clock figure."""
    import time

    sacn = pytest.importorskip("sacn")
    from hilsim.live.netguard import NetGuardError

    fed = threading.Condition()

    class Signalled(DmxInput):
        def feed(self, t, data, sender):
            super().feed(t, data, sender)
            with fed:
                fed.notify_all()

    inp = Signalled(DmxConfig("sacn", (joint16(),), port=5568))
    try:
        rx = listen(inp, lambda: 1.0)
    except NetGuardError as exc:  # 5568 taken on this host
        pytest.skip(str(exc))
    got: dict[str, float] = {}
    kinds: list[str] = []

    def until(cond) -> bool:
        end = time.monotonic() + 10.0
        with fed:
            while True:
                p = inp.poll(1.0)
                got.update({j: d for j, d, _ in p.values})
                kinds.extend(e.kind for e in p.events)
                if cond() or not fed.wait(timeout=max(0.0, end - time.monotonic())):
                    return cond()

    senders = []
    try:
        for prio, slots in ((100, (0x80, 0x00)), (150, (0xFF, 0xFF))):
            s = sacn.sACNsender(bind_address="127.0.0.1", bind_port=0, source_name=f"p{prio}")
            s.start()
            s.activate_output(1)
            s[1].multicast, s[1].destination, s[1].priority = False, "127.0.0.1", prio
            s[1].dmx_data = slots
            senders.append(s)
            want = 10.0 if prio == 100 else 50.0
            assert until(lambda w=want: got.get("head_pan") == w), got
        assert kinds.count("dmx_source") == 1  # priority 150 took over
        senders[1].deactivate_output(1)  # three "stream terminated" packets: it leaves at once
        assert until(lambda: got.get("head_pan") == 10.0 and kinds.count("dmx_source") == 2), (
            got,
            kinds,
            inp.counts,
            inp.guard.drops.snapshot(),
        )
    finally:
        for s in senders:
            s.stop()
        rx.close()


def test_artnet_data_waits_for_artsync_once_the_sender_sends_it():
    stupid = pytest.importorskip("stupidArtnet")
    a = stupid.StupidArtnet("127.0.0.1", universe=0, packet_size=2, artsync=True)
    a.close()

    def artdmx(slots):
        a.set(list(slots))
        return bytes(a.packet_header) + bytes(a.buffer)

    cfg = DmxConfig("artnet", (DmxJoint("head_pan", 0, 1, 16, -50.0, 10.0, 50.0),))
    inp = DmxInput(cfg)
    inp.feed(0.0, artdmx((0x80, 0)), SENDER)  # no ArtSync seen yet: applied as it comes
    assert values(inp, 0.0) == {"head_pan": 10.0}
    inp.feed(0.01, bytes(a.artsync_header), SENDER)
    inp.feed(0.02, artdmx((0xFF, 0xFF)), SENDER)
    assert values(inp, 0.02) == {}  # waits for the next ArtSync
    inp.feed(0.03, bytes(a.artsync_header), SENDER)
    assert values(inp, 0.03) == {"head_pan": 50.0}


def test_a_flood_is_dropped_and_said_at_most_once_a_second():
    inp = sacn_input()
    for i in range(1000):  # 1000 packets in 0.1 s from one sender: over rate 1000/s, burst 200
        inp.feed(i * 1e-4, e131(sequence=i % 256), SENDER)
    lines = [e for t in (0.1, 0.5, 1.05, 1.2) for e in inp.poll(t).events
             if e.kind == "input_dropped" and e.detail["reason"] == "flood"]  # fmt: skip
    assert inp.guard.drops.by_kind["flood"] > 600
    assert [round(e.t, 2) for e in lines] == [0.1]  # 0.5 s and 1.05 s: within its second


def test_two_consoles_taking_a_universe_in_turn_are_a_line_a_second_the_last_said():
    """Two senders, one flapping its priority above and below the other's 1000 times a
    second for 3 s: every packet is elected as E1.31 says, but the ``dmx_source`` lines are
    4 at once then one a second, and the last one names the source left winning."""
    inp = sacn_input()
    lines = []
    for k in range(3000):
        t = k / 1000
        inp.feed(t, e131(cid=CID_A, priority=100, sequence=k % 256), SENDER)
        flap = 150 if k % 2 == 0 else 50
        inp.feed(t, e131(cid=CID_B, priority=flap, sequence=k % 256), ("127.0.0.2", 5568))
        if k % 4 == 0:
            lines += [e for e in inp.poll(t).events if e.kind == "dmx_source"]
    lines += [e for e in inp.poll(5.0).events if e.kind == "dmx_source"]
    assert len(lines) <= 4 + 3 + 2
    said = lines[-1].detail["message"]  # k = 2999: B at 50, so A (priority 100) holds it
    assert "(priority 100) takes over" in said and "held back" in said


def test_artnet_broadcast_is_heard_with_broadcast_and_off_loopback_by_default(tmp_path):
    """A console sending Art-Net to the subnet's broadcast (here loopback's, 127.255.255.255)
    reaches a socket bound to any address, never one bound to the interface's own address:
    ``broadcast = true`` binds so (the default off loopback); the allow-list still decides."""
    import socket

    from hilsim.live.dmx_config import read_dmx
    from hilsim.rig.reader import Reader

    fed = threading.Semaphore(0)

    class Signalled(DmxInput):
        def feed(self, t, data, sender):
            super().feed(t, data, sender)
            fed.release()

    cfg = DmxConfig("artnet", (DmxJoint("head_pan", 0, 1, 16, -50.0, 10.0, 50.0),), port=0,
                    broadcast=True)  # fmt: skip
    inp = Signalled(cfg)
    rx = listen(inp, lambda: 1.0)
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        artdmx = b"Art-Net\0\x00\x50\x00\x0e\x01\x00\x00\x00\x00\x02\xff\xff"
        s.sendto(artdmx, ("127.255.255.255", rx.address[1]))
        assert fed.acquire(timeout=5.0), "the broadcast was not heard"
        assert values(inp, 1.0) == {"head_pan": 50.0}
    finally:
        s.close()
        rx.close()
    limits = {"head_pan": (-50.0, 50.0)}
    joints = {"head_pan": {"universe": 0, "channel": 1}}
    lan = {"interface": "192.168.1.10", "allow": ["192.168.1.20"], "joints": joints}
    assert read_dmx(Reader(tmp_path, lan, "inputs.artnet"), "artnet", limits).broadcast
    assert not read_dmx(Reader(tmp_path, {"joints": joints}, "inputs.artnet"), "artnet",
                        limits).broadcast  # fmt: skip
    with pytest.raises(hilsim.RigError, match="broadcast is Art-Net's"):
        read_dmx(Reader(tmp_path, {"broadcast": True, "joints": {"head_pan": {
            "universe": 1, "channel": 1}}}, "inputs.sacn"), "sacn", limits)  # fmt: skip
