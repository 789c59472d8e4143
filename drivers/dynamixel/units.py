"""Servo units <-> SI, for the X series. Radians inside the program, ticks only on the wire.

Position: 4096 ticks (pulses) per revolution, tick 2048 is 0 rad, so in Position Control
Mode ticks 0..4095 span [-π, π). The same formula holds in Extended Position mode
(multi-turn, ±1,048,575 ticks ≈ ±256 rev): no wrapping anywhere here.
Velocity: 1 unit = 0.229 rev/min ≈ 0.023981 rad/s.

Functions accept floats or arrays and return the same kind; rounding is to the nearest
tick (halves to even, like :func:`numpy.rint`); nothing is clipped unless the caller
passes bounds. Pure numpy, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from drivers.protocol2.control_table import EXTENDED_GOAL_LIMIT, OperatingMode

TICKS_PER_REV = 4096
#: The tick that is 0 rad.
CENTER_TICK = 2048
RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_REV
TICKS_PER_RAD = TICKS_PER_REV / (2.0 * math.pi)
#: Present/Goal/Profile Velocity unit, rev/min, and the same in rad/s.
VELOCITY_UNIT_RPM = 0.229
RAD_S_PER_VELOCITY_UNIT = VELOCITY_UNIT_RPM * 2.0 * math.pi / 60.0

#: what the functions below take as "an array" for their overloads (a scalar: a float)
_Array = NDArray[np.generic] | Sequence[float]


@overload
def rad_to_ticks(rad: float, *, lo: int | None = None, hi: int | None = None) -> int: ...
@overload
def rad_to_ticks(
    rad: _Array, *, lo: int | ArrayLike | None = None, hi: int | ArrayLike | None = None
) -> NDArray[np.int64]: ...
@overload
def rad_to_ticks(
    rad: ArrayLike, *, lo: int | ArrayLike | None = None, hi: int | ArrayLike | None = None
) -> NDArray[np.int64] | int: ...


def rad_to_ticks(
    rad: ArrayLike, *, lo: int | ArrayLike | None = None, hi: int | ArrayLike | None = None
) -> NDArray[np.int64] | int:
    """Radians (servo frame) -> nearest tick. Clipped to ``[lo, hi]`` ticks only if given.

    Non-finite input raises ValueError (a NaN must never become a position).
    A scalar gives an ``int``, an array an ``int64`` array of the same shape.
    """
    x = np.asarray(rad, dtype=np.float64)
    if not np.isfinite(x).all():
        raise ValueError(f"cannot convert non-finite angle(s) to ticks: {rad!r}")
    t = np.rint(x * TICKS_PER_RAD) + CENTER_TICK
    if lo is not None or hi is not None:
        t = np.clip(t, lo, hi)
    out = t.astype(np.int64)
    return int(out) if out.ndim == 0 else out


def decode_position(raw: int) -> int:
    """A position register as it comes off the wire (4 bytes little-endian, read as an
    unsigned int: what the SDK's ``getData``/``read4ByteTxRx`` return) -> signed ticks
    (two's complement: Goal and Present Position are signed 32-bit)."""
    return raw - 0x1_0000_0000 if raw & 0x8000_0000 else raw


@overload
def ticks_to_rad(ticks: float) -> float: ...
@overload
def ticks_to_rad(ticks: _Array) -> NDArray[np.float64]: ...
@overload
def ticks_to_rad(ticks: ArrayLike) -> NDArray[np.float64] | float: ...
def ticks_to_rad(ticks: ArrayLike) -> NDArray[np.float64] | float:
    """Ticks -> radians (servo frame). Scalar in, float out."""
    x = (np.asarray(ticks, dtype=np.float64) - CENTER_TICK) * RAD_PER_TICK
    return float(x) if x.ndim == 0 else x


@overload
def velocity_to_rad_s(units: float) -> float: ...
@overload
def velocity_to_rad_s(units: _Array) -> NDArray[np.float64]: ...
@overload
def velocity_to_rad_s(units: ArrayLike) -> NDArray[np.float64] | float: ...
def velocity_to_rad_s(units: ArrayLike) -> NDArray[np.float64] | float:
    """Velocity units (0.229 rev/min) -> rad/s."""
    x = np.asarray(units, dtype=np.float64) * RAD_S_PER_VELOCITY_UNIT
    return float(x) if x.ndim == 0 else x


@overload
def rad_s_to_velocity(rad_s: float) -> int: ...
@overload
def rad_s_to_velocity(rad_s: _Array) -> NDArray[np.int64]: ...
@overload
def rad_s_to_velocity(rad_s: ArrayLike) -> NDArray[np.int64] | int: ...
def rad_s_to_velocity(rad_s: ArrayLike) -> NDArray[np.int64] | int:
    """rad/s -> nearest velocity unit (0.229 rev/min). Non-finite input raises ValueError."""
    x = np.asarray(rad_s, dtype=np.float64)
    if not np.isfinite(x).all():
        raise ValueError(f"cannot convert non-finite velocity: {rad_s!r}")
    out = np.rint(x / RAD_S_PER_VELOCITY_UNIT).astype(np.int64)
    return int(out) if out.ndim == 0 else out


def goal_tick_range(
    mode: OperatingMode | int, min_limit: int = 0, max_limit: int = TICKS_PER_REV - 1
) -> tuple[int, int]:
    """Goal Position ticks a servo accepts in ``mode``.

    Position Control Mode (3) is bounded by Min/Max Position Limit (addr 52/48);
    Extended and Current-based Position (4, 5) by ±1,048,575. Other modes ignore
    Goal Position: ValueError.
    """
    mode = OperatingMode(mode)
    if mode is OperatingMode.POSITION:
        return int(min_limit), int(max_limit)
    if mode in (OperatingMode.EXTENDED_POSITION, OperatingMode.CURRENT_BASED_POSITION):
        return -EXTENDED_GOAL_LIMIT, EXTENDED_GOAL_LIMIT
    raise ValueError(f"{mode.name} mode does not follow Goal Position")


@overload
def fold_ticks(ticks: int) -> int: ...
@overload
def fold_ticks(ticks: NDArray[np.generic] | Sequence[int]) -> NDArray[np.int64]: ...
@overload
def fold_ticks(ticks: ArrayLike) -> NDArray[np.int64] | int: ...
def fold_ticks(ticks: ArrayLike) -> NDArray[np.int64] | int:
    """Fold multi-turn ticks into one turn 0..4095 (what Position mode reports after a
    switch from Extended mode, a Reboot or torque on)."""
    out = np.mod(np.asarray(ticks, dtype=np.int64), TICKS_PER_REV)
    return int(out) if out.ndim == 0 else out
