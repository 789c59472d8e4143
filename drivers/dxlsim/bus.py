"""The emulated half-duplex Dynamixel bus: wire timing, addressing, reply chains, faults.

Host side, a :class:`DxlBus` looks like a serial line: :meth:`DxlBus.write` puts bytes
on the wire, :meth:`DxlBus.read` returns the bytes the host can see *now*. Time comes
from an injected clock (virtual or real); every byte has a time:

* host bytes leave back to back, ``10 / baud`` s each (8N1), starting when the host
  writes (or when the line is free);
* a servo acts on an instruction packet when its last byte has arrived, and starts
  its status packet ``Return Delay Time + turnaround`` later;
* in a Sync/Bulk Read chain each servo waits for the previous servo's status packet to
  end, then its own delay. A servo that stays silent breaks the chain for those after
  it (they wait for a packet that never comes), which is how Protocol 2.0 slaves behave;
* Fast Sync/Bulk Read is one packet: the first servo sends the header and its block
  after its delay, the others append their blocks;
* the USB adapter (latency timer ``L``) hands bytes to the host in chunks
  (:mod:`drivers.dxlsim.usb`).

So "instruction start -> last reply byte readable" = wire time + Return Delay +
turnaround (+ L), exactly, on either clock. Addressing and what each instruction does:
:mod:`drivers.dxlsim.dispatch`.

Not modelled (host/servo collisions, noise beyond the fault plan, ...): the one list is
``docs/dxlsim.md``.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterable
from dataclasses import dataclass
from operator import itemgetter

from drivers.clock import Clock, VirtualClock
from drivers.dxlsim.dispatch import (
    BROADCAST_EXECUTED,
    Inst,
    bulk_write,
    error_byte,
    execute,
    execute_broadcast,
    execute_secondary,
    read_items,
    replies_to,
    sync_write,
)
from drivers.dxlsim.faults import Fault, FaultKind, FaultPlan, parse_fault_plan
from drivers.dxlsim.protocol import (
    BROADCAST_ID,
    HEADER,
    ErrorCode,
    StreamParser,
    crc16,
    encode_status,
)
from drivers.dxlsim.servo import VirtualServo
from drivers.dxlsim.usb import UsbChunks
from drivers.protocol2.crc import crc16_blocks, word_table
from drivers.protocol2.wire_time import DEFAULT_TURNAROUND_S

#: A servo drops a half-received instruction packet after this much silence (e-Manual).
INTER_BYTE_TIMEOUT_S = 1.5e-3
#: One servo's answer to a read: the servo, its ERR byte, its data.
_Answer = tuple[VirtualServo, int, bytes]


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


class DxlBus:
    """An emulated bus of :class:`VirtualServo` s behind one host port.

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
        servos: Iterable[VirtualServo],
        *,
        baud: int = 1_000_000,
        clock: Clock | None = None,
        latency_timer_ms: float = 0.0,
        turnaround_us: float = DEFAULT_TURNAROUND_S * 1e6,
        faults: FaultPlan | str | None = None,
        seed: int = 0,
        trace: bool = False,
    ) -> None:
        self.servos: list[VirtualServo] = list(servos)
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

        word_table()  # build the CRC's table now, not when the first packet is due
        self._parser = StreamParser()
        self._stream_pos = 0  # stream index of the next host byte fed to the parser
        self._tx_free = self.t0  # when the host's last byte has left
        # Received bytes not yet read by the host, sorted by wire time.
        self._rx_data = bytearray()
        self._rx_wire: list[float] = []
        self._rx_vis: list[float] = []
        self._rx_base = 0  # the stream index of _rx_data[0]
        self._usb = UsbChunks(self.latency_s)  # the adapter's chunks of the unread bytes
        self._fast_headers: dict[int, tuple[bytes, int]] = {}  # size -> (header, its CRC)
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
    def servo(self, servo_id: int) -> VirtualServo:
        """The (first) servo with ``servo_id``; KeyError if none."""
        for s in self.servos:
            if s.id == servo_id:
                return s
        raise KeyError(f"no servo with ID {servo_id} on this bus")

    def _hears(self, servo: VirtualServo, t: float) -> bool:
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
                twin = VirtualServo(
                    servo.model.name,
                    servo.id,
                    baud=servo.baud,
                    return_delay_us=servo.return_delay_s * 1e6,
                    t=te,
                )
                self.servos.append(twin)

    # ------------------------------------------------------------------ dispatch
    def _process(self, fid: int, crc_ok: bool, inst: int, params: bytes, t: float) -> None:
        """One instruction packet complete at ``t``: its ID byte, whether its CRC held, its
        instruction and (unstuffed) parameters."""
        self.stats["instructions"] += 1
        if self._offline:
            hearing = [s for s in self.servos if self._hears(s, t)]
        else:  # the common case: nobody is browned out
            baud = self.baud
            hearing = [s for s in self.servos if s.listening_baud == baud]
        if not crc_ok:
            self.stats["crc_errors"] += 1
            # Never executed. A servo that recognises its ID complains (CRC Error).
            targets = [s for s in hearing if s.id == fid]
            for s in targets:
                s.touch(t)
            replies = [
                (s, encode_status(s.id, error_byte(s, ErrorCode.CRC)))
                for s in targets
                if s.status_return_level >= 2
            ]
            self._send_unicast(replies, t)
            return
        if fid == BROADCAST_ID:
            self._broadcast(inst, params, hearing, t)
            return
        targets = [s for s in hearing if s.id == fid]
        replies = []
        for s in targets:
            s.touch(t)
            err, data = execute(s, inst, params, t)
            if replies_to(s, inst):  # answers as the ID it was asked as, even after an ID write
                replies.append((s, encode_status(fid, err, data)))
        for s in hearing:
            if s.id != fid and s.secondary_id == fid and s not in targets:
                s.touch(t)
                execute_secondary(s, inst, params, t)
        self._send_unicast(replies, t)

    def _broadcast(self, inst: int, params: bytes, hearing: list[VirtualServo], t: float) -> None:
        if inst == Inst.SYNC_WRITE:  # the instruction of every tick first
            parsed = sync_write(params)
            if parsed is not None:
                addr, by_id = parsed
                for s in hearing:
                    data = by_id.get(s.id)
                    if data is not None:
                        s.touch(t)
                        s.write(addr, data, t)
        elif (read := read_items(inst, params)) is not None:
            self._read_chain(read[0], read[1], hearing, t)
        elif inst == Inst.PING:
            chain = sorted(hearing, key=lambda s: s.id)
            for s in chain:
                s.touch(t)
            self._send_chain([(s, *s.ping(t)) for s in chain], t)
        elif inst == Inst.BULK_WRITE:
            writes = bulk_write(params) or {}
            for s in hearing:
                if (w := writes.get(s.id)) is not None:
                    s.touch(t)
                    s.write(w[0], w[1], t)
        elif inst in BROADCAST_EXECUTED:
            for s in hearing:
                s.touch(t)
                execute_broadcast(s, inst, params, t)  # executed, never answered

    def _read_chain(
        self, fast: bool, items: list[tuple[int, int, int]], hearing: list[VirtualServo], t: float
    ) -> None:
        """Sync/Bulk Read (plain or fast): servos answer in the order the packet lists them.

        Each link of the chain is ``(answers, length)``; ``answers`` lists ``(servo, err,
        data)`` for every servo on that ID (several only with a duplicate-ID fault) and is
        empty when nobody answers, which stops the chain there.
        """
        # The servos on each ID, in bus order, looked up once (IDs and firmware do not change
        # while the chain is read, so this is the same list the scan per item would find).
        by_id: dict[int, list[VirtualServo]] = {}
        for s in hearing:
            if not fast or s.supports_fast_read:
                by_id.setdefault(s.id, []).append(s)
        links: list[tuple[list[_Answer], int]] = []
        for sid, addr, length in items:
            members = by_id.get(sid)
            if members is None:
                links.append(([], length))
            elif len(members) == 1:  # the usual case, without a comprehension
                s = members[0]
                s.touch(t)
                links.append(([(s, *s.read(addr, length, t))], length))
            else:
                for s in members:
                    s.touch(t)
                links.append(([(s, *s.read(addr, length, t)) for s in members], length))
        if fast:
            self._send_fast(links, t)
        else:
            self._send_chain_groups([answers or None for answers, _ in links], t)

    # ------------------------------------------------------------------ replies on the wire
    def _send_unicast(self, replies: list[tuple[VirtualServo, bytes]], t: float) -> None:
        if not replies:
            return
        self._emit_group(replies, t + replies[0][0].return_delay_s + self.turnaround_s)

    def _send_chain(self, results: list[tuple[VirtualServo, int, bytes]], t: float) -> None:
        self._send_chain_groups([[r] for r in results], t)

    def _send_chain_groups(self, chain: list[list[_Answer] | None], t: float) -> None:
        """Each entry: servos answering the same link (several only with a duplicate ID)."""
        ready = t
        for group in chain:
            if group is None:
                return
            lead = group[0][0]
            packets = [(s, encode_status(s.id, err, data)) for s, err, data in group]
            end = self._emit_group(packets, ready + lead.return_delay_s + self.turnaround_s)
            if end is None:
                return  # silent (dropped/truncated): later servos never hear it
            ready = end

    def _emit_group(self, packets: list[tuple[VirtualServo, bytes]], start: float) -> float | None:
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
            i = rng.randrange(len(HEADER), len(data))  # keep the header so the host finds it
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

    def _send_fast(self, links: list[tuple[list[_Answer], int]], t: float) -> None:
        """Fast Sync/Bulk Read: one packet, header and first block from the first servo,
        then each servo appends ``ERR ID data CRC`` (data zero-filled after an error).

        Each block's CRC runs on over what its servo heard on the line before it (header
        and earlier blocks with their CRCs). Two servos on one ID send their blocks at the
        same moment, each with its own data and CRC; the line carries both merged (0 wins,
        as :meth:`_emit_group` does), and the servos after them run their CRCs on over the
        merged bytes they heard - so the packet's last CRC can hold over a garbled block.
        """
        answered = []
        for answers, _ in links:
            if not answers:
                break
            answered.append(answers)
        if not answered:
            return
        # the first servo announces every block: INST + (ERR ID data CRC) per link
        size = 1 + 4 * len(links) + sum(map(itemgetter(1), links))
        cached = self._fast_headers.get(size)
        if cached is None:
            header = HEADER + bytes((BROADCAST_ID, size & 0xFF, size >> 8, Inst.STATUS))
            cached = self._fast_headers[size] = (header, crc16(header))
        header, heard = cached  # heard: the running CRC of the line so far, as servos hear it
        ready = t + answered[0][0][0].return_delay_s + self.turnaround_s
        bodies = []  # per link: what each of its servos sends, ERR ID data (and then CRC)
        collision = False
        for answers, (_, length) in zip(answered, links, strict=False):
            link = []
            for s, err, data in answers:
                link.append(
                    (s, bytes((err, s.id)) + (data if len(data) == length else bytes(length)))
                )
            bodies.append(link)
            collision = collision or len(link) > 1
        if not collision:  # one servo per link: the line carries each block as it is
            crcs = crc16_blocks([link[0][1] for link in bodies], heard)
            groups = [
                [(s, body + bytes((crc & 0xFF, crc >> 8)))]
                for ((s, body),), crc in zip(bodies, crcs, strict=True)
            ]
        else:
            groups = []  # per link: the block each of its servos sends
            for link in bodies:
                blocks = []
                for s, body in link:
                    crc = crc16(body, heard)
                    blocks.append((s, body + bytes((crc & 0xFF, crc >> 8))))
                heard = crc16(_merge([b for _, b in blocks]), heard)
                groups.append(blocks)
        groups[0] = [(s, header + b) for s, b in groups[0]]  # the first with the header
        if self._emit_burst(groups, ready):
            return
        for packets in groups:
            end = self._emit_group(packets, ready)
            if end is None:
                return
            ready = end

    def _emit_burst(self, groups: list[list[tuple[VirtualServo, bytes]]], start: float) -> bool:
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
