"""A dynamixel-sdk ``PortHandler`` that opens any pyserial URL and runs on an injected clock.

The SDK's own ``PortHandler`` hard-codes ``serial.Serial(port=...)`` and measures packet
timeouts with ``time.time()``. This subclass changes exactly that and nothing of the
packet code:

* the port is opened with :func:`serial.serial_for_url`, so ``/dev/ttyUSB0``, a pty
  path and ``dxlsim://...`` (the emulated bus) all work;
* "now" comes from a :class:`~drivers.clock.Clock`. A ``dxlsim://`` port brings its bus's
  clock; hardware uses the monotonic clock. On a virtual clock the SDK's busy-poll for a
  status packet becomes one blocking read up to the packet deadline (a jump), so the
  SDK's own timeouts still fire and nothing sleeps;
* the latency-timer term of the SDK's packet timeout is a per-port attribute instead of
  the module global ``port_handler.LATENCY_TIMER``;
* a ``SerialException`` (adapter unplugged) releases the port before it propagates, so
  the SDK's ``is_using`` flag is not left stuck at True.
"""

from __future__ import annotations

import dynamixel_sdk
import serial

from drivers.clock import Clock, MonotonicClock

#: The SDK's default latency-timer allowance (ms), matching an untuned FTDI adapter.
SDK_LATENCY_TIMER_MS = 16.0


class PortHandler(dynamixel_sdk.PortHandler):
    """``dynamixel_sdk.PortHandler`` for any pyserial URL, on an injected clock.

    Parameters
    ----------
    port_name:
        Device path, pty path or ``dxlsim://...`` URL.
    clock:
        Time source. Default: the port's own clock if it has one (``dxlsim://``), else
        the host's monotonic clock. Giving a clock that differs from a ``dxlsim://``
        bus's clock is an error (two clocks would disagree about every timeout).
    latency_timer_ms:
        The adapter latency allowance in the SDK's packet timeout
        ``tx_time·len + 2·latency + 2 ms``. Lower it after lowering the adapter's timer.
    """

    def __init__(
        self,
        port_name: str,
        *,
        clock: Clock | None = None,
        latency_timer_ms: float = SDK_LATENCY_TIMER_MS,
    ) -> None:
        super().__init__(port_name)
        if latency_timer_ms < 0:
            raise ValueError(f"latency_timer_ms must be >= 0, got {latency_timer_ms}")
        self._clock = clock
        self.latency_timer_ms = float(latency_timer_ms)

    @property
    def clock(self) -> Clock:
        if self._clock is None:
            self._clock = MonotonicClock()
        return self._clock

    # -- the two SDK methods that touch the OS ------------------------------------
    def setupPort(self, cflag_baud):
        if self.is_open:
            self.closePort()
        if self.port_name.lower().startswith("dxlsim://"):
            import drivers.dxlsim  # noqa: F401  (registers dxlsim:// with pyserial, on demand)
        self.ser = serial.serial_for_url(
            self.port_name, baudrate=self.baudrate, bytesize=serial.EIGHTBITS, timeout=0
        )
        port_clock = getattr(self.ser, "clock", None)
        if port_clock is not None:
            if self._clock is not None and self._clock is not port_clock:
                self.ser.close()
                raise ValueError(
                    f"{self.port_name} runs on its own clock; do not pass a different one"
                )
            self._clock = port_clock
        elif self._clock is not None and self._clock.virtual:
            self.ser.close()
            raise ValueError(f"a virtual clock cannot drive a real port ({self.port_name})")
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True

    def getCurrentTime(self) -> float:
        return self.clock.now() * 1000.0  # the SDK works in ms

    def setPacketTimeout(self, packet_length) -> None:
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = (
            self.tx_time_per_byte * packet_length + self.latency_timer_ms * 2.0 + 2.0
        )

    def readPort(self, length):
        if self.clock.virtual:
            # Nobody else moves a virtual clock: wait on the port until the bytes are
            # readable or just past the SDK's deadline, whichever is first.
            remaining_ms = self.packet_start_time + self.packet_timeout - self.getCurrentTime()
            self.ser.timeout = max(remaining_ms, 0.0) * 1e-3 + 1e-6
        try:
            return self.ser.read(length)
        except serial.SerialException:
            self.is_using = False
            raise

    def writePort(self, packet):
        try:
            return self.ser.write(bytes(packet))
        except serial.SerialException:
            self.is_using = False
            raise

    def clearPort(self) -> None:
        try:
            self.ser.reset_input_buffer()
        except serial.SerialException:
            self.is_using = False
            raise
