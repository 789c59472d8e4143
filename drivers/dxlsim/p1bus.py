"""The emulated bus for Protocol 1.0 framing: Dynamixel AX/MX (P1 firmware), Feetech STS/SCS.

The wire (timing, the USB adapter, reply faults, fault events) is
:class:`~drivers.dxlsim.wire.WireBus`'s; this module is the codec
(:mod:`drivers.protocol1.packet`) and the dispatch. The servos are
:class:`~drivers.dxlsim.p1servo.P1Servo`. One protocol per bus: Dynamixel P1 and Feetech
servos are not mixed (the URL refuses it).

Instructions: PING, READ, WRITE, REG_WRITE, ACTION, RESET to one ID; broadcast (0xFE, never
answered) WRITE, REG_WRITE, ACTION, RESET, SYNC WRITE 0x83; and the group reads, whose servos
answer one status packet each, in the order the packet lists them, each after the previous
reply and its own Return Delay Time + turnaround (a silent servo stops the chain, as on
Protocol 2.0): Feetech STS SYNC READ 0x82, Dynamixel MX BULK READ 0x92. A Feetech broadcast
PING is answered by every servo in ID order; a Dynamixel P1 one by none (the SDK has no
broadcast ping for P1). A packet whose checksum fails is never executed: a Dynamixel servo
on that ID answers with the Checksum Error bit (Status Return Level 2), a Feetech one is silent.
An instruction the family does not know: Instruction Error (Dynamixel), silence (Feetech).
"""

from __future__ import annotations

from typing import Any

from drivers.dxlsim.faults import FaultKind, FaultPlan, parse_fault_plan
from drivers.dxlsim.p1servo import P1Servo
from drivers.dxlsim.wire import WireBus
from drivers.protocol1.control_table import DxlP1Error
from drivers.protocol1.packet import (
    BROADCAST_ID,
    Inst,
    StreamParser,
    encode_status,
    parse_bulk_read,
    parse_sync_read,
    parse_sync_write,
)

#: Instructions a broadcast executes (without a reply).
_BROADCAST_EXECUTED = frozenset({Inst.WRITE, Inst.REG_WRITE, Inst.ACTION, Inst.RESET})


class P1Bus(WireBus[P1Servo]):
    """An emulated Protocol 1.0-framed bus; the parameters are
    :class:`~drivers.dxlsim.wire.WireBus`'s."""

    HEADER_LEN = 2

    def __init__(self, servos: Any, **kwargs: Any) -> None:
        faults = kwargs.get("faults")
        if isinstance(faults, str):
            faults = kwargs["faults"] = parse_fault_plan(faults, seed=kwargs.get("seed", 0))
        servos = list(servos)
        protocols = {s.family.protocol for s in servos}
        if len(protocols) > 1:
            named = sorted({f"{s.table.model} ({s.family.protocol})" for s in servos})
            raise ValueError(f"one protocol per bus, got {', '.join(named)}")
        if isinstance(faults, FaultPlan) and any(
            f.kind is FaultKind.WATCHDOG_TRIP for f in faults.faults
        ):
            raise ValueError("watchdog_trip: these servos have no Bus Watchdog")
        super().__init__(servos, **kwargs)
        self._parser = StreamParser()

    def _encode_status(self, packet_id: int, error: int, data: bytes) -> bytes:
        return encode_status(packet_id, error, data)

    def _twin(self, servo: P1Servo, t: float) -> P1Servo:
        return P1Servo(
            servo.table,
            servo.id,
            baud=servo.baud,
            return_delay_us=servo.return_delay_s * 1e6,
            t=t,
        )

    def _process(self, fid: int, ok: bool, inst: int, params: bytes, t: float) -> None:
        self.stats["instructions"] += 1
        if self._offline:
            hearing = [s for s in self.servos if self._hears(s, t)]
        else:
            baud = self.baud
            hearing = [s for s in self.servos if s.listening_baud == baud]
        if not ok:
            self.stats["crc_errors"] += 1
            targets = [s for s in hearing if s.id == fid and s.dxl]
            for s in targets:
                s.touch(t)
            self._send_unicast(
                [
                    (s, encode_status(s.id, s.status(DxlP1Error.CHECKSUM)))
                    for s in targets
                    if s.status_return_level >= 2
                ],
                t,
            )
            return
        if fid == BROADCAST_ID:
            self._broadcast(inst, params, hearing, t)
            return
        replies = []
        for s in hearing:
            if s.id != fid:
                continue
            s.touch(t)
            answer = execute(s, inst, params, t)
            if answer is not None and s.replies_to(inst):
                replies.append((s, encode_status(fid, *answer)))
        self._send_unicast(replies, t)

    def _broadcast(self, inst: int, params: bytes, hearing: list[P1Servo], t: float) -> None:
        if inst == Inst.SYNC_WRITE:
            parsed = parse_sync_write(params)
            if parsed is not None:
                addr, by_id = parsed
                for s in hearing:
                    if (data := by_id.get(s.id)) is not None:
                        s.write(addr, data, t)
            return
        items: list[tuple[int, int, int]] | None = None
        if inst == Inst.SYNC_READ and (sr := parse_sync_read(params)) is not None:
            items = [(sid, sr[0], sr[1]) for sid in sr[2]]
            hearing = [s for s in hearing if s.family.sync_read]
        elif inst == Inst.BULK_READ:
            items = parse_bulk_read(params)
            hearing = [s for s in hearing if s.family.bulk_read]
        elif inst == Inst.PING:
            chain = sorted((s for s in hearing if not s.dxl), key=lambda s: s.id)
            self._send_chain([(s, *s.ping(t)) for s in chain], t)
            return
        elif inst in _BROADCAST_EXECUTED:
            for s in hearing:
                s.touch(t)
                execute(s, inst, params, t)
            return
        if items is None:
            return
        self._read_chain(items, hearing, t)

    def _read_chain(
        self, items: list[tuple[int, int, int]], hearing: list[P1Servo], t: float
    ) -> None:
        """Sync/Bulk Read: one status packet per listed ``(id, addr, length)``, in order."""
        servos: dict[int, list[P1Servo]] = {}
        for s in hearing:
            servos.setdefault(s.id, []).append(s)
        links: list[list[tuple[Any, int, bytes]] | None] = []
        for sid, addr, length in items:
            members = servos.get(sid)
            links.append([(m, *m.read(addr, length, t)) for m in members] if members else None)
        self._send_chain_groups(links, t)


def execute(s: P1Servo, inst: int, params: bytes, t: float) -> tuple[int, bytes] | None:
    """One instruction on one servo: ``(ERR, data)`` for its status packet, or None when the
    servo stays silent whatever its Status Return Level."""
    if inst == Inst.PING:
        return s.ping(t)
    if inst == Inst.READ:
        if len(params) != 2:
            return _bad(s)
        return s.read(params[0], params[1], t)
    if inst in (Inst.WRITE, Inst.REG_WRITE):
        if len(params) < 2:
            return _bad(s)
        if inst == Inst.WRITE:
            return s.write(params[0], params[1:], t), b""
        return s.reg_write(params[0], params[1:], t), b""
    if inst == Inst.ACTION:
        return s.action(t), b""
    if inst == Inst.RESET:
        return s.factory_reset(t), b""
    return _bad(s)


def _bad(s: P1Servo) -> tuple[int, bytes] | None:
    """An unknown instruction or a malformed one: Instruction Error on Dynamixel; a Feetech
    servo does not answer."""
    return (s.status(DxlP1Error.INSTRUCTION), b"") if s.dxl else None
