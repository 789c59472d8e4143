"""The wire half of an emulated half-duplex bus: byte timing, the USB adapter, reply faults.

:class:`WireBus` is what every emulated bus shares whatever its protocol: host side, it looks
like a serial line (:meth:`WireBus.write` puts bytes on the wire, :meth:`WireBus.read` returns
the bytes the host can see *now*); servo side, it puts status packets on the wire after each
servo's Return Delay Time and turnaround, one after another in a chain, applies the fault
plan's reply faults and events, and hands bytes to the host through the adapter's latency
model (:mod:`drivers.dxlsim.usb`). Time comes from an injected clock (virtual or real).

A protocol's bus subclasses it with its codec and dispatch: :class:`drivers.dxlsim.bus.DxlBus`
(Protocol 2.0, X series) and :class:`drivers.dxlsim.p1bus.P1Bus` (Protocol 1.0 framing:
Dynamixel AX/MX, Feetech STS/SCS). A subclass sets ``_parser`` (a stream parser whose
``feed_decoded`` yields ``(end, (raw, id, ok, inst, params))``), and defines ``_process``,
``_encode_status`` and ``_twin``; ``HEADER_LEN`` is its packets' header length (a corrupt
reply keeps the header so the host finds the packet).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

from drivers.clock import Clock, VirtualClock
from drivers.dxlsim.faults import Fault, FaultKind, FaultPlan, parse_fault_plan
from drivers.dxlsim.usb import UsbChunks
from drivers.protocol2.wire_time import DEFAULT_TURNAROUND_S

#: A servo drops a half-received instruction packet after this much silence (e-Manual).
INTER_BYTE_TIMEOUT_S = 1.5e-3


class WireServo(Protocol):
    """What the wire needs of a servo (:class:`~drivers.dxlsim.servo.VirtualServo`,
    :class:`~drivers.dxlsim.p1servo.P1Servo`)."""

    @property
    def id(self) -> int: ...
    @property
    def baud(self) -> int: ...
    @property
    def listening_baud(self) -> int: ...
    @property
    def return_delay_s(self) -> float: ...
    @property
    def status_return_level(self) -> int: ...
    def touch(self, t: float) -> None: ...
    def brownout(self, t: float) -> None: ...
    def inject_hardware_error(self, bits: int, t: float) -> None: ...
    def cut_torque(self, t: float) -> None: ...
    def trip_watchdog(self, t: float) -> None: ...


S = TypeVar("S", bound=WireServo)
#: One servo's answer to a read: the servo, its ERR byte, its data.
_Answer = tuple[Any, int, bytes]


@dataclass(frozen=True, slots=True)
class TraceRecord:
    """Bytes on the wire: ``t_start``/``t_end`` are when the first byte began and the last
    byte's stop bit ended (seconds on the bus clock). ``direction`` is ``"tx"`` (host to
    servos) or ``"rx"`` (servos to host); ``note`` names the servo and any fault."""

    t_start: float
    t_end: float
    direction: str
    data: bytes
    note: str = ""


class WireBus(Generic[S]):
    """An emulated bus of servos behind one host port (a protocol's subclass speaks to them).

    Parameters
    ----------
    servos:
        The servos on the bus (IDs may repeat only to model a duplicate-ID fault).
    baud:
        The host's line rate in bit/s. Servos set to another rate hear noise and never answer.
    clock:
        Time source; default a fresh :class:`~drivers.clock.VirtualClock`.
    latency_timer_ms:
        USB adapter latency timer (FTDI default 16, tuned 1, or 0 for an ideal port).
    turnaround_us:
        Servo processing time added to each servo's Return Delay Time.
    faults:
        A :class:`FaultPlan` or its text form (see :mod:`drivers.dxlsim.faults`).
    trace:
        Keep a :class:`TraceRecord` for every burst of bytes, both directions.
    """

    def __init__(
        self,
        servos: Iterable[S],
        *,
        baud: int = 1_000_000,
        clock: Clock | None = None,
        latency_timer_ms: float = 0.0,
        turnaround_us: float = DEFAULT_TURNAROUND_S * 1e6,
        faults: FaultPlan | str | None = None,
        seed: int = 0,
        trace: bool = False,
    ) -> None:
        self.servos: list[S] = list(servos)
        if baud <= 0:
            raise ValueError(f"baud must be positive, got {baud}")
        if latency_timer_ms < 0 or turnaround_us < 0:
            raise ValueError("latency_timer_ms and turnaround_us must be >= 0")
        self.baud = int(baud)
        self.clock: Clock = clock if clock is not None else VirtualClock()
        self.latency_s = latency_timer_ms * 1e-3
        self.turnaround_s = turnaround_us * 1e-6
        if isinstance(faults, str):
            faults = parse_fault_plan(faults, seed=seed)
        self.faults: FaultPlan = faults if faults is not None else FaultPlan(seed=seed)
        self.t0 = self.clock.now()
        self.trace: list[TraceRecord] | None = [] if trace else None

        self._parser: Any = None  # the protocol's stream parser (set by the subclass)
        self._stream_pos = 0  # stream index of the next host byte fed to the parser
        self._tx_free = self.t0  # when the host's last byte has left
        # Received bytes not yet read by the host, sorted by wire time.
        self._rx_data = bytearray()
        self._rx_wire: list[float] = []
        self._rx_vis: list[float] = []
        self._rx_base = 0  # the stream index of _rx_data[0]
        self._usb = UsbChunks(self.latency_s)  # the adapter's chunks of the unread bytes
        self._steps: list[float] = []  # k · byte time, k = 1, 2, ... (see _byte_steps)
        self._steps_bt = 0.0
        self._events = self.faults.events
        self._offline: dict[int, float] = {}  # id(servo) -> back-online time
        self.unplugged_at: float | None = None
        self.stats = {
            "instructions": 0,
            "crc_errors": 0,
            "replies": 0,
            "bytes_tx": 0,
            "bytes_rx": 0,
        }

    # ------------------------------------------------------------------ host side
    @property
    def byte_time(self) -> float:
        """Seconds one byte occupies on the wire (10 bits: start, 8 data, stop)."""
        return 10.0 / self.baud

    def unplugged(self, t: float | None = None) -> bool:
        if not self._events and self.unplugged_at is None:
            return False  # no unplug to come (the port asks on every call: hot path)
        t = self.clock.now() if t is None else t
        self._apply_events(t)  # an unplug is due even if the host has not written since
        return self.unplugged_at is not None and t >= self.unplugged_at

    def write(self, data: bytes, t: float | None = None) -> float:
        """Put ``data`` on the wire at ``t`` (default now); returns when its last byte has left
        (bus clock). A ``t`` in the past is for a server that was not running when the bytes
        came (see :mod:`drivers.dxlsim.pty_server`)."""
        now = self.clock.now() if t is None else t
        if self._events:
            self._apply_events(now)
        bt = 10.0 / self.baud  # byte_time
        start = max(now, self._tx_free)
        end = start + len(data) * bt
        if start - self._tx_free > INTER_BYTE_TIMEOUT_S and self._parser.pending:
            self._parser.reset()  # the servos gave up on the half-received packet
        base = self._stream_pos
        self._stream_pos += len(data)
        self._tx_free = end
        self.stats["bytes_tx"] += len(data)
        if self.trace is not None:
            self.trace.append(TraceRecord(start, end, "tx", bytes(data)))
        for frame_end, (_, fid, crc_ok, inst, params) in self._parser.feed_decoded(data):
            t_frame = start + (frame_end - base) * bt
            if self._events:
                self._apply_events(t_frame)
            self._process(fid, crc_ok, inst, params, t_frame)
        return end

    def in_waiting(self, t: float | None = None) -> int:
        """Bytes the host can read at ``t`` (default now)."""
        t = self.clock.now() if t is None else t
        return bisect.bisect_right(self._rx_vis, t)

    def read(self, size: int, t: float | None = None) -> bytes:
        """Up to ``size`` bytes readable at ``t`` (default now), removed from the buffer."""
        n = min(size, self.in_waiting(t))
        if n <= 0:
            return b""
        out = bytes(self._rx_data[:n])
        del self._rx_data[:n], self._rx_wire[:n], self._rx_vis[:n]
        self._rx_base += n
        return out

    def visible_at(self, count: int = 1) -> float | None:
        """When ``count`` unread bytes will be readable, or None if fewer are on their way."""
        if count <= 0:
            return self.clock.now()
        if count > len(self._rx_vis):
            return None
        return self._rx_vis[count - 1]

    @property
    def pending_rx(self) -> int:
        """Unread bytes, readable or still on their way."""
        return len(self._rx_vis)

    def reset_input(self, t: float | None = None) -> None:
        """Discard what the host could read at ``t`` (bytes still on the wire survive)."""
        n = self.in_waiting(t)
        del self._rx_data[:n], self._rx_wire[:n], self._rx_vis[:n]
        self._rx_base += n

    # ------------------------------------------------------------------ servos
    def servo(self, servo_id: int) -> S:
        """The (first) servo with ``servo_id``; KeyError if none."""
        for s in self.servos:
            if s.id == servo_id:
                return s
        raise KeyError(f"no servo with ID {servo_id} on this bus")

    def _hears(self, servo: S, t: float) -> bool:
        back = self._offline.get(id(servo))
        if back is not None:
            if t < back:
                return False
            del self._offline[id(servo)]
            servo.brownout(back)  # power returns: RAM comes back at defaults
        return servo.listening_baud == self.baud

    def _apply_events(self, t: float) -> None:
        while self._events and self.t0 + self._events[0].at <= t:
            ev = self._events.pop(0)
            te = self.t0 + ev.at
            if ev.kind is FaultKind.UNPLUG:
                self.unplugged_at = te
                continue
            (sid,) = ev.ids or (None,)
            targets = [s for s in self.servos if s.id == sid]
            if not targets:
                continue
            servo = targets[0]
            if ev.kind is FaultKind.BROWNOUT:
                self._offline[id(servo)] = te + ev.duration
            elif ev.kind is FaultKind.HARDWARE_ERROR:
                servo.inject_hardware_error(ev.bits, te)
            elif ev.kind is FaultKind.TORQUE_OFF:
                servo.cut_torque(te)
            elif ev.kind is FaultKind.WATCHDOG_TRIP:
                servo.trip_watchdog(te)
            elif ev.kind is FaultKind.DUPLICATE_ID:
                self.servos.append(self._twin(servo, te))

    # ------------------------------------------------------------------ the protocol's part
    #: Bytes of a packet's header (kept by a corrupt-reply fault so the host finds the packet).
    HEADER_LEN = 4

    def _process(self, fid: int, ok: bool, inst: int, params: bytes, t: float) -> None:
        """One instruction packet complete at ``t``: its ID, whether its check held, its
        instruction and parameters."""
        raise NotImplementedError

    def _encode_status(self, packet_id: int, error: int, data: bytes) -> bytes:
        raise NotImplementedError

    def _twin(self, servo: S, t: float) -> S:
        """A second servo like ``servo`` on its ID (the duplicate-ID fault)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ replies on the wire
    def _send_unicast(self, replies: list[tuple[S, bytes]], t: float) -> None:
        if not replies:
            return
        self._emit_group(replies, t + replies[0][0].return_delay_s + self.turnaround_s)

    def _send_chain(self, results: list[tuple[S, int, bytes]], t: float) -> None:
        self._send_chain_groups([[r] for r in results], t)

    def _send_chain_groups(self, chain: list[list[_Answer] | None], t: float) -> None:
        """Each entry: servos answering the same link (several only with a duplicate ID)."""
        ready = t
        for group in chain:
            if group is None:
                return
            lead = group[0][0]
            packets = [(s, self._encode_status(s.id, err, data)) for s, err, data in group]
            end = self._emit_group(packets, ready + lead.return_delay_s + self.turnaround_s)
            if end is None:
                return  # silent (dropped/truncated): later servos never hear it
            ready = end

    def _emit_group(self, packets: list[tuple[S, bytes]], start: float) -> float | None:
        """Put one status packet (or colliding ones) on the wire; apply reply faults.

        Returns when its last byte ends, or None if the chain must stop here.
        """
        lead = packets[0][0]
        data = packets[0][1] if len(packets) == 1 else _merge([p for _, p in packets])
        note = ""  # only the trace reads it
        if self.trace is not None:
            note = f"id={lead.id}" + " collision" * (len(packets) - 1)
        fault = self.faults.reply_fault(lead.id, start - self.t0) if self.faults.faults else None
        keep_chain = True
        if fault is not None:
            if self.trace is not None:
                note += f" fault={fault.kind}"
            data, start, keep_chain = self._apply_reply_fault(fault, data, start)
        end = self._emit(data, start, note) if data else start
        self.stats["replies"] += 1
        return end if keep_chain else None

    def _apply_reply_fault(
        self, fault: Fault, data: bytes, start: float
    ) -> tuple[bytes, float, bool]:
        rng = self.faults.rng
        kind = fault.kind
        if kind is FaultKind.DROP:
            return b"", start, False
        if kind is FaultKind.CORRUPT:
            i = rng.randrange(self.HEADER_LEN, len(data))  # keep the header so the host finds it
            flipped = bytearray(data)
            flipped[i] ^= rng.randrange(1, 256)
            return bytes(flipped), start, True
        if kind is FaultKind.TRUNCATE:
            return data[: rng.randrange(1, len(data))], start, False
        if kind is FaultKind.LATE:
            return data, start + fault.delay, True
        if kind is FaultKind.GARBAGE:
            junk = bytes(rng.randrange(256) for _ in range(fault.nbytes))
            return junk + data, start, True
        return data, start, True

    def _emit_burst(self, groups: list[list[tuple[S, bytes]]], start: float) -> bool:
        """Put the groups on the wire back to back from ``start`` as :meth:`_emit_group`
        would one by one, and work out the USB visibility once at the end; False (nothing
        done) where that would not be the same.

        It is the same when no fault rule can strike a group (then every group is sent and
        the next starts where it ended), the bytes go after those already received, and
        every byte arrives after ``now`` on a clock that stands still meanwhile (virtual):
        one by one, no byte of the burst could be seen before the burst is complete (its
        chunk's time is at or after its own arrival), so the intermediate visibilities
        leave no trace, and the chunks are cut where the full computation cuts them.
        """
        if self.faults.faults or not getattr(self.clock, "virtual", False):
            return False
        if not start > self.clock.now():
            return False
        bt = 10.0 / self.baud  # byte_time
        wire = self._rx_wire
        if wire and start + bt < wire[-1]:
            return False  # a late reply ahead of it: the merge in _emit
        steps = self._byte_steps(bt, 0)
        first = start
        rx = self._rx_data
        trace = self.trace
        n_bytes = 0
        for packets in groups:
            data = packets[0][1] if len(packets) == 1 else _merge([p for _, p in packets])
            n = len(data)
            if n > len(steps):
                steps = self._byte_steps(bt, n)
            wire += map(start.__add__, steps[:n])  # start + k·bt, k = 1..n
            end = wire[-1]
            rx += data
            n_bytes += n
            if trace is not None:
                note = f"id={packets[0][0].id}" + " collision" * (len(packets) - 1)
                trace.append(TraceRecord(start, end, "rx", bytes(data), note))
            start = end
        self.stats["bytes_rx"] += n_bytes
        self.stats["replies"] += len(groups)
        if self.latency_s <= 0.0:
            self._rx_vis += wire[len(self._rx_vis) :]
        else:
            self._update_visibility(bt + 4.0 * math.ulp(abs(first) + abs(start)) < self.latency_s)
        return True

    def _emit(self, data: bytes, start: float, note: str) -> float:
        bt = 10.0 / self.baud  # byte_time
        n = len(data)
        steps = self._byte_steps(bt, n)
        times = list(map(start.__add__, steps[:n]))  # start + k·bt, k = 1..n
        end = times[-1]
        if not self._rx_wire or times[0] >= self._rx_wire[-1]:
            self._rx_data += data
            self._rx_wire += times
            if self.latency_s <= 0.0:
                self._rx_vis += times  # ideal adapter: readable when the stop bit ends
            else:
                # No gap inside this burst can exceed the latency timer when a byte time
                # (plus the round-off of start + k·bt, a few ulps) stays below it.
                even = bt + 4.0 * math.ulp(abs(start) + abs(end)) < self.latency_s
                self._update_visibility(even)
        else:  # a late reply overtaken by newer ones: merge by wire time
            merged = sorted(
                zip(self._rx_wire + times, self._rx_data + data, strict=True), key=lambda p: p[0]
            )
            self._rx_wire = [w for w, _ in merged]
            self._rx_data = bytearray(b for _, b in merged)
            self._usb.forget()  # chunks no longer line up: recompute them all
            self._update_visibility(False)
        self.stats["bytes_rx"] += n
        if self.trace is not None:
            self.trace.append(TraceRecord(start, end, "rx", bytes(data), note))
        return end

    def _byte_steps(self, bt: float, n: int) -> list[float]:
        """``[k * bt for k in 1..]``, at least ``n`` long, kept while the baud rate holds.

        It doubles only to hold a longer burst; a new baud rate refills it at the same length
        (doubling there too made each rate change cost twice the last)."""
        steps = self._steps
        if bt != self._steps_bt:
            size = max(n, len(steps), 256)
        elif len(steps) < n:
            size = max(n, 2 * len(steps))
        else:
            return steps
        self._steps = steps = [k * bt for k in range(1, size + 1)]
        self._steps_bt = bt
        return steps

    def _update_visibility(self, even: bool) -> None:
        """When each unread byte reaches the host (:mod:`drivers.dxlsim.usb`), after bytes
        joined the buffer (``even``: they came at the end, one burst with no gap over the
        latency)."""
        self._rx_vis = self._usb.update(
            self._rx_wire, self._rx_vis, self._rx_base, self.clock, self.latency_s, even
        )


def _merge(packets: list[bytes]) -> bytes:
    """What the line carries when several servos send at once: every byte ANDed (a driven
    0 wins on the open-drain bus; a shorter packet leaves the line idle, 0xFF)."""
    data = packets[0]
    for other in packets[1:]:
        n = max(len(data), len(other))
        a, b = data.ljust(n, b"\xff"), other.ljust(n, b"\xff")
        data = bytes(x & y for x, y in zip(a, b, strict=True))
    return data
