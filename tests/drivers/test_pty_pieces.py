"""``hilsim emulate``'s pty delivers reply bytes as a USB adapter does, in pieces (issue 12:
fewer wake-ups per reply): a run of bytes that follow each other on the wire, at most one USB
packet (62 bytes), written when its last byte is readable. A Fast Sync Read reply is one
piece, at the time its last byte was due; the Sync Read's status packets, a Return Delay and
turnaround apart, are a piece each.

The schedule is checked on the virtual clock (``piece_due`` reads only the bus's byte times);
one real exchange over a pty checks that the server writes a reply in one piece."""

from __future__ import annotations

import os
import select
import threading
import tty
import types

import dynamixel_sdk as sdk
import pytest

import drivers.dxlsim.pty_server as pty_server
from drivers.dxlsim.pty_server import PtyServer, piece_due
from drivers.dxlsim.url import DxlsimUrl
from drivers.dynamixel.port import PortHandler
from drivers.protocol2.crc import crc16
from drivers.protocol2.wire_time import USB_CHUNK

BAUD = 1_000_000


def sent(n: int, fast: bool, extra: str = ""):
    """A virtual-clock bus of ``n`` servos that has just received a (Fast) Sync Read of
    Present Position: ``(bus, the time the request was sent)``."""
    port = PortHandler(f"dxlsim://?ids=1-{n}&rdt_us=0&clock=virtual{extra}")
    port.openPort()
    port.setBaudRate(BAUD)
    group = sdk.GroupSyncRead(port, sdk.PacketHandler(2.0), 132, 4)
    for i in range(1, n + 1):
        group.addParam(i)
    t = port.clock.now()
    assert (group.fastSyncReadTxPacket() if fast else group.txPacket()) == sdk.COMM_SUCCESS
    return port.ser.bus, t


def test_a_fast_sync_read_reply_is_one_piece_due_with_its_last_byte():
    bus, _ = sent(4, fast=True)
    n = bus.pending_rx
    due, count = piece_due(bus)
    assert count == n == 40 and due == bus.visible_at(n)


def test_a_piece_is_at_most_one_usb_packet():
    bus, _ = sent(16, fast=True)
    assert bus.pending_rx > USB_CHUNK
    due, count = piece_due(bus)
    assert count == USB_CHUNK and due == bus.visible_at(USB_CHUNK)


def test_a_latency_timer_chunk_is_one_piece():
    bus, _ = sent(4, fast=True, extra="&latency_ms=1")
    due, count = piece_due(bus)
    assert count == bus.pending_rx and due == bus.visible_at(count)


def test_status_packets_a_turnaround_apart_are_pieces_of_their_own():
    bus, _ = sent(2, fast=False)
    assert bus.pending_rx == 2 * 15  # two status packets of 4 data bytes, 15 bytes each
    due, count = piece_due(bus)
    assert count == 15 and due == bus.visible_at(15) < bus.visible_at(16)
    bus.clock.wait_until(due)
    assert len(bus.read(64)) == 15  # the first packet, read as the server writes it
    assert piece_due(bus) == (bus.visible_at(15), 15)  # then the second


def test_nothing_on_its_way_is_no_piece():
    bus, t = sent(1, fast=True)
    bus.clock.wait_until(t + 0.01)
    bus.read(bus.in_waiting())
    assert piece_due(bus) == (None, 0)


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="no pseudo-terminals")
def test_the_server_writes_a_fast_sync_read_reply_in_one_piece(monkeypatch):
    writes: list[int] = []

    def write(fd, data):
        writes.append(len(data))
        return os.write(fd, data)

    monkeypatch.setattr(pty_server, "os", types.SimpleNamespace(**{**vars(os), "write": write}))
    bus = DxlsimUrl.parse("dxlsim://?ids=1-4&rdt_us=0").build_bus(host_baud=BAUD)
    server = PtyServer(bus)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    fd = os.open(server.path, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd)
        request = bytes([0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x0B, 0x00, 0x8A, 0x84, 0x00, 0x04, 0x00])
        request += bytes([1, 2, 3, 4])
        crc = crc16(request)
        os.write(fd, request + bytes([crc & 0xFF, crc >> 8]))
        reply = b""
        while len(reply) < 40:
            ready, _, _ = select.select([fd], [], [], 10.0)
            assert ready, f"no reply after {reply!r}"
            reply += os.read(fd, 64)
        assert reply[:8] == bytes([0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x21, 0x00, 0x55])
        assert writes == [40]  # the whole reply, once
    finally:
        server.stop()
        thread.join(timeout=5)
        os.close(fd)
        server.close()
