"""One open port, over dynamixel-sdk: snake_case unicast and broadcast transactions.

:class:`Link` - ping, read, write, reboot, broadcast ping - returns values or raises;
used by :class:`~drivers.dynamixel.bus.DynamixelBus` (start-up check, torque, watchdog,
exit policy) and :func:`drivers.dynamixel.scan.scan`. Result codes become exceptions in
:func:`drivers.dynamixel.sdk_result.raise_for`; :func:`tune_latency_timer`
lowers a Linux USB adapter's latency timer when the port opens, and
:func:`device_allowance_ms` says how much more a packet timeout must allow for a device
that is not such an adapter (a pty served by another process, an unknown device).

SDK traps avoided: unicast ``action()`` does not wait for the servo's status packet (the
next request would receive it), so Reg Write/Action is not used; a SerialException inside
the SDK leaves ``port.is_using`` stuck (our :class:`~drivers.dynamixel.port.PortHandler`
frees it, and :meth:`Link.recover` frees it after an interrupted call, e.g. Ctrl-C).
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import dynamixel_sdk as sdk
import serial

from drivers.clock import Clock
from drivers.dynamixel.errors import CorruptPacket, PortGone
from drivers.dynamixel.port import SDK_LATENCY_TIMER_MS, PortHandler
from drivers.dynamixel.read_order import LATE_BLOCK_S as LATE_REPLY_S
from drivers.dynamixel.sdk_result import CORRUPT, OK, SERIAL_ERRORS, TIMEOUT, port_gone, raise_for
from drivers.dynamixel.tick_packets import read_request, read_transaction
from drivers.protocol2 import control_table as ct
from drivers.protocol2.control_table import Item, check_unicast_id
from drivers.protocol2.wire_time import PTY_LATENCY_MS

# A pty's adapter latency is wire_time.PTY_LATENCY_MS; the scheduling tail under load is
# UNCHARACTERISED_DEVICE_ALLOWANCE_MS's business.
#: The least device allowance in the packet timeout (``2·latency`` is raised to this, ms)
#: for a device that is not a known USB adapter: a pty served by a process that may be
#: descheduled under CPU load, a CDC-ACM board, any other device. It is the SDK's stock
#: allowance (2 x 16 ms): a busy host delays a pty's replies by tens of ms, and a smaller
#: allowance lost pings under load (docs/performance.md). It costs time only when a servo is
#: really silent.
UNCHARACTERISED_DEVICE_ALLOWANCE_MS = 2.0 * SDK_LATENCY_TIMER_MS

T = TypeVar("T")

#: Sysfs directory of Linux usb-serial devices (FTDI adapters such as the U2D2).
SYSFS_USB_SERIAL = Path("/sys/bus/usb-serial/devices")


def latency_timer_path(device: str, sysfs: Path = SYSFS_USB_SERIAL) -> Path:
    """The sysfs latency-timer file of the USB-serial adapter behind ``device``
    (``/dev/ttyUSB0`` or a symlink to it): ``<sysfs>/ttyUSB0/latency_timer``. It exists
    only on Linux, for a usb-serial adapter."""
    return sysfs / os.path.basename(os.path.realpath(device)) / "latency_timer"


# ----------------------------------------------------------------------- latency timer
class LatencyTimerWarning(RuntimeWarning):
    """The USB adapter's latency timer is high: every read waits for it."""


def _latency_fix(dev: str, ms: int) -> str:
    return (
        f"{dev}: USB latency timer is {ms} ms, so every read waits >= {ms} ms. Lower it:\n"
        f"  echo 1 | sudo tee {SYSFS_USB_SERIAL / dev / 'latency_timer'}\n"
        "or for good, a udev rule (/etc/udev/rules.d/99-dynamixel.rules):\n"
        '  ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", '
        'ATTR{latency_timer}="1"'
    )


def tune_latency_timer(
    ser: serial.SerialBase, device: str, sysfs: Path = SYSFS_USB_SERIAL
) -> float:
    """Lower a Linux USB-serial adapter's latency timer to 1 ms where allowed; return the
    value in force (ms), which the SDK's packet timeout must allow for.

    Tries pyserial's ``set_low_latency_mode(True)`` and writing 1 to
    ``<sysfs>/<ttyUSBn>/latency_timer``; warns (:class:`LatencyTimerWarning`) with the exact
    fix when it stays above 1 ms. A pseudo-terminal returns :data:`PTY_LATENCY_MS`; other
    devices without a latency timer (CDC-ACM, other OSes) the SDK's conservative 16 ms.
    """
    if not sys.platform.startswith("linux") or not device.startswith("/dev/"):
        return SDK_LATENCY_TIMER_MS
    if _is_pty(device):
        return PTY_LATENCY_MS
    dev = os.path.basename(os.path.realpath(device))
    with contextlib.suppress(AttributeError, ValueError, OSError):
        ser.set_low_latency_mode(True)  # ASYNC_LOW_LATENCY: ftdi_sio then uses 1 ms
    path = latency_timer_path(device, sysfs)
    try:
        ms = int(path.read_text().strip())
    except (OSError, ValueError):
        return SDK_LATENCY_TIMER_MS
    if ms > 1:
        try:
            path.write_text("1")
            ms = int(path.read_text().strip())
        except (OSError, ValueError):
            pass
    if ms > 1:
        warnings.warn(_latency_fix(dev, ms), LatencyTimerWarning, stacklevel=3)
    return float(ms)


def _is_pty(device: str) -> bool:
    """A Unix98 pseudo-terminal slave (``/dev/pts/N``; Linux majors 136-143)."""
    real = os.path.realpath(device)
    if real.startswith("/dev/pts/"):
        return True
    try:
        return 136 <= os.major(os.stat(real).st_rdev) <= 143
    except (OSError, ValueError):
        return False


def device_allowance_ms(
    ser: serial.SerialBase, device: str, sysfs: Path = SYSFS_USB_SERIAL
) -> float:
    """The least device allowance a packet timeout needs on this port (ms; see
    :attr:`~drivers.dynamixel.port.PortHandler.device_allowance_ms`).

    0 where the latency timer says it all: the in-process emulator (``dxlsim://``, whose
    own model is the latency) and a Linux USB-serial adapter with a sysfs latency timer
    (FTDI: U2D2, USB2Dynamixel). :data:`UNCHARACTERISED_DEVICE_ALLOWANCE_MS` for the rest:
    a pty (its replies come from another process, late when that one waits for a CPU) and
    any device we cannot characterise.
    """
    if getattr(ser, "bus", None) is not None and device.lower().startswith("dxlsim://"):
        return 0.0
    if sys.platform.startswith("linux") and device.startswith("/dev/") and not _is_pty(device):
        if latency_timer_path(device, sysfs).exists():
            return 0.0
    return UNCHARACTERISED_DEVICE_ALLOWANCE_MS


# ----------------------------------------------------------------------- link
class Link:
    """One open port and Protocol 2.0: unicast and broadcast transactions, snake_case.

    Every method returns values or raises (:mod:`drivers.dynamixel.errors`): result codes
    through :func:`~drivers.dynamixel.sdk_result.raise_for`, a vanished adapter as
    :class:`PortGone`. Not for the per-tick path
    (:class:`~drivers.dynamixel.bus.DynamixelBus` does that leaner).
    """

    def __init__(self, port: PortHandler) -> None:
        self.port = port
        self.ph = sdk.PacketHandler(2.0)
        # Read requests built once per (ID, address, size): the health reads repeat a few
        # (b"": one the SDK would stuff, left to it)
        self._reads: dict[tuple[int, int, int], bytes] = {}
        #: told ``(servo_id, size)`` of each read that got no reply or a corrupt one, whose
        #: reply may so come late (the bus keeps its plain reads from taking it)
        self.unanswered: Callable[[int, int], None] | None = None

    @classmethod
    def open(
        cls,
        port: str,
        *,
        baud: int,
        clock: Clock | None = None,
        latency_timer_ms: float | None = None,
    ) -> Link:
        """Open ``port`` (device path, pty or ``dxlsim://`` URL) at ``baud`` bit/s.

        ``latency_timer_ms``: the adapter's latency (packet timeouts, capacity checks).
        None: the emulator's own model for ``dxlsim://``; on a Linux USB adapter the timer
        is lowered to 1 ms where permitted (:func:`tune_latency_timer`); 1 ms for a pty;
        else 16 ms. Whatever it is, a device that is not a known USB adapter gets the
        timeout allowance of :func:`device_allowance_ms` (the ``device_allowance_ms``
        of :attr:`port`).
        """
        ph = PortHandler(
            port,
            clock=clock,
            latency_timer_ms=SDK_LATENCY_TIMER_MS if latency_timer_ms is None else latency_timer_ms,
        )
        _check_baud(ph, baud)
        try:
            ph.setBaudRate(baud)
        except SERIAL_ERRORS as exc:
            if isinstance(exc.__cause__, ValueError):  # a dxlsim:// URL it cannot parse
                raise ValueError(str(exc)) from exc
            raise PortGone(f"cannot open {port}: {exc}{port_hint(port, str(exc))}") from exc
        link = cls(ph)
        try:
            ph.device_allowance_ms = device_allowance_ms(ph.ser, port)
            if latency_timer_ms is None:
                emulated = getattr(ph.ser, "bus", None)
                if emulated is not None and hasattr(emulated, "latency_s"):
                    ph.latency_timer_ms = emulated.latency_s * 1e3
                else:
                    ph.latency_timer_ms = tune_latency_timer(ph.ser, port)
        except BaseException:
            link.close()
            raise
        return link

    @property
    def name(self) -> str:
        return self.port.port_name

    @property
    def baud(self) -> int:
        return self.port.baudrate

    @property
    def clock(self) -> Clock:
        return self.port.clock

    @property
    def latency_timer_ms(self) -> float:
        """The adapter's latency (ms): what a bus-capacity estimate counts."""
        return self.port.latency_timer_ms

    @property
    def timeout_margin_ms(self) -> float:
        """What every packet timeout adds on top of ``2·latency_timer_ms`` for this
        device (ms; 0 on a known USB adapter and the in-process emulator)."""
        return self.port.timeout_margin_ms

    def set_baud(self, baud: int) -> None:
        """Change the host's line rate without reopening the port."""
        _check_baud(self.port, baud)
        self._call("set baud rate", setattr, self.port.ser, "baudrate", baud)
        self.port.baudrate = baud
        self.port.tx_time_per_byte = 10_000.0 / baud  # ms per 10-bit byte, as the SDK has it

    def recover(self) -> None:
        """Free the port after an interrupted transaction (e.g. KeyboardInterrupt inside
        the SDK leaves ``is_using`` True and half a reply in the buffer)."""
        if self.port.is_using:
            self.port.is_using = False
            self._call("clear input", self.port.clearPort)

    def close(self) -> None:
        """Close the port; never raises (the device may already be gone)."""
        try:
            if self.port.ser is not None:
                self.port.closePort()
        except Exception:  # a vanished device may raise anything here
            self.port.is_open = False

    def _call(self, what: str, fn: Callable[..., T], *args: object) -> T:
        try:
            return fn(*args)
        except SERIAL_ERRORS as exc:
            raise port_gone(exc, self.name, what) from exc

    def settle(self) -> None:
        """Before retrying a transaction that got no reply or a corrupt one: its reply may
        still come, so the next transaction waits :data:`LATE_REPLY_S` and the adapter's
        latency, and discards what came meanwhile (the retry would otherwise meet the late
        reply, or take it for its own)."""
        wait = LATE_REPLY_S + self.latency_timer_ms * 1e-3
        self.port.hold_until_quiet(self.port.clock.now() + wait)

    # -- transactions --------------------------------------------------------------
    def ping(self, servo_id: int) -> tuple[int, int]:
        """Ping one servo: ``(model number, firmware version)``."""
        check_unicast_id(servo_id)
        tx = [0] * 10
        tx[4], tx[5], tx[6], tx[7] = servo_id, 3, 0, sdk.INST_PING
        rx, result, error = self._call("Ping", self.ph.txRxPacket, self.port, tx)
        raise_for(result, error, servo_id, "Ping", rx)
        if len(rx) < 14:
            raise CorruptPacket(
                f"servo {servo_id}: short Ping reply", servo_id=servo_id, what="Ping"
            )
        return rx[9] | rx[10] << 8, rx[11]

    def broadcast_ping(self) -> dict[int, tuple[int, int]]:
        """Ping every ID at once: ``{id: (model number, firmware)}`` of those that
        answered intact (possibly none)."""
        found, result = self._call("broadcast Ping", self.ph.broadcastPing, self.port)
        if result not in (OK, TIMEOUT, CORRUPT):  # silence and noise are answers here
            raise_for(result, 0, None, "broadcast Ping")
        return {int(i): (int(m), int(fw)) for i, (m, fw) in found.items()}

    def read(self, servo_id: int, addr: int, size: int) -> bytes:
        """Read ``size`` bytes from ``addr``."""
        key = (servo_id, addr, size)
        request = self._reads.get(key)
        if request is None:
            check_unicast_id(servo_id)
            request = self._reads[key] = read_request(servo_id, addr, size) or b""
        what = f"Read {size} B at {addr}"
        if request:  # the SDK's txRxPacket, byte for byte, without its per-byte CRC loops
            rx, result, error = self._call(
                what, read_transaction, self.port, request, servo_id, size
            )
        else:
            tx = [0] * 14
            tx[4], tx[5], tx[6], tx[7] = servo_id, 7, 0, sdk.INST_READ
            tx[8:12] = addr & 0xFF, addr >> 8, size & 0xFF, size >> 8
            rx, result, error = self._call(what, self.ph.txRxPacket, self.port, tx)
        if result in (TIMEOUT, CORRUPT) and self.unanswered is not None:
            self.unanswered(servo_id, size)
        raise_for(result, error, servo_id, what, rx)
        # LEN = INST ERR data CRC(2): a reply of another length (a late one to another
        # request) is not this one's data, whatever its first bytes are
        got = (rx[5] | rx[6] << 8) - 4
        if got != size:
            if self.unanswered is not None:  # (its own reply may still come)
                self.unanswered(servo_id, size)
            raise CorruptPacket(
                f"servo {servo_id}: {got} of {size} bytes in reply to {what}",
                servo_id=servo_id,
                what=what,
            )
        return bytes(rx[9 : 9 + size])

    def read_item(self, servo_id: int, item: Item) -> int:
        return item.decode(self.read(servo_id, item.addr, item.size), item.addr)

    def write(self, servo_id: int, addr: int, data: bytes) -> None:
        """Write ``data`` at ``addr`` and wait for the status packet."""
        check_unicast_id(servo_id)
        what = f"Write {len(data)} B at {addr}"
        result, error = self._call(
            what, self.ph.writeTxRx, self.port, servo_id, addr, len(data), list(data)
        )
        raise_for(result, error, servo_id, what)

    def write_item(self, servo_id: int, item: Item, value: int) -> None:
        self.write(servo_id, item.addr, item.encode(value))

    def reboot(self, servo_id: int) -> None:
        """Reboot one servo (clears a latched hardware error; RAM back to defaults)."""
        check_unicast_id(servo_id)
        result, error = self._call("Reboot", self.ph.reboot, self.port, servo_id)
        raise_for(result, error, servo_id, "Reboot")


def _check_baud(port: PortHandler, baud: int) -> None:
    if port.getCFlagBaud(baud) <= 0:
        raise ValueError(
            f"baud {baud} is not supported; use one of "
            f"{sorted(set(ct.BAUD_RATES.values()) - {4_500_000})}"
        )


def port_hint(port: str, message: str) -> str:
    """What to try when ``port`` could not be opened (empty when nothing is known)."""
    if port.lower().startswith("dxlsim:") and not port.lower().startswith("dxlsim://"):
        return f" (the emulator's URLs begin with dxlsim://, e.g. dxlsim://{port[7:].lstrip('/')})"
    if "://" in port:
        return ""
    if not os.path.exists(port):
        return (
            " (no such device: is the USB adapter plugged in? On Linux it is usually "
            "/dev/ttyUSB0 or /dev/ttyACM0; `ls /dev/serial/by-id/` lists them)"
        )
    if "ermission denied" in message:
        return (
            " (not allowed: add yourself to the group that owns it, e.g. dialout, and log in again)"
        )
    return ""
