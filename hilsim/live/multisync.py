"""FPP MultiSync remote: a Falcon Player master's sync packets -> the show time, per tick.

A master FPP playing a sequence sends, on UDP 32320 (multicast 239.70.80.80 or unicast to its
remotes), control packets ``'FPPD'``, type (1 = MultiSync), ExtraDataLen (u16), then the
MultiSync data: action (0 Start, 1 Stop, 2 Sync, 3 Open), file type (0 fseq, 1 media), the
frame number (u32), the seconds elapsed (float32) and the file name, NUL-terminated. The
numbers are little-endian (FPP's packed structs on its ARM and x86 hosts). Sync comes every
few frames (2-4 a second once running). Other packet types (Ping, commands) are ignored.

The remote follows one ``sequence`` (a file name; empty: whichever the master plays): the
show time is the master's seconds elapsed (minus ``offset_s``), run on from the last packet by
the loop's own clock. Each Sync re-anchors it; a Sync further than ``jump_s`` from where the
show time was (a seek, a dropped-out master) is said in one ``multisync_seek`` event (a storm
of them, or of starts and stops: a line a second, the last one said). The show time drives
the rig's animation and the show's timeline like the MTC chase does, so the figure plays the
animation at the master's time; a seek is a step in the *target*, and each joint's spring and
the safety filter carry the command there (never a jump).

Before a Start the show time holds at 0 (the first frame's pose). On Stop (or no packet for
``lost_after_s`` while playing): ``on_stop = "hold"`` holds the show time where it stopped
(``multisync_stop`` / ``input_lost``), ``"stop"`` ends the show by its exit policy.
Packets pass :class:`~hilsim.live.netguard.NetGuard` first; :func:`parse_multisync` raises only
:class:`MultiSyncError`. Keys and an FPP set-up: ``docs/live.md`` (FPP MultiSync).
"""

from __future__ import annotations

import ipaddress
import math
import struct
import threading
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from hilsim.live.inbox import LineGate, LiveEvent
from hilsim.live.netguard import Address, DropLog, GuardConfig, NetGuard, UdpReceiver, read_guard
from hilsim.rig.reader import Reader

MULTISYNC_PORT = 32320
MULTISYNC_GROUP = "239.70.80.80"
ACTIONS = {0: "start", 1: "stop", 2: "sync", 3: "open"}
ON_STOP = ("hold", "stop")
#: the lines a storm of packets could repeat, and the gate key each is held back under
_GATED = {"multisync_open": "state", "multisync_start": "state", "multisync_stop": "state",
          "multisync_seek": "seek"}  # fmt: skip
_HEAD = struct.Struct("<4sBH")
_SYNC = struct.Struct("<BBIf")


class MultiSyncError(ValueError):
    """The bytes are not a well-formed FPP control packet."""


@dataclass(frozen=True)
class SyncMessage:
    action: str  # start | stop | sync | open
    media: bool  # file type 1 (media) rather than 0 (fseq)
    frame: int
    seconds: float
    filename: str


def parse_multisync(data: bytes) -> SyncMessage | None:
    """A MultiSync message; ``None`` for another valid FPP control packet (ping, command)."""
    d = bytes(data)
    if len(d) < _HEAD.size:
        raise MultiSyncError(f"{len(d)} bytes: shorter than an FPP control packet")
    magic, kind, extra = _HEAD.unpack_from(d)
    if magic != b"FPPD":
        raise MultiSyncError("no 'FPPD' header")
    if extra != len(d) - _HEAD.size:
        raise MultiSyncError(f"ExtraDataLen {extra} for {len(d) - _HEAD.size} bytes")
    if kind != 1:
        return None
    if extra < _SYNC.size + 1:
        raise MultiSyncError(f"MultiSync: {extra} bytes of data, shorter than {_SYNC.size + 1}")
    action, ftype, frame, seconds = _SYNC.unpack_from(d, _HEAD.size)
    if action not in ACTIONS or ftype > 1:
        raise MultiSyncError(f"MultiSync: action {action}, file type {ftype}")
    if not (math.isfinite(seconds) and 0.0 <= seconds <= 7 * 86400.0):
        raise MultiSyncError(f"MultiSync: seconds elapsed {seconds!r}")
    name = d[_HEAD.size + _SYNC.size :]
    nul = name.find(b"\0")
    if nul < 0:
        raise MultiSyncError("MultiSync: the file name is not NUL-terminated")
    try:
        filename = name[:nul].decode("utf-8")
    except UnicodeDecodeError:
        raise MultiSyncError("MultiSync: the file name is not UTF-8") from None
    return SyncMessage(ACTIONS[action], ftype == 1, frame, float(seconds), filename)


def build_multisync(action: str, seconds: float, filename: str, frame: int = 0) -> bytes:
    """A MultiSync packet as the layout above describes it (tests' and tools' master)."""
    code = {v: k for k, v in ACTIONS.items()}[action]
    body = _SYNC.pack(code, 0, frame, seconds) + filename.encode() + b"\0"
    return _HEAD.pack(b"FPPD", 1, len(body)) + body


@dataclass(frozen=True)
class MultiSyncConfig:
    """``[inputs.multisync]``."""

    sequence: str = ""  # the master's file followed ("" : any)
    port: int = MULTISYNC_PORT
    guard: GuardConfig = field(default_factory=GuardConfig)
    multicast: bool = False  # join 239.70.80.80 on the interface
    offset_s: float = 0.0  # show time = master seconds - offset_s
    jump_s: float = 0.1  # a Sync further than this from the running show time: a seek
    lost_after_s: float = 2.5  # no packet this long while playing: lost (then on_stop)
    on_stop: str = "hold"
    max_rx_per_s: float = 2000.0  # the receiver thread's read cap (netguard.UdpReceiver)


class MultiSyncRemote:
    """``feed`` on the receiver's side, ``poll(t)`` once per tick (module docstring)."""

    source = "multisync"

    def __init__(self, config: MultiSyncConfig) -> None:
        if config.on_stop not in ON_STOP:
            raise ValueError(f"on_stop = {config.on_stop!r}: one of {', '.join(ON_STOP)}")
        self.config = config
        self.guard = NetGuard(config.guard)
        self._lock = threading.Lock()
        self._inbox: deque[tuple[float, SyncMessage]] = deque(maxlen=64)
        self._drop_log = DropLog()
        self._gate = LineGate()
        self.state = "waiting"  # waiting | playing | stopped | lost
        self._anchor: tuple[float, float] | None = None  # (loop t, show time) of the last packet
        self._last_rx = -math.inf
        self._other: set[str] = set()
        self.stop_requested = False
        self.counts = {"packets": 0, "syncs": 0, "seeks": 0, "other_sequence": 0,
                       "other_packets": 0}  # fmt: skip

    def feed(self, t: float, data: bytes, sender: Address | str) -> None:
        """One datagram at show time ``t``. Never raises."""
        host = sender[0] if isinstance(sender, tuple) else str(sender)
        try:
            if self.guard.admit(t, len(data), host) is not None:
                return
            try:
                msg = parse_multisync(data)
            except MultiSyncError:
                self.guard.drops.count("malformed")
                return
            with self._lock:
                if msg is None:  # a ping, a command: valid, not for a remote's time
                    self.counts["other_packets"] += 1
                    return
                if len(self._inbox) == self._inbox.maxlen:
                    self.guard.drops.count("queue_full")
                self._inbox.append((t, msg))
        except Exception:
            self.guard.drops.count("internal")

    def show_time(self, t: float) -> float:
        """The show time at loop time ``t``: the master's, run on while playing, else held."""
        if self._anchor is None:
            return 0.0
        t_a, s_a = self._anchor
        return s_a + (t - t_a) if self.state == "playing" else s_a

    def poll(self, t: float) -> list[LiveEvent]:
        """Apply what arrived by ``t``; data loss; drop lines. Bounded, no clock reads."""
        with self._lock:
            got = list(self._inbox)
            self._inbox.clear()
        out: list[LiveEvent] = []
        applied: list[LiveEvent] = []
        for tm, msg in got:
            self._apply(tm, msg, applied)
        for ev in applied:  # a storm of starts, stops or seeks: a line a second (LineGate)
            key = _GATED.get(ev.kind)
            if key is None or (ev.kind == "multisync_stop" and self.stop_requested):
                out.append(ev)  # the line that ends the show is never held back
            elif (said := self._gate.offer(ev, key)) is not None:
                out.append(said)
        out += self._gate.due(t)
        if self.state == "playing" and t - self._last_rx > self.config.lost_after_s:
            self._anchor = (t, self.show_time(t))
            self.state = "lost"
            self._end(t, "input_lost", f"no MultiSync packet for more than "
                      f"{self.config.lost_after_s:g} s", out)  # fmt: skip
        for line in self._drop_log.lines(t, self.guard.drops.snapshot()):
            out.append(self._event(t, "input_dropped", f"MultiSync: {line.new} dropped "
                                   f"({line.kind}) since the last report, {line.total} in all",
                                   reason=line.kind, new=line.new, total=line.total))  # fmt: skip
        return out

    def _apply(self, t: float, msg: SyncMessage, out: list[LiveEvent]) -> None:
        want = self.config.sequence
        if want and msg.filename != want:
            self.counts["other_sequence"] += 1
            if msg.filename not in self._other and len(self._other) < 64:
                self._other.add(msg.filename)
                said = f"MultiSync: {msg.filename!r} is not {want!r}: not followed"
                out.append(self._event(t, "multisync_ignored", said, file=msg.filename))
            return
        self.counts["packets"] += 1
        self._last_rx = t
        show = msg.seconds - self.config.offset_s
        if msg.action == "open":
            out.append(self._event(t, "multisync_open", f"MultiSync: master opened "
                                   f"{msg.filename!r}", file=msg.filename))  # fmt: skip
        elif msg.action == "stop":
            if self.state == "playing":
                self._anchor = (t, self.show_time(t))
                self.state = "stopped"
                self._end(t, "multisync_stop", f"MultiSync: master stopped {msg.filename!r}", out)
        else:  # start, or a sync (which starts a remote that missed the start, as FPP's do)
            self.counts["syncs"] += msg.action == "sync"
            was, playing = self.show_time(t), self.state == "playing"
            self._anchor = (t, show)
            if not playing:
                self.state = "playing"
                out.append(self._event(t, "multisync_start", f"MultiSync: following "
                                       f"{msg.filename!r} from {show:.3f} s",
                                       file=msg.filename, show_s=show))  # fmt: skip
            elif abs(show - was) > self.config.jump_s:
                self.counts["seeks"] += 1
                out.append(self._event(t, "multisync_seek", f"MultiSync: {msg.filename!r} "
                                       f"moved from {was:.3f} s to {show:.3f} s",
                                       from_s=was, to_s=show))  # fmt: skip

    def _end(self, t: float, kind: str, message: str, out: list[LiveEvent]) -> None:
        stop = self.config.on_stop == "stop"
        then = "the show stops (exit policy)" if stop else f"holding at {self.show_time(t):.3f} s"
        out.append(self._event(t, kind, f"{message}: {then}"))
        if stop:
            self.stop_requested = True

    def _event(self, t: float, kind: str, message: str, **detail: Any) -> LiveEvent:
        return LiveEvent(t, kind, self.source, {"message": message, **detail})

    def summary(self) -> dict[str, Any]:
        return {**self.counts, "state": self.state, "drops": self.guard.drops.snapshot()}


def listen(remote: MultiSyncRemote, clock: Any, **kw: Any) -> UdpReceiver:
    """The UDP socket (``multicast``: 239.70.80.80 joined) feeding ``remote`` from a thread."""
    cfg = remote.config
    groups = (MULTISYNC_GROUP,) if cfg.multicast else ()
    kw.setdefault("max_rx_per_s", cfg.max_rx_per_s)
    return UdpReceiver(remote.guard, remote.feed, cfg.port, clock, name="MultiSync",
                       groups=groups, **kw)  # fmt: skip


def read_multisync(r: Reader) -> MultiSyncConfig:
    """``[inputs.multisync]`` from the show file. Raises RigError (one line)."""
    guard = read_guard(r, 512)
    on_stop = r.get("on_stop", str, "hold")
    if on_stop not in ON_STOP:
        raise r.fail("on_stop", f"one of {', '.join(ON_STOP)}; got {on_stop!r}")
    off_loopback = not ipaddress.ip_address(guard.bind_address).is_loopback
    out = MultiSyncConfig(
        sequence=r.get("sequence", str, ""),
        port=r.integer("port", MULTISYNC_PORT, lo=1, hi=65535),
        guard=guard,
        multicast=r.get("multicast", bool, off_loopback),
        offset_s=r.number("offset_s", 0.0, at_least=-86400.0, at_most=86400.0),
        jump_s=r.number("jump_s", 0.1, positive=True, at_most=3600.0),
        lost_after_s=r.number("lost_after_s", 2.5, positive=True, at_most=3600.0),
        on_stop=on_stop,
        max_rx_per_s=r.number("max_rx_per_s", 2000.0, positive=True, at_most=1e6),
    )  # fmt: skip
    r.finish()
    return out
