"""A small stand-in for a bus of Protocol 1.0-framed servos (Feetech STS/SCS, Dynamixel AX/MX),
for host-side tests on the virtual clock.

:class:`P1StubBus` answers what the host sends, byte for byte, from each servo's register file
(:mod:`drivers.protocol1.control_table`'s defaults): PING, READ, WRITE, SYNC WRITE, and SYNC READ
(STS) / BULK READ (MX) with one status packet per servo, each after its Return Delay Time.
Goals are reached at once. Faults are switches on a :class:`StubServo` (silent, drop or corrupt
its next replies, error bits). Registered with :func:`drivers.dxlsim.register_bus`, it opens as
``dxlsim://NAME`` (it has what the dxlsim serial port asks of a bus), so a whole show runs on it.
It is not the emulator: no motion model, no USB chunking; it exists to hold the host's rules.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from drivers.clock import VirtualClock
from drivers.protocol1 import packet
from drivers.protocol1.control_table import ControlTable, table_for

BYTE_S = 10e-6  # 1 Mbit/s


@dataclass
class StubServo:
    id: int
    table: ControlTable
    regs: bytearray = field(default_factory=lambda: bytearray(128))
    silent: bool = False
    drop: int = 0  # the next replies not sent
    corrupt: int = 0  # the next replies with a wrong checksum
    err: int = 0  # ERR bits in every reply
    torque_sticks_off: bool = False  # writes of Torque Enable are acknowledged, not kept

    def __post_init__(self) -> None:
        t = self.table
        center = t.resolution // 2
        for it in t.items:
            value = it.default
            if value is None:
                value = {"Present Voltage": t.volts}.get(it.name, 0)
                if "Position" in it.name:
                    value = center
                if it.name == "Model Number":
                    value = t.model_number
                if it.name.startswith("Firmware"):
                    value = t.firmware
                if it.name == "Present Temperature":
                    value = 31
                if it.name == "Torque Limit":
                    value = 1000
            self.regs[it.addr : it.end] = it.encode(value)
        self.regs[t.item("ID").addr] = self.id
        self.set("Return Delay Time", 0)
        self.set("Baud Rate", t.family.baud_code(1_000_000))

    def get(self, name: str) -> int:
        it = self.table.item(name)
        return it.decode(self.regs)

    def set(self, name: str, value: int) -> None:
        it = self.table.item(name)
        self.regs[it.addr : it.end] = it.encode(value)

    def write(self, addr: int, data: bytes) -> None:
        torque = self.table.item("Torque Enable").addr
        if self.torque_sticks_off and addr == torque:
            data = b"\x00" + data[1:]
        self.regs[addr : addr + len(data)] = data
        goal = self.table.item("Goal Position")
        if addr <= goal.addr < addr + len(data) and self.get("Torque Enable"):
            self.set("Present Position", self.get("Goal Position"))


class P1StubBus:
    """A bus of :class:`StubServo` s with what ``dxlsim://`` asks of a bus."""

    def __init__(self, models: dict[int, str], clock: VirtualClock | None = None) -> None:
        self.clock = clock or VirtualClock()
        self.baud = 1_000_000
        self.latency_s = 1e-3
        self.servos = {sid: StubServo(sid, table_for(m)) for sid, m in models.items()}
        self._rx: list[tuple[float, bytes]] = []  # (visible at, bytes)
        self._tx_free = 0.0
        self.gone = False
        self.sent: list[tuple[float, bytes]] = []  # every packet the host wrote
        self._plan: list[tuple[float, object]] = []  # (bus time, callable) run at the next write
        self.hook = None  # called with each packet before it is handled (may raise)

    def at(self, t: float, fn) -> None:
        """Run ``fn()`` at the first write at or after bus time ``t`` (a fault plan)."""
        self._plan.append((t, fn))

    # -- what the dxlsim serial port calls -----------------------------------------
    def unplugged(self) -> bool:
        return self.gone

    @property
    def pending_rx(self) -> int:
        return sum(len(b) for _, b in self._rx)

    def in_waiting(self) -> int:
        now = self.clock.now()
        return sum(len(b) for t, b in self._rx if t <= now)

    def visible_at(self, size: int) -> float | None:
        n = 0
        for t, b in self._rx:
            n += len(b)
            if n >= size:
                return t
        return None

    def read(self, size: int) -> bytes:
        now = self.clock.now()
        out = bytearray()
        while self._rx and self._rx[0][0] <= now and len(out) < size:
            t, b = self._rx.pop(0)
            take = size - len(out)
            out += b[:take]
            if len(b) > take:
                self._rx.insert(0, (t, b[take:]))
        return bytes(out)

    def reset_input(self) -> None:
        now = self.clock.now()
        self._rx = [(t, b) for t, b in self._rx if t > now]

    def write(self, data: bytes) -> None:
        now = self.clock.now()
        for item in [p for p in self._plan if p[0] <= now]:
            self._plan.remove(item)
            item[1]()  # type: ignore[operator]
        if self.hook is not None:
            self.hook(bytes(data))
        self.sent.append((now, bytes(data)))
        t = now + len(data) * BYTE_S
        self._tx_free = t
        for p in packet.StreamParser().feed(bytes(data)):
            if p is not None:
                t = self._answer(p, t)

    # -- the servos ----------------------------------------------------------------
    def _reply(self, s: StubServo, params: bytes, t: float) -> float:
        t += s.get("Return Delay Time") * 2e-6 + 20e-6
        frame = packet.encode_status(s.id, s.err, params)
        t_end = t + len(frame) * BYTE_S
        if s.drop:
            s.drop -= 1
            return t_end
        if s.corrupt:
            s.corrupt -= 1
            frame = frame[:-1] + bytes(((frame[-1] + 1) & 0xFF,))
        self._rx.append((t_end + self.latency_s, frame))
        return t_end

    def _answers(self, s: StubServo, inst: int) -> bool:
        fam = s.table.family
        level = s.get(
            "Response Status Level" if fam.protocol == "feetech" else "Status Return Level"
        )
        if inst == packet.Inst.PING or level >= fam.srl_all:
            return True
        return inst == packet.Inst.READ and level >= fam.srl_read

    def _answer(self, p: packet.Packet, t: float) -> float:
        inst, prm = p.code, p.params
        if inst == packet.Inst.SYNC_WRITE:
            parsed = packet.parse_sync_write(prm)
            if parsed is not None:
                addr, data = parsed
                for sid, d in data.items():
                    if sid in self.servos and not self.servos[sid].silent:
                        self.servos[sid].write(addr, d)
            return t
        if inst == packet.Inst.SYNC_READ:
            addr, n, ids = packet.parse_sync_read(prm) or (0, 0, [])
            for sid in ids:
                s = self.servos.get(sid)
                if s is not None and not s.silent and s.table.family.sync_read:
                    t = self._reply(s, bytes(s.regs[addr : addr + n]), t)
            return t
        if inst == packet.Inst.BULK_READ:
            for sid, addr, n in packet.parse_bulk_read(prm) or []:
                s = self.servos.get(sid)
                if s is not None and not s.silent and s.table.family.bulk_read:
                    t = self._reply(s, bytes(s.regs[addr : addr + n]), t)
            return t
        s = self.servos.get(p.id)
        if s is None or s.silent:
            return t
        data = b""
        if inst == packet.Inst.READ:
            data = bytes(s.regs[prm[0] : prm[0] + prm[1]])
        elif inst == packet.Inst.WRITE:
            s.write(prm[0], prm[1:])
        if not self._answers(s, inst):
            return t
        return self._reply(s, data, t)

    # -- what the tests look at ----------------------------------------------------
    def instructions(self, start: int = 0) -> list[packet.Packet]:
        """The packets the host wrote, from its ``start``-th write on (``len(self.sent)``)."""
        out = []
        for _, b in self.sent[start:]:
            out += [p for p in packet.StreamParser().feed(b) if p is not None]
        return out
