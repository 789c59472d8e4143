"""A bus opened for measurement: our PortHandler, the unmodified dynamixel-sdk, a few reads.

The bench (hilsim/bench) times dynamixel-sdk's group objects through this module
(``GroupSyncWrite.txPacket``, ``GroupSyncRead.txRxPacket`` / ``fastSyncRead``): the point is
to time exactly what the SDK does. Everything SDK-shaped stays in this module; the others
get bound methods and plain numbers.

Ports: a device path, a pty, or ``dxlsim://``, opened as given (the bench chooses an
emulator's clock in :mod:`hilsim.bench.ports`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Self

import dynamixel_sdk as sdk

from drivers.clock import Clock
from drivers.dynamixel.port import SDK_LATENCY_TIMER_MS, PortHandler
from drivers.dynamixel.sdk_result import OK
from drivers.dynamixel.units import decode_position
from drivers.protocol2 import control_table as ct
from drivers.protocol2.control_table import Item

if TYPE_CHECKING:
    from drivers.dxlsim.bus import DxlBus

#: Addresses :mod:`hilsim.bench` passes to :meth:`BenchBus.read` / :meth:`BenchBus.write1`
#: (the control table's items; :meth:`BenchBus.read_item` takes the items themselves).
ADDR_RETURN_DELAY = ct.RETURN_DELAY_TIME.addr
ADDR_TORQUE = ct.TORQUE_ENABLE.addr


class BenchError(RuntimeError):
    """The bus cannot be measured (cannot open, nobody answers, ...); the message says why."""


class StampedPortHandler(PortHandler):
    """Our PortHandler that notes the clock time of every ``writePort`` (``write_times``)."""

    def __init__(
        self,
        port_name: str,
        *,
        clock: Clock | None = None,
        latency_timer_ms: float = SDK_LATENCY_TIMER_MS,
        device_allowance_ms: float = 0.0,
    ) -> None:
        super().__init__(
            port_name,
            clock=clock,
            latency_timer_ms=latency_timer_ms,
            device_allowance_ms=device_allowance_ms,
        )
        self.write_times: list[float] = []

    def writePort(self, packet: bytes | bytearray | memoryview | list[int]) -> int:
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
    def bus(self) -> DxlBus | None:
        bus: DxlBus | None = getattr(self.port.ser, "bus", None)  # a dxlsim:// port's
        return bus

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

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
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

    def read_item(self, servo_id: int, item: Item) -> int | None:
        """Value of control-table ``item`` (signed where the item is), or None."""
        value = self.read(servo_id, item.addr, item.size)
        return None if value is None else item.decode(item.encode(value), item.addr)

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
        result: int
        err: int
        result, err = self.ph.write1ByteTxRx(self.port, servo_id, addr, value)
        return result == OK and err == 0

    # -- the group objects the cycle uses ---------------------------------------------------
    def goal_writer(self, goals: dict[int, int]) -> sdk.GroupSyncWrite:
        """A GroupSyncWrite of Goal Position (4 B) holding ``goals`` (ticks by ID)."""
        item = ct.GOAL_POSITION
        writer = sdk.GroupSyncWrite(self.port, self.ph, item.addr, item.size)
        for servo_id, goal in goals.items():
            writer.addParam(servo_id, goal_bytes(goal))
        return writer

    def position_reader(self, ids: Sequence[int], block_at: int | None = None) -> sdk.GroupSyncRead:
        """A GroupSyncRead of Present Position (4 B) from ``ids``, in that order; or, with
        ``block_at`` (Indirect Data 1's address), of the tick block hilsim's tick reads
        (``ct.TICK_BLOCK_SIZE`` bytes: :mod:`drivers.dynamixel.tick_block`)."""
        item = ct.PRESENT_POSITION
        addr, size = (item.addr, item.size) if block_at is None else (block_at, ct.TICK_BLOCK_SIZE)
        reader = sdk.GroupSyncRead(self.port, self.ph, addr, size)
        for servo_id in ids:
            reader.addParam(servo_id)
        return reader

    def read_positions(self, ids: Sequence[int]) -> dict[int, int]:
        """Present Position of every servo by one plain Sync Read; BenchError if it fails."""
        return self._sync_read(ids, ct.PRESENT_POSITION)

    def read_goals(self, ids: Sequence[int]) -> dict[int, int]:
        """Goal Position registers (ticks): writing them back changes nothing on the servos."""
        return self._sync_read(ids, ct.GOAL_POSITION)

    def _sync_read(self, ids: Sequence[int], item: Item) -> dict[int, int]:
        """``item`` (a 4-byte position) of every servo in ``ids`` by one plain Sync Read."""
        addr, size = item.addr, item.size
        reader = sdk.GroupSyncRead(self.port, self.ph, addr, size)
        for servo_id in ids:
            reader.addParam(servo_id)
        result = reader.txRxPacket()
        if result != OK:
            raise BenchError(
                f"{self.url}: Sync Read of {item.name} from IDs {list(ids)} failed: "
                f"{self.ph.getTxRxResult(result)}"
            )
        return {i: decode_position(reader.getData(i, addr, size)) for i in ids}


def goal_bytes(goal: int) -> list[int]:
    """Goal Position ticks as the 4 little-endian bytes GroupSyncWrite wants."""
    return list(int(goal).to_bytes(4, "little", signed=True))


def position(reader: sdk.GroupSyncRead, servo_id: int) -> int:
    """Signed Present Position (ticks) of ``servo_id`` from the reader's last result."""
    item = ct.PRESENT_POSITION
    return decode_position(reader.getData(servo_id, item.addr, item.size))


def open_bus(url: str, baud: int, *, stamped: bool = False) -> BenchBus:
    """Open ``url`` at ``baud`` through our PortHandler; ``stamped`` records write times."""
    cls = StampedPortHandler if stamped else PortHandler
    port = cls(url)
    try:
        ok = port.setBaudRate(baud)  # opens the port (once: a dxlsim URL builds a new bus)
    except Exception as exc:  # pyserial's SerialException, OSError, ValueError
        raise BenchError(f"cannot open {url}: {exc}") from exc
    if not ok:
        raise BenchError(f"{url}: dynamixel-sdk does not support {baud} bps")
    return BenchBus(port, sdk.PacketHandler(2.0), url, baud)
