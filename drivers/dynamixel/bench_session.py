"""A bus opened for measurement: our PortHandler, the unmodified dynamixel-sdk, a few reads.

The bench (hilsim/bench) times dynamixel-sdk's group objects through this module
(``GroupSyncWrite.txPacket``, ``GroupSyncRead.txRxPacket`` / ``fastSyncRead``): the point is
to time exactly what the SDK does. Everything SDK-shaped stays in this module; the others
get bound methods and plain numbers.

Ports: a device path, a pty, or ``dxlsim://``. A ``dxlsim://?...`` URL that does not say
``clock=`` is opened on the real clock (the bench measures what this host achieves).
"""

from __future__ import annotations

import os
import urllib.parse
from collections.abc import Sequence
from dataclasses import dataclass

import dynamixel_sdk as sdk

from drivers.clock import Clock
from drivers.dynamixel.port import PortHandler

ADDR_FIRMWARE = 6
ADDR_RETURN_DELAY = 9
ADDR_TORQUE = 64
ADDR_GOAL_POSITION = 116
ADDR_PRESENT_POSITION = 132
OK = sdk.COMM_SUCCESS


class BenchError(RuntimeError):
    """The bus cannot be measured (cannot open, nobody answers, ...); the message says why."""


def emulator_url(
    ids: Sequence[int],
    baud: int,
    *,
    rdt_us: float = 0.0,
    turnaround_us: float = 20.0,
    latency_ms: float = 0.0,
    firmware: int | None = None,
    clock: str = "real",
) -> str:
    """``dxlsim://`` URL of an emulated bus with these servos (all on ``baud``)."""
    q = {
        "ids": ",".join(str(i) for i in ids),
        "baud": str(baud),
        "rdt_us": f"{rdt_us:g}",
        "turnaround_us": f"{turnaround_us:g}",
        "latency_ms": f"{latency_ms:g}",
        "clock": clock,
    }
    if firmware is not None:
        q["firmware"] = str(firmware)
    return "dxlsim://?" + urllib.parse.urlencode(q, safe=",")


def prepare_url(url: str, *, clock: str = "real", trace: bool = False) -> str:
    """For a ``dxlsim://?...`` URL: add ``clock=`` when missing and ``trace=1`` when asked.
    Other ports (and named emulated buses) pass through unchanged."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme.lower() != "dxlsim" or parts.netloc or parts.path.strip("/"):
        return url
    query = urllib.parse.parse_qs(parts.query, keep_blank_values=True)
    query.setdefault("clock", [clock])
    if trace:
        query["trace"] = ["1"]
    return "dxlsim://?" + urllib.parse.urlencode(query, doseq=True, safe=",")


class StampedPortHandler(PortHandler):
    """Our PortHandler that notes the clock time of every ``writePort`` (``write_times``)."""

    def __init__(self, *args, **kw) -> None:
        super().__init__(*args, **kw)
        self.write_times: list[float] = []

    def writePort(self, packet):
        self.write_times.append(self.clock.now())
        return super().writePort(packet)


@dataclass
class BenchBus:
    """An open port with its packet handler. ``bus`` is the emulated bus, or None on hardware."""

    port: PortHandler
    ph: sdk.Protocol2PacketHandler
    url: str
    baud: int

    @property
    def bus(self):
        return getattr(self.port.ser, "bus", None)

    @property
    def emulated(self) -> bool:
        return self.bus is not None

    @property
    def clock(self) -> Clock:
        return self.port.clock

    @property
    def device(self) -> str | None:
        """The real device behind the port name (``/dev/ttyUSB0``), or None for emulators."""
        if self.emulated or "://" in self.url:
            return None
        return os.path.realpath(self.url)

    def close(self) -> None:
        if self.port.is_open:
            self.port.closePort()

    def __enter__(self) -> BenchBus:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- single-servo transactions: None when the servo does not answer ------------------
    def ping(self, servo_id: int) -> int | None:
        """Model number, or None."""
        model, result, _err = self.ph.ping(self.port, servo_id)
        return model if result == OK else None

    def read(self, servo_id: int, addr: int, size: int) -> int | None:
        """Unsigned value of ``size`` (1, 2, 4) bytes at ``addr``, or None."""
        fn = {1: self.ph.read1ByteTxRx, 2: self.ph.read2ByteTxRx, 4: self.ph.read4ByteTxRx}[size]
        value, result, _err = fn(self.port, servo_id, addr)
        return value if result == OK else None

    def discover_ids(self) -> list[int]:
        """IDs on the bus: the emulator's servos, or a broadcast Ping on hardware (~0.8 s)."""
        if self.bus is not None:
            return sorted({s.id for s in self.bus.servos})
        found, result = self.ph.broadcastPing(self.port)
        if result != OK and not found:
            raise BenchError(
                f"{self.url}: no servo answers a broadcast Ping at {self.baud} bps "
                f"({self.ph.getTxRxResult(result)})"
            )
        return sorted(found)

    def write1(self, servo_id: int, addr: int, value: int) -> bool:
        result, err = self.ph.write1ByteTxRx(self.port, servo_id, addr, value)
        return result == OK and err == 0

    # -- the group objects the cycle uses ---------------------------------------------------
    def goal_writer(self, goals: dict[int, int]) -> sdk.GroupSyncWrite:
        """A GroupSyncWrite of Goal Position (4 B) holding ``goals`` (ticks by ID)."""
        writer = sdk.GroupSyncWrite(self.port, self.ph, ADDR_GOAL_POSITION, 4)
        for servo_id, goal in goals.items():
            writer.addParam(servo_id, goal_bytes(goal))
        return writer

    def position_reader(self, ids: Sequence[int]) -> sdk.GroupSyncRead:
        """A GroupSyncRead of Present Position (4 B) from ``ids``, in that order."""
        reader = sdk.GroupSyncRead(self.port, self.ph, ADDR_PRESENT_POSITION, 4)
        for servo_id in ids:
            reader.addParam(servo_id)
        return reader

    def read_positions(self, ids: Sequence[int]) -> dict[int, int]:
        """Present Position of every servo by one plain Sync Read; BenchError if it fails."""
        return self._sync_read(ids, ADDR_PRESENT_POSITION, "Present Position")

    def read_goals(self, ids: Sequence[int]) -> dict[int, int]:
        """Goal Position registers (ticks): writing them back changes nothing on the servos."""
        return self._sync_read(ids, ADDR_GOAL_POSITION, "Goal Position")

    def _sync_read(self, ids: Sequence[int], addr: int, what: str) -> dict[int, int]:
        reader = sdk.GroupSyncRead(self.port, self.ph, addr, 4)
        for servo_id in ids:
            reader.addParam(servo_id)
        result = reader.txRxPacket()
        if result != OK:
            raise BenchError(
                f"{self.url}: Sync Read of {what} from IDs {list(ids)} failed: "
                f"{self.ph.getTxRxResult(result)}"
            )
        return {i: _signed32(reader.getData(i, addr, 4)) for i in ids}


def goal_bytes(goal: int) -> list[int]:
    """Goal Position ticks as the 4 little-endian bytes GroupSyncWrite wants."""
    return list(int(goal).to_bytes(4, "little", signed=True))


def position(reader: sdk.GroupSyncRead, servo_id: int) -> int:
    """Signed Present Position (ticks) of ``servo_id`` from the reader's last result."""
    return _signed32(reader.getData(servo_id, ADDR_PRESENT_POSITION, 4))


def _signed32(value: int) -> int:
    return value - (1 << 32) if value >= 1 << 31 else value


def open_bus(
    url: str,
    baud: int,
    *,
    clock: str = "real",
    trace: bool = False,
    stamped: bool = False,
) -> BenchBus:
    """Open ``url`` at ``baud`` through our PortHandler. ``clock``/``trace`` apply to
    ``dxlsim://?...`` URLs (see :func:`prepare_url`); ``stamped`` records write times."""
    url = prepare_url(url, clock=clock, trace=trace)
    cls = StampedPortHandler if stamped else PortHandler
    port = cls(url)
    try:
        ok = port.setBaudRate(baud)  # opens the port (once: a dxlsim URL builds a new bus)
    except Exception as exc:  # pyserial's SerialException, OSError, ValueError
        raise BenchError(f"cannot open {url}: {exc}") from exc
    if not ok:
        raise BenchError(f"{url}: dynamixel-sdk does not support {baud} bps")
    return BenchBus(port, sdk.PacketHandler(2.0), url, baud)
