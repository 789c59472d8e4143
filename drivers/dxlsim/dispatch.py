"""What a servo does with an instruction packet: addressing and execution.

Addressing (e-Manual protocol2.md, ``control_table_shadowid.md``): a packet to an ID is
executed and answered by the servo with that ID (ID(7) has priority) and executed, never
answered, by every other servo whose Secondary ID(12) is that ID (0-252; 253-255 turn it
off). Through a Secondary ID the EEPROM area cannot be changed: a Write or Reg Write that
touches an address below 64 is dropped there, as are Factory Reset and Control Table
Backup; Ping and Read would only produce an answer, which is never sent. A broadcast
Factory Reset with option 0xFF is ignored by firmware 42 and up (nothing executed, no
reply, as for every broadcast but Ping and the reads).

The bus (:mod:`drivers.dxlsim.bus`) decides who hears a packet and puts the answers on the
wire; this module parses the parameters and runs the instruction on each servo.
"""

from __future__ import annotations

from itertools import repeat
from types import SimpleNamespace

from drivers.dxlsim.protocol import ErrorCode, Instruction
from drivers.dxlsim.servo import VirtualServo
from drivers.protocol2.control_table import EEPROM_END

__all__ = [
    "BROADCAST_RESET_ALL_MIN_FIRMWARE",
    "Inst",
    "bulk_write",
    "error_byte",
    "execute",
    "execute_broadcast",
    "execute_secondary",
    "read_items",
    "replies_to",
    "sync_write",
]

#: From this firmware a broadcast Factory Reset with option 0xFF (Reset All) is not
#: executed (protocol2.md Factory Reset: "MX(2.0) FW42, X-series FW42 or above").
BROADCAST_RESET_ALL_MIN_FIRMWARE = 42
RESET_ALL = b"\xff"

#: The instruction codes as plain ints (an enum lookup through its class costs more, several
#: times a packet; the comparisons are the same). # hot path
Inst = SimpleNamespace(**{m.name: int(m) for m in Instruction})
#: What a servo executes when addressed by its Secondary ID (never answered).
_BY_SECONDARY_ID = frozenset((Inst.WRITE, Inst.REG_WRITE, Inst.ACTION, Inst.REBOOT, Inst.CLEAR))
#: Broadcast instructions every servo executes and none answers.
BROADCAST_EXECUTED = frozenset(
    (
        Inst.WRITE,
        Inst.REG_WRITE,
        Inst.ACTION,
        Inst.REBOOT,
        Inst.FACTORY_RESET,
        Inst.CLEAR,
        Inst.BACKUP,
    )
)
_READS = {
    Inst.SYNC_READ: False,
    Inst.FAST_SYNC_READ: True,
    Inst.BULK_READ: False,
    Inst.FAST_BULK_READ: True,
}


def error_byte(servo: VirtualServo, code: int) -> int:
    """A status packet's ERR byte: ``code``, with the Alert bit when the servo has one."""
    return code | (0x80 if servo.alert else 0)


def replies_to(servo: VirtualServo, inst: int) -> bool:
    """Whether ``servo`` answers ``inst`` sent to its ID (Status Return Level)."""
    level = servo.status_return_level
    if inst == Inst.PING:
        return True
    if inst == Inst.READ:
        return level >= 1
    return level >= 2


def execute(s: VirtualServo, inst: int, params: bytes, t: float) -> tuple[int, bytes]:
    """One instruction addressed to one servo -> (ERR byte, status params)."""
    bad = error_byte(s, ErrorCode.INSTRUCTION)
    if inst == Inst.PING:
        return s.ping(t) if not params else (bad, b"")
    if inst == Inst.READ:
        if len(params) != 4:
            return bad, b""
        return s.read(params[0] | params[1] << 8, params[2] | params[3] << 8, t)
    if inst in (Inst.WRITE, Inst.REG_WRITE):
        if len(params) < 3:
            return bad, b""
        fn = s.write if inst == Inst.WRITE else s.reg_write
        return fn(params[0] | params[1] << 8, params[2:], t), b""
    if inst == Inst.ACTION:
        return (s.action(t), b"") if not params else (bad, b"")
    if inst == Inst.REBOOT:
        return (s.reboot(t), b"") if not params else (bad, b"")
    if inst == Inst.FACTORY_RESET:
        return (s.factory_reset(params[0], t), b"") if len(params) == 1 else (bad, b"")
    if inst == Inst.CLEAR:
        return s.clear(params, t), b""
    if inst == Inst.BACKUP:
        return s.backup(params, t), b""
    return bad, b""  # unknown, or a broadcast-only instruction sent to one ID


def execute_secondary(s: VirtualServo, inst: int, params: bytes, t: float) -> None:
    """An instruction for ``s``'s Secondary ID: RAM only, executed, never answered."""
    if inst not in _BY_SECONDARY_ID:
        return
    if inst in (Inst.WRITE, Inst.REG_WRITE) and (
        len(params) < 3 or (params[0] | params[1] << 8) < EEPROM_END
    ):
        return  # the EEPROM area cannot be modified with the Secondary ID
    execute(s, inst, params, t)


def execute_broadcast(s: VirtualServo, inst: int, params: bytes, t: float) -> None:
    """One of :data:`BROADCAST_EXECUTED`, on one servo that heard it: executed, not answered."""
    if (
        inst == Inst.FACTORY_RESET
        and params == RESET_ALL
        and s.firmware >= BROADCAST_RESET_ALL_MIN_FIRMWARE
    ):
        return  # the FW42+ safety rule: a broadcast Reset All is not executed
    execute(s, inst, params, t)


def sync_write(params: bytes) -> tuple[int, dict[int, bytes]] | None:
    """A Sync Write's start address and each ID's data, or None (malformed: ignored)."""
    if len(params) < 4:
        return None
    addr, length = params[0] | params[1] << 8, params[2] | params[3] << 8
    body = params[4:]
    if length == 0 or len(body) % (length + 1):
        return None  # malformed: every servo ignores it
    by_id = {}
    for k in range(0, len(body), length + 1):
        by_id[body[k]] = body[k + 1 : k + 1 + length]
    return addr, by_id


def bulk_write(params: bytes) -> dict[int, tuple[int, bytes]] | None:
    """A Bulk Write's (address, data) per ID, or None (malformed: ignored)."""
    k, writes = 0, dict[int, tuple[int, bytes]]()
    while k + 5 <= len(params):
        sid, addr = params[k], params[k + 1] | params[k + 2] << 8
        length = params[k + 3] | params[k + 4] << 8
        if k + 5 + length > len(params):
            return None
        writes[sid] = (addr, params[k + 5 : k + 5 + length])
        k += 5 + length
    return writes if k == len(params) else None


def read_items(inst: int, params: bytes) -> tuple[bool, list[tuple[int, int, int]]] | None:
    """A Sync or Bulk Read (plain or Fast): whether it is Fast, and ``(id, address, length)``
    in the order the servos answer; None for another instruction or a malformed packet."""
    fast = _READS.get(inst)
    if fast is None or len(params) < 5:
        return None
    if inst in (Inst.SYNC_READ, Inst.FAST_SYNC_READ):
        addr, length = params[0] | params[1] << 8, params[2] | params[3] << 8
        return fast, list(zip(params[4:], repeat(addr), repeat(length)))
    if len(params) % 5:
        return None
    return fast, [
        (params[k], params[k + 1] | params[k + 2] << 8, params[k + 3] | params[k + 4] << 8)
        for k in range(0, len(params), 5)
    ]
