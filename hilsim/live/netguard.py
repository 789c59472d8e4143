"""Who may talk to a network input, and how much: nobody else drives the figure.

A network input passes every datagram through one :class:`NetGuard` before it decodes a
byte of it, cheapest check first:

1. **size**: more than ``max_packet_bytes`` is dropped unread (``oversized``);
2. **sender**: a sender outside the allow-list is dropped (``sender``);
3. **rate**: a token bucket per sender, on the packets' show-time stamps (so a test floods
   in virtual time); a packet with no token is dropped (``flood``).

The input counts its own drops here too. :class:`DropCounts` counts by kind; :class:`DropLog`
says at most one line per kind per second of show time. Nothing here raises on a packet.

Listening is on ``127.0.0.1`` unless an interface is named; another interface *requires* an
allow-list. :class:`UdpReceiver` is the receiver thread, held back so a flood cannot starve
the loop: at most ``max_rx_per_s`` reads a second, SCHED_OTHER, nice 19. It counts the
kernel's drops (``socket_overflow``) where Linux reports them.

The rules for users: ``docs/live.md`` (OSC). Why the receiver is capped, measured:
``docs/performance.md``. This module knows nothing of OSC; it imports only the standard library.
"""

from __future__ import annotations

import contextlib
import ipaddress
import math
import os
import socket
import struct
import sys
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hilsim.rig.reader import Reader

DEFAULT_BIND = "127.0.0.1"
LOG_INTERVAL_S = 1.0  # at most one drop line per kind per second of show time

# The kinds a drop is counted under, in the order a report lists them.
DROP_KINDS = (
    "oversized",  # longer than max_packet_bytes
    "sender",  # a sender outside the allow-list
    "flood",  # over the sender's rate (token bucket)
    "malformed",  # not a well-formed packet of the protocol
    "unknown",  # well formed, but an address / name / arguments this input does not use
    "value",  # a value that is NaN, infinite or outside its range (dropped, never clamped)
    "queue_full",  # an event pushed out of the bounded hand-over queue (the oldest goes)
    "internal",  # an unexpected exception while decoding (a bug; the packet is dropped)
    "socket_overflow",  # dropped by the kernel while the receiver was at its own cap (Linux)
)

SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)  # Linux: the socket's kernel-drop counter
#: Linux: each datagram's arrival time stamped by the kernel (a CLOCK_REALTIME timespec)
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_TIMESPEC = struct.Struct("@ll")  # time_t and long: 16 bytes on 64-bit Linux, 8 on 32-bit ARM
#: a kernel stamp older than this (s) is not believed (a realtime clock step): capped
MAX_ARRIVAL_AGE_S = 1.0
_realtime = time.time  # the clock the kernel's stamps are on (a test shifts it)


class NetGuardError(ValueError):
    """A network input's configuration is unusable (one line: what, the value, what is allowed)."""


Network = ipaddress.IPv4Network | ipaddress.IPv6Network
#: a datagram's sender as the socket gives it: (host, port), IPv6 (host, port, flow, scope)
Address = tuple[str, int] | tuple[str, int, int, int]


def _parse_networks(entries: Iterable[str]) -> tuple[Network, ...]:
    nets = []
    for entry in entries:
        try:
            nets.append(ipaddress.ip_network(str(entry).strip(), strict=False))
        except ValueError:
            raise NetGuardError(
                f"allow-list entry {entry!r} is not an IP address or network "
                "(e.g. 192.168.1.20 or 10.0.0.0/24)"
            ) from None
    return tuple(nets)


@dataclass(frozen=True)
class GuardConfig:
    """A network input's safety settings; validated on construction (NetGuardError)."""

    interface: str | None = None  # the address to listen on; None -> 127.0.0.1
    allow: tuple[str, ...] = ()  # senders accepted; () -> loopback senders only
    max_packet_bytes: int = 1024  # a larger datagram is dropped unread
    rate_per_s: float = 1000.0  # packets a second per sender (token bucket refill)
    burst: int = 200  # packets a sender may send at once (bucket size)
    max_senders: int = 64  # buckets kept; the least recently seen is forgotten
    networks: tuple[Network, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "allow", tuple(self.allow))
        object.__setattr__(self, "networks", _parse_networks(self.allow))
        bind = self.bind_address
        try:
            ip = ipaddress.ip_address(bind)
        except ValueError:
            raise NetGuardError(
                f"interface {self.interface!r} is not an IP address "
                "(name the address to listen on, e.g. 127.0.0.1 or 192.168.1.10)"
            ) from None
        if not ip.is_loopback and not self.networks:
            raise NetGuardError(
                f"interface {bind} opens the input to the network: name the senders allowed "
                'to drive the figure (allow = ["192.168.1.20", ...]), or listen on 127.0.0.1'
            )
        checks = (
            ("max_packet_bytes", self.max_packet_bytes, 16, 65507),
            ("burst", self.burst, 1, 1_000_000),
            ("max_senders", self.max_senders, 1, 65536),
        )
        for name, value, lo, hi in checks:
            if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
                raise NetGuardError(f"{name} = {value!r}: an integer in {lo}..{hi}")
        rate = self.rate_per_s
        if (
            isinstance(rate, bool)
            or not isinstance(rate, int | float)
            or not (math.isfinite(rate) and 0 < rate <= 1e6)
        ):
            raise NetGuardError(f"rate_per_s = {rate!r}: packets a second, > 0 and <= 1e6")

    @property
    def bind_address(self) -> str:
        return self.interface if self.interface else DEFAULT_BIND


def read_guard(r: Reader, max_packet_bytes: int) -> GuardConfig:
    """A show file's input section's guard keys (``interface``, ``allow``,
    ``max_packet_bytes``, ``rate_per_s``, ``burst``). Each value is read first, so a bad one
    is its own line; a guard that cannot be built is one line naming the section. Raises
    RigError."""
    from hilsim.rig import RigError

    allow = r.get("allow", list, [])
    if not all(isinstance(a, str) for a in allow):
        raise r.fail("allow", f"a list of addresses or networks as strings, got {allow!r}")
    interface = r.get("interface", str, None)
    max_bytes = r.integer("max_packet_bytes", max_packet_bytes, lo=16, hi=65507)
    rate = r.number("rate_per_s", 1000.0, positive=True, at_most=1e6)
    burst = r.integer("burst", 200, lo=1, hi=1_000_000)
    try:
        return GuardConfig(
            interface=interface,
            allow=tuple(allow),
            max_packet_bytes=max_bytes,
            rate_per_s=rate,
            burst=burst,
        )
    except ValueError as exc:
        raise RigError(f"{r.path}: {r.where}: {exc}") from None


class TokenBucket:
    """``rate`` tokens a second up to ``burst``, refilled from the packets' own timestamps.

    A timestamp earlier than the last one refills nothing (time never runs backwards here)."""

    __slots__ = ("burst", "rate", "t", "tokens")

    def __init__(self, rate: float, burst: int, t: float) -> None:
        self.rate, self.burst = rate, float(burst)
        self.tokens, self.t = float(burst), t

    def take(self, t: float) -> bool:
        dt = t - self.t
        if dt > 0:  # also False for NaN
            self.tokens = min(self.burst, self.tokens + dt * self.rate)
            self.t = t
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


class DropCounts:
    """Drops by kind since the input opened. One writer (the receiver); readers copy."""

    def __init__(self) -> None:
        self.by_kind: dict[str, int] = dict.fromkeys(DROP_KINDS, 0)
        self.version = 0  # changes with every count: a reader skips work when it has not

    def count(self, kind: str, n: int = 1) -> None:
        self.by_kind[kind] = self.by_kind.get(kind, 0) + n
        self.version += 1

    @property
    def total(self) -> int:
        return sum(self.by_kind.values())

    def snapshot(self) -> dict[str, int]:
        return dict(self.by_kind)


@dataclass(frozen=True)
class DropLine:
    kind: str
    new: int  # drops of this kind since the last line about it
    total: int  # drops of this kind since the input opened
    t: float


class DropLog:
    """Counts -> at most one line per kind per LOG_INTERVAL_S of show time (the loop's ``t``)."""

    def __init__(self, interval_s: float = LOG_INTERVAL_S) -> None:
        self.interval_s = interval_s
        self._reported: dict[str, int] = {}
        self._line_t: dict[str, float] = {}
        self.pending = False  # drops counted but not yet said (their kind's second not over)

    def lines(self, t: float, counts: dict[str, int]) -> list[DropLine]:
        out, self.pending = [], False
        for kind, total in counts.items():
            new = total - self._reported.get(kind, 0)
            if new <= 0:
                continue
            if t - self._line_t.get(kind, -math.inf) < self.interval_s:
                self.pending = True
                continue
            out.append(DropLine(kind, new, total, t))
            self._reported[kind] = total
            self._line_t[kind] = t
        return out


class NetGuard:
    """Size, sender and rate checks for one input; every drop counted in ``drops``."""

    def __init__(self, config: GuardConfig | None = None) -> None:
        self.config = config or GuardConfig()
        self.drops = DropCounts()
        self._buckets: OrderedDict[str, TokenBucket] = OrderedDict()
        self._allowed: dict[str, bool] = {}  # host -> verdict, bounded like the buckets

    def sender_allowed(self, host: str) -> bool:
        verdict = self._allowed.get(host)
        if verdict is None:
            verdict = self._judge(host)
            if len(self._allowed) >= 4 * self.config.max_senders:
                self._allowed.clear()
            self._allowed[host] = verdict
        return verdict

    def _judge(self, host: str) -> bool:
        try:
            ip = ipaddress.ip_address(host.split("%", 1)[0])
        except ValueError:
            return False
        if ip.version == 6 and ip.ipv4_mapped is not None:
            ip = ip.ipv4_mapped
        nets = self.config.networks
        if not nets:
            return ip.is_loopback
        return any(ip.version == net.version and ip in net for net in nets)

    def admit(self, t: float, size: int, host: str) -> str | None:
        """None if the packet may be decoded, else the kind it was dropped (and counted) as."""
        cfg = self.config
        if size > cfg.max_packet_bytes:
            kind = "oversized"
        elif not self.sender_allowed(host):
            kind = "sender"
        else:
            bucket = self._buckets.get(host)
            if bucket is None:
                if len(self._buckets) >= cfg.max_senders:
                    self._buckets.popitem(last=False)  # forget the least recently seen
                bucket = self._buckets[host] = TokenBucket(cfg.rate_per_s, cfg.burst, t)
            else:
                self._buckets.move_to_end(host)
            if bucket.take(t):
                return None
            kind = "flood"
        self.drops.count(kind)
        return kind


class UdpReceiver:
    """A UDP socket on ``guard.config.bind_address`` and a thread that stamps each datagram with
    ``clock()`` (show time) and hands it to ``feed(t, data, sender)``, which must not raise
    (a raise is counted ``internal``). At most ``max_rx_per_s`` datagrams a second are read
    (bursts of ``rx_burst``); past that the thread waits and the kernel drops the rest (counted
    ``socket_overflow`` on Linux). ``close()`` ends it within ``timeout_s``. ``groups``: IPv4
    multicast groups joined on the bind address's interface; the socket is then bound to any
    address (multicast reaches no other), so the allow-list alone decides who is heard; so is
    it with ``any_address`` (a subnet's broadcast, e.g. Art-Net's, reaches no other either).
    ``arrival_stamps`` (real clock only): each datagram is stamped when the kernel received it,
    not when this thread got to read it (Linux ``SO_TIMESTAMPNS``; the age the kernel's stamp
    gives is taken off ``clock()``), so a receiver held back by the loop, the interpreter lock
    or a busy host stamps the same instant as another process on the host would."""

    def __init__(
        self,
        guard: NetGuard,
        feed: Callable[[float, bytes, Address], None],
        port: int,
        clock: Callable[[], float],
        *,
        name: str = "UDP",
        max_rx_per_s: float = 2000.0,
        rx_burst: int = 100,
        timeout_s: float = 0.2,
        groups: Sequence[str] = (),
        arrival_stamps: bool = False,
        any_address: bool = False,
    ) -> None:
        self.guard, self.feed, self.clock, self.name = guard, feed, clock, name
        if not (isinstance(max_rx_per_s, int | float) and 0 < max_rx_per_s <= 1e7):
            msg = f"max_rx_per_s = {max_rx_per_s!r}: datagrams a second, 0 < x <= 1e7"
            raise NetGuardError(msg)
        if isinstance(rx_burst, bool) or not isinstance(rx_burst, int) or rx_burst < 1:
            raise NetGuardError(f"rx_burst = {rx_burst!r}: an integer >= 1")
        host = guard.config.bind_address
        sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
        try:
            if groups or any_address:  # multicast and broadcast reach no interface's address
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                sock.bind(("0.0.0.0", port))
                for group in groups:
                    mreq = socket.inet_aton(group) + socket.inet_aton(host)
                    sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
            else:
                sock.bind((host, port))
        except OSError as exc:
            sock.close()
            joined = f" (joining {', '.join(groups)})" if groups else ""
            msg = f"{name}: cannot listen on {host} port {port}{joined}: {exc.strerror}"
            raise NetGuardError(msg) from None
        self.overflow_counted = self.kernel_stamps = False
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
            self.overflow_counted = True
        if arrival_stamps and sys.platform.startswith("linux"):
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
                self.kernel_stamps = True
        sock.settimeout(timeout_s)
        self._sock, self._kernel_drops = sock, 0
        self._last_stamp = -math.inf
        self._bufsize = guard.config.max_packet_bytes + 1  # one byte more: an oversized is seen
        self._budget = TokenBucket(max_rx_per_s, rx_burst, time.monotonic())
        self._refill_s = max(1e-3, rx_burst / 2 / max_rx_per_s)
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"{name}-receiver", daemon=True)
        self._thread.start()

    @property
    def address(self) -> tuple[str, int]:
        host, port = self._sock.getsockname()[:2]  # (IPv6 adds flow info and scope id)
        return host, port

    def _run(self) -> None:
        # A thread inherits its creator's policy: started from a SCHED_FIFO loop, a receiver
        # under a flood would starve the loop. It runs SCHED_OTHER (lowering is always allowed).
        with contextlib.suppress(AttributeError, OSError):
            if os.sched_getscheduler(0) != os.SCHED_OTHER:
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        with contextlib.suppress(AttributeError, OSError):  # Linux: the nice of this thread only
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)
        sock, closing, drops = self._sock, self._closing, self.guard.drops
        anc = socket.CMSG_SPACE(4) if self.overflow_counted else 0
        anc += socket.CMSG_SPACE(_TIMESPEC.size) if self.kernel_stamps else 0
        while not closing.is_set():
            if not self._budget.take(time.monotonic()):
                closing.wait(self._refill_s)  # at the cap: the kernel buffers, then drops
                continue
            try:
                data, ancdata, _flags, sender = sock.recvmsg(self._bufsize, anc)
            except TimeoutError:
                continue
            except OSError:
                if closing.is_set():
                    return
                continue  # e.g. an ICMP port-unreachable report: not a reason to stop
            try:
                kernel_s = None
                for level, kind, raw in ancdata:
                    if level != socket.SOL_SOCKET:
                        continue
                    if kind == SO_RXQ_OVFL and len(raw) >= 4:
                        total = int.from_bytes(raw[:4], sys.byteorder)  # a native uint32
                        if total > self._kernel_drops:
                            drops.count("socket_overflow", total - self._kernel_drops)
                            self._kernel_drops = total
                    elif kind == SO_TIMESTAMPNS and len(raw) >= _TIMESPEC.size:
                        sec, nsec = _TIMESPEC.unpack_from(raw)
                        kernel_s = sec + nsec * 1e-9
                if kernel_s is None:
                    t = self.clock()
                else:  # never before the last datagram's stamp (they arrived in this order)
                    t = self._last_stamp = max(self._last_stamp, self._arrival(kernel_s))
                self.feed(t, data, sender)
            except Exception:  # feed never raises; a broken clock must not end the thread
                drops.count("internal")

    def _arrival(self, kernel_s: float) -> float:
        """``clock()`` when the kernel received the datagram (``kernel_s``, realtime): the
        datagram's age, read between two realtime readings around ``clock()`` (the tightest
        of three tries), so a thread preempted between the readings does not shift it."""
        best_w, t = math.inf, 0.0
        for _ in range(3):
            r1 = _realtime()
            c = self.clock()
            r2 = _realtime()
            if r2 - r1 < best_w:
                best_w = r2 - r1
                age = min(MAX_ARRIVAL_AGE_S, max(0.0, (r1 + r2) / 2 - kernel_s))
                t = max(0.0, c - age) if age > 0.0 else c
            if best_w < 50e-6:
                break
        return t

    def close(self) -> None:
        self._closing.set()
        self._thread.join()
        self._sock.close()
