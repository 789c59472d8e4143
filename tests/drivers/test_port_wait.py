"""Waiting costs nothing (issue 12): on a real port ``PortHandler.readPort`` waits in the OS.

On a device or a pty the port hands pyserial the time left to the packet deadline, so one
read returns the moment the bytes the SDK asked for are there (or at the deadline) instead
of the SDK busy-polling; a read that reached the deadline is followed by one poll that does
not wait, and only that one declares the timeout. The host-stall watch counts a blocking
read's time only past its deadline. An unplugged pty raises and frees the port.

Real ptys, but nothing here waits on purpose: the bytes are written before the read, the
one deadline that passes is 0.3 ms away, and the stall figures come from a hand-moved clock.
"""

from __future__ import annotations

import contextlib
import os
import tty

import dynamixel_sdk as sdk
import pytest
import serial

from drivers.dxlsim.protocol import encode_status
from drivers.dynamixel.port import HOST_STALL_THRESHOLD_S, PortHandler

pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="no pseudo-terminals")

BAUD = 1_000_000
PING_REPLY = encode_status(3, 0, bytes((0x06, 0x04, 0x2A)))  # XM430-W350, firmware 42


@contextlib.contextmanager
def pty_port(clock=None):
    """``(port, master fd)``: hilsim's PortHandler open on a fresh pty's slave."""
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    port = PortHandler(os.ttyname(slave), clock=clock)
    try:
        assert port.setBaudRate(BAUD)
        yield port, master
    finally:
        port.closePort()
        for fd in (master, slave):
            with contextlib.suppress(OSError):
                os.close(fd)


def read_from(master: int, n: int, timeout_s: float = 10.0) -> bytes:
    """``n`` bytes from the pty's master: two writes may arrive in two reads."""
    import select

    got = b""
    while len(got) < n and select.select([master], [], [], timeout_s)[0]:
        got += os.read(master, n - len(got))
    return got


def spy_reads(port) -> list[tuple[int, float]]:
    """Record ``(length asked, timeout it may wait)`` for every read of the device."""
    calls = []
    read = port._read_fd

    def spy(ser, n, timeout):
        calls.append((n, timeout))
        return read(ser, n, timeout)

    port._read_fd = spy
    return calls


def test_a_reply_already_there_is_taken_in_the_reads_the_sdk_asks_for():
    with pty_port() as (port, master):
        os.write(master, PING_REPLY)
        calls = spy_reads(port)
        port.setPacketTimeoutMillis(50.0)
        packet, result = sdk.PacketHandler(2.0).rxPacket(port, False)
        assert result == sdk.COMM_SUCCESS and bytes(packet) == PING_REPLY
        # 11 bytes (a minimal status packet), then exactly the rest its LENGTH names; each
        # read may wait (up to the deadline), none was asked for a byte more
        assert [n for n, _ in calls] == [11, len(PING_REPLY) - 11]
        assert all(0.0 < t <= 0.050 + 1e-5 for _, t in calls)
        assert port.ser._timeout == 0  # the port is left non-blocking
        assert port.host_stalls == 0


def test_a_read_that_reaches_the_deadline_is_followed_by_one_poll_that_does_not_wait():
    with pty_port() as (port, _master):
        calls = spy_reads(port)
        port.setPacketTimeoutMillis(0.3)
        _packet, result = sdk.PacketHandler(2.0).rxPacket(port, False)
        assert result == sdk.COMM_RX_TIMEOUT
        timeouts = [t for _, t in calls]
        # the waiting read(s) began before the deadline: the SDK polled once more, at once,
        # and only that poll (begun after the deadline) declared the timeout
        assert timeouts[-1] == 0 and all(t > 0 for t in timeouts[:-1]) and len(timeouts) >= 2


def test_half_a_reply_at_the_deadline_is_corrupt_not_more_waiting():
    with pty_port() as (port, master):
        os.write(master, PING_REPLY[:12])
        calls = spy_reads(port)
        port.setPacketTimeoutMillis(0.3)
        _packet, result = sdk.PacketHandler(2.0).rxPacket(port, False)
        assert result == sdk.COMM_RX_CORRUPT
        assert calls[0][0] == 11 and calls[0][1] > 0 and calls[-1][1] == 0


class HandClock:
    """A real-time clock (``virtual`` False) that moves only when the fake port says."""

    virtual = False

    def __init__(self) -> None:
        self.t = 100.0

    def now(self) -> float:
        return self.t

    def wait_until(self, t: float, idle=None) -> float:
        self.t = max(self.t, t)
        return self.t


class SlowSerial:
    """Stands in for the pty after it is open: each read takes ``took[i]`` clock seconds
    and returns the bytes asked for from ``data``; records the timeouts it was given."""

    def __init__(self, clock: HandClock, data: bytes, took: list[float]) -> None:
        self.clock, self.data, self.took, self.timeouts = clock, data, list(took), []
        self.timeout = 0

    def read(self, n: int) -> bytes:
        self.timeouts.append(self.timeout)
        self.clock.t += self.took.pop(0) if self.took else 0.0
        out, self.data = self.data[:n], self.data[n:]
        return out

    def reset_input_buffer(self) -> None:
        pass

    def write(self, data) -> int:
        return len(data)

    def close(self) -> None:
        pass


@pytest.mark.parametrize(
    ("took", "stall"),
    [
        ([0.009, 0.0], 0.0),  # waited 9 ms of its 10 for the device: no stall
        ([0.010 + 0.0005, 0.0], 0.0),  # returned half a ms past the deadline: timer slack
        ([0.010 + 0.050, 0.0], 0.050),  # 50 ms past it: the host was not running, at least
        ([0.002, 0.030], 0.030 - 0.008),  # the second read may wait the 8 ms left, no more
    ],
)
def test_a_blocking_read_is_a_host_stall_only_past_its_deadline(took, stall):
    clock = HandClock()
    with pty_port(clock) as (port, _master):
        real = port.ser
        port.ser = fake = SlowSerial(clock, PING_REPLY, took)
        try:
            port.clearPort()  # a transmit: the stall watch starts here
            port.setPacketTimeoutMillis(10.0)
            packet, result = sdk.PacketHandler(2.0).rxPacket(port, False)
        finally:
            port.ser = real
        assert result == sdk.COMM_SUCCESS and bytes(packet) == PING_REPLY  # never dropped
        assert fake.timeouts[0] == pytest.approx(0.010, abs=1e-5)
        assert port.host_stall_s == pytest.approx(stall, abs=2e-6)  # the timeout has +1 µs
        assert port.host_stalls == (1 if stall > HOST_STALL_THRESHOLD_S else 0)
        assert port.device_wait_s == pytest.approx(sum(took), abs=1e-9)


def test_an_unplugged_pty_raises_at_once_and_frees_the_port():
    with pty_port() as (port, master):
        os.close(master)  # the other end is gone: the slave reads EOF/EIO, never blocks
        port.is_using = True
        port.setPacketTimeoutMillis(60_000.0)
        with pytest.raises(serial.SerialException):
            port.readPort(11)
        assert port.is_using is False


# -- the device read and write without pyserial's per-call objects, with its semantics
class SelectSpy:
    """Stands in for the port module's ``select``: records each call's timeout and may
    write bytes to the pty's master side first (bytes that arrive during the wait)."""

    def __init__(self, real, master: int, arriving: bytes = b"") -> None:
        self.real, self.master, self.arriving, self.timeouts = real, master, arriving, []

    def __call__(self, r, w, x, timeout=None):
        self.timeouts.append(timeout)
        if self.arriving:
            os.write(self.master, self.arriving)
            self.arriving = b""
        return self.real(r, w, x, timeout)


def test_a_read_waits_in_the_os_for_the_time_left_and_never_polls(monkeypatch):
    import drivers.dynamixel.port as port_mod

    with pty_port() as (port, master):
        os.write(master, PING_REPLY[:5])  # the first bytes are there, the rest is coming
        spy = SelectSpy(port_mod._select, master, arriving=PING_REPLY[5:])
        monkeypatch.setattr(port_mod, "_select", spy)
        port.setPacketTimeoutMillis(50.0)
        packet, result = sdk.PacketHandler(2.0).rxPacket(port, False)
        assert result == sdk.COMM_SUCCESS and bytes(packet) == PING_REPLY
        # one wait, handed the time to the deadline; the rest of the packet, there by then,
        # was read without another one
        (timeout,) = spy.timeouts
        assert 0.040 < timeout <= 0.050 + 1e-5


def test_a_reply_already_there_needs_no_select(monkeypatch):
    import drivers.dynamixel.port as port_mod

    with pty_port() as (port, master):
        os.write(master, PING_REPLY)
        spy = SelectSpy(port_mod._select, master)
        monkeypatch.setattr(port_mod, "_select", spy)
        port.setPacketTimeoutMillis(50.0)
        packet, result = sdk.PacketHandler(2.0).rxPacket(port, False)
        assert result == sdk.COMM_SUCCESS and bytes(packet) == PING_REPLY
        assert spy.timeouts == []


def test_cancel_read_ends_a_waiting_read_with_what_is_there():
    with pty_port() as (port, master):
        os.write(master, PING_REPLY[:4])
        port.setPacketTimeoutMillis(60_000.0)
        port.ser.cancel_read()  # pyserial's way to wake a blocked reader (another thread's)
        assert port.readPort(11) == PING_REPLY[:4]  # at once, not in a minute


def test_write_port_writes_every_byte_when_the_os_takes_a_part_at_a_time():
    import threading

    packet = bytes(range(256)) * 1024  # 256 KiB: more than a pty buffers
    with pty_port() as (port, master):
        got = bytearray()

        def drain() -> None:
            while len(got) < len(packet):
                got.extend(os.read(master, 65536))

        reader = threading.Thread(target=drain, daemon=True)
        reader.start()
        assert port.writePort(packet) == len(packet)
        reader.join(timeout=30)
        assert bytes(got) == packet


def test_write_port_takes_the_sdks_lists_and_prebuilt_frames():
    with pty_port() as (port, master):
        assert port.writePort([0xFF, 0xFF, 0xFD]) == 3
        assert port.writePort(bytearray(b"\x00\x01")) == 2
        assert read_from(master, 5) == b"\xff\xff\xfd\x00\x01"


def test_a_closed_port_raises_and_frees_it():
    with pty_port() as (port, _master):
        port.ser.close()
        port.is_using = True
        with pytest.raises(serial.SerialException):
            port.readPort(11)
        assert port.is_using is False
        port.is_using = True
        with pytest.raises(serial.SerialException):
            port.writePort(b"\xff")
        assert port.is_using is False


def test_a_blocking_descriptor_is_left_to_pyserial():
    """Reading the descriptor directly relies on it being non-blocking (pyserial opens it
    so); a descriptor that blocks is found at open and read by pyserial, which selects
    before it reads (a direct read would block past the deadline)."""
    import fcntl

    import drivers.dynamixel.port as port_mod

    with pty_port() as (port, _master):
        assert port._direct and port_mod._non_blocking(port.ser)
        fd = port.ser.fd
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
        assert not port_mod._non_blocking(port.ser)
        port._direct = port_mod._non_blocking(port.ser)  # as setupPort decides it
        calls = spy_reads(port)
        port.setPacketTimeoutMillis(0.3)
        _packet, result = sdk.PacketHandler(2.0).rxPacket(port, False)
        assert result == sdk.COMM_RX_TIMEOUT and calls == []  # pyserial's read, not ours
