"""The Dynamixel backend of :class:`~drivers.servo_bus.ServoBus`, over dynamixel-sdk.

This is the one module that speaks the SDK's camelCase. Two layers:

* :class:`Link` - one open port: snake_case unicast/broadcast transactions (ping, read,
  write, reboot, broadcast ping) that return values or raise; used by start-up checks,
  exit policy and :func:`drivers.dynamixel.scan.scan`.
* :class:`DynamixelBus` - the loop's bus: one Sync Write of Goal Position per tick, one
  Fast Sync Read (or plain Sync Read) of Present Position per tick with a status for
  every servo, start-up :meth:`~DynamixelBus.check`, watchdog, torque and exit policy.

Per-servo status on every read. The SDK's ``GroupSyncRead`` drops each servo's ERR byte
and ``getData`` returns 0 for missing data, and its Fast Sync Read reports one result for
the whole packet, so the bus sends the request with ``syncReadTx`` and parses the replies
itself: plain Sync Read takes each status packet with ``rxPacket`` and files it under the
ID it carries (a corrupt one costs only that servo); Fast Sync Read takes the one packet
and, when the SDK finds it corrupt or short, checks every block's own CRC (the running
CRC, re-seeded from the previous block's transmitted CRC, so one bad block does not
condemn the rest) and keeps the blocks that verify.

In a Sync Read chain a silent servo silences those after it (each waits for the previous
status packet). So after a read with a STALE servo, the first STALE servo moves to the
back of the read order: one dead servo costs one tick of collateral STALE, not all ticks.

SDK traps avoided: unicast ``action()`` does not wait for the servo's status packet (the
next request would receive it), so Reg Write/Action is not used; a SerialException inside
the SDK leaves ``port.is_using`` stuck (our :class:`~drivers.dynamixel.port.PortHandler`
frees it, and :meth:`Link.recover` frees it after an interrupted call, e.g. Ctrl-C).
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import TypeVar

import dynamixel_sdk as sdk
import numpy as np
import serial

from drivers.clock import Clock
from drivers.dynamixel import control_table as ct
from drivers.dynamixel.control_table import Item, OperatingMode
from drivers.dynamixel.errors import (
    CommError,
    CommTimeout,
    CorruptPacket,
    DynamixelError,
    ExitNotConfirmed,
    Mismatch,
    PortBusy,
    PortGone,
    ServoError,
    StartupMismatch,
)
from drivers.dynamixel.port import SDK_LATENCY_TIMER_MS, PortHandler
from drivers.dynamixel.units import (
    CENTER_TICK,
    RAD_PER_TICK,
    TICKS_PER_RAD,
    goal_tick_range,
    rad_to_ticks,
    ticks_to_rad,
)
from drivers.servo_bus import ExitPolicy, ExitReport, PresentReading, ReadStatus, ServoBus

T = TypeVar("T")

_OK = sdk.COMM_SUCCESS
_TIMEOUT = sdk.COMM_RX_TIMEOUT
_CORRUPT = sdk.COMM_RX_CORRUPT
_RESULT_TEXT = {
    sdk.COMM_TX_FAIL: "the instruction packet could not be sent",
    sdk.COMM_RX_FAIL: "no status packet could be received",
    sdk.COMM_TX_ERROR: "the instruction packet is malformed",
    sdk.COMM_RX_WAITING: "a status packet is still arriving",
    sdk.COMM_NOT_AVAILABLE: "the instruction is not available",
}
_STALE, _ERROR, _ALERT, _GOOD = (
    int(s) for s in (ReadStatus.STALE, ReadStatus.ERROR, ReadStatus.ALERT, ReadStatus.OK)
)
_SERIAL_ERRORS = (serial.SerialException, OSError)
#: Sysfs directory of Linux usb-serial devices (FTDI adapters such as the U2D2).
SYSFS_USB_SERIAL = Path("/sys/bus/usb-serial/devices")
#: Servo processing time allowed per reply on top of its Return Delay Time (AX ~20 µs,
#: MX ~50 µs; X series unpublished).
TURNAROUND_ALLOWANCE_S = 50e-6
#: Return Delay Time assumed until :meth:`DynamixelBus.check` has read the real one.
FACTORY_RETURN_DELAY_S = 500e-6
#: Watchdog period a ``hold`` exit arms when :meth:`DynamixelBus.arm_watchdog` never ran.
DEFAULT_EXIT_WATCHDOG_S = 0.1


def _raise_for(result: int, error: int, servo_id: int | None, what: str) -> None:
    """The one place SDK result codes and status error numbers become exceptions.

    Returns quietly when ``result`` is success and the error number (ERR bits 0-6) is 0;
    an Alert bit alone is not an error of the instruction.
    """
    if result == _OK:
        if error & ct.ERROR_NUMBER_MASK:
            raise ServoError(servo_id if servo_id is not None else -1, error, what)
        return
    who = "broadcast" if servo_id is None else f"servo {servo_id}"
    if result == _TIMEOUT:
        raise CommTimeout(f"{who}: no reply to {what} (timeout)", servo_id=servo_id, what=what)
    if result == _CORRUPT:
        raise CorruptPacket(f"{who}: corrupt reply to {what}", servo_id=servo_id, what=what)
    if result == sdk.COMM_PORT_BUSY:
        raise PortBusy(
            f"{who}: port busy during {what} (an earlier transaction never finished)",
            servo_id=servo_id,
            what=what,
        )
    text = _RESULT_TEXT.get(result, f"communication failed ({result})")
    raise CommError(f"{who}: {text} ({what})", servo_id=servo_id, what=what)


def _gone(exc: BaseException, port_name: str, what: str) -> PortGone:
    return PortGone(f"{port_name}: adapter gone during {what}: {exc}")


# ----------------------------------------------------------------------- latency timer
class LatencyTimerWarning(RuntimeWarning):
    """The USB adapter's latency timer is high: every read waits for it."""


def _latency_fix(dev: str, ms: int) -> str:
    return (
        f"{dev}: USB latency timer is {ms} ms, so every read waits >= {ms} ms. Lower it:\n"
        f"  echo 1 | sudo tee /sys/bus/usb-serial/devices/{dev}/latency_timer\n"
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
    fix when it stays above 1 ms. Devices without a latency timer (ptys, CDC-ACM, other
    OSes) return the SDK's conservative 16 ms allowance.
    """
    if not sys.platform.startswith("linux") or not device.startswith("/dev/"):
        return SDK_LATENCY_TIMER_MS
    dev = os.path.basename(os.path.realpath(device))
    with contextlib.suppress(AttributeError, ValueError, OSError):
        ser.set_low_latency_mode(True)  # ASYNC_LOW_LATENCY: ftdi_sio then uses 1 ms
    path = sysfs / dev / "latency_timer"
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


# ----------------------------------------------------------------------- link
class Link:
    """One open port and Protocol 2.0: unicast and broadcast transactions, snake_case.

    Every method returns values or raises (:mod:`drivers.dynamixel.errors`): result codes
    through :func:`_raise_for`, a vanished adapter as :class:`PortGone`. Not for the
    per-tick path (:class:`DynamixelBus` does that leaner).
    """

    def __init__(self, port: PortHandler) -> None:
        self.port = port
        self.ph = sdk.PacketHandler(2.0)

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

        ``latency_timer_ms``: the adapter latency the packet timeouts allow for. None:
        the emulator's own model for ``dxlsim://``; on a Linux USB adapter the timer is
        lowered to 1 ms where permitted (:func:`tune_latency_timer`); else 16 ms.
        """
        ph = PortHandler(
            port,
            clock=clock,
            latency_timer_ms=SDK_LATENCY_TIMER_MS if latency_timer_ms is None else latency_timer_ms,
        )
        _check_baud(ph, baud)
        try:
            ph.setBaudRate(baud)
        except _SERIAL_ERRORS as exc:
            if isinstance(exc.__cause__, ValueError):  # a dxlsim:// URL it cannot parse
                raise ValueError(str(exc)) from exc
            raise PortGone(f"cannot open {port}: {exc}") from exc
        link = cls(ph)
        try:
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
        return self.port.latency_timer_ms

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
        except _SERIAL_ERRORS as exc:
            raise _gone(exc, self.name, what) from exc

    # -- transactions --------------------------------------------------------------
    def ping(self, servo_id: int) -> tuple[int, int]:
        """Ping one servo: ``(model number, firmware version)``."""
        _check_unicast(servo_id)
        tx = [0] * 10
        tx[4], tx[5], tx[6], tx[7] = servo_id, 3, 0, sdk.INST_PING
        rx, result, error = self._call("Ping", self.ph.txRxPacket, self.port, tx)
        _raise_for(result, error, servo_id, "Ping")
        if len(rx) < 14:
            raise CorruptPacket(
                f"servo {servo_id}: short Ping reply", servo_id=servo_id, what="Ping"
            )
        return rx[9] | rx[10] << 8, rx[11]

    def broadcast_ping(self) -> dict[int, tuple[int, int]]:
        """Ping every ID at once: ``{id: (model number, firmware)}`` of those that
        answered intact (possibly none)."""
        found, result = self._call("broadcast Ping", self.ph.broadcastPing, self.port)
        if result not in (_OK, _TIMEOUT, _CORRUPT):  # silence and noise are answers here
            _raise_for(result, 0, None, "broadcast Ping")
        return {int(i): (int(m), int(fw)) for i, (m, fw) in found.items()}

    def read(self, servo_id: int, addr: int, size: int) -> bytes:
        """Read ``size`` bytes from ``addr``."""
        _check_unicast(servo_id)
        what = f"Read {size} B at {addr}"
        data, result, error = self._call(what, self.ph.readTxRx, self.port, servo_id, addr, size)
        _raise_for(result, error, servo_id, what)
        if len(data) != size:
            raise CorruptPacket(
                f"servo {servo_id}: {len(data)} of {size} bytes in reply to {what}",
                servo_id=servo_id,
                what=what,
            )
        return bytes(data)

    def read_item(self, servo_id: int, item: Item) -> int:
        return item.decode(self.read(servo_id, item.addr, item.size), item.addr)

    def write(self, servo_id: int, addr: int, data: bytes) -> None:
        """Write ``data`` at ``addr`` and wait for the status packet."""
        _check_unicast(servo_id)
        what = f"Write {len(data)} B at {addr}"
        result, error = self._call(
            what, self.ph.writeTxRx, self.port, servo_id, addr, len(data), list(data)
        )
        _raise_for(result, error, servo_id, what)

    def write_item(self, servo_id: int, item: Item, value: int) -> None:
        self.write(servo_id, item.addr, item.encode(value))

    def reboot(self, servo_id: int) -> None:
        """Reboot one servo (clears a latched hardware error; RAM back to defaults)."""
        _check_unicast(servo_id)
        result, error = self._call("Reboot", self.ph.reboot, self.port, servo_id)
        _raise_for(result, error, servo_id, "Reboot")


def _check_baud(port: PortHandler, baud: int) -> None:
    if port.getCFlagBaud(baud) <= 0:
        raise ValueError(
            f"baud {baud} is not supported; use one of "
            f"{sorted(set(ct.BAUD_RATES.values()) - {4_500_000})}"
        )


def _check_unicast(servo_id: int) -> None:
    if not 0 <= servo_id <= 252:
        raise ValueError(f"servo ID must be 0..252, got {servo_id}")


def _retry(attempts: int, fn: Callable[[], T]) -> T:
    """Call ``fn`` up to ``attempts`` times while it fails on the wire (CommError)."""
    for k in range(attempts):
        try:
            return fn()
        except CommError:
            if k + 1 == attempts:
                raise
    raise AssertionError("unreachable")


# ----------------------------------------------------------------------- start-up data
class ReadMode(StrEnum):
    """How :meth:`DynamixelBus.read_present` reads: Fast Sync Read, plain Sync Read, or
    ``auto`` (fast when every servo's firmware supports it)."""

    AUTO = "auto"
    FAST = "fast"
    PLAIN = "plain"


@dataclass(frozen=True)
class Expectation:
    """What the rig expects of one servo; :meth:`DynamixelBus.check` compares.

    Attributes:
        id: servo ID.
        model: model name (``"XM430-W350"``); None accepts any model.
        operating_mode: Operating Mode (addr 11).
        position_range_rad: ``(lo, hi)`` rad, servo frame, the loop will command; must
            lie within Min/Max Position Limit in Position mode. None: not checked.
        return_delay_us_max: largest acceptable Return Delay Time, µs (factory 500; 0
            is what a 1 kHz loop wants).
        allow_torque_on: False makes torque already on at start a mismatch; True (default)
            only reports it (:attr:`StartupReport.torque_on_ids`) and the loop decides.
    """

    id: int
    model: str | None = None
    operating_mode: OperatingMode = OperatingMode.POSITION
    position_range_rad: tuple[float, float] | None = None
    return_delay_us_max: float = 0.0
    allow_torque_on: bool = True

    def __post_init__(self) -> None:
        _check_unicast(self.id)
        if self.model is not None:
            ct.model_number(self.model)  # raises ValueError naming the known models
        object.__setattr__(self, "operating_mode", OperatingMode(self.operating_mode))
        if self.position_range_rad is not None:
            lo, hi = (float(x) for x in self.position_range_rad)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(
                    f"servo {self.id}: position_range_rad must be finite "
                    f"(lo, hi) with lo <= hi, got {self.position_range_rad}"
                )
            object.__setattr__(self, "position_range_rad", (lo, hi))
        if not self.return_delay_us_max >= 0:
            raise ValueError(f"servo {self.id}: return_delay_us_max must be >= 0")


@dataclass(frozen=True)
class ServoState:
    """What :meth:`DynamixelBus.check` found on one servo (raw control-table values,
    plus Present Position in rad, servo frame)."""

    id: int
    model_number: int
    model_name: str
    firmware: int
    fast_read: bool
    operating_mode: int
    torque_on: bool
    return_delay_us: float
    status_return_level: int
    hardware_error: int
    bus_watchdog: int
    position_limits: tuple[int, int]  # Min, Max Position Limit, ticks
    position_rad: float


@dataclass(frozen=True)
class StartupReport:
    """Result of a passing :meth:`DynamixelBus.check`."""

    port: str
    baud: int
    read_mode: ReadMode  # FAST or PLAIN: what read_present will use
    servos: tuple[ServoState, ...]
    notes: tuple[str, ...] = ()

    @property
    def torque_on_ids(self) -> tuple[int, ...]:
        return tuple(s.id for s in self.servos if s.torque_on)

    @property
    def positions_rad(self) -> np.ndarray:
        """(n,) Present Position at check time, rad, servo frame, in ``ids`` order."""
        return np.array([s.position_rad for s in self.servos])

    def __str__(self) -> str:
        lines = [
            f"{self.port} @ {self.baud} bit/s, {len(self.servos)} servo(s), "
            f"{self.read_mode.value} sync read"
        ]
        lines += [
            f"  servo {s.id}: {s.model_name} fw {s.firmware}, mode {s.operating_mode}, "
            f"torque {'on' if s.torque_on else 'off'}, {s.position_rad:+.4f} rad"
            for s in self.servos
        ]
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


class _UnconfirmedError(Exception):
    """One exit step could not be confirmed on one servo (internal)."""


# ----------------------------------------------------------------------- the bus
class DynamixelBus(ServoBus):
    """Dynamixel X-series servos (Protocol 2.0) on one port, through dynamixel-sdk.

    Build with :meth:`open`. Positions are rad in the servo frame (tick 2048 = 0 rad,
    4096 ticks per turn). ``retries`` is how often non-tick transactions (check, torque,
    watchdog) are repeated on a wire failure; per-tick calls never retry.
    """

    def __init__(self, link: Link, ids: Sequence[int], read_mode: ReadMode, retries: int) -> None:
        super().__init__(ids, link.clock)
        self.link = link
        self.retries = int(retries)
        self._requested = read_mode
        self._fast = read_mode is ReadMode.FAST
        self._ph, self._port = link.ph, link.port
        n = self.n
        self._index = {sid: k for k, sid in enumerate(self.ids)}
        self._set_order(list(range(n)))
        # write_goals buffers: ticks (float work, int32) and the Sync Write parameters
        self._tickf = np.empty(n)
        self._ticks = np.empty(n, dtype="<i4")
        self._wparam = np.zeros((n, 5), dtype=np.uint8)
        self._wparam[:, 0] = self.ids
        self._ticks_u8 = self._ticks.view(np.uint8).reshape(n, 4)
        self._lo = np.zeros(n)  # accepted Goal Position ticks (Position mode until check)
        self._hi = np.full(n, 4095.0)
        self._rdt_s = np.full(n, FACTORY_RETURN_DELAY_S)
        self._watchdog_units: int | None = None
        self._update_timeouts()

    @classmethod
    def open(
        cls,
        port: str,
        *,
        baud: int,
        ids: Sequence[int],
        read_mode: ReadMode | str = ReadMode.AUTO,
        latency_timer_ms: float | None = None,
        clock: Clock | None = None,
        retries: int = 2,
    ) -> DynamixelBus:
        """Open ``port`` (``/dev/ttyUSB0``, a pty, ``dxlsim://...``) for servos ``ids``.

        ``read_mode`` ``"auto"`` pings every servo now and reads fast only if all answer
        with Fast Sync Read firmware. ``latency_timer_ms``, ``clock``: see
        :meth:`Link.open`. Nothing is written to the servos.
        """
        mode = ReadMode(read_mode)
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        link = Link.open(port, baud=baud, clock=clock, latency_timer_ms=latency_timer_ms)
        try:
            bus = cls(link, ids, mode, retries)
            if mode is ReadMode.AUTO:
                bus._fast = bus._all_support_fast()
        except BaseException:
            link.close()
            raise
        return bus

    def __repr__(self) -> str:
        return (
            f"DynamixelBus({self.link.name!r}, baud={self.link.baud}, ids={self.ids}, "
            f"read_mode={self.read_mode.value!r})"
        )

    @property
    def read_mode(self) -> ReadMode:
        """What :meth:`read_present` uses now: FAST or PLAIN."""
        return ReadMode.FAST if self._fast else ReadMode.PLAIN

    @property
    def read_order(self) -> tuple[int, ...]:
        """Servo IDs in the order the next Sync Read lists them."""
        return tuple(self._read_param)

    # -- per tick ------------------------------------------------------------------
    def _write_goals(self, goals: np.ndarray) -> None:
        t = self._tickf
        np.multiply(goals, TICKS_PER_RAD, out=t)
        np.rint(t, out=t)
        t += CENTER_TICK
        if not ((t >= self._lo) & (t <= self._hi)).all():
            bad = [
                f"servo {sid}: {g:+.4f} rad = tick {int(x)} outside [{int(lo)}, {int(hi)}]"
                for sid, g, x, lo, hi in zip(self.ids, goals, t, self._lo, self._hi, strict=True)
                if not lo <= x <= hi
            ]
            raise ValueError("goal out of range, nothing sent: " + "; ".join(bad))
        self._ticks[:] = t
        self._wparam[:, 1:] = self._ticks_u8
        try:
            result = self._ph.syncWriteTxOnly(
                self._port, ct.GOAL_POSITION.addr, 4, self._wparam.tobytes(), 5 * self.n
            )
        except _SERIAL_ERRORS as exc:
            raise _gone(exc, self.link.name, "Sync Write") from exc
        if result != _OK:
            _raise_for(result, 0, None, "Sync Write of Goal Position")

    def _read_present(self, out: PresentReading) -> None:
        clock = self.clock
        out.t = clock.now()
        out.positions.fill(np.nan)
        out.status.fill(_STALE)
        out.errors.fill(0)
        port, ph = self._port, self._ph
        fast = self._fast
        try:
            result = ph.syncReadTx(
                port, ct.PRESENT_POSITION.addr, 4, self._read_param, self.n, fast
            )
            if result == _OK:
                if fast:
                    port.setPacketTimeoutMillis(self._fast_timeout_ms)
                    packet, rx = ph.rxPacket(port, True)
                    if rx == _OK or (rx == _CORRUPT and packet):
                        self._parse_fast(packet, rx == _OK, out)
                else:
                    port.setPacketTimeoutMillis(self._plain_timeout_ms)
                    self._receive_plain(out)
        except _SERIAL_ERRORS as exc:
            if isinstance(exc, DynamixelError):
                raise
            raise _gone(exc, self.link.name, "Sync Read") from exc
        if result != _OK:
            _raise_for(result, 0, None, "Sync Read of Present Position")
        out.t_done = clock.now()
        status = out.status
        if status.any():
            order = self._order
            for i, k in enumerate(order):
                if status[k] == _STALE:
                    if i + 1 < len(order):  # the chain broke here: ask it last next time
                        self._set_order(order[:i] + order[i + 1 :] + [k])
                    break

    def _receive_plain(self, out: PresentReading) -> None:
        """Take up to n status packets; file each under the ID it carries."""
        pos, status, errors = out.positions, out.status, out.errors
        index, ph, port = self._index, self._ph, self._port
        missing = self.n
        for _ in range(2 * self.n):
            packet, result = ph.rxPacket(port, False)
            if result == _OK:
                k = index.get(packet[4])
                if k is None or status[k] != _STALE:
                    continue  # a stranger, or a second reply from the same servo
                err = packet[8]
                errors[k] = err
                if err & ct.ERROR_NUMBER_MASK:
                    status[k] = _ALERT if err & ct.ALERT_BIT else _ERROR
                elif (packet[5] | packet[6] << 8) >= 8:  # LEN = INST ERR data(4) CRC(2)
                    v = packet[9] | packet[10] << 8 | packet[11] << 16 | packet[12] << 24
                    pos[k] = ((v - 0x1_0000_0000 if v & 0x8000_0000 else v) - CENTER_TICK) * (
                        RAD_PER_TICK
                    )
                    status[k] = _ALERT if err & ct.ALERT_BIT else _GOOD
                else:
                    continue  # no data and no error: not a reading
                missing -= 1
                if not missing:
                    return
            elif result == _TIMEOUT:
                return
            # corrupt: that reply is lost; the next may be fine

    def _parse_fast(self, packet: list[int], verified: bool, out: PresentReading) -> None:
        """Blocks ``ERR ID pos(4) CRC(2)`` from offset 8. ``verified``: the SDK checked the
        packet CRC (which covers every block); else each block's CRC is checked alone."""
        if packet[:5] != [0xFF, 0xFF, 0xFD, 0x00, 0xFE]:
            return
        pos, status, errors, index = out.positions, out.status, out.errors, self._index
        crc = self._ph.updateCRC
        end = len(packet)
        seed = None if verified else crc(0, packet, 8)
        for o in range(8, 8 + 8 * self.n, 8):
            if o + 8 > end:
                return
            if not verified:
                if o > 8:  # the sender's running CRC went on over the previous CRC bytes
                    seed = crc(packet[o - 2] | packet[o - 1] << 8, packet[o - 2 : o], 2)
                if crc(seed, packet[o : o + 6], 6) != packet[o + 6] | packet[o + 7] << 8:
                    continue
            k = index.get(packet[o + 1])
            if k is None:
                continue
            err = packet[o]
            errors[k] = err
            if err & ct.ERROR_NUMBER_MASK:
                status[k] = _ALERT if err & ct.ALERT_BIT else _ERROR
                continue
            v = packet[o + 2] | packet[o + 3] << 8 | packet[o + 4] << 16 | packet[o + 5] << 24
            pos[k] = ((v - 0x1_0000_0000 if v & 0x8000_0000 else v) - CENTER_TICK) * RAD_PER_TICK
            status[k] = _ALERT if err & ct.ALERT_BIT else _GOOD

    def _set_order(self, order: list[int]) -> None:
        self._order = order
        self._read_param = [self.ids[k] for k in order]

    def _update_timeouts(self) -> None:
        """Packet timeouts for the reads: the SDK's (wire + 2·latency + 2 ms) plus the
        servos' Return Delay Times, which the SDK leaves out (n of them in a plain chain,
        one in a fast reply)."""
        base = self._port.tx_time_per_byte * 15 * self.n + 2.0 * self.link.latency_timer_ms + 2.0
        delays = self._rdt_s + TURNAROUND_ALLOWANCE_S
        self._plain_timeout_ms = base + 1e3 * float(delays.sum())
        self._fast_timeout_ms = base + 1e3 * float(delays.max())

    # -- start-up ------------------------------------------------------------------
    def _all_support_fast(self) -> bool:
        for sid in self.ids:
            try:
                model, fw = _retry(1 + self.retries, lambda sid=sid: self.link.ping(sid))
            except (CommError, ServoError):
                return False
            if not ct.supports_fast_read(model, fw):
                return False
        return True

    def check(self, expectations: Iterable[Expectation]) -> StartupReport:
        """Compare every servo with its :class:`Expectation`; read-only.

        Checked per servo: answers Ping; model; Fast Sync Read firmware (read_mode
        ``"fast"``); Operating Mode; the expected position range within Min/Max Position
        Limit (Position mode) or the multi-turn range; Return Delay Time; Status Return
        Level 2 (1 leaves writes unanswered, their errors unseen; 0 shows as "answers
        Ping, not Read"); Hardware Error Status 0; Bus Watchdog not tripped; torque
        (reported, a mismatch only if not ``allow_torque_on``). Raises
        :class:`StartupMismatch` with one table of every difference. Also loads each
        servo's accepted goal range and Return Delay Time into the bus (``write_goals``
        validation, read timeouts) and settles ``read_mode`` ``"auto"``.
        """
        self._check_open()
        exps = {e.id: e for e in expectations}
        missing = [sid for sid in self.ids if sid not in exps]
        extra = sorted(set(exps) - set(self.ids))
        if missing or extra:
            raise ValueError(
                f"expectations must cover exactly servos {self.ids}: "
                f"missing {missing}, not on this bus {extra}"
            )
        self.link.recover()
        rows: list[Mismatch] = []
        states: list[ServoState] = []
        notes: list[str] = []
        for k, sid in enumerate(self.ids):
            state = self._check_one(k, exps[sid], rows, notes)
            if state is not None:
                states.append(state)
        fast_ok = len(states) == self.n and all(s.fast_read for s in states)
        if self._requested is ReadMode.AUTO:
            self._fast = fast_ok
            if not fast_ok and len(states) == self.n:
                slow = [s.id for s in states if not s.fast_read]
                notes.append(f"plain Sync Read: no Fast Sync Read firmware on servo(s) {slow}")
        self._update_timeouts()
        if rows:
            raise StartupMismatch(rows, port=self.link.name)
        return StartupReport(
            self.link.name, self.link.baud, self.read_mode, tuple(states), tuple(notes)
        )

    def _check_one(
        self, k: int, exp: Expectation, rows: list[Mismatch], notes: list[str]
    ) -> ServoState | None:
        sid, link, attempts = exp.id, self.link, 1 + self.retries

        def add(item: str, expected: str, found: str, fix: str = "") -> None:
            rows.append(Mismatch(sid, item, expected, found, fix))

        try:
            model, fw = _retry(attempts, lambda: link.ping(sid))
        except CommTimeout:
            add(
                "answers Ping",
                "yes",
                "no (timeout)",
                f"check ID, power, wiring and baud ({link.baud})",
            )
            return None
        except CorruptPacket:
            add("answers Ping", "yes", "corrupt replies", "two servos with this ID?")
            return None
        except ServoError as exc:
            add("answers Ping", "yes", f"error reply: {exc.name}", "")
            return None
        name = ct.model_name(model)
        if exp.model is not None and model != ct.model_number(exp.model):
            add(
                "model",
                f"{exp.model} ({ct.model_number(exp.model)})",
                f"{name} ({model})",
                "fix the rig file or the servo",
            )
        fast = ct.supports_fast_read(model, fw)
        if self._requested is ReadMode.FAST and not fast:
            least = ct.fast_read_min_firmware(model)
            add(
                "firmware (Fast Sync Read)",
                f">= {least}" if least else "known model",
                str(fw),
                "update firmware (DYNAMIXEL Wizard 2.0) or read_mode='plain'",
            )
        block_item = ct.STARTUP_BLOCK
        try:
            block = _retry(attempts, lambda: link.read(sid, 0, block_item.size))
        except CommTimeout:
            add(
                "Status Return Level",
                "2",
                "0? (answers Ping, not Read)",
                "write 2 to addr 68 (Status Return Level)",
            )
            return None
        except (CorruptPacket, ServoError) as exc:
            add("read control table", "a reply", str(exc), "")
            return None

        def get(item: Item) -> int:
            return item.decode(block)

        mode, rdt_us = get(ct.OPERATING_MODE), get(ct.RETURN_DELAY_TIME) * 2.0
        srl, hw, wd = (
            get(ct.STATUS_RETURN_LEVEL),
            get(ct.HARDWARE_ERROR_STATUS),
            get(ct.BUS_WATCHDOG),
        )
        torque = get(ct.TORQUE_ENABLE) == 1
        lo_lim, hi_lim = get(ct.MIN_POSITION_LIMIT), get(ct.MAX_POSITION_LIMIT)
        present = ticks_to_rad(get(ct.PRESENT_POSITION))
        if mode != exp.operating_mode:
            add(
                "Operating Mode",
                _mode_text(exp.operating_mode),
                _mode_text(mode),
                "write addr 11 (torque off)",
            )
        if mode in ct.POSITION_MODES:
            lo_t, hi_t = goal_tick_range(mode, lo_lim, hi_lim)
            self._lo[k], self._hi[k] = lo_t, hi_t
            if exp.position_range_rad is not None:
                want = rad_to_ticks(np.array(exp.position_range_rad))
                if want[0] < lo_t or want[1] > hi_t:
                    r = exp.position_range_rad
                    add(
                        "position range",
                        f"[{r[0]:+.3f}, {r[1]:+.3f}] rad = ticks [{want[0]}, {want[1]}]",
                        f"limits [{lo_t}, {hi_t}] ticks",
                        "widen Min/Max Position Limit (addr 52/48) or narrow the joint",
                    )
        self._rdt_s[k] = rdt_us * 1e-6
        if rdt_us > exp.return_delay_us_max:
            add(
                "Return Delay Time",
                f"<= {exp.return_delay_us_max:g} us",
                f"{rdt_us:g} us",
                f"write {int(exp.return_delay_us_max // 2)} to addr 9 (2 us units)",
            )
        if srl != ct.STATUS_RETURN_ALL:
            add("Status Return Level", "2", str(srl), "write 2 to addr 68")
        if hw:
            add(
                "Hardware Error Status",
                "0",
                f"0x{hw:02X} ({ct.describe_hardware_error(hw)})",
                "remove the cause, then Reboot the servo",
            )
        if wd == ct.WATCHDOG_TRIPPED:
            add(
                "Bus Watchdog",
                "not tripped",
                "tripped (-1)",
                "write 0 to addr 98 (bus.disarm_watchdog())",
            )
        if torque:
            if not exp.allow_torque_on:
                add("Torque Enable", "off", "on", "bus.set_torque(False)")
            else:
                notes.append(f"servo {sid}: torque already on, holding {present:+.4f} rad")
        return ServoState(
            sid, model, name, fw, fast, mode, torque, rdt_us, srl, hw, wd, (lo_lim, hi_lim), present
        )

    # -- state changes -------------------------------------------------------------
    def _each(self, what: str, fn: Callable[[int], None]) -> None:
        """Do ``fn(id)`` on every servo (with retries); raise the first failure after
        trying all, the others noted on it."""
        self.link.recover()
        failures: list[DynamixelError] = []
        for sid in self.ids:
            try:
                _retry(1 + self.retries, lambda sid=sid: fn(sid))
            except (CommError, ServoError) as exc:
                failures.append(exc)
        if failures:
            first = failures[0]
            if len(failures) > 1:
                first.add_note(f"{what} also failed on: " + "; ".join(map(str, failures[1:])))
            raise first

    def _set_torque(self, on: bool) -> None:
        self._each("torque", lambda sid: self.link.write_item(sid, ct.TORQUE_ENABLE, int(on)))

    def _arm_watchdog(self, period_s: float) -> None:
        units = round(period_s / ct.WATCHDOG_UNIT_S)
        if not 1 <= units <= ct.WATCHDOG_MAX_UNITS:
            raise ValueError(
                f"watchdog period {period_s} s is outside 0.02..2.54 s (20 ms units, 1..127)"
            )
        self._each("arm watchdog", lambda sid: self.link.write_item(sid, ct.BUS_WATCHDOG, units))
        self._watchdog_units = units

    def _disarm_watchdog(self) -> None:
        self._each("disarm watchdog", lambda sid: self.link.write_item(sid, ct.BUS_WATCHDOG, 0))
        self._watchdog_units = None

    def hardware_error_status(self, servo_id: int) -> int:
        """Hardware Error Status (addr 70) of one servo; see
        :func:`~drivers.dynamixel.control_table.describe_hardware_error`."""
        self._check_open()
        return self.link.read_item(servo_id, ct.HARDWARE_ERROR_STATUS)

    # -- exit ----------------------------------------------------------------------
    def _apply_exit_policy(self, policy: ExitPolicy, retries: int) -> ExitReport:
        """``hold``: torque must be on; a tripped watchdog is cleared, Goal Position :=
        Present Position, then the watchdog armed (the last :meth:`arm_watchdog` period,
        else 0.1 s); each read back. ``relax``: Torque Enable := 0, read back. A servo
        whose step fails ``1 + retries`` times is skipped and named; the adapter gone
        stops at once. Raises :class:`ExitNotConfirmed` unless every servo is confirmed."""
        confirmed: list[int] = []
        failed: list[tuple[int, str]] = []
        attempts = 1 + retries
        try:
            self.link.recover()
            for sid in self.ids:
                try:
                    if policy is ExitPolicy.HOLD:
                        self._hold_one(sid, attempts)
                    else:
                        self._confirm(sid, ct.TORQUE_ENABLE, 0, attempts)
                    confirmed.append(sid)
                except _UnconfirmedError as exc:
                    failed.append((sid, str(exc)))
        except PortGone as exc:
            done = {s for s, _ in failed} | set(confirmed)
            failed += [(s, f"adapter gone: {exc}") for s in self.ids if s not in done]
            raise ExitNotConfirmed(ExitReport(policy, tuple(confirmed), tuple(failed))) from exc
        report = ExitReport(policy, tuple(confirmed), tuple(failed))
        if failed:
            raise ExitNotConfirmed(report)
        return report

    def _hold_one(self, sid: int, attempts: int) -> None:
        if not self._read(sid, ct.TORQUE_ENABLE, attempts):
            raise _UnconfirmedError("torque is off: cannot hold (the servo is limp)")
        if self._read(sid, ct.BUS_WATCHDOG, attempts) == ct.WATCHDOG_TRIPPED:
            self._confirm(sid, ct.BUS_WATCHDOG, 0, attempts)
        present = self._read(sid, ct.PRESENT_POSITION, attempts)
        self._confirm(sid, ct.GOAL_POSITION, present, attempts)
        units = self._watchdog_units or round(DEFAULT_EXIT_WATCHDOG_S / ct.WATCHDOG_UNIT_S)
        self._confirm(sid, ct.BUS_WATCHDOG, units, attempts)

    def _read(self, sid: int, item: Item, attempts: int) -> int:
        last: Exception | None = None
        for _ in range(attempts):
            try:
                return self.link.read_item(sid, item)
            except (CommError, ServoError) as exc:
                last = exc
        raise _UnconfirmedError(f"reading {item.name} failed {attempts}x: {last}")

    def _confirm(self, sid: int, item: Item, value: int, attempts: int) -> None:
        """Write ``item := value`` and read it back, up to ``attempts`` times."""
        last = ""
        for _ in range(attempts):
            try:
                self.link.write_item(sid, item, value)
                got = self.link.read_item(sid, item)
            except (CommError, ServoError) as exc:
                last = str(exc)
                continue
            if got == value:
                return
            last = f"wrote {value}, read back {got}"
        raise _UnconfirmedError(
            f"{item.name} := {value} not confirmed after {attempts} attempt(s): {last}"
        )

    def _close(self) -> None:
        self.link.close()


def _mode_text(mode: int) -> str:
    try:
        return f"{OperatingMode(mode).name.lower()} ({mode})"
    except ValueError:
        return f"unknown ({mode})"
