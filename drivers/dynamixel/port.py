"""A dynamixel-sdk ``PortHandler`` that opens any pyserial URL and runs on an injected clock.

The SDK's own ``PortHandler`` hard-codes ``serial.Serial(port=...)`` and measures packet
timeouts with ``time.time()``. This subclass changes exactly that and nothing of the
packet code:

* the port is opened with :func:`serial.serial_for_url` (a device, a pty, ``dxlsim://``);
  re-opening a ``dxlsim://`` port keeps its bus and clock;
* "now" comes from a :class:`~drivers.clock.Clock`: the bus's for ``dxlsim://``, else monotonic;
* :meth:`readPort` waits in the OS (or on the virtual clock) for the bytes the SDK asked for,
  up to the packet deadline, instead of the SDK's busy-poll;
* :meth:`isPacketTimeout` is True only for a poll that began after the deadline, so a
  descheduled process never calls a servo silent whose reply is in the buffer;
* :attr:`host_stall_s` / :attr:`host_stalls` measure, as a lower bound, the time the process
  was not running within transactions;
* the packet timeout's device allowance is per port (:attr:`latency_timer_ms`,
  :attr:`device_allowance_ms`), not the SDK's module global;
* :meth:`hold_until_quiet` discards the rest of a failed reply chain; a ``SerialException``
  releases the port before it propagates.

Each of these, and why: ``docs/port.md``.
"""

from __future__ import annotations

import os
import select
import time

import dynamixel_sdk
import serial

try:
    import fcntl

    _HAVE_FCNTL = True
except ImportError:  # not POSIX: pyserial's own read and write
    _HAVE_FCNTL = False

from drivers.clock import Clock, MonotonicClock

#: The SDK's default latency-timer allowance (ms), matching an untuned FTDI adapter.
SDK_LATENCY_TIMER_MS = 16.0
#: A gap between two polls of one transaction, or a call returning later than it may
#: wait (a write or a polling read: at once; a blocking read: at its deadline), by more
#: than this (s) is a host stall. One poll (a read plus the SDK's bookkeeping) takes
#: 2-20 us in CPython; interrupts, a context switch or ``select``'s timer slack (50 us)
#: cost tens of us; a whole millisecond (a quarter of a 250 Hz tick, a fifth of its read
#: timeout) is the process not running: descheduled by a busy neighbour, a GC pause,
#: SIGSTOP.
HOST_STALL_THRESHOLD_S = 1e-3
#: The package whose ``protocol_dxlsim`` module serves ``dxlsim://`` URLs (the emulator).
#: Named, never imported here: pyserial imports it when such a URL is opened.
URL_HANDLER_PACKAGE = "drivers.dxlsim"
#: The SDK's own port handler (``timeout=0``, ``rxPacket`` busy-polls it): the reference
#: :mod:`hilsim.bench.cpu` measures this one against.
SdkPortHandler = dynamixel_sdk.PortHandler
#: pyserial's POSIX port: read and written through its descriptor (:meth:`PortHandler._read_fd`,
#: :func:`_write_fd`) with pyserial's semantics and without its per-call costs (its ``timeout``
#: setter alone re-applies the termios settings, ~7 µs).
_POSIX_SERIAL = getattr(getattr(serial, "serialposix", None), "Serial", None)
#: packets written as they are (the tick's prebuilt frames); anything else (the SDK's lists)
#: becomes ``bytes`` first
_BUFFERS = (bytes, bytearray, memoryview)
_monotonic = time.monotonic
_select = select.select


def _non_blocking(ser: serial.SerialBase) -> bool:
    """Whether ``ser`` is pyserial's POSIX port on a non-blocking descriptor."""
    if not _HAVE_FCNTL or type(ser) is not _POSIX_SERIAL:
        return False
    try:
        return bool(fcntl.fcntl(ser.fd, fcntl.F_GETFL) & os.O_NONBLOCK)
    except (OSError, TypeError, ValueError):
        return False


def _write_fd(ser: serial.Serial, data: bytes | bytearray | memoryview) -> int:
    """pyserial's POSIX ``write(data)`` with no write timeout: every byte, waiting (``select``)
    only when the OS takes part of it, without its ``select`` after every write (~3 µs).
    Returns the bytes written: all of them, or fewer if ``cancel_write`` aborted the wait."""
    if not ser.is_open:
        raise serial.PortNotOpenError()
    fd, total, done = ser.fd, len(data), 0
    view = None
    while done < total:
        try:
            done += os.write(fd, data if view is None else view[done:])
        except (BlockingIOError, InterruptedError):
            pass
        except OSError as exc:
            raise serial.SerialException(f"write failed: {exc}") from None
        if done < total:
            if view is None:
                view = memoryview(data)
            abort, _, _ = _select((ser.pipe_abort_write_r,), (fd,), (), None)
            if abort:
                os.read(ser.pipe_abort_write_r, 1)
                break
    return done


def register_url_handlers() -> None:
    """Let :func:`serial.serial_for_url` open ``dxlsim://`` URLs (idempotent).

    pyserial looks a URL's ``<scheme>`` up as ``<package>.protocol_<scheme>`` in each of
    ``serial.protocol_handler_packages`` and imports it on demand, so the driver only names
    :data:`URL_HANDLER_PACKAGE` and never imports the emulator itself.
    """
    if URL_HANDLER_PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(URL_HANDLER_PACKAGE)


class PortHandler(dynamixel_sdk.PortHandler):  # type: ignore[misc]  # the SDK has no types
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
        The adapter's latency: it holds received bytes up to this long. Enters the SDK's
        packet timeout ``tx_time·len + 2·latency + 2 ms`` and any bus-capacity estimate.
        Lower it after lowering the adapter's timer.
    device_allowance_ms:
        The least total the timeout allows for the device's own delays (``2·latency``
        raised to this): 0 for a known USB adapter or the in-process emulator, more for a
        device whose delays are not its latency timer (a pty served by another process,
        an unknown adapter). See :func:`drivers.dynamixel.link.device_allowance_ms`.

    Attributes
    ----------
    host_stall_s:
        Cumulative seconds the host was not running during transactions, from a
        transaction's transmit to its last poll: the gaps between this port's calls, and
        the time a call took beyond what it may wait (a write, a polling read: nothing; a
        blocking read: until its deadline), each where longer than
        :data:`HOST_STALL_THRESHOLD_S`. A lower bound (``docs/port.md``). A
        counter: difference it around a transaction. 0 on a virtual clock.
    host_stalls:
        How many such gaps :attr:`host_stall_s` adds up.
    device_wait_s:
        Cumulative seconds spent in transactions (transmit to last poll): waiting on the
        device, the SDK's code between polls, and the host stalls in them (which
        :attr:`host_stall_s` reports). A caller that takes this from its wall time is left
        with its own work, where a stall outside the port shows.
    """

    # the SDK's attributes this class uses (the SDK declares none): ``ser`` is None until
    # the port is first opened, and nothing here runs before that
    ser: serial.SerialBase
    is_open: bool
    is_using: bool
    port_name: str
    baudrate: int
    tx_time_per_byte: float
    packet_start_time: float
    packet_timeout: float

    def __init__(
        self,
        port_name: str,
        *,
        clock: Clock | None = None,
        latency_timer_ms: float = SDK_LATENCY_TIMER_MS,
        device_allowance_ms: float = 0.0,
    ) -> None:
        super().__init__(port_name)
        if latency_timer_ms < 0:
            raise ValueError(f"latency_timer_ms must be >= 0, got {latency_timer_ms}")
        if device_allowance_ms < 0:
            raise ValueError(f"device_allowance_ms must be >= 0, got {device_allowance_ms}")
        self._clock = clock
        self.latency_timer_ms = float(latency_timer_ms)
        self.device_allowance_ms = float(device_allowance_ms)
        self.host_stall_s = 0.0
        self.host_stalls = 0
        self.device_wait_s = 0.0
        self._poll_ms: float | None = None  # when the last poll of this transaction began
        self._mark_s: float | None = None  # stall measurement: the previous poll (s)
        self._quiet_at: float | None = None  # replies may still arrive until then (s)
        # how readPort waits for bytes (setupPort): "poll" (timeout 0, the SDK's way: before
        # setupPort), "virtual" (the emulator's read jumps its clock), "clock" (the emulator
        # in this process on the real clock: its read sleeps until the bytes are due, as the
        # clock waits for a tick), "select" (a real port: the OS waits)
        self._wait = "poll"
        # the device's descriptor is non-blocking (pyserial's POSIX port keeps it so): only
        # then is it read and written directly (_read_fd, _write_fd)
        self._direct = False

    @property
    def clock(self) -> Clock:
        if self._clock is None:
            self._clock = MonotonicClock()
        return self._clock

    @property
    def timeout_margin_ms(self) -> float:
        """What the packet timeouts add on top of ``2·latency_timer_ms`` (ms): enough to
        reach :attr:`device_allowance_ms`, never negative."""
        return max(0.0, self.device_allowance_ms - 2.0 * self.latency_timer_ms)

    # -- the two SDK methods that touch the OS ------------------------------------
    def setupPort(self, cflag_baud: int) -> bool:
        old = self.ser
        if old is not None and getattr(old, "bus", None) is not None and old.port == self.port_name:
            # A dxlsim:// port: re-opened (the SDK's setBaudRate, closePort/openPort) it is
            # the same adapter on the same powered bus, so the serial object is re-used and
            # keeps its bus; a new baud changes the host's rate only (drivers.dxlsim.url).
            old.baudrate = self.baudrate
            if not old.is_open:
                old.open()
            self.ser = old
        else:
            if self.is_open:
                self.closePort()
            if self.port_name.lower().startswith("dxlsim://"):
                register_url_handlers()
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
        if port_clock is None:
            self._wait = "select"
            self._direct = _non_blocking(self.ser)
            self.clock  # noqa: B018 - the monotonic clock, made now: the hot paths use _clock
        else:
            self._wait = "virtual" if port_clock.virtual else "clock"
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True

    def getCurrentTime(self) -> float:
        return self.clock.now() * 1000.0  # the SDK works in ms

    def setPacketTimeout(self, packet_length: int) -> None:
        self._start()
        self.packet_timeout = (
            self.tx_time_per_byte * packet_length
            + self.latency_timer_ms * 2.0
            + 2.0
            + self.timeout_margin_ms
        )

    def setPacketTimeoutMillis(self, msec: float) -> None:
        """Exactly ``msec`` (the SDK's meaning; callers add any device allowance)."""
        self._start()
        self.packet_timeout = msec

    def _start(self) -> None:
        clock = self.clock
        now = clock.now()
        self._watch(now, now)
        self.packet_start_time = now * 1000.0
        self._poll_ms = None

    # -- the host-stall watch. Within a transaction (from its transmit to its last poll)
    # time goes to waiting on the device: quick polls, or reads that block until their
    # bytes or their deadline. A gap between this port's calls, or a call that returned
    # later than it was allowed to wait (``may_wait``: 0 for a write or a polling read, the
    # timeout of a blocking one), by more than HOST_STALL_THRESHOLD_S is the process not
    # running (host_stall_s). All of it is device_wait_s: the caller's own work is what
    # lies outside.
    def _watch(self, entry: float, now: float, may_wait: float = 0.0) -> None:
        mark = self._mark_s
        if mark is None:
            return
        stall = 0.0
        if not (self._clock or self.clock).virtual:
            if entry - mark > HOST_STALL_THRESHOLD_S:
                stall += entry - mark
            late = now - entry - may_wait
            if late > HOST_STALL_THRESHOLD_S:
                stall += late
            if stall:
                self.host_stall_s += stall
                self.host_stalls += 1
        self.device_wait_s += now - mark  # stalls included: host_stall_s reports them
        self._mark_s = now

    def isPacketTimeout(self) -> bool:
        """True only if the last poll began after the deadline (then the SDK gives up, as
        its own version does, with ``packet_timeout`` set to 0). A poll that began before
        the deadline may have missed bytes that arrived while the host was not running:
        the SDK then polls once more."""
        poll = self._poll_ms
        if poll is not None and poll >= self.packet_start_time + self.packet_timeout:
            self.packet_timeout = 0
            return True
        return False

    def readPort(self, length: int) -> bytes:
        """Up to ``length`` bytes: all of them as soon as they are readable, or what is
        there at the packet deadline (at once for a poll that begins after it, or while
        no transaction is timed). Nothing spins for the wire: a device is waited on in the
        OS, an emulated bus on its clock."""
        clock = self._clock or self.clock  # the property only before the port is opened
        now = clock.now()
        now_ms = now * 1000.0
        self._poll_ms = now_ms
        mode, ser = self._wait, self.ser
        timeout: float = 0
        if mode != "poll":
            # Wait on the port until the bytes are readable or just past the SDK's
            # deadline, whichever is first (on a virtual clock the wait is a jump: nobody
            # else moves it). A poll that begins at or after the deadline takes what is
            # readable and never waits.
            remaining_ms = self.packet_start_time + self.packet_timeout - now_ms
            if remaining_ms > 0.0:
                timeout = remaining_ms * 1e-3 + 1e-6
        try:
            if mode == "select":
                if self._direct and type(ser) is _POSIX_SERIAL:
                    return self._read_fd(ser, length, timeout)
                ser.timeout = timeout
            elif mode != "poll":
                ser.timeout = timeout
            data: bytes = ser.read(length)  # pyserial ships no types
            return data
        except serial.SerialException:
            self.is_using = False
            raise
        finally:
            self._watch(now, clock.now(), timeout)  # (a virtual clock's: not watched)

    def _read_fd(self, ser: serial.Serial, length: int, timeout: float) -> bytes:
        """pyserial's POSIX ``read(length)`` with ``timeout`` (s), without its per-call
        objects (a ``Timeout``, a ``bytearray`` and its copy: ~10 µs a call): read what is
        there first (the rest of a packet whose first bytes woke the last read usually is),
        then ``select`` on the device and pyserial's ``cancel_read`` pipe until ``length``
        bytes or the timeout. The descriptor stays non-blocking, as pyserial keeps it."""
        if not ser.is_open:
            raise serial.PortNotOpenError()
        fd = ser.fd
        try:
            data = os.read(fd, length)
        except BlockingIOError:
            data = b""
        except OSError as exc:
            raise serial.SerialException(f"read failed: {exc}") from None
        n = len(data)
        if n >= length or timeout <= 0.0:
            return data
        abort = ser.pipe_abort_read_r
        watched = (fd, abort)
        deadline = _monotonic() + timeout
        wait = timeout
        while True:
            try:
                ready = _select(watched, (), (), wait)[0]
                if not ready:
                    return data  # the deadline: what is there
                if abort in ready:
                    os.read(abort, 1000)  # cancel_read(): return what is there
                    return data
                more = os.read(fd, length - n)
            except BlockingIOError:
                more = None  # readable but nothing there after all: wait again
            except InterruptedError:
                more = None
            except OSError as exc:
                raise serial.SerialException(f"read failed: {exc}") from None
            if more is not None:
                if not more:  # what pyserial says of a vanished device
                    raise serial.SerialException(
                        "device reports readiness to read but returned no data "
                        "(device disconnected or multiple access on port?)"
                    )
                data = more if not n else data + more
                n = len(data)
                if n >= length:
                    return data
            wait = deadline - _monotonic()
            if wait <= 0.0:
                return data

    def writePort(self, packet: bytes | bytearray | memoryview | list[int]) -> int:
        clock = self._clock or self.clock  # the property only before the port is opened
        entry = clock.now()
        ser = self.ser
        data = packet if isinstance(packet, _BUFFERS) else bytes(packet)  # the SDK gives a list
        try:
            if self._direct and type(ser) is _POSIX_SERIAL and ser._write_timeout is None:
                return _write_fd(ser, data)
            written: int = ser.write(data)  # pyserial ships no types
            return written
        except serial.SerialException:
            self.is_using = False
            raise
        finally:
            self._watch(entry, clock.now())

    def hold_until_quiet(self, t: float) -> None:
        """Replies may still be on the wire until ``t`` (clock seconds), e.g. the rest of
        a Sync Read chain after a read timed out: the next :meth:`clearPort` (every
        transmit calls it) first waits until then, so those bytes are discarded instead
        of read as the next transaction's reply."""
        if self._quiet_at is None or t > self._quiet_at:
            self._quiet_at = t

    def clearPort(self) -> None:
        quiet, self._quiet_at = self._quiet_at, None
        clock = self._clock or self.clock
        start = clock.now()
        try:
            if quiet is not None:
                clock.wait_until(quiet)  # waiting out a failed chain: device time
            self.ser.reset_input_buffer()
        except serial.SerialException:
            self.is_using = False
            raise
        # every transmit begins here: the watch starts afresh (time before a transaction
        # is the caller's to account for)
        self._mark_s = mark = clock.now()
        self.device_wait_s += mark - start
