"""Serve an emulated bus on a pseudo-terminal, for programs that only know device paths.

The bus runs on the host's monotonic clock. Bytes the client writes go on the emulated wire
as they arrive. Replies reach the pty as a USB adapter delivers them: in pieces of
back-to-back bytes, each written when its last byte is readable. A piece is at most
:data:`~drivers.protocol2.wire_time.USB_CHUNK` bytes (62, an FTDI packet). So a whole Fast
Sync Read reply arrives in one write, when its last byte would have.

Timing is only as good as the OS's wake-up (``select``): typically 0.1-1 ms late, tens of
ms on a busy host. Use ``dxlsim://`` in-process for timing work, this for compatibility.

The line rate is the client's. Before each burst of client bytes, the bus takes the pty's
speed as the host's rate (``tcgetattr``, or Linux's ``TCGETS2`` for custom rates). Servos at
another baud hear noise and never answer, as on a real bus. The pty starts at the bus's
rate, so a client that never sets one is heard.

More (modem lines, the FTDI latency timer, the jitter): ``docs/dxlsim.md`` (the
pseudo-terminal).
"""

from __future__ import annotations

import array
import contextlib
import fcntl
import os
import re
import select
import sys
import termios
import threading
import tty
from typing import Self

from drivers.clock import precise_timers
from drivers.dxlsim.url import AnyBus
from drivers.protocol2.wire_time import USB_CHUNK

#: Longest the server sleeps with nothing due, so a stop request is seen promptly.
_IDLE_S = 0.05
#: a wake-up later than asked by more than this means this process was not running (s)
_LATE_WAKE_S = 0.005
#: Reply bytes whose stop bits are at most this many byte times apart are one piece (a byte
#: follows the previous one after exactly one byte time; a servo's Return Delay Time and
#: turnaround, 20 µs and more, separate two status packets).
_PIECE_GAP_BYTES = 1.5
#: termios speed code -> bit/s (``B0``, hang-up, is not a rate).
_SPEEDS = {
    getattr(termios, name): int(name[1:])
    for name in dir(termios)
    if re.fullmatch(r"B[1-9][0-9]*", name)
}
_CODES = {bps: code for code, bps in _SPEEDS.items()}


#: Linux ``TCGETS2`` = ``_IOR('T', 0x2A, struct termios2)`` (44 bytes) on x86, arm, riscv;
#: pyserial sets custom rates with its ``TCSETS2`` twin.
_TCGETS2 = 0x802C542A if sys.platform.startswith("linux") else None
#: ``struct termios2`` as 32-bit words: iflag, oflag, cflag, lflag, line + cc[19], ispeed,
#: ospeed -> ``c_ospeed`` is word 10 (pyserial's own index).
_OSPEED_WORD = 10


def line_speed(fd: int) -> int | None:
    """The speed (bit/s) a terminal is set to, or None if it cannot be read."""
    try:
        code = termios.tcgetattr(fd)[5]
    except termios.error:
        return None
    speed = _SPEEDS.get(code)
    if speed is not None or _TCGETS2 is None:
        return speed
    buf = array.array("i", [0] * 64)  # larger than struct termios2, as pyserial's
    try:
        fcntl.ioctl(fd, _TCGETS2, buf)
    except OSError:
        return None
    return buf[_OSPEED_WORD] or None


def piece_due(bus: AnyBus) -> tuple[float | None, int]:
    """When the next piece of reply bytes is due, and its length: ``(None, 0)`` when no
    byte is on its way. The piece starts at the first unread byte and runs while each next
    byte's stop bit follows the previous one's within :data:`_PIECE_GAP_BYTES` byte times
    (as far as the bus has scheduled them), up to :data:`USB_CHUNK` bytes; it is due when
    its last byte is readable."""
    visible_at = bus.visible_at
    first = visible_at(1)
    if first is None:
        return None, 0
    gap = _PIECE_GAP_BYTES * bus.byte_time
    last, n = first, 1
    end = min(bus.pending_rx, USB_CHUNK)
    while n < end:
        t = visible_at(n + 1)
        if t is None or t - last > gap:  # (not None: n + 1 <= pending_rx)
            break
        last, n = t, n + 1
    return last, n


class PtyServer:
    """Owns a pty pair; :attr:`path` is the device a client opens."""

    def __init__(self, bus: AnyBus) -> None:
        if bus.clock.virtual:
            raise ValueError("a pty is served in real time: build the bus on a MonotonicClock")
        self.bus = bus
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line discipline: bytes pass untouched
        code = _CODES.get(bus.baud)
        if code is not None:  # until the client sets its own, the line runs at the bus's
            attrs = termios.tcgetattr(self._slave)
            attrs[4] = attrs[5] = code
            termios.tcsetattr(self._slave, termios.TCSANOW, attrs)
        self.path = os.ttyname(self._slave)
        self._stop = threading.Event()

    def stop(self) -> None:
        self._stop.set()

    def close(self) -> None:
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def serve_forever(self) -> None:
        """Serve until :meth:`stop`; this thread's timer slack is 1 ns meanwhile (Linux), so
        each piece is written when it is due, not up to 50 µs later."""
        with precise_timers():
            self._serve()

    def _serve(self) -> None:
        bus, clock, master = self.bus, self.bus.clock, self._master
        while not self._stop.is_set():
            due = piece_due(bus)[0]
            t_wait = clock.now()
            wait = _IDLE_S if due is None else min(_IDLE_S, max(0.0, due - t_wait))
            readable, _, _ = select.select([master], [], [], wait)
            t_woke = clock.now()
            # This process may itself be descheduled (a busy host): bytes that came while it
            # was not running reached real servos on time. When it woke late, take them as
            # arrived when it began to wait, so its own stall never trips a servo's watchdog
            # or delays a reply (a real host silence finds no bytes waiting, and still trips).
            arrived = t_wait if t_woke - t_wait > wait + _LATE_WAKE_S else None
            if readable:
                try:
                    data = os.read(master, 4096)
                except OSError:  # client side closed: keep serving the next one
                    data = b""
                if data:
                    speed = line_speed(self._slave)
                    if speed is not None:
                        bus.baud = speed  # the host's rate: the client's setting
                    bus.write(data, arrived)
            n = bus.in_waiting()
            if n and n >= piece_due(bus)[1]:  # the piece is readable to its last byte
                os.write(master, bus.read(n))

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
