"""sACN (E1.31) or Art-Net in -> live joint targets, for the director to poll once per tick.

Per universe, as E1.31 receivers do:

- **sources**: each sender (E1.31 CID; Art-Net host) is tracked; the highest priority wins
  (Art-Net: all 100). On a tie the source already winning keeps the universe. A source silent
  for ``lost_after_s`` (2.5 s) or ending its stream (E1.31 "stream terminated") leaves; the
  next one takes over (``dmx_source`` event; sources taking the universe in turn faster than
  that: a line a second per universe, the last one said).
- **sequence**: a packet whose sequence number is 1..19 behind the source's last is late and
  dropped (``late``), as E1.31 says; Art-Net's sequence 0 means "not numbered".
- **sync**: data naming a sync address (E1.31) waits for that address's sync packet, as long
  as sync packets keep coming (within ``lost_after_s``); Art-Net data waits for ArtSync once
  the sender sends ArtSync.
- **loss**: no source left: the universe's joints hold their last value (``input_lost``, once),
  then ``input_returned`` when data comes back.

Values go through :class:`~hilsim.live.dmx_config.DmxJoint` to degrees and reach the figure
through the director (the live layer, each joint's spring, the safety filter). A 0 value holds
by default. Packets pass :class:`~hilsim.live.netguard.NetGuard` first; malformed, late and
flooding packets are dropped and counted (one ``input_dropped`` line per kind per second).

:meth:`DmxInput.feed` is the receiver's side (any thread); :meth:`DmxInput.poll` the loop's:
bounded work, no clock reads. :func:`listen` opens the socket (joining multicast groups).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from hilsim.live.dmx_config import DmxConfig, DmxJoint
from hilsim.live.dmx_packets import (
    DmxData,
    DmxDecodeError,
    DmxSync,
    e131_multicast_group,
    parse_artnet,
    parse_e131,
)
from hilsim.live.inbox import LineGate, LiveEvent
from hilsim.live.netguard import Address, DropLog, NetGuard, UdpReceiver

#: E1.31: a sequence number this far behind the last (or equal) is a late packet
LATE_WINDOW = 20
#: sources tracked per universe; more are dropped (``flood``) until one leaves
MAX_SOURCES = 16


@dataclass
class _Source:
    priority: int
    last_t: float
    label: str
    sequence: int | None = None


@dataclass
class _Universe:
    number: int
    joints: tuple[DmxJoint, ...]
    sources: dict[str, _Source] = field(default_factory=dict)
    winner: str | None = None
    pending: DmxData | None = None  # the winner's data waiting for its sync
    lost: bool = False
    seen: bool = False  # any data applied yet


@dataclass
class DmxPoll:
    """What one poll hands the director: ``values`` (joint, degrees, show time of the
    packet), ``releases`` (joints a 0 hands back, ``zero = "release"``), ``events``."""

    values: list[tuple[str, float, float]] = field(default_factory=list)
    releases: list[str] = field(default_factory=list)
    events: list[LiveEvent] = field(default_factory=list)


class DmxInput:
    """One ``[inputs.sacn]`` or ``[inputs.artnet]`` (module docstring)."""

    def __init__(self, config: DmxConfig) -> None:
        self.config = config
        self.source = config.protocol  # the live layer's holder name: "sacn" | "artnet"
        self.name = "sACN" if config.protocol == "sacn" else "Art-Net"
        self.guard = NetGuard(config.guard)
        self.guard.drops.by_kind.setdefault("late", 0)  # listed in the summary even when none
        by_u: dict[int, list[DmxJoint]] = {}
        for j in config.joints:
            by_u.setdefault(j.universe, []).append(j)
        self._universes = {u: _Universe(u, tuple(js)) for u, js in by_u.items()}
        self._joints = {j.joint: j for j in config.joints}
        self._sync_t: dict[tuple[str, int], float] = {}  # (source, sync address) -> last sync
        self._lock = threading.Lock()
        self._latest: dict[str, tuple[int, float]] = {}  # joint -> (raw value, t)
        self._events: list[LiveEvent] = []
        self._drop_log = DropLog()
        self._gate = LineGate()
        self.counts = {"packets": 0, "applied": 0, "other_universe": 0, "unused": 0}

    # -- the receiver's side ------------------------------------------------------------
    def feed(self, t: float, data: bytes, sender: Address | str) -> None:
        """One datagram at show time ``t`` from ``sender``. Never raises."""
        drops = self.guard.drops
        host = sender[0] if isinstance(sender, tuple) else str(sender)
        try:
            if self.guard.admit(t, len(data), host) is not None:
                return
            try:
                sacn = self.source == "sacn"
                packet = parse_e131(data) if sacn else parse_artnet(data, host)
            except DmxDecodeError:
                drops.count("malformed")
                return
            with self._lock:
                self.counts["packets"] += 1
                if packet is None:
                    self.counts["unused"] += 1
                elif isinstance(packet, DmxSync):
                    self._sync(t, packet)
                else:
                    self._data(t, packet)
        except Exception:  # a bug here must not stop the receiver
            drops.count("internal")

    def _data(self, t: float, p: DmxData) -> None:
        u = self._universes.get(p.universe)
        if u is None:
            self.counts["other_universe"] += 1
            return
        self._expire(u, t)
        src = u.sources.get(p.source)
        if p.terminated:
            if src is not None:
                del u.sources[p.source]
                self._elect(u, t, f"{src.label} ended its stream")
            return
        if src is None:
            if len(u.sources) >= MAX_SOURCES:
                self.guard.drops.count("flood")
                return
            label = f"{p.name or p.source} ({p.source})" if p.name else p.source
            src = u.sources[p.source] = _Source(p.priority, t, label)
        elif p.sequence is not None and src.sequence is not None:
            behind = (src.sequence - p.sequence) % 256
            if behind < LATE_WINDOW:  # equal, or 1..19 behind: late
                self.guard.drops.count("late")
                return
        src.sequence, src.last_t, src.priority = p.sequence, t, p.priority
        self._elect(u, t, "the highest priority")
        if u.winner != p.source:
            return
        key = (p.source, p.sync_address if self.source == "sacn" else 0)
        waits = self.source == "artnet" or p.sync_address != 0
        if waits and t - self._sync_t.get(key, -math.inf) <= self.config.lost_after_s:
            u.pending = p
            return
        self._apply(u, p, t)

    def _sync(self, t: float, s: DmxSync) -> None:
        if len(self._sync_t) >= 4 * MAX_SOURCES and (s.source, s.sync_address) not in self._sync_t:
            self._sync_t.clear()  # bounded: a flood of made-up sources forgets the old ones
        self._sync_t[(s.source, s.sync_address)] = t
        for u in self._universes.values():
            p = u.pending
            if (
                p is not None
                and p.source == s.source
                and (self.source == "artnet" or p.sync_address == s.sync_address)
            ):
                self._apply(u, p, t)

    def _apply(self, u: _Universe, p: DmxData, t: float) -> None:
        u.pending = None
        self.counts["applied"] += 1
        if u.lost:
            u.lost = False
            self._say(t, "input_returned", u, f"{self.name} universe {u.number} is back")
        u.seen = True
        for j in u.joints:
            v = j.raw(p.slots)
            if v is not None:
                self._latest[j.joint] = (v, t)

    def _elect(self, u: _Universe, t: float, why: str) -> None:
        """The highest priority among the sources left wins; on a tie the winner stays."""
        best = max((s.priority for s in u.sources.values()), default=None)
        was = u.winner
        if best is None:
            u.winner = None
            return
        if was in u.sources and u.sources[was].priority == best:
            return
        u.winner = next(k for k, s in u.sources.items() if s.priority == best)
        u.pending = None
        if was is not None and u.winner != was:
            new = u.sources[u.winner]
            self._say(t, "dmx_source", u, f"{self.name} universe {u.number}: {new.label} "
                      f"(priority {new.priority}) takes over ({why})")  # fmt: skip

    def _expire(self, u: _Universe, t: float) -> None:
        gone = [k for k, s in u.sources.items() if t - s.last_t > self.config.lost_after_s]
        for k in gone:
            del u.sources[k]
        if gone and u.winner in gone:
            self._elect(u, t, f"{len(gone)} source(s) silent > {self.config.lost_after_s:g} s")
        if not u.sources and u.seen and not u.lost:
            u.lost = True
            names = [j.joint for j in u.joints]
            self._say(t, "input_lost", u,
                      f"no {self.name} data on universe {u.number} for more than "
                      f"{self.config.lost_after_s:g} s: {', '.join(names)} hold")  # fmt: skip

    def _say(self, t: float, kind: str, u: _Universe, message: str) -> None:
        if len(self._events) < 256:
            self._events.append(LiveEvent(t, kind, self.source, {
                "universe": u.number, "joints": [j.joint for j in u.joints], "message": message,
            }))  # fmt: skip
        else:
            self.guard.drops.count("queue_full")

    # -- the loop's side ----------------------------------------------------------------
    def poll(self, t: float) -> DmxPoll:
        """The values that arrived, data loss at show time ``t``, drop lines. Bounded."""
        out = DmxPoll()
        with self._lock:
            for u in self._universes.values():
                self._expire(u, t)
            latest, self._latest = self._latest, {}
            out.events, self._events = self._events, []
        said: list[LiveEvent] = []
        for ev in out.events:  # two consoles taking a universe in turn: a line a second
            if ev.kind != "dmx_source":
                said.append(ev)
            elif (ok := self._gate.offer(ev, f"source {ev.detail['universe']}")) is not None:
                said.append(ok)
        out.events = said + self._gate.due(t)
        for joint, (v, tm) in latest.items():
            j = self._joints[joint]
            deg = j.degrees(v)
            if deg is not None:
                out.values.append((joint, deg, tm))
            elif j.zero == "release":
                out.releases.append(joint)
        for line in self._drop_log.lines(t, self.guard.drops.snapshot()):
            out.events.append(LiveEvent(t, "input_dropped", self.source, {
                "reason": line.kind, "new": line.new, "total": line.total,
                "message": f"{self.name}: {line.new} dropped ({line.kind}) since the last "
                           f"report, {line.total} in all",
            }))  # fmt: skip
        return out

    def sources(self, universe: int) -> list[str]:
        """The live sources of ``universe``, the winner first (for tests and the summary)."""
        with self._lock:
            u = self._universes[universe]
            return sorted(u.sources, key=lambda k: k != u.winner)

    def summary(self) -> dict[str, Any]:
        return {**self.counts, "drops": self.guard.drops.snapshot()}


def listen(dmx: DmxInput, clock: Any, **kw: Any) -> UdpReceiver:
    """The UDP socket (``config.port`` on the guard's address; with ``multicast``, every
    universe's E1.31 group joined on that interface; with ``broadcast``, on any address, so
    the subnet's Art-Net broadcast is heard) feeding ``dmx`` from a thread."""
    cfg = dmx.config
    groups: Sequence[str] = ()
    if cfg.multicast:
        groups = [e131_multicast_group(u) for u in cfg.universes]
    return UdpReceiver(dmx.guard, dmx.feed, cfg.port, clock, name=dmx.name, groups=groups,
                       any_address=cfg.broadcast, **kw)  # fmt: skip
