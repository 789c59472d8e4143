"""MIDI control change -> joint degrees, polled once per tick; a real port through mido.

A :class:`CcMapping` ties one controller (channel 1–16 as users see it, controller 0–127) to one
joint's range: value 0 -> ``min_deg``, 127 -> ``max_deg``, linear (``min_deg > max_deg`` inverts).
With ``fine = True`` the controller (0–31) is the MSB of a 14-bit pair whose LSB is controller +
32: 0 -> ``min_deg``, 16383 -> ``max_deg``; an MSB resets the LSB to 0 (MIDI 1.0), and an LSB
before any MSB is ignored.

:class:`MidiCcInput` takes ``mido.Message`` objects (or anything with ``type``, ``channel``,
``control``, ``value``) stamped with show time through ``feed`` (tests; the port's receiver
thread), and the loop calls ``poll(t)`` each tick: the latest degrees per joint (``None`` until a
first message), each applied message as a ``(t, joint, deg)`` sample for a take, and events.

**Lost input.** A fader sends only when it moves, so silence on one controller is not a fault.
With ``lost_after_s`` set, *any* message on the port (Active Sensing, which many controllers send
every 300 ms, counts) keeps the input alive; none for ``lost_after_s`` -> one ``input_lost``
event, and ``lost`` stays true (the joints hold their last value) until a message arrives
(``input_resumed``). The timer starts at the first poll: a port that never sends is lost too.

mido is optional (``pip install 'hilsim[live]'``); parsing needs no mido, a port needs mido and
its python-rtmidi backend (:func:`open_midi_input`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeGuard

from hilsim.live.inbox import DEFAULT_CAPACITY, MAX_LIVE_DEG, Inbox, LiveEvent

#: the line a missing optional package gets
EXTRA_HINT = "pip install 'hilsim[live]'"


class LiveExtraError(RuntimeError):
    """An optional package a live input needs is not installed (one line, names the extra)."""


def require_mido() -> Any:
    """Import mido lazily; missing -> :class:`LiveExtraError` naming the extra."""
    try:
        import mido
    except ImportError:
        raise LiveExtraError(f"MIDI input needs the optional package mido: {EXTRA_HINT}") from None
    return mido


@dataclass(frozen=True)
class CcMapping:
    """One MIDI controller -> one joint's range (degrees).

    Args:
        joint: the joint's name.
        channel: 1–16, as a user sees it (mido's ``channel`` is this − 1).
        control: controller number 0–127 (0–31 with ``fine``).
        min_deg: the joint angle at value 0 (deg).
        max_deg: the joint angle at value 127 (16383 with ``fine``) (deg); ≠ ``min_deg``.
        fine: 14-bit pair: ``control`` is the MSB, ``control + 32`` the LSB.

    Raises:
        ValueError: one line naming the field, the value and what is allowed.
    """

    joint: str
    channel: int
    control: int
    min_deg: float
    max_deg: float
    fine: bool = False

    def __post_init__(self) -> None:
        where = f"MIDI mapping for joint {self.joint!r}"
        if not isinstance(self.joint, str) or not self.joint:
            raise ValueError(f"MIDI mapping: joint must be a non-empty name, got {self.joint!r}")
        if not _is_int(self.channel) or not 1 <= self.channel <= 16:
            raise ValueError(f"{where}: channel must be 1-16, got {self.channel!r}")
        top = 31 if self.fine else 127
        if not _is_int(self.control) or not 0 <= self.control <= top:
            extra = " (a 14-bit pair's MSB; its LSB is control + 32)" if self.fine else ""
            raise ValueError(f"{where}: control must be 0-{top}{extra}, got {self.control!r}")
        for name in ("min_deg", "max_deg"):
            x = getattr(self, name)
            if (
                isinstance(x, bool)
                or not isinstance(x, int | float)
                or not (math.isfinite(x) and abs(x) <= MAX_LIVE_DEG)
            ):
                raise ValueError(
                    f"{where}: {name} must be a number of degrees within ±{MAX_LIVE_DEG:g}, "
                    f"got {x!r}"
                )
        if self.min_deg == self.max_deg:
            raise ValueError(f"{where}: min_deg and max_deg are both {self.min_deg!r}")

    @property
    def full_scale(self) -> int:
        """The largest raw value: 127, or 16383 for a 14-bit pair."""
        return 16383 if self.fine else 127

    def degrees(self, raw: int) -> float:
        """The joint angle (deg) for a raw controller value."""
        return self.min_deg + (self.max_deg - self.min_deg) * raw / self.full_scale


def _is_int(x: object) -> TypeGuard[int]:
    return isinstance(x, int) and not isinstance(x, bool)


@dataclass
class MidiPoll:
    """What one ``poll(t)`` found.

    ``values``: joint -> latest degrees (``None`` before a first message; the input's own dict,
    read it, do not keep it); ``samples``: ``(t, joint, deg)`` per applied message, for a take;
    ``events``; ``lost``: no message for ``lost_after_s`` (hold the joints).
    """

    values: Mapping[str, float | None]
    samples: list[tuple[float, str, float]] = field(default_factory=list)
    events: list[LiveEvent] = field(default_factory=list)
    lost: bool = False


class MidiCcInput:
    """MIDI control changes -> joint degrees (see the module docstring).

    Args:
        mappings: one :class:`CcMapping` per joint; no joint or controller twice.
        lost_after_s: silence on the port (s, > 0) that counts as lost input; ``None``: never.
        capacity: the inbox's size (messages); a full inbox drops the oldest (``inbox_overflow``).
        source: the events' ``source``.
    """

    def __init__(
        self,
        mappings: Sequence[CcMapping],
        *,
        lost_after_s: float | None = None,
        capacity: int = DEFAULT_CAPACITY,
        source: str = "midi",
    ) -> None:
        if lost_after_s is not None and not (
            isinstance(lost_after_s, int | float)
            and not isinstance(lost_after_s, bool)
            and 0 < lost_after_s < math.inf
        ):
            raise ValueError(
                f"lost_after_s must be a positive number of seconds, got {lost_after_s!r}"
            )
        self.mappings = tuple(mappings)
        self.lost_after_s = lost_after_s
        self.source = source
        self.inbox = Inbox(capacity)
        # (mido channel 0-15, control) -> (mapping index, is the LSB of a 14-bit pair)
        self._keys: dict[tuple[int, int], tuple[int, bool]] = {}
        seen: dict[str, CcMapping] = {}
        for i, m in enumerate(self.mappings):
            if m.joint in seen:
                raise ValueError(f"MIDI mappings: joint {m.joint!r} is mapped twice")
            seen[m.joint] = m
            for control, lsb in (
                (m.control, False),
                *(((m.control + 32, True),) if m.fine else ()),
            ):
                key = (m.channel - 1, control)
                if key in self._keys:
                    other = self.mappings[self._keys[key][0]].joint
                    raise ValueError(
                        f"MIDI mappings: channel {m.channel} control {control} is used by "
                        f"both {other!r} and {m.joint!r}"
                    )
                self._keys[key] = (i, lsb)
        self._raw: list[int | None] = [None] * len(self.mappings)
        self.values: dict[str, float | None] = {m.joint: None for m in self.mappings}
        self._last_msg_t: float | None = None
        self._msb_pending = -1  # the mapping whose MSB was the last message applied
        self.lost = False
        self.applied = 0  #: control changes applied to a joint
        self.ignored = 0  #: messages that moved nothing (unmapped, other types, a lone LSB)

    def feed(self, message: Any, t: float) -> None:
        """Hand in one message stamped ``t`` (show time, s); never blocks."""
        self.inbox.put(t, message)

    def poll(self, t: float) -> MidiPoll:
        """Apply the messages due at ``t`` (show time, s); bounded work, never waits."""
        due = self.inbox.take_due(t)
        out = MidiPoll(self.values)
        drops = self.inbox.take_drops()
        if drops:
            out.events.append(
                LiveEvent(
                    t,
                    "inbox_overflow",
                    self.source,
                    {"dropped": drops, "total": self.inbox.dropped},
                )
            )
        if self._last_msg_t is None:
            self._last_msg_t = t  # the lost-input timer starts at the first poll
        for tm, msg in due:
            self._apply(tm, msg, out.samples)
        if due:
            self._last_msg_t = due[-1][0]
            if self.lost:
                self.lost = False
                out.events.append(
                    LiveEvent(
                        due[0][0], "input_resumed", self.source, {"joints": list(self.values)}
                    )
                )
        if (
            not self.lost
            and self.lost_after_s is not None
            and t - self._last_msg_t > self.lost_after_s
        ):
            self.lost = True
            out.events.append(
                LiveEvent(
                    t,
                    "input_lost",
                    self.source,
                    {
                        "joints": list(self.values),
                        "held_deg": dict(self.values),
                        "silent_since_s": self._last_msg_t,
                        "lost_after_s": self.lost_after_s,
                    },
                )
            )
        out.lost = self.lost
        return out

    def _apply(self, tm: float, msg: Any, samples: list[tuple[float, str, float]]) -> None:
        if getattr(msg, "type", None) != "control_change":
            self.ignored += 1
            return
        hit = self._keys.get((msg.channel, msg.control))
        if hit is None:
            self.ignored += 1
            return
        i, lsb = hit
        m = self.mappings[i]
        value = int(msg.value) & 0x7F
        raw = self._raw[i]
        if not m.fine:
            raw = value
        elif not lsb:
            raw = value << 7  # an MSB resets the LSB (MIDI 1.0)
        elif raw is None:
            self.ignored += 1  # an LSB before any MSB: nothing to refine
            return
        else:
            raw = (raw & ~0x7F) | value
            if samples and samples[-1][1] == m.joint and self._msb_pending == i:
                samples.pop()  # MSB then its LSB: one sample, not a dip to LSB 0 and back
        self._msb_pending = i if (m.fine and not lsb) else -1
        self._raw[i] = raw
        deg = m.degrees(raw)
        self.values[m.joint] = deg
        samples.append((tm, m.joint, deg))
        self.applied += 1


class MidiSink(Protocol):
    """Anything a port's receiver hands messages to (:class:`MidiCcInput`, the MTC chase)."""

    def feed(self, message: Any, t: float) -> None: ...


class MidiPort:
    """An open MIDI input port whose messages go to ``sinks``, stamped by ``now()`` on arrival
    (mido's callback thread). Close it with :meth:`close` (or use it as a context manager)."""

    def __init__(self, port: Any, name: str) -> None:
        self._port = port
        self.name = name

    def close(self) -> None:
        self._port.close()

    def __enter__(self) -> MidiPort:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_midi_input(
    name: str | None, sinks: Sequence[MidiSink], now: Callable[[], float]
) -> MidiPort:
    """Open the MIDI input port ``name`` (``None``: the backend's default) and feed every message
    to each sink, stamped ``now()`` (the loop clock's show time) when it arrives.

    Raises:
        LiveExtraError: mido or its python-rtmidi backend is not installed (names the extra).
        ValueError: no such port (lists the ports there are).
    """
    mido = require_mido()

    def on_message(msg: Any) -> None:
        t = now()
        for sink in sinks:
            sink.feed(msg, t)

    try:
        names = mido.get_input_names()
        if name is not None and name not in names:
            listed = ", ".join(repr(n) for n in names) or "none"
            raise ValueError(f"no MIDI input port {name!r}; the ports are: {listed}")
        port = mido.open_input(name, callback=on_message)
    except ImportError as exc:
        raise LiveExtraError(
            f"a MIDI port needs mido's backend ({exc.name or exc}): {EXTRA_HINT}"
        ) from None
    except OSError as exc:
        which = repr(name) if name else "(the first one)"
        raise ValueError(f"cannot open MIDI input port {which}: {exc}") from None
    return MidiPort(port, port.name)


class MidiTriggerInput:
    """MIDI notes and controller presses -> a show's trigger keys (:mod:`hilsim.live.show_spec`).

    A note-on with velocity > 0 gives ``"midi:note:<n>:ch<c>"``; a control change crossing from
    below 64 to 64 or more (a foot switch, a button sending 127/0) gives ``"midi:cc:<n>:ch<c>"``
    (channel 1–16). Only the keys in ``keys`` are kept; everything else moves nothing. Fed by a
    port's receiver like :class:`MidiCcInput`; ``poll(t)`` returns ``(t, key)`` in order.
    """

    def __init__(self, keys: Sequence[str], *, capacity: int = DEFAULT_CAPACITY) -> None:
        self.keys = frozenset(keys)
        self.inbox = Inbox(capacity)
        self._cc_high: dict[tuple[int, int], bool] = {}

    def feed(self, message: Any, t: float) -> None:
        self.inbox.put(t, message)

    def poll(self, t: float) -> list[tuple[float, str]]:
        out = []
        for tm, msg in self.inbox.take_due(t):
            kind = getattr(msg, "type", None)
            channel = getattr(msg, "channel", None)
            if not _is_int(channel) or not 0 <= channel <= 15:
                continue
            if kind == "note_on" and _is_int(getattr(msg, "velocity", None)) and msg.velocity:
                key = f"midi:note:{msg.note}:ch{channel + 1}"
            elif kind == "control_change" and _is_int(getattr(msg, "value", None)):
                cc = (channel, msg.control)
                high, was = msg.value >= 64, self._cc_high.get(cc, False)
                self._cc_high[cc] = high
                if not high or was:
                    continue
                key = f"midi:cc:{msg.control}:ch{channel + 1}"
            else:
                continue
            if key in self.keys:
                out.append((tm, key))
        return out
