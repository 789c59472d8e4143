"""The network guard: listening address, allow-list, token bucket on show time, drop lines."""

from __future__ import annotations

import math
import os
import socket
import sys
import threading
import time

import pytest

from hilsim.live import netguard
from hilsim.live.netguard import (
    DropCounts,
    DropLog,
    GuardConfig,
    NetGuard,
    NetGuardError,
    TokenBucket,
    UdpReceiver,
)


def test_loopback_by_default_and_loopback_senders_only():
    guard = NetGuard()
    assert guard.config.bind_address == "127.0.0.1"
    assert guard.admit(0.0, 20, "127.0.0.1") is None
    assert guard.admit(0.0, 20, "::1") is None
    assert guard.admit(0.0, 20, "192.168.1.20") == "sender"
    assert guard.drops.by_kind["sender"] == 1


def test_an_interface_needs_an_allow_list():
    with pytest.raises(NetGuardError, match="name the senders allowed"):
        GuardConfig(interface="0.0.0.0")
    cfg = GuardConfig(interface="0.0.0.0", allow=("192.168.1.20", "10.0.0.0/24"))
    guard = NetGuard(cfg)
    assert guard.admit(0.0, 20, "192.168.1.20") is None
    assert guard.admit(0.0, 20, "10.0.0.77") is None
    assert guard.admit(0.0, 20, "::ffff:10.0.0.9") is None  # IPv4-mapped, as a dual socket sees it
    assert guard.admit(0.0, 20, "192.168.1.21") == "sender"
    assert guard.admit(0.0, 20, "127.0.0.1") == "sender"  # the allow-list is the whole list
    assert guard.admit(0.0, 20, "not-an-address") == "sender"
    assert guard.drops.by_kind["sender"] == 3


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"interface": "eth0"}, "is not an IP address"),
        ({"allow": ("192.168.1.300",)}, "not an IP address or network"),
        ({"max_packet_bytes": 0}, "max_packet_bytes"),
        ({"max_packet_bytes": 70000}, "max_packet_bytes"),
        ({"burst": 0}, "burst"),
        ({"rate_per_s": math.nan}, "rate_per_s"),
        ({"rate_per_s": -1.0}, "rate_per_s"),
        ({"max_senders": True}, "max_senders"),
    ],
)
def test_bad_configuration_is_one_line(kwargs, match):
    with pytest.raises(NetGuardError, match=match) as err:
        GuardConfig(**kwargs)
    assert "\n" not in str(err.value)


def test_oversized_is_dropped_before_anything_else():
    guard = NetGuard(GuardConfig(max_packet_bytes=64))
    assert guard.admit(0.0, 64, "127.0.0.1") is None
    assert guard.admit(0.0, 65, "192.168.9.9") == "oversized"  # unread: the sender not even judged
    assert guard.drops.snapshot()["oversized"] == 1
    assert guard.drops.snapshot()["sender"] == 0


def test_token_bucket_refills_from_the_timestamps():
    bucket = TokenBucket(rate=100.0, burst=5, t=0.0)
    assert [bucket.take(0.0) for _ in range(6)] == [True] * 5 + [False]
    assert bucket.take(0.005) is False  # half a token
    assert bucket.take(0.010) is True  # one token after 10 ms at 100/s
    assert bucket.take(0.010) is False
    assert bucket.take(-5.0) is False  # time running backwards refills nothing
    assert bucket.take(math.nan) is False
    assert bucket.take(100.0) is True  # refilled, but never beyond the burst
    assert sum(bucket.take(100.0) for _ in range(10)) == 4


def test_flood_from_one_sender_leaves_another_alone():
    guard = NetGuard(GuardConfig(rate_per_s=50.0, burst=10))
    admitted = sum(guard.admit(0.5, 20, "127.0.0.1") is None for _ in range(1000))
    assert admitted == 10
    assert guard.drops.by_kind["flood"] == 990
    assert guard.admit(0.5, 20, "127.0.0.2") is None  # its own bucket
    assert guard.admit(0.7, 20, "127.0.0.1") is None  # 0.2 s at 50/s: 10 more tokens


def test_sender_table_is_bounded():
    guard = NetGuard(GuardConfig(max_senders=4))
    for i in range(1000):
        guard.admit(0.0, 20, f"127.0.{i // 250}.{i % 250}")
    assert len(guard._buckets) == 4
    assert len(guard._allowed) <= 16


def test_drop_log_one_line_per_kind_per_second_of_show_time():
    counts = DropCounts()
    log = DropLog()
    counts.count("malformed", 3)
    (line,) = log.lines(0.0, counts.snapshot())
    assert (line.kind, line.new, line.total) == ("malformed", 3, 3)
    counts.count("malformed", 5)
    counts.count("flood", 2)
    lines = log.lines(0.5, counts.snapshot())
    assert [(x.kind, x.new) for x in lines] == [("flood", 2)]  # malformed waits its second
    assert log.lines(0.99, counts.snapshot()) == []
    lines = log.lines(1.0, counts.snapshot())
    assert [(x.kind, x.new, x.total) for x in lines] == [("malformed", 5, 8)]
    assert log.lines(5.0, counts.snapshot()) == []  # nothing new, nothing said


# -- the UDP receiver (real sockets on 127.0.0.1; blocking waits with a timeout, no sleeping) ----


class _Feed:
    """A feed that records packets; ``hold`` blocks the receiver inside its first feed."""

    def __init__(self, hold: bool = False) -> None:
        self.got: list[tuple[float, bytes, tuple]] = []
        self.fed = threading.Semaphore(0)
        self.release = threading.Event()
        if not hold:
            self.release.set()

    def __call__(self, t, data, sender):
        self.got.append((t, data, sender))
        self.fed.release()
        assert self.release.wait(10.0)


def test_receiver_counts_what_the_kernel_dropped_while_it_was_busy():
    feed = _Feed(hold=True)
    guard = NetGuard()
    rx = UdpReceiver(guard, feed, 0, clock=lambda: 2.0, max_rx_per_s=1e7, rx_burst=100_000)
    try:
        if not rx.overflow_counted:
            pytest.skip("this kernel does not report socket drops (SO_RXQ_OVFL)")
        addr, sent = rx.address, 0
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            tx.sendto(b"first", addr)
            sent += 1
            assert feed.fed.acquire(timeout=5.0)  # the receiver now sits in feed
            for _ in range(5000):  # ~1 MB of datagrams: far past the socket's buffer
                tx.sendto(b"x" * 200, addr)
                sent += 1
            feed.release.set()
            # A marker ends the test; one sent while the buffer is still full is itself dropped
            # (and counted), so another follows whenever the receiver has gone quiet.
            markers = 0
            while not feed.got or feed.got[-1][1] != b"end":
                if not feed.fed.acquire(timeout=0.2):
                    tx.sendto(b"end", addr)
                    sent, markers = sent + 1, markers + 1
        kernel = guard.drops.by_kind["socket_overflow"]
        assert kernel > 0
        assert len(feed.got) < 5000  # most of the flood never reached the receiver ...
        # ... and every datagram was read or counted (but for markers still on their way)
        assert sent - markers < kernel + len(feed.got) <= sent
        assert {t for t, _, _ in feed.got} == {2.0}
    finally:
        feed.release.set()
        rx.close()


def test_receiver_thread_is_not_realtime_and_yields_to_the_loop(monkeypatch):
    """The suite never runs SCHED_FIFO for real (conftest): the policy is faked, the request
    the receiver thread makes for itself is recorded."""
    asked = []
    monkeypatch.setattr(os, "sched_getscheduler", lambda pid: os.SCHED_FIFO, raising=False)
    monkeypatch.setattr(
        os, "sched_setscheduler", lambda pid, policy, param: asked.append((pid, policy))
    )
    niced = []
    monkeypatch.setattr(os, "setpriority", lambda *args: niced.append(args), raising=False)
    feed = _Feed()
    rx = UdpReceiver(NetGuard(), feed, 0, clock=lambda: 0.0)
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            tx.sendto(b"ping", rx.address)
            assert feed.fed.acquire(timeout=5.0)  # the thread has started and set its policy
    finally:
        rx.close()
    assert asked == [(0, os.SCHED_OTHER)]
    assert niced == [(os.PRIO_PROCESS, rx._thread.native_id, 19)]  # the receiver thread only


@pytest.mark.parametrize(("stamps", "late_s", "want"), [(False, 0.25, (2.0, 2.0)),
                                                         (True, 0.25, (1.0, 1.75)),
                                                         (True, 30.0, (1.0, 1.0))])  # fmt: skip
def test_arrival_stamps_are_the_kernels_not_when_the_thread_got_to_read(
    monkeypatch, stamps, late_s, want
):
    """With ``arrival_stamps`` the datagram is stamped when the kernel received it: a reader
    that got to it ``late_s`` later (the real clock shifted that far on) takes the delay off
    its clock (at most MAX_ARRIVAL_AGE_S, 1 s). Without, the stamp is the clock at read."""
    if not sys.platform.startswith("linux"):
        pytest.skip("kernel arrival stamps are Linux's SO_TIMESTAMPNS")
    monkeypatch.setattr(netguard, "_realtime", lambda: time.time() + late_s)
    feed = _Feed()
    rx = UdpReceiver(NetGuard(), feed, 0, clock=lambda: 2.0, arrival_stamps=stamps)
    try:
        assert rx.kernel_stamps == stamps
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            tx.sendto(b"ping", rx.address)
            assert feed.fed.acquire(timeout=5.0)
    finally:
        rx.close()
    ((t, data, _),) = feed.got
    assert data == b"ping" and want[0] <= t <= want[1]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"max_rx_per_s": 0}, "max_rx_per_s"), ({"rx_burst": 0}, "rx_burst")],
)
def test_receiver_bad_caps_are_one_line(kwargs, match):
    with pytest.raises(NetGuardError, match=match):
        UdpReceiver(NetGuard(), _Feed(), 0, clock=lambda: 0.0, **kwargs)
