"""A Bottango live driver: hilsim answers Bottango's driver protocol, so a figure animated in
Bottango moves on Dynamixels through hilsim's springs and safety filter.

The show file's ``[inputs.bottango]`` (:func:`from_table`) picks the transport and maps
Bottango's effectors to joints:

* ``transport = "pty"``: hilsim plays Bottango's Arduino (USB serial) driver on a
  pseudo-terminal; every line must carry its ``,h<sum>`` hash.
* ``transport = "tcp"``: hilsim plays Bottango's networked driver, connecting out to the app
  (127.0.0.1:59225 by default).

One ASCII command a line, answered ``OK`` (or ``HASH_FAIL`` for a bad hash, which does
nothing). Handshake, registration, time sync, curves, clears and ``STOP`` (the exit policy)
are implemented from Bottango's driver sources. Curves are evaluated by
:mod:`hilsim.targets.formats.bottango_curve`, as the export reader does. Nothing here raises
on a line; drops are counted by kind and said at most once a second
(:class:`~hilsim.live.netguard.DropLog`).

How to set it up, the protocol, and what is not done: ``docs/live.md`` (Bottango live).
"""

from __future__ import annotations

import re
import threading
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from hilsim._types import JsonDict
from hilsim.live.bottango_config import (
    MAX_LINE,
    NETWORK_VERSION,
    SERIAL_VERSION,
    BottangoConfig,
    EffectorMap,
    from_table,
)
from hilsim.live.inbox import LiveEvent
from hilsim.live.netguard import DropCounts, DropLog
from hilsim.targets.formats.bottango_curve import Y_MAX, BezierSegment, BezierTrack
from hilsim.targets.formats.common import UnitMap

if TYPE_CHECKING:  # the transport is imported when the input starts
    from hilsim.live.bottango_link import BottangoLink

__all__ = ["BottangoConfig", "BottangoLive", "BottangoPoll", "EffectorMap", "from_table"]

MAX_FIELDS = 15  # COMMANDS_PARAMS_SIZE: name + parameters + hash
MAX_CURVES = 16  # per effector, oldest dropped (the firmware keeps 8)
MAX_EFFECTORS = 64
MAX_EVENTS = 64
OK, HASH_FAIL = b"OK\n", b"HASH_FAIL\n"
_INT = re.compile(r"[+-]?\d{1,10}")
_NUM = re.compile(r"[+-]?(\d{1,10}(\.\d{0,9})?|\.\d{1,9})")
#: known commands that move no joint (events, colours, audio, relays, sync, config): OK, noted
_NOTED_NAMES = "sCO sCT sCC sCCI rECOnOff rECTrig rECColor rAud rCtrl xCtrl xUCtrl sR sSY sycM"
_NOTED = frozenset((_NOTED_NAMES + " sCfg rBOOT rMAC ota RLY_POLL").split())
_REGISTER = {"rSVPin": 5, "rSVI2C": 6, "rMTR": 5, "rSTPin": 8, "rSTDir": 7, "rECC": 4}


@dataclass
class BottangoPoll:
    """What :meth:`BottangoLive.poll` hands the director: ``values`` joint -> degrees now,
    ``events``, ``stop`` (once, when ``STOP`` came) and why."""

    values: dict[str, float]
    events: list[LiveEvent]
    stop: bool = False
    stop_reason: str | None = None
    triggers: tuple[str, ...] = ()


@dataclass
class _Effector:
    ident: str
    kind: str
    lo: float
    hi: float
    signal: float  # where it is (held between curves)
    umap: UnitMap | None = None  # signal -> joint degrees (None: no joint)
    #: (sequence number, curve, start ms, end ms), the latest MAX_CURVES sent
    curves: deque[tuple[int, BezierTrack, float, float]] = field(
        default_factory=lambda: deque(maxlen=MAX_CURVES)
    )


class BottangoLive:
    """The protocol engine: :meth:`feed_line` (a receiver thread, or a test) answers one line,
    :meth:`poll` (the loop) says where each mapped joint is now. Thread-safe, never blocks
    longer than one line's work, never raises on a line.

    ``network=True`` answers as Bottango's network driver does (``docs/live.md``);
    ``driver_version`` replaces the version the handshake reports."""

    def __init__(
        self,
        effectors: Mapping[str, EffectorMap],
        *,
        driver_version: str | None = None,
        network: bool = False,
        require_hash: bool | None = None,
        max_line: int = MAX_LINE,
        config: BottangoConfig | None = None,
    ) -> None:
        self.maps = dict(effectors)
        self.network = network
        self.version = driver_version or (NETWORK_VERSION if network else SERIAL_VERSION)
        self.require_hash = (not network) if require_hash is None else require_hash
        self.max_line, self.config = max_line, config
        self.drops = DropCounts()
        self.counts: dict[str, int] = {"lines": 0, "curves": 0, "handshakes": 0}
        self._drop_log, self._drops_seen = DropLog(), -1
        self._lock = threading.Lock()
        self._eff: dict[str, _Effector] = {}
        self._events: deque[LiveEvent] = deque()
        self._said: set[str] = set()
        self._handshake = False
        self._modules: deque[bytes] | None = None
        self._sync_ms = 0
        self._sync_t: float | None = None  # show time of the last tSYN (None: none yet)
        self._seq = 0
        self._stop: str | None = None
        self._link: BottangoLink | None = None

    @classmethod
    def from_config(cls, config: BottangoConfig) -> BottangoLive:
        return cls(
            config.effectors,
            driver_version=config.driver_version,
            network=config.transport == "tcp",
            require_hash=config.require_hash,
            max_line=config.max_line,
            config=config,
        )

    # ------------------------------------------------------------------ the loop's side
    def poll(self, t: float) -> BottangoPoll:
        """Joint degrees at show time ``t`` from the curves scheduled; events; a stop."""
        with self._lock:
            ms = self._driver_ms(t)
            values = {}
            for eid, eff in self._eff.items():
                um = eff.umap
                if um is not None:
                    sig = self._signal_at(eff, ms)
                    values[self.maps[eid].joint] = um.degrees[0] + (sig - um.source[0]) * (
                        um.deg_per_unit
                    )
            events = list(self._events)
            self._events.clear()
            stop, self._stop = self._stop, None
            if self.drops.version != self._drops_seen or self._drop_log.pending:
                self._drops_seen = self.drops.version
                for ln in self._drop_log.lines(t, self.drops.snapshot()):
                    msg = f"Bottango: {ln.new} lines dropped ({ln.kind}), {ln.total} in all"
                    detail = {"reason": ln.kind, "new": ln.new, "total": ln.total, "message": msg}
                    events.append(LiveEvent(t, "input_dropped", "bottango", detail))
        if stop is not None:
            events.append(LiveEvent(t, "stop", "bottango", {"message": stop}))
        return BottangoPoll(values, events, stop is not None, stop)

    def summary(self) -> JsonDict:
        with self._lock:
            drops = {k: n for k, n in self.drops.snapshot().items() if n}
            return {**self.counts, "effectors": sorted(self._eff), "drops": drops}

    def start(self, now: Callable[[], float]) -> str:
        """Open the configured transport (:mod:`hilsim.live.bottango_link`); says where."""
        from hilsim.live.bottango_link import BottangoLink

        self._link = BottangoLink(self, self.config or BottangoConfig(self.maps), now)
        return self._link.start()

    def close(self) -> None:
        if self._link is not None:
            self._link.close()

    # ------------------------------------------------------------------ the receiver's side
    def feed_line(self, t: float, line: bytes) -> list[bytes]:
        """One line from Bottango (its ``\\n`` optional) arriving at show time ``t``; returns
        the lines to send back, each ending ``\\n``. Never raises."""
        try:
            with self._lock:
                self.counts["lines"] += 1
                return self._line(float(t), bytes(line))
        except Exception as exc:  # a bug: the line is dropped, the app is told it failed
            self.drops.count("internal")
            self._event(t, "bottango_error", f"Bottango: internal error {exc!r}", once="internal")
            return [HASH_FAIL]

    def disconnected(self, t: float) -> None:
        """The transport lost its peer: the next ``hRQ`` is a new connection's."""
        with self._lock:
            self._handshake, self._modules = False, None
            self._event(t, "bottango_disconnected", "Bottango disconnected; joints held")

    def _line(self, t: float, raw: bytes) -> list[bytes]:
        raw = raw[:-1] if raw.endswith(b"\n") else raw
        raw = raw[:-1] if raw.endswith(b"\r") else raw
        if len(raw) > self.max_line:
            self.drops.count("oversized")
            return [b"\n", f"errCmdTooLong: {len(raw)}\n".encode(), OK]
        if not raw.isascii() or any(b < 0x20 or b == 0x7F for b in raw):
            self.drops.count("malformed")
            return [HASH_FAIL]
        text = raw.decode("ascii")
        body, sep, tail = text.rpartition(",h")
        if sep:
            if not (tail.isdigit() and len(tail) <= 10) or sum(raw[: len(body)]) != int(tail):
                self.drops.count("hash")
                return [HASH_FAIL]
        elif self.require_hash or not text:
            self.drops.count("hash")
            return [HASH_FAIL]
        else:
            body = text
        f = body.split(",")
        if len(f) + bool(sep) > MAX_FIELDS:
            self.drops.count("malformed")
            return [b"\n", f"errTooManyParams {MAX_FIELDS}\n".encode(), OK]
        return self._command(t, f[0], f[1:])

    # ------------------------------------------------------------------ the commands
    def _command(self, t: float, name: str, a: list[str]) -> list[bytes]:
        if name == "hRQ":
            if self._handshake and not self.network:
                self.drops.count("duplicate_handshake")  # BottangoCore: ignored, no answer
                return []
            self._handshake = True
            self.counts["handshakes"] += 1
            self._eff.clear()
            self._modules = None
            self._event(t, "bottango_connected", f"Bottango connected (driver {self.version})")
            code = a[0] if a else ""
            return [f"btngoHSK,{self.version},{code}{',1' if self.network else ''}\n".encode(), OK]
        if name == "OK":  # the app is ready for the next part of a multi-line answer
            return [OK, self._modules.popleft()] if self._modules else [OK]
        if name == "hMOD":
            cfg = f"MOD,CMD_CFG,{self.max_line},{MAX_CURVES},0,32\n".encode()
            self._modules = deque([cfg, b"MOD,EoM\n"])
            return [OK, b"MOD,CMD_SRC,0\n"]
        if name == "tSYN":
            ms = self._ints(a, 1)
            if ms is not None:
                self._sync_ms, self._sync_t = ms[0], t
            return [OK]
        if name == "STOP":
            self._stop = "Bottango STOP"
            self._eff.clear()
            self._handshake, self._modules = False, None
            return [OK] if self.network else [b"\n", b"BOOT\n"]  # the board reboots: no OK
        if name in _REGISTER:
            return self._register(t, name, a)
        if name in ("sC", "sCI"):
            return self._curve(t, name, a)
        if name in ("xE", "xC"):
            for each in self._eff.values():
                self._clear(t, each)
            if name == "xE":
                self._eff.clear()
            return [OK]
        if name in ("xUE", "xUC", "upE"):
            eff = self._eff.get(a[0]) if a else None
            if eff is None:
                return _no_effector(a[0] if a else "")
            if name == "upE":
                v = self._ints(a[1:], 3)
                if v is not None and v[0] != v[1]:  # curves stay; the held signal too
                    eff.lo, eff.hi = float(v[0]), float(v[1])
                    eff.umap = self._umap(eff)
                return [OK]
            self._clear(t, eff)
            if name == "xUE":
                del self._eff[eff.ident]
                self._event(t, "bottango_deregister", f"Bottango: effector {eff.ident} removed")
            return [OK]
        if name in _NOTED:
            self._event(t, "bottango_ignored", f"Bottango: {name} moves no joint; ignored",
                        once=name)  # fmt: skip
            return [OK]
        self.drops.count("unknown")  # executeCommand has no else: answered OK
        return [OK]

    def _register(self, t: float, name: str, a: list[str]) -> list[bytes]:
        n = _REGISTER[name]
        if len(a) < n:
            self.drops.count("value")
            return [OK]
        if name == "rECC":  # id, maxSpeed, startMovement, pin: a movement 0..1
            if not all(_NUM.fullmatch(x) for x in a[1:3]):
                self.drops.count("value")
                return [OK]
            start = float(a[2])
            ident, lo, hi, start = a[0], 0.0, 1.0, start / Y_MAX if start > 1.0 else start
        else:
            first = 1 if name == "rMTR" else 0
            v = self._ints(a[first:n], n - first)
            if v is None:
                return [OK]
            if name == "rMTR":
                ident = a[0]
            elif name == "rSVI2C":
                ident = f"{v[0]}{v[1]}"  # the address and pin written together
            else:
                ident = str(v[0])
            lo, hi, start = float(v[-4]), float(v[-3]), float(v[-1])
        if not ident or len(ident) > 16 or lo == hi:
            self.drops.count("value")
            return [OK]
        if ident in self._eff:
            return [b"\n", f"errServoCollision: {ident}\n".encode(), OK]
        if len(self._eff) >= MAX_EFFECTORS:
            return [b"\n", b"errNoSpaceAvailable\n", OK]
        start = min(max(start, min(lo, hi)), max(lo, hi))
        eff = self._eff[ident] = _Effector(ident, name, lo, hi, start)
        eff.umap = self._umap(eff)
        m = self.maps.get(ident)
        where = f"joint {m.joint}" if m else "no joint (not in inputs.bottango.effectors)"
        msg = f"Bottango: {name} effector {ident}, signal {lo:g}..{hi:g} -> {where}"
        self._event(t, "bottango_register", msg)
        return [OK]

    def _curve(self, t: float, name: str, a: list[str]) -> list[bytes]:
        eff = self._eff.get(a[0]) if a else None
        if eff is None:  # addCurve asks the pool twice, each time reporting the missing one
            return _no_effector(a[0] if a else "", twice=True)
        if name == "sCI":
            v = self._ints(a[1:], 1)
            if v is None:
                return [OK]
            start, dur, y0, y1 = round(self._driver_ms(t)), 0, v[0], v[0]
            c1x = c1y = c2x = c2y = 0
        else:
            v = self._ints(a[1:], 8)
            if v is None:
                return [OK]
            rel, dur, y0, c1x, c1y, y1, c2x, c2y = v
            start = max(0, self._sync_ms + rel)
            if dur < 0:
                self.drops.count("value")
                return [OK]
        seg = BezierSegment.from_command(start, dur, y0, c1x, c1y, y1, c2x, c2y)
        self._seq += 1
        eff.curves.append((self._seq, BezierTrack((seg,), 0.0, 1.0), seg.start_ms, seg.end_ms))
        self.counts["curves"] += 1
        return [OK]

    # ------------------------------------------------------------------ helpers
    def _ints(self, a: Sequence[str], n: int) -> list[int] | None:
        if len(a) < n or not all(_INT.fullmatch(x) for x in a[:n]):
            self.drops.count("value")
            return None
        return [int(x) for x in a[:n]]

    def _driver_ms(self, t: float) -> float:
        """The driver's clock (ms) at show time t: the last tSYN's ms + the time since."""
        if self._sync_t is None:
            return t * 1000.0
        return self._sync_ms + (t - self._sync_t) * 1000.0

    def _signal_at(self, eff: _Effector, ms: float) -> float:
        """In a curve: its value (the latest sent wins); else the end of the last finished
        one; else where it was. Remembered as where it is."""
        best = done = None
        for c in eff.curves:
            seq, _, start, end = c
            if start <= ms <= end:
                if best is None or seq > best[0]:
                    best = c
            elif end < ms and (done is None or (end, seq) > (done[3], done[0])):
                done = c
        if best is not None:
            y = best[1].sample_y(ms / 1000.0)[0]
        elif done is not None:
            y = done[1].sample_y(done[3] / 1000.0 + 1.0)[0]
        else:
            return eff.signal
        eff.signal = eff.lo + (eff.hi - eff.lo) * y / Y_MAX
        return eff.signal

    def _clear(self, t: float, eff: _Effector) -> None:
        """Clear its curves; it holds where they had taken it at t."""
        self._signal_at(eff, self._driver_ms(t))
        eff.curves.clear()

    def _umap(self, eff: _Effector) -> UnitMap | None:
        m = self.maps.get(eff.ident)
        return None if m is None else m.unit_map(eff.lo, eff.hi)

    def _event(self, t: float, kind: str, message: str, once: str | None = None) -> None:
        if once is not None:
            if once in self._said:
                return
            self._said.add(once)
        if len(self._events) >= MAX_EVENTS:
            self._events.popleft()
            self.drops.count("queue_full")
        self._events.append(LiveEvent(t, kind, "bottango", {"message": message}))


def _no_effector(ident: str, twice: bool = False) -> list[bytes]:
    err = [b"\n", f"errNoEffectorOnPin: {ident}\n".encode()]
    return err * (2 if twice else 1) + [OK]
