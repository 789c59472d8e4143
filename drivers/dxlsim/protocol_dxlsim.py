"""pyserial URL handler for ``dxlsim://``: an emulated Dynamixel bus behind a serial port.

pyserial finds this module as ``<package>.protocol_dxlsim`` once ``drivers.dxlsim`` is in
``serial.protocol_handler_packages`` (importing :mod:`drivers.dxlsim` puts it there).

Reads follow pyserial's timeout rules against the bus's clock: ``timeout=0`` returns
what is readable now; ``timeout=T`` waits until ``size`` bytes are readable or ``T``
has passed. On a virtual clock that wait is a jump, so nothing ever sleeps. Once the
bus's fault plan unplugs the adapter every call raises :class:`serial.SerialException`,
as a real USB adapter that vanished does.

Opening a ``dxlsim://?...`` URL connects to the bus other ports have open under the same
normal form, or powers one up; closing lets go of it, and re-opening the same port object
keeps its bus (the rule: :mod:`drivers.dxlsim.url`). Changing ``baudrate`` changes the host's
rate only: servos at another rate hear noise and never answer.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from drivers.dxlsim.url import acquire_bus, release_bus

if TYPE_CHECKING:
    from collections.abc import Iterable

    from drivers.clock import Clock
    from drivers.dxlsim.url import AnyBus


class Serial(SerialBase):  # type: ignore[misc]  # pyserial ships no types
    """A serial port whose other end is an emulated bus (:data:`~drivers.dxlsim.url.AnyBus`)."""

    bus: AnyBus | None = None
    _bus_key = ""
    _bus_url: str | None = None
    # pyserial's attributes this class uses (pyserial declares none)
    is_open: bool
    _port: str | None
    _baudrate: int
    _timeout: float | None

    def open(self) -> None:
        url = self._port  # pyserial's port setter sets portstr to the same
        if url is None:
            raise SerialException("Port must be configured before it can be used.")
        if self.is_open:
            raise SerialException("Port is already open.")
        try:
            keep = self.bus if self._bus_url == url else None
            self.bus, self._bus_key = acquire_bus(url, host_baud=self._baudrate, keep=keep)
            self._bus_url = url
        except ValueError as exc:
            raise SerialException(str(exc)) from exc
        self.is_open = True
        self._reconfigure_port()
        self.reset_input_buffer()

    @property
    def clock(self) -> Clock:
        """The bus's clock: a PortHandler on this port must use it."""
        bus = self.bus
        if bus is None:  # never opened: no clock (``getattr(port, "clock", None)`` is None)
            raise AttributeError("clock")
        return bus.clock

    def _reconfigure_port(self) -> None:
        if self.bus is not None:
            self.bus.baud = int(self._baudrate)  # the host's line rate; servos keep theirs

    def close(self) -> None:
        if self.is_open and self.bus is not None:
            release_bus(self._bus_key, self.bus)  # the bus stays with this object for a re-open
        self.is_open = False

    def from_url(self, url: str) -> str:  # pyserial calls this with the whole URL
        return url

    def _check(self) -> AnyBus:
        """The bus, while the port is open and the adapter plugged in."""
        bus = self.bus
        if not self.is_open or bus is None:  # (open sets the bus before is_open)
            raise PortNotOpenError()
        if bus.unplugged():
            self.close()
            raise SerialException(
                "device reports readiness to read but returned no data "
                "(device disconnected or multiple access on port?)"
            )
        return bus

    @property
    def in_waiting(self) -> int:
        return self._check().in_waiting()

    def read(self, size: int = 1) -> bytes:
        bus = self._check()
        if self._timeout is None:
            due = bus.visible_at(size)
            if due is None:
                raise SerialException(
                    f"read({size}) with timeout=None would block forever: "
                    f"only {bus.pending_rx} byte(s) are on their way"
                )
            bus.clock.wait_until(due)
        elif self._timeout > 0:
            clock = bus.clock
            deadline = clock.now() + self._timeout
            due = bus.visible_at(size)
            clock.wait_until(deadline if due is None or due > deadline else due)
            self._check()
        return bus.read(size)

    def write(self, data: bytes | bytearray | memoryview | Iterable[int]) -> int:
        bus = self._check()
        data = bytes(data)
        bus.write(data)
        return len(data)

    def reset_input_buffer(self) -> None:
        self._check().reset_input()

    def reset_output_buffer(self) -> None:
        self._check()  # bytes written are already on the wire

    @property
    def out_waiting(self) -> int:
        return 0

    def flush(self) -> None:
        bus = self._check()
        bus.clock.wait_until(bus._tx_free)

    # modem lines: accepted and ignored (the bus has none)
    def _update_break_state(self) -> None: ...
    def _update_rts_state(self) -> None: ...
    def _update_dtr_state(self) -> None: ...

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True
