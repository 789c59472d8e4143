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

import struct
from operator import itemgetter
from typing import Any

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
from drivers.dxlsim.protocol import (
    BROADCAST_ID,
    HEADER,
    ErrorCode,
    StreamParser,
    crc16,
    encode_status,
)
from drivers.dxlsim.servo import VirtualServo
from drivers.dxlsim.wire import INTER_BYTE_TIMEOUT_S, TraceRecord, WireBus, _merge
from drivers.protocol2.crc import crc16_blocks, word_table

__all__ = ["INTER_BYTE_TIMEOUT_S", "DxlBus", "TraceRecord"]

#: One servo's answer to a read: the servo, its ERR byte, its data.
_Answer = tuple[VirtualServo, int, bytes]
#: A CRC as the line carries it, low byte first; a read item's length
_CRC_BYTES = struct.Struct("<H").pack
_LENGTH = itemgetter(2)


class DxlBus(WireBus[VirtualServo]):
    """An emulated Protocol 2.0 bus of :class:`VirtualServo` s behind one host port; the
    parameters are :class:`~drivers.dxlsim.wire.WireBus`'s."""

    def __init__(self, servos: Any, **kwargs: Any) -> None:
        super().__init__(servos, **kwargs)
        word_table()  # build the CRC's table now, not when the first packet is due
        self._parser = StreamParser()
        self._fast_headers: dict[int, tuple[bytes, int]] = {}  # size -> (header, its CRC)

    def _encode_status(self, packet_id: int, error: int, data: bytes) -> bytes:
        return encode_status(packet_id, error, data)

    def _twin(self, servo: VirtualServo, t: float) -> VirtualServo:
        return VirtualServo(
            servo.model.name, servo.id, baud=servo.baud,
            return_delay_us=servo.return_delay_s * 1e6, t=t,
        )  # fmt: skip

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
        if fast:
            hearing = [s for s in hearing if s.supports_fast_read]
            one = {s.id: s for s in hearing}
            if len(one) == len(hearing):  # no two servos on one ID: the common case
                self._read_fast(items, one, t)
                return
        # The servos on each ID, in bus order, looked up once (IDs and firmware do not change
        # while the chain is read, so this is the same list the scan per item would find).
        by_id: dict[int, list[VirtualServo]] = {}
        for s in hearing:
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

    def _read_fast(
        self, items: list[tuple[int, int, int]], one: dict[int, VirtualServo], t: float
    ) -> None:
        """Fast Sync/Bulk Read with one servo at most on each ID: :meth:`_send_fast`'s work
        without its links. Every listed servo is read; the blocks stop at the first ID
        nobody answers, and the header still announces them all."""
        servos: list[VirtualServo] = []
        bodies: list[bytes] = []
        for sid, addr, length in items:
            s = one.get(sid)
            if s is None:
                for sid, addr, length in items[len(servos) + 1 :]:  # read, never sent
                    if (s := one.get(sid)) is not None:
                        s.touch(t)
                        s.read(addr, length, t)
                break
            s.touch(t)
            err, data = s.read(addr, length, t)
            servos.append(s)
            bodies.append(bytes((err, sid)) + (data if len(data) == length else bytes(length)))
        if not servos:
            return
        # INST + (ERR ID data CRC) per item
        header, heard = self._fast_header(1 + 4 * len(items) + sum(map(_LENGTH, items)))
        crc_bytes = _CRC_BYTES
        groups = [
            [(s, body + crc_bytes(crc))]
            for s, body, crc in zip(servos, bodies, crc16_blocks(bodies, heard), strict=True)
        ]
        groups[0][0] = (servos[0], header + groups[0][0][1])
        self._put_fast(groups, t + servos[0].return_delay_s + self.turnaround_s)

    def _fast_header(self, size: int) -> tuple[bytes, int]:
        """A Fast reply's header announcing ``size`` (INST and every block) and its CRC."""
        cached = self._fast_headers.get(size)
        if cached is None:
            header = HEADER + bytes((BROADCAST_ID, size & 0xFF, size >> 8, Inst.STATUS))
            cached = self._fast_headers[size] = (header, crc16(header))
        return cached

    def _put_fast(self, groups: list[list[tuple[VirtualServo, bytes]]], ready: float) -> None:
        """A Fast reply's blocks on the wire from ``ready``, one after another."""
        if self._emit_burst(groups, ready):
            return
        for packets in groups:
            end = self._emit_group(packets, ready)
            if end is None:
                return
            ready = end

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
        header, heard = self._fast_header(size)  # heard: the running CRC of the line so far
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
        self._put_fast(groups, ready)
