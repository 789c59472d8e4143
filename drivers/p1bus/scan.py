"""Find Feetech and Dynamixel Protocol 1.0 servos on a port: a Ping per ID at each baud rate.

These families have no broadcast Ping the host can rely on (Dynamixel Protocol 1.0 has none;
Feetech SCS has none), so each candidate ID is pinged alone; each servo that answers is asked
its Model Number (Dynamixel: address 0; Feetech: address 3, big-endian on SCS) and firmware,
and named with its family. On hardware a silent ID costs one packet timeout (about 4 ms with
a 1 ms latency timer): narrow the IDs (``--ids``) to scan quicker.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from drivers.clock import Clock
from drivers.dynamixel.errors import CommError
from drivers.p1bus.link import P1Link, StatusError
from drivers.p1bus.table import AX, STS, Family, Protocol, model_by_number
from drivers.protocol1 import packet

#: the family whose registers a first read of an answering servo uses, per protocol
_PROBE: dict[Protocol, Family] = {Protocol.DXL1: AX, Protocol.FEETECH: STS}


@dataclass(frozen=True, order=True)
class Found1:
    """One servo that answered a Ping."""

    baud: int
    id: int
    model_number: int
    model_name: str
    family: str
    firmware: int

    def __str__(self) -> str:
        return (
            f"ID {self.id:3d} @ {self.baud:>7d} bit/s: {self.model_name} ({self.family}; "
            f"model {self.model_number}, firmware {self.firmware})"
        )


def scan1(
    port: str,
    bauds: Sequence[int],
    ids: Iterable[int] | None,
    protocol: Protocol,
    *,
    clock: Clock | None = None,
    latency_timer_ms: float | None = None,
) -> list[Found1]:
    """Every servo of ``protocol`` (Dynamixel 1.0 or Feetech) answering on ``port`` at each
    of ``bauds``, sorted by (baud, id); ``ids`` default 0..252."""
    wanted = list(range(253)) if ids is None else sorted(set(ids))
    if not bauds:
        raise ValueError("give at least one baud rate")
    probe = _PROBE[protocol]
    found: list[Found1] = []
    link = P1Link.open(port, baud=bauds[0], clock=clock, latency_timer_ms=latency_timer_ms)
    assert isinstance(link, P1Link)
    try:
        for baud in bauds:
            link.set_baud(baud)
            for sid in wanted:
                try:
                    link.ping1(sid)
                except CommError:
                    continue
                found.append(identify(link, probe, protocol, baud, sid))
    finally:
        link.close()
    return sorted(found)


def identify(link: P1Link, probe: Family, protocol: Protocol, baud: int, sid: int) -> Found1:
    reg = probe.model_number
    try:
        _, raw = link.read_bytes(probe, sid, reg.addr, reg.size)
        firmware = link.read_reg(probe, sid, probe.firmware)
    except (CommError, StatusError):
        return Found1(baud, sid, -1, "a servo (its model could not be read)", str(protocol), -1)
    for number in (int.from_bytes(raw, "little"), int.from_bytes(raw, "big")):  # SCS: big
        known = model_by_number(protocol, number)
        if known is not None:
            return Found1(baud, sid, number, known[0], known[1].name, firmware)
    number = int.from_bytes(raw, "little")
    return Found1(baud, sid, number, f"unknown model {number}", str(protocol), firmware)


def broadcast_ping(link: P1Link) -> list[int]:
    """The IDs answering a Feetech broadcast Ping at the link's baud (each replies after the
    one before; the wait allows a reply from every ID). Dynamixel Protocol 1.0 servos do
    not answer it."""
    replies = link.transact(packet.ping(packet.BROADCAST_ID), range(253), 0, "broadcast Ping")
    link.settle()
    return sorted(replies.got)


def feetech_answers(
    port: str,
    bauds: Sequence[int],
    *,
    clock: Clock | None = None,
    latency_timer_ms: float | None = None,
) -> list[tuple[int, list[int]]]:
    """``(baud, IDs)`` for each of ``bauds`` at which Feetech servos answer a broadcast Ping:
    a quick look (one Ping a baud) for a scan in another protocol that found nothing."""
    hits: list[tuple[int, list[int]]] = []
    link = P1Link.open(port, baud=bauds[0], clock=clock, latency_timer_ms=latency_timer_ms)
    assert isinstance(link, P1Link)
    try:
        for baud in bauds:
            try:
                link.set_baud(baud)
                ids = broadcast_ping(link)
            except (ValueError, CommError):
                continue
            if ids:
                hits.append((baud, ids))
    finally:
        link.close()
    return hits
