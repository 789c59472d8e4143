"""One open port speaking Protocol 1.0 framing: transactions that return values or raise.

:class:`P1Link` is :class:`drivers.dynamixel.link.Link` (the port opened through the
driver's :class:`~drivers.dynamixel.port.PortHandler`: any pyserial URL, the injected clock,
the adapter's latency timer, host-stall accounting) with the Protocol 1.0 transactions in
place of the 2.0 ones. Packets are built and cut out of the stream by
:mod:`drivers.protocol1.packet`; :meth:`P1Link.transact` sends one request and collects a
status packet from each servo that should answer (a Sync or Bulk Read's chain, or one
reply), each checked on its own: a reply that is missing, cut short or fails its checksum is
simply not there, and the caller reports that servo STALE.

Why not dynamixel-sdk's ``PacketHandler(1.0)``: it frames these packets right, but its
``rxPacket`` takes one packet per call with a whole-packet timeout each, and its group
reads refuse Sync Read on Protocol 1.0; Feetech's Sync Read replies come as a chain, read
here against one deadline (``pyproject.toml`` says why no Feetech SDK is used).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from drivers.dynamixel.errors import CommTimeout, CorruptPacket, DynamixelError
from drivers.dynamixel.link import Link
from drivers.dynamixel.sdk_result import SERIAL_ERRORS, port_gone
from drivers.p1bus.table import Family, Reg
from drivers.protocol1 import encoding, packet

#: Servo processing time allowed per reply on top of its Return Delay Time (AX ~20 µs,
#: MX ~50 µs by ROBOTIS's figures; Feetech unpublished): a timeout's allowance.
TURNAROUND_ALLOWANCE_S = 100e-6
#: Return Delay Time assumed until the start-up check has read the real one (AX/MX factory
#: 250 = 500 µs; Feetech factory 250 = 500 µs as well).
FACTORY_RETURN_DELAY_S = 500e-6


class StatusError(DynamixelError):
    """A servo answered with error bits that make its reply no answer (an instruction,
    range or checksum error; or a hardware bit on a write)."""

    def __init__(self, servo_id: int, error: int, text: str, what: str) -> None:
        self.servo_id, self.error, self.what = servo_id, int(error), what
        super().__init__(f"servo {servo_id}: {text} (ERR 0x{error:02X}) on {what}")


@dataclass(slots=True)
class Replies:
    """What one :meth:`P1Link.transact` received: ``{id: (err, params)}`` of the intact
    status packets from the IDs asked, and the raw bytes of the damaged ones."""

    got: dict[int, tuple[int, bytes]]
    corrupt: list[bytes]


class P1Link(Link):
    """:class:`~drivers.dynamixel.link.Link` for Protocol 1.0 framing (AX, MX, STS, SCS).

    ``return_delay_s`` is the longest Return Delay Time on the bus (factory 500 µs until the
    start-up check has read them): every reply timeout allows it per reply.
    """

    return_delay_s: float = FACTORY_RETURN_DELAY_S

    # -- the transaction ---------------------------------------------------------
    def transact(
        self, request: bytes, ids: Sequence[int], data_len: int, what: str = ""
    ) -> Replies:
        """Send ``request``; collect one status packet of ``data_len`` data bytes from each of
        ``ids`` (none for a broadcast write), all against one deadline: the chain's wire
        time, each reply's Return Delay Time and turnaround, and the adapter's allowance."""
        port = self.port
        per_reply = packet.OVERHEAD + data_len
        total = per_reply * len(ids)
        try:
            port.is_using = True
            port.clearPort()
            if port.writePort(request) != len(request):
                raise DynamixelError(f"{self.name}: could not send {what or 'a packet'}")
            if not ids:
                return Replies({}, [])
            timeout_ms = (
                port.tx_time_per_byte * (total + len(request))
                + 2.0 * port.latency_timer_ms
                + 2.0
                + port.timeout_margin_ms
                + 1e3 * len(ids) * (self.return_delay_s + TURNAROUND_ALLOWANCE_S)
            )
            port.setPacketTimeoutMillis(timeout_ms)
            return _receive(port, ids, per_reply, total)
        except SERIAL_ERRORS as exc:
            if isinstance(exc, DynamixelError):
                raise
            raise port_gone(exc, self.name, what or "a transaction") from exc
        finally:
            port.is_using = False

    def chain_s(self, n: int, data_len: int) -> float:
        """Expected seconds of ``n`` replies of ``data_len`` data bytes (wire, Return Delay,
        turnaround): how long a failed chain may still be arriving."""
        byte_s = self.port.tx_time_per_byte * 1e-3
        return n * ((packet.OVERHEAD + data_len) * byte_s + self.return_delay_s + 100e-6)

    def one(self, request: bytes, servo_id: int, data_len: int, what: str) -> tuple[int, bytes]:
        """One request, one reply from ``servo_id``: ``(err, params)``, or raise
        :class:`CommTimeout` / :class:`CorruptPacket` (its late reply waited out)."""
        replies = self.transact(request, (servo_id,), data_len, what)
        found = replies.got.get(servo_id)
        if found is None:
            self.settle()  # its reply may still come: the next request must not take it
            if replies.corrupt:
                exc = CorruptPacket(
                    f"servo {servo_id}: corrupt reply to {what}", servo_id=servo_id, what=what
                )
                exc.complete = True
                raise exc
            raise CommTimeout(
                f"servo {servo_id}: no reply to {what} (timeout)", servo_id=servo_id, what=what
            )
        return found

    # -- unicast -----------------------------------------------------------------
    def ping1(self, servo_id: int) -> int:
        """Ping one servo; its status ERR byte (P1's Ping carries no model number)."""
        err, _ = self.one(packet.ping(servo_id), servo_id, 0, "Ping")
        return err

    def read_bytes(self, fam: Family, servo_id: int, addr: int, size: int) -> tuple[int, bytes]:
        """``(err, data)`` of ``size`` bytes at ``addr``; a reply of another length raises."""
        what = f"Read {size} B at {addr}"
        err, params = self.one(packet.read(servo_id, addr, size), servo_id, size, what)
        if err & ~fam.hardware_bits:
            raise StatusError(servo_id, err, fam.describe_error(err), what)
        if len(params) != size:
            raise CorruptPacket(
                f"servo {servo_id}: {len(params)} of {size} bytes in reply to {what}",
                servo_id=servo_id,
                what=what,
            )
        return err, params

    def read_reg(self, fam: Family, servo_id: int, reg: Reg) -> int:
        _, data = self.read_bytes(fam, servo_id, reg.addr, reg.size)
        return decode(fam, reg, data)

    def write_bytes(self, fam: Family, servo_id: int, addr: int, data: bytes) -> None:
        """Write ``data`` at ``addr`` and wait for the status packet (Status Return Level all,
        which the start-up check requires); error bits other than the servo's own
        condition raise."""
        what = f"Write {len(data)} B at {addr}"
        err, _ = self.one(packet.write(servo_id, addr, data), servo_id, 0, what)
        if err & ~fam.hardware_bits:
            raise StatusError(servo_id, err, fam.describe_error(err), what)

    def write_reg(self, fam: Family, servo_id: int, reg: Reg, value: int) -> None:
        self.write_bytes(fam, servo_id, reg.addr, encode(fam, reg, value))


def encode(fam: Family, reg: Reg, value: int) -> bytes:
    """``value`` as the register's bytes in the family's encoding."""
    raw = value if reg.sign_bit is None else encoding.to_sign_magnitude(value, reg.sign_bit)
    return encoding.encode_word(raw, reg.size, fam.big_endian)


def decode(fam: Family, reg: Reg, data: bytes, start: int | None = None) -> int:
    """The register's value from ``data`` (a read that began at ``start``, default its own)."""
    i = 0 if start is None else reg.addr - start
    raw = encoding.decode_word(data[i : i + reg.size], fam.big_endian)
    return raw if reg.sign_bit is None else encoding.from_sign_magnitude(raw, reg.sign_bit)


def _receive(port: object, ids: Iterable[int], per_reply: int, total: int) -> Replies:
    """Status packets from ``ids`` until each has one or the packet deadline passes."""
    want = set(ids)
    data = port.readPort(max(1, total))  # type: ignore[attr-defined]
    if len(data) == total and (whole := _whole_chain(data, want, per_reply)) is not None:
        return Replies(whole, [])
    got: dict[int, tuple[int, bytes]] = {}
    corrupt: list[bytes] = []
    parser = packet.StreamParser()
    received = 0
    while True:
        received += len(data)
        for _, (raw, fid, ok, code, params) in parser.feed_decoded(data):
            if not ok or len(params) != per_reply - packet.OVERHEAD:
                corrupt.append(raw)  # its ID is not to be trusted: nobody's reply
            elif fid in want and fid not in got:
                got[fid] = (code, params)
        if len(got) == len(want) or port.isPacketTimeout():  # type: ignore[attr-defined]
            if parser.pending and len(got) < len(want):
                corrupt.append(b"")  # a reply cut short
            return Replies(got, corrupt)
        data = port.readPort(max(1, total - received))  # type: ignore[attr-defined]


def _whole_chain(
    data: bytes, want: set[int], per_reply: int
) -> dict[int, tuple[int, bytes]] | None:
    """The usual tick: ``data`` is exactly one intact status packet of ``per_reply`` bytes
    from each ID of ``want``, back to back. Then ``{id: (err, params)}``, what the stream
    parser would make of it; else None (the parser sorts it out)."""
    got: dict[int, tuple[int, bytes]] = {}
    last = per_reply - 1
    size = per_reply - 4
    for i in range(0, len(data), per_reply):
        fid = data[i + 2]
        if (
            data[i] != 0xFF
            or data[i + 1] != 0xFF
            or data[i + 3] != size
            or fid not in want
            or fid in got
            or ~sum(data[i + 2 : i + last]) & 0xFF != data[i + last]
        ):
            return None
        got[fid] = (data[i + 4], data[i + 5 : i + last])
    return got if len(got) == len(want) else None
