"""Serve an emulated bus on a pseudo-terminal, for programs that only know device paths.

The bus runs on the host's monotonic clock: bytes the client writes go on the emulated
wire when they arrive; each reply byte is written to the pty when the bus says it is
readable. Accuracy is bounded by the OS's wake-up latency (``select``), typically
0.1-1 ms late: use ``dxlsim://`` in-process for timing work, this for compatibility.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import tty

from drivers.dxlsim.bus import DxlBus

#: Longest the server sleeps with nothing due, so a stop request is seen promptly.
_IDLE_S = 0.05


class PtyServer:
    """Owns a pty pair; :attr:`path` is the device a client opens."""

    def __init__(self, bus: DxlBus) -> None:
        if bus.clock.virtual:
            raise ValueError("a pty is served in real time: build the bus on a MonotonicClock")
        self.bus = bus
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line discipline: bytes pass untouched
        self.path = os.ttyname(self._slave)
        self._stop = threading.Event()

    def stop(self) -> None:
        self._stop.set()

    def close(self) -> None:
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def serve_forever(self) -> None:
        bus, clock, master = self.bus, self.bus.clock, self._master
        while not self._stop.is_set():
            due = bus.visible_at(1)
            wait = _IDLE_S if due is None else min(_IDLE_S, max(0.0, due - clock.now()))
            readable, _, _ = select.select([master], [], [], wait)
            if readable:
                try:
                    data = os.read(master, 4096)
                except OSError:  # client side closed: keep serving the next one
                    data = b""
                if data:
                    bus.write(data)
            n = bus.in_waiting()
            if n:
                os.write(master, bus.read(n))

    def __enter__(self) -> PtyServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
