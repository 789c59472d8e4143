"""OSC over UDP -> live joint targets, cues and a stop, for the loop to poll once per tick.

Addresses (OSC 1.0 messages, alone or in bundles):

- ``/hilsim/joint/<name>`` with one number in 0..1: the joint's live target, ``lo + v·(hi − lo)``
  degrees;
- ``/hilsim/cue/<name>`` (or any address in ``triggers``): a ``cue`` event, unless the first
  argument is the number 0 (a button's release);
- ``/hilsim/stop``: a ``stop`` event;
- ``/hilsim/release/<name>`` (``/hilsim/release``: every joint): a ``release`` event, the joint
  handed back to the show (unless the first argument is the number 0, a button's release).

:func:`decode_packet` is our own strict OSC 1.0 decoder; it raises only :class:`OscDecodeError`.
Each datagram passes :class:`~hilsim.live.netguard.NetGuard` first. Values that are NaN, ±inf or
outside 0..1 are dropped and counted, never clamped.

Threads and time: :meth:`OscInput.feed` is the receiver's side: ``(t, bytes, sender)``, in show
time. It hands over the latest value per joint and a bounded event queue, under one lock.
:meth:`OscInput.poll` is the loop's side: bounded work, no clock reads, no sleeps. A joint
silent for ``lost_after_s`` holds its value (``input_lost``, then ``input_returned``).
:func:`listen` opens the real UDP socket and its thread.

The drop kinds, the decoder's limits and why it is our own: ``docs/live.md`` (OSC).
"""

from __future__ import annotations

import collections
import math
import struct
import threading
from collections.abc import Callable, Collection, ItemsView, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple, TypeGuard

from hilsim.live.inbox import LiveEvent
from hilsim.live.netguard import Address, DropLine, DropLog, GuardConfig, NetGuard, UdpReceiver

JOINT_PREFIX = "/hilsim/joint/"
CUE_PREFIX = "/hilsim/cue/"
STOP_ADDRESS = "/hilsim/stop"
RELEASE_ADDRESS = "/hilsim/release"  # + "/<joint>": one joint; alone: all
MAX_DEPTH = 8  # bundles inside bundles
MAX_MESSAGES = 64  # messages in one packet
MAX_NAME = 64  # characters of a joint or cue name

_BUNDLE = b"#bundle\0"
_FIXED = {"i": (4, ">i"), "f": (4, ">f"), "d": (8, ">d"), "h": (8, ">q")}
_CONSTANT = {"T": True, "F": False, "N": None, "I": math.inf}


class OscDecodeError(ValueError):
    """The bytes are not a well-formed OSC 1.0 packet of the types we read."""


#: one decoded argument: i h (int), f d (float), s (str), b (bytes), T F N I (True False None inf)
OscArg = int | float | str | bytes | bool | None

#: what one message asks of the loop: a joint's value (deg), a cue or trigger address, a stop
_Action = (
    tuple[Literal["joint"], str, float]
    | tuple[Literal["cue", "trigger"], str]
    | tuple[Literal["release"], str | None]
    | tuple[Literal["stop"]]
)


class OscMessage(NamedTuple):
    address: str
    args: tuple[OscArg, ...]


def _string(data: bytes, start: int, pos: int, end: int) -> tuple[bytes, int]:
    """A NUL-terminated string padded with NULs to a multiple of 4 (from ``start``)."""
    nul = data.find(b"\0", pos, end)
    if nul < 0:
        raise OscDecodeError("unterminated string")
    nxt = start + ((nul - start) // 4 + 1) * 4
    if nxt > end or data[nul:nxt].count(0) != nxt - nul:
        raise OscDecodeError("bad string padding")
    return data[pos:nul], nxt


def _message(data: bytes, start: int, end: int) -> OscMessage:
    raw, pos = _string(data, start, start, end)
    if not raw.startswith(b"/") or not all(0x21 <= c <= 0x7E for c in raw):
        raise OscDecodeError("the address is not '/' and printable ASCII")
    if pos >= end:
        raise OscDecodeError("no type tag string")
    tags, pos = _string(data, start, pos, end)
    if not tags.startswith(b","):
        raise OscDecodeError("the type tag string does not start with ','")
    args: list[OscArg] = []
    for code in tags[1:].decode("ascii", "replace"):
        if code in _FIXED:
            size, fmt = _FIXED[code]
            if pos + size > end:
                raise OscDecodeError("an argument runs past the end")
            args.append(struct.unpack_from(fmt, data, pos)[0])
            pos += size
        elif code in _CONSTANT:
            args.append(_CONSTANT[code])
        elif code == "s":
            text, pos = _string(data, start, pos, end)
            try:
                args.append(text.decode("utf-8"))
            except UnicodeDecodeError:
                raise OscDecodeError("a string argument is not UTF-8") from None
        elif code == "b":
            if pos + 4 > end:
                raise OscDecodeError("a blob size runs past the end")
            n = struct.unpack_from(">i", data, pos)[0]
            nxt = pos + 4 + ((n + 3) // 4) * 4
            if n < 0 or nxt > end:
                raise OscDecodeError("a blob runs past the end")
            args.append(bytes(data[pos + 4 : pos + 4 + n]))
            pos = nxt
        else:
            raise OscDecodeError(f"unsupported type tag {code!r}")
    if pos != end:
        raise OscDecodeError("bytes after the last argument")
    return OscMessage(raw.decode("ascii"), tuple(args))


def _element(data: bytes, start: int, end: int, depth: int, out: list[OscMessage]) -> None:
    if data.startswith(_BUNDLE, start, end):
        if depth >= MAX_DEPTH:
            raise OscDecodeError("bundles nested too deep")
        pos = start + 16  # "#bundle\0" + the 8-byte timetag (ignored: applied on arrival)
        if pos > end:
            raise OscDecodeError("a bundle without its timetag")
        while pos < end:
            if pos + 4 > end:
                raise OscDecodeError("a bundle element size runs past the end")
            size = struct.unpack_from(">i", data, pos)[0]
            pos += 4
            if size <= 0 or size % 4 or pos + size > end:
                raise OscDecodeError("a bundle element of a bad size")
            _element(data, pos, pos + size, depth + 1, out)
            pos += size
    else:
        if len(out) >= MAX_MESSAGES:
            raise OscDecodeError(f"more than {MAX_MESSAGES} messages in one packet")
        out.append(_message(data, start, end))


def decode_packet(data: bytes) -> list[OscMessage]:
    """Every message of a packet (a bundle's in order), or :class:`OscDecodeError`: all or none."""
    data = bytes(data)
    if not data or len(data) % 4:
        raise OscDecodeError("an OSC packet is a non-empty multiple of 4 bytes")
    out: list[OscMessage] = []
    _element(data, 0, len(data), 0, out)
    return out


@dataclass
class LiveTarget:
    deg: float
    t: float  # show time of the message that set it
    lost: bool = False


class LiveTargets:
    """Each joint's latest live target (degrees) with its timestamp, and lost input.

    Source-agnostic (OSC here; MIDI could share it): ``set`` a value, ``check`` at each poll."""

    def __init__(self, source: str, lost_after_s: float) -> None:
        if not (math.isfinite(lost_after_s) and lost_after_s > 0):
            raise ValueError(f"lost_after_s = {lost_after_s!r}: seconds, > 0")
        self.source, self.lost_after_s = source, lost_after_s
        self._targets: dict[str, LiveTarget] = {}
        self._next_loss = math.inf  # no target can be lost before this show time

    def get(self, joint: str) -> LiveTarget | None:
        return self._targets.get(joint)

    def items(self) -> ItemsView[str, LiveTarget]:
        return self._targets.items()

    def forget(self, joint: str | None) -> None:
        """The joint (None: all) was handed back: no value held, so none to lose."""
        if joint is None:
            self._targets.clear()
        else:
            self._targets.pop(joint, None)

    def set(self, joint: str, deg: float, t: float, events: list[LiveEvent]) -> None:
        self._next_loss = min(self._next_loss, t + self.lost_after_s)
        cur = self._targets.get(joint)
        if cur is None:
            self._targets[joint] = LiveTarget(deg, t)
            return
        if cur.lost:
            events.append(
                LiveEvent(
                    t,
                    "input_returned",
                    self.source,
                    {
                        "joint": joint,
                        "deg": deg,
                        "silent_s": t - cur.t,
                        "message": f"{self.source} input for {joint} returned after "
                        f"{t - cur.t:.3f} s: {deg:.3f} deg",
                    },
                )
            )
        cur.deg, cur.t, cur.lost = deg, t, False

    def check(self, t: float, events: list[LiveEvent]) -> None:
        """Lost: ``t > t_last + lost_after_s`` (one expression, for the skip and the decision)."""
        if not t > self._next_loss:
            return  # the common tick: nothing can have been lost yet
        nxt = math.inf
        for joint, cur in self._targets.items():
            if cur.lost:
                continue
            due = cur.t + self.lost_after_s
            if not t > due:
                nxt = min(nxt, due)
            else:
                cur.lost = True
                events.append(
                    LiveEvent(
                        t,
                        "input_lost",
                        self.source,
                        {
                            "joint": joint,
                            "deg": cur.deg,
                            "last_t": cur.t,
                            "message": f"no {self.source} input for {joint} for "
                            f"{t - cur.t:.3f} s (> {self.lost_after_s:g} s): "
                            f"holding {cur.deg:.3f} deg",
                        },
                    )
                )
        self._next_loss = nxt


def _sender_host(sender: Address | str) -> str:
    return sender[0] if isinstance(sender, tuple) else str(sender)


class OscInput:
    """The OSC input: ``feed`` on the receiver's side, ``poll(t)`` once per tick on the loop's."""

    def __init__(
        self,
        joints: Mapping[str, tuple[float, float]],
        *,
        guard: GuardConfig | None = None,
        lost_after_s: float = 0.5,
        cues: Collection[str] | None = None,
        triggers: Collection[str] = (),
        queue_size: int = 64,
        releasable: Collection[str] | None = None,
    ) -> None:
        self.ranges: dict[str, tuple[float, float]] = {}
        for name, (lo, hi) in joints.items():
            lo, hi = float(lo), float(hi)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(f"joint {name!r}: range {lo!r}..{hi!r} must be finite, lo < hi")
            self.ranges[name] = (lo, hi)
        if not 1 <= queue_size <= 65536:
            raise ValueError(f"queue_size = {queue_size!r}: 1..65536")
        self.guard = NetGuard(guard)
        self.targets = LiveTargets("osc", lost_after_s)
        self.cues = None if cues is None else frozenset(cues)
        #: the joints ``/hilsim/release/<name>`` may name (default: the ones OSC drives)
        self.releasable = frozenset(self.ranges if releasable is None else releasable)
        #: other addresses a show's cues are triggered by (e.g. QLab's "/trigger/pir")
        self.trigger_addresses = frozenset(triggers)
        self._lock = threading.Lock()
        self._latest: dict[str, tuple[float, float]] = {}  # joint -> (deg, t), handed over
        self._events: collections.deque[LiveEvent] = collections.deque(maxlen=queue_size)
        self._stop: LiveEvent | None = None
        self._drop_log = DropLog()
        self._drops_seen = -1
        self._fresh = False  # something handed over since the last poll
        self.stop_requested = False
        #: the joints the last poll set (a value arrived), in arrival order
        self.updated: tuple[str, ...] = ()

    # -- the receiver's side ------------------------------------------------------------
    def feed(self, t: float, data: bytes, sender: Address | str) -> None:
        """One datagram received at show time ``t`` from ``sender`` ((host, port) or host).

        Never raises: a datagram is dropped whole (counted) or decoded, and then each of its
        messages is handed over or counted."""
        drops = self.guard.drops
        try:
            if self.guard.admit(t, len(data), _sender_host(sender)) is not None:
                return
            try:
                messages = decode_packet(data)
            except OscDecodeError:
                drops.count("malformed")
                return
            actions = [a for a in map(self._action, messages) if a is not None]
        except Exception:  # a decoder bug must not stop the receiver
            drops.count("internal")
            return
        if actions:
            self._hand_over(t, actions)

    def _action(self, msg: OscMessage) -> _Action | None:
        """("joint", name, deg) | ("cue", name) | ("stop",) | None (counted as a drop)."""
        drops = self.guard.drops
        address, args = msg
        if address.startswith(JOINT_PREFIX):
            rng = self.ranges.get(address[len(JOINT_PREFIX) :])
            if rng is None or len(args) != 1 or not _is_number(args[0]):
                drops.count("unknown")
                return None
            v = float(args[0])
            if not 0.0 <= v <= 1.0:  # also False for NaN
                drops.count("value")
                return None
            lo, hi = rng
            return ("joint", address[len(JOINT_PREFIX) :], lo + v * (hi - lo))
        if address.startswith(CUE_PREFIX):
            name = address[len(CUE_PREFIX) :]
            if not name or len(name) > MAX_NAME or "/" in name:
                drops.count("unknown")
                return None
            if self.cues is not None and name not in self.cues:
                drops.count("unknown")
                return None
            if args and _is_number(args[0]) and args[0] == 0:
                return None  # a button's release: not a cue, not a drop
            return ("cue", name)
        if address == STOP_ADDRESS:
            return ("stop",)
        if address == RELEASE_ADDRESS or address.startswith(RELEASE_ADDRESS + "/"):
            joint = address[len(RELEASE_ADDRESS) + 1 :] or None
            if joint is not None and joint not in self.releasable:
                drops.count("unknown")
                return None
            if args and _is_number(args[0]) and args[0] == 0:
                return None  # a button's release: not a press
            return ("release", joint)
        if address in self.trigger_addresses:
            if args and _is_number(args[0]) and args[0] == 0:
                return None  # a button's release
            return ("trigger", address)
        drops.count("unknown")
        return None

    def _hand_over(self, t: float, actions: list[_Action]) -> None:
        with self._lock:
            self._fresh = True
            for action in actions:
                if action[0] == "joint":
                    self._latest[action[1]] = (action[2], t)
                elif action[0] == "release":
                    joint = action[1]
                    if joint is None:
                        self._latest.clear()  # values before the release go with it
                    else:
                        self._latest.pop(joint, None)
                    if len(self._events) == self._events.maxlen:
                        self.guard.drops.count("queue_full")
                    address = RELEASE_ADDRESS + ("" if joint is None else "/" + joint)
                    self._events.append(
                        LiveEvent(
                            t,
                            "release",
                            "osc",
                            {"joint": joint, "address": address, "message": f"OSC {address}"},
                        )
                    )
                elif action[0] in ("cue", "trigger"):
                    if len(self._events) == self._events.maxlen:
                        self.guard.drops.count("queue_full")
                    name = action[1]
                    address = name if action[0] == "trigger" else CUE_PREFIX + name
                    self._events.append(
                        LiveEvent(
                            t, "cue", "osc", {"cue": name, "address": address,
                                              "message": f"OSC {address}"}
                        )
                    )  # fmt: skip
                elif self._stop is None:
                    self._stop = LiveEvent(t, "stop", "osc", {"message": "OSC /hilsim/stop"})

    def pending(self) -> int:
        """Items waiting for the next poll (bounded by the joints + queue_size + 1)."""
        with self._lock:
            return len(self._latest) + len(self._events) + (self._stop is not None)

    # -- the loop's side ----------------------------------------------------------------
    def poll(self, t: float) -> list[LiveEvent]:
        """Apply what arrived, at show time ``t``; the events in order (a stop last). Bounded
        work; never blocks longer than the receiver's hand-over of one packet."""
        out: list[LiveEvent] = []
        stop = None
        self.updated = ()
        if self._fresh:  # read without the lock: a hand-over it misses is taken next tick
            with self._lock:
                latest, self._latest = self._latest, {}
                events = list(self._events)
                self._events.clear()
                stop, self._stop = self._stop, None
                self._fresh = False
            for ev in events:  # a release came before every value still in ``latest``
                if ev.kind == "release":
                    self.targets.forget(ev.detail["joint"])
            for joint, (deg, t_msg) in latest.items():
                self.targets.set(joint, deg, t_msg, out)
            self.updated = tuple(latest)
            out.extend(events)
        self.targets.check(t, out)
        drops = self.guard.drops
        lines: Sequence[DropLine]
        if drops.version == self._drops_seen and not self._drop_log.pending:
            lines = ()
        else:
            self._drops_seen = drops.version
            lines = self._drop_log.lines(t, drops.snapshot())
        for line in lines:
            out.append(
                LiveEvent(
                    t,
                    "input_dropped",
                    "osc",
                    {
                        "reason": line.kind,
                        "new": line.new,
                        "total": line.total,
                        "message": f"OSC: {line.new} dropped ({line.kind}) since the last "
                        f"report, {line.total} in all",
                    },
                )
            )
        if stop is not None and not self.stop_requested:
            self.stop_requested = True
            out.append(stop)
        return out

    def target(self, joint: str) -> float | None:
        """The joint's live target in degrees (held while lost), or None before any input."""
        cur = self.targets.get(joint)
        return None if cur is None else cur.deg


def _is_number(x: object) -> TypeGuard[float]:
    return isinstance(x, int | float) and not isinstance(x, bool)


def listen(osc: OscInput, port: int, clock: Callable[[], float], **kw: Any) -> UdpReceiver:
    """A UDP socket on the guard's address feeding ``osc`` from a thread (see
    :class:`~hilsim.live.netguard.UdpReceiver`); ``clock()``: the show time the loop polls with."""
    return UdpReceiver(osc.guard, osc.feed, port, clock, name="OSC", **kw)
