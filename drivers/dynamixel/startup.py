"""Start-up expectations and findings, as data: what the rig expects of each servo
(:class:`Expectation`), what :meth:`~drivers.dynamixel.bus.DynamixelBus.check` found
(:class:`ServoState`, :class:`StartupReport`), and how the bus reads (:class:`ReadMode`).

Imports neither ``dynamixel_sdk`` nor the bus, so a rig can be turned into expectations
(and a report read) without loading the SDK.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from drivers.protocol2 import control_table as ct
from drivers.protocol2.control_table import OperatingMode, check_unicast_id


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
        shutdown_bits: Hardware Error bits the servo's Shutdown mask (addr 63) must include,
            so it cuts its own torque on them (default the factory's: overheating,
            electrical shock, overload); 0: not checked.
    """

    id: int
    model: str | None = None
    operating_mode: OperatingMode = OperatingMode.POSITION
    position_range_rad: tuple[float, float] | None = None
    return_delay_us_max: float = 0.0
    allow_torque_on: bool = True
    shutdown_bits: int = int(
        ct.HardwareError.OVERHEATING | ct.HardwareError.ELECTRICAL_SHOCK | ct.HardwareError.OVERLOAD
    )

    def __post_init__(self) -> None:
        check_unicast_id(self.id)
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
