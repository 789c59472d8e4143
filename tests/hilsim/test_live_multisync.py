"""FPP MultiSync remote: a master emulated from FPP's documented packets (Open, Start, Sync at
4 Hz, Stop) drives the show time; the commanded positions match the same animation played
alone, shifted by the master's time; a 5 s seek relocks through the springs and the safety
filter. Virtual time on the emulator; no wall-clock figure is asserted."""

from __future__ import annotations

import contextlib
import struct
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hilsim.live.multisync import (
    MultiSyncConfig,
    MultiSyncError,
    MultiSyncRemote,
    SyncMessage,
    build_multisync,
    listen,
    parse_multisync,
)
from hilsim.rig import load_rig
from hilsim.show.parts import build_parts, with_show
from hilsim.show.session import open_bus, open_telemetry, port_for, run_show
from hilsim.show.stop import StopFlag
from hilsim.telemetry.reader import read_run

PERIOD = 0.004
SPEED = 200.0
SENDER = ("127.0.0.1", 32320)
SONG = "song.fseq"


def fpp_packet(action: int, seconds: float, name: str, frame: int = 0) -> bytes:
    """A MultiSync packet laid out byte by byte from FPP's description (not our builder)."""
    extra = bytes([action, 0]) + struct.pack("<I", frame) + struct.pack("<f", seconds)
    extra += name.encode() + b"\0"
    return b"FPPD" + bytes([1]) + struct.pack("<H", len(extra)) + extra


def test_the_packet_layout_and_our_builder_agree():
    raw = fpp_packet(2, 12.5, SONG, 250)
    assert build_multisync("sync", 12.5, SONG, 250) == raw
    assert parse_multisync(raw) == SyncMessage("sync", False, 250, 12.5, SONG)
    assert parse_multisync(b"FPPD\x04\x00\x00") is None  # a ping (type 4): not ours
    remote = MultiSyncRemote(MultiSyncConfig())
    remote.feed(0.0, b"FPPD\x04\x00\x00", SENDER)
    assert remote.poll(0.0) == [] and remote.counts["other_packets"] == 1
    for bad in (b"FPPX\x01\x00\x00", raw[:-1], raw[:7] + b"\x09" + raw[8:]):
        with pytest.raises(MultiSyncError):
            parse_multisync(bad)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(st.binary(max_size=80),
                 st.binary(max_size=40).map(lambda b: fpp_packet(2, 1.0, SONG)[:9] + b)))  # fmt: skip
def test_nothing_but_its_own_error_leaves_the_parser(data):
    with contextlib.suppress(MultiSyncError):
        parse_multisync(data)
    remote = MultiSyncRemote(MultiSyncConfig())
    remote.feed(0.0, data, SENDER)
    remote.poll(0.01)
    assert remote.guard.drops.by_kind["internal"] == 0


def test_the_remote_follows_start_sync_seek_and_stop():
    r = MultiSyncRemote(MultiSyncConfig(sequence=SONG))
    assert r.show_time(3.0) == 0.0  # before a start: the first frame
    r.feed(1.0, fpp_packet(3, 0.0, SONG), SENDER)
    r.feed(1.0, fpp_packet(3, 0.0, "other.fseq"), SENDER)
    r.feed(1.0, fpp_packet(0, 0.0, SONG), SENDER)
    kinds = [e.kind for e in r.poll(1.004)]
    assert kinds == ["multisync_open", "multisync_ignored", "multisync_start"]
    assert r.show_time(1.5) == pytest.approx(0.5)
    r.feed(1.5, fpp_packet(2, 0.52, SONG), SENDER)  # 20 ms of drift: re-anchored, no event
    assert r.poll(1.5) == [] and r.show_time(2.0) == pytest.approx(1.02)
    r.feed(2.0, fpp_packet(2, 6.0, SONG), SENDER)
    (seek,) = r.poll(2.0)
    assert seek.kind == "multisync_seek" and seek.detail["to_s"] == pytest.approx(6.0)
    r.feed(2.5, fpp_packet(1, 6.5, SONG), SENDER)
    (stop,) = r.poll(2.6)
    assert stop.kind == "multisync_stop" and "holding at 6.500 s" in stop.detail["message"]
    assert r.show_time(10.0) == pytest.approx(6.5) and not r.stop_requested


def test_a_master_that_goes_quiet_is_lost_and_on_stop_stop_asks_for_the_exit_policy():
    r = MultiSyncRemote(MultiSyncConfig(on_stop="stop"))
    r.feed(0.0, fpp_packet(0, 3.0, SONG), SENDER)
    r.poll(0.0)
    assert r.poll(2.5) == []
    (ev,) = r.poll(2.504)
    assert ev.kind == "input_lost" and "exit policy" in ev.detail["message"]
    assert r.stop_requested and r.show_time(9.0) == pytest.approx(5.504)


def test_a_real_loopback_socket_is_heard():
    fed = threading.Semaphore(0)

    class Signalled(MultiSyncRemote):
        def feed(self, t, data, sender):
            super().feed(t, data, sender)
            fed.release()

    r = Signalled(MultiSyncConfig(port=0))
    rx = listen(r, lambda: 1.0)
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.sendto(fpp_packet(0, 4.0, SONG), rx.address)
        assert fed.acquire(timeout=5.0), "the receiver did not feed the packet"
        assert [e.kind for e in r.poll(1.0)] == ["multisync_start"]
        assert r.show_time(1.25) == pytest.approx(4.25)
    finally:
        s.close()
        rx.close()


@pytest.mark.parametrize("storm", ["seeks", "starts and stops"])
def test_a_storm_of_well_formed_packets_is_a_line_a_second_and_its_last_state_is_said(storm):
    """A master (or anyone on loopback) seeking, or starting and stopping, 1000 times a
    second for 3 s: every packet acts, but the lines are 4 at once then one a second, and the
    last line says the state the storm left."""
    r = MultiSyncRemote(MultiSyncConfig(sequence=SONG))
    r.feed(0.0, fpp_packet(0, 0.0, SONG), SENDER)
    lines = [e for e in r.poll(0.0)]
    for k in range(1, 3001):
        t = k / 1000
        if storm == "seeks":
            packet = fpp_packet(2, 10.0 * (k % 2) + t, SONG)
        else:
            packet = fpp_packet(0 if k % 2 == 0 else 1, t, SONG)
        r.feed(t, packet, SENDER)
        if k % 4 == 0:
            lines += r.poll(t)
    lines += r.poll(5.0)  # the storm is over: what was held back is said
    kinds = [e.kind for e in lines if e.kind.startswith("multisync_")]
    assert len(kinds) <= 1 + 4 + 3 + 2  # the start, a burst of 4, one a second, the last
    if storm == "seeks":
        assert r.counts["seeks"] == 3000  # each acted
        last = [e for e in lines if e.kind == "multisync_seek"][-1]
        assert last.detail["to_s"] == pytest.approx(3.0) and "held back" in last.detail["message"]
        assert r.show_time(3.0) == pytest.approx(3.0)
    else:
        assert kinds[-1] == "multisync_start" and r.state == "playing"  # k = 3000: a start


# ------------------------------------------------------------------------------ a show
RIG = f"""
name = "remote"
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
target = {{ type = "sine", amplitude_deg = 30, frequency_hz = 0.25 }}
"""
SHOW = f"""
[inputs.multisync]
sequence = "{SONG}"
"""


def run(tmp_path: Path, duration: float, sends=None) -> SimpleNamespace:
    (tmp_path / "rig.toml").write_text(RIG)
    rig = load_rig(tmp_path / "rig.toml")
    parts = build_parts(rig)
    if sends is not None:
        (tmp_path / "show.toml").write_text(SHOW)
        parts = with_show(parts, str(tmp_path / "show.toml"), False, virtual=True)
        director = parts.director
        real_tick = director.tick

        def tick(k, t, present):
            real_tick(k, t, present)
            for data in sends(k):
                director.multisync.feed(k * PERIOD, data, SENDER)

        director.tick = tick
    bus = open_bus(rig, port_for(rig, True))
    out = tmp_path / ("remote" if sends else "alone")
    tel = open_telemetry(rig, out, True)
    try:
        run_show(parts, bus, tel, duration_s=duration, stop=StopFlag())
    finally:
        bus.close()
    r = read_run(out)
    return SimpleNamespace(cmd=np.degrees(r.joint("cmd")[:, 0]), events=r.events)


def test_a_remote_plays_the_animation_at_the_masters_time_and_relocks_after_a_seek(tmp_path):
    """Start at 1 s (master 0 s), Sync at 4 Hz, a 5 s seek at 5 s, Stop at 9 s."""
    k0, k_seek, k_stop = 250, 1250, 2250

    def master_s(k):
        return (k - k0) * PERIOD + (5.0 if k >= k_seek else 0.0)

    def sends(k):
        if k == k0 - 50:
            return [fpp_packet(3, 0.0, SONG)]
        if k == k0:
            return [fpp_packet(0, 0.0, SONG)]
        if (k0 < k < k_stop and (k - k0) % 62 == 0) or k == k_seek:
            return [fpp_packet(2, master_s(k), SONG, frame=int(master_s(k) / 0.025))]
        if k == k_stop:
            return [fpp_packet(1, master_s(k), SONG)]
        return []

    remote = run(tmp_path, 10.0, sends).cmd
    alone = run(tmp_path, 16.0).cmd

    def within_one_tick(j, shift):
        """No further from the animation alone than it moves in one tick (+1e-6 deg: the
        master's seconds are a float32)."""
        a_prev, a, a_next = alone[j - shift - 1 : j - shift + 2]
        return abs(remote[j] - a) <= max(abs(a - a_prev), abs(a_next - a)) + 1e-6

    before = [j for j in range(k0 + 125, k_seek) if not within_one_tick(j, k0)]
    assert before == []
    shift_after = k0 - round(5.0 / PERIOD)  # the master's time is 5 s further on
    after = [j for j in range(k_seek + 500, k_stop) if not within_one_tick(j, shift_after)]
    assert after == []
    assert np.max(np.abs(np.diff(remote))) / PERIOD <= SPEED * (1 + 1e-9)
    held = remote[k_stop + 200 :]
    assert np.ptp(held) < 1e-6  # stopped: held where the master stopped
    assert np.max(np.abs(remote[: k0 - 10])) < 1e-6  # before the start: the first frame


def test_a_timeline_clip_named_for_the_sequence_plays_at_the_masters_time(tmp_path):
    """``[[timeline]] at_s = 0, clip = "song"``: the clip's targets are sampled at the master's
    seconds (started at 1 s, synced at 4 Hz), and the show has no end of its own."""
    show = (
        SHOW
        + """
[clips.song]
head_pan = { type = "sine", amplitude_deg = 20, frequency_hz = 0.5 }
[[timeline]]
at_s = 0
clip = "song"
"""
    )
    (tmp_path / "rig.toml").write_text(RIG)
    (tmp_path / "show.toml").write_text(show)
    rig = load_rig(tmp_path / "rig.toml")
    parts = with_show(build_parts(rig), str(tmp_path / "show.toml"), False, virtual=True)
    director, real_tick = parts.director, parts.director.tick
    k0 = 250

    def tick(k, t, present):
        real_tick(k, t, present)
        if k >= k0 and (k - k0) % 62 == 0:
            director.multisync.feed(k * PERIOD, fpp_packet(0 if k == k0 else 2,
                                                           (k - k0) * PERIOD, SONG), SENDER)  # fmt: skip

    director.tick = tick
    assert director.tracks[0].duration is None  # followed: no end of its own
    bus = open_bus(rig, port_for(rig, True))
    tel = open_telemetry(rig, tmp_path / "run", True)
    try:
        run_show(parts, bus, tel, duration_s=4.0, stop=StopFlag())
    finally:
        bus.close()
    target = np.degrees(read_run(tmp_path / "run").joint("target")[:, 0])
    k = np.arange(k0 + 1, 1000)
    want = 20 * np.sin(2 * np.pi * 0.5 * (k - k0) * PERIOD)
    assert np.max(np.abs(target[k] - want)) < 1e-4  # float32 seconds


def test_mtc_and_multisync_together_are_one_line(tmp_path):
    import hilsim

    (tmp_path / "rig.toml").write_text(RIG)
    (tmp_path / "show.toml").write_text(SHOW + "[inputs.mtc]\n")
    with pytest.raises(hilsim.RigError, match=r"inputs\.mtc sets the show time too"):
        hilsim.Show(tmp_path / "rig.toml", virtual_time=True, show=tmp_path / "show.toml")


# ------------------------------------------------------------------------------ one clock
def test_two_figures_on_one_host_hear_one_master_by_multicast_and_agree_on_show_time(tmp_path):
    """Two directors (two figures' shows on one host) with ``multicast = true`` on one port:
    every packet the master multicasts reaches both (each socket joined 239.70.80.80, the
    kernel hands a multicast datagram to each), so both command the same show time, tick by
    tick. One virtual clock stamps both (no timing is asserted)."""
    import socket

    from drivers.clock import VirtualClock
    from hilsim.live.multisync import MULTISYNC_GROUP
    from hilsim.live.netguard import NetGuardError

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:  # a free port for both
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    (tmp_path / "rig.toml").write_text(RIG)
    (tmp_path / "show.toml").write_text(SHOW + f"port = {port}\nmulticast = true\n")
    rig = load_rig(tmp_path / "rig.toml")
    clock, fed = VirtualClock(), threading.Semaphore(0)
    directors = []
    for _ in range(2):
        d = with_show(build_parts(rig), str(tmp_path / "show.toml"), False, virtual=True).director
        real_feed = d.multisync.feed

        def feed(t, data, sender, real_feed=real_feed):
            real_feed(t, data, sender)
            fed.release()

        d.multisync.feed = feed  # the receiver feeds this one
        directors.append(d)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for d in directors:
            try:
                d.open(clock, lambda line: None)
            except NetGuardError as exc:  # a host without multicast on loopback
                pytest.skip(str(exc))
            d.begin(0.0, lambda *a, **k: None, None)
        tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
        master = [(0.5, fpp_packet(0, 0.0, SONG))]  # Start at 0.5 s, Sync at 4 Hz
        master += [(0.5 + i * 0.25, fpp_packet(2, i * 0.25, SONG)) for i in range(1, 9)]
        shows = []
        for k in range(800):  # 3.2 s of ticks; each packet sent when its time comes
            t = k * PERIOD
            while master and master[0][0] <= t:
                at, packet = master.pop(0)
                clock.advance(at - clock.now())  # both receivers stamp the packet at `at`
                tx.sendto(packet, (MULTISYNC_GROUP, port))
                for _ in directors:
                    assert fed.acquire(timeout=5.0), "a figure did not hear the master"
            for d in directors:
                d.tick(k, t, [0.0])
            shows.append([t + d.offset for d in directors])
    finally:
        tx.close()
        for d in directors:
            d.close_inputs()
    shows = np.array(shows)
    assert np.array_equal(shows[:, 0], shows[:, 1])  # one clock: the same show time, every tick
    assert [d.multisync.counts["packets"] for d in directors] == [9, 9]
    assert shows[-1, 0] == pytest.approx(3.2 - PERIOD - 0.5)  # the master's time, run on
