"""The joint ↔ servo map, in one place.

A joint's angle x (rad, the animation's frame: 0 at the joint's home, positive as the rig's
``direction`` says) and its servo's angle (rad, the servo's frame: 0 at encoder position 0,
as the driver reads and writes it) are related by::

    servo = home + direction · x          x = (servo − home) · direction

with ``direction`` = ±1 (a joint whose servo is mounted mirrored). Because direction is ±1 it
is its own inverse; a gear ratio would not be, which is why every conversion goes through
this class (and why it refuses anything else). The operation order is fixed — ``x·d + home``
and ``(s − home)·d`` — so results are bit-for-bit what the loop has always sent.
"""

from __future__ import annotations

from collections.abc import Sequence
from operator import add, mul, sub
from typing import Protocol

import numpy as np

from hilsim._types import FloatArray


class Mounted(Protocol):
    """What :meth:`JointMap.of` reads of a joint (a rig's :class:`~hilsim.rig.JointConfig`)."""

    @property
    def home_rad(self) -> float: ...
    @property
    def direction(self) -> int: ...


class JointMap:
    """Per-joint ``home`` (rad, servo frame) and ``direction`` (±1), in joint order."""

    __slots__ = ("_direction_l", "_home_l", "direction", "home")

    def __init__(self, home: Sequence[float], direction: Sequence[float]) -> None:
        self.home = np.array(home, dtype=np.float64)
        self.direction = np.array(direction, dtype=np.float64)
        if self.home.ndim != 1 or self.home.shape != self.direction.shape or not self.home.size:
            raise ValueError(
                f"home and direction must be 1-D and of one length, got {self.home.shape} "
                f"and {self.direction.shape}"
            )
        if not np.isfinite(self.home).all():
            raise ValueError(f"home must be finite, got {self.home.tolist()}")
        if not np.isin(self.direction, (-1.0, 1.0)).all():
            raise ValueError(f"direction must be +1 or -1, got {self.direction.tolist()}")
        self.home.flags.writeable = False
        self.direction.flags.writeable = False
        self._home_l: list[float] = self.home.tolist()
        self._direction_l: list[float] = self.direction.tolist()

    @classmethod
    def of(cls, joints: Sequence[Mounted]) -> JointMap:
        """From rig joints (anything with ``home_rad`` and ``direction``)."""
        return cls([j.home_rad for j in joints], [float(j.direction) for j in joints])

    def __len__(self) -> int:
        return int(self.home.size)

    def to_servo(self, x: FloatArray, out: FloatArray) -> FloatArray:
        """Joint angles → servo angles, into ``out`` (no allocation; the tick's path)."""
        np.multiply(x, self.direction, out=out)
        out += self.home
        return out

    def to_joint(self, servo: FloatArray, out: FloatArray) -> FloatArray:
        """Servo angles → joint angles, into ``out`` (NaN stays NaN: no reading)."""
        np.subtract(servo, self.home, out=out)
        out *= self.direction
        return out

    def to_servo_list(self, x: Sequence[float]) -> list[float]:
        """:meth:`to_servo` on Python floats: the same operations, so the same bits, without
        numpy's per-call cost (the tick's path for a few joints)."""
        d, h = self._direction_l, self._home_l
        if len(x) != len(h):
            raise ValueError(f"{len(x)} joint angles for {len(h)} joints")
        return list(map(add, map(mul, x, d), h))  # x·d + h, element by element in C

    def to_joint_list(self, servo: Sequence[float]) -> list[float]:
        """:meth:`to_joint` on Python floats (NaN stays NaN)."""
        d, h = self._direction_l, self._home_l
        if len(servo) != len(h):
            raise ValueError(f"{len(servo)} servo angles for {len(h)} joints")
        return list(map(mul, map(sub, servo, h), d))  # (s − h)·d

    def joint_angle(self, i: int, servo_rad: float) -> float:
        """One joint's angle from its servo's angle."""
        return (servo_rad - float(self.home[i])) * float(self.direction[i])

    def servo_angle(self, i: int, x_rad: float) -> float:
        """One servo's angle from its joint's angle."""
        return float(self.home[i]) + float(self.direction[i]) * x_rad

    def servo_range(self, i: int, lo_rad: float, hi_rad: float) -> tuple[float, float]:
        """The servo-frame interval a joint-frame interval [lo, hi] maps to (ends sorted)."""
        a, b = self.servo_angle(i, lo_rad), self.servo_angle(i, hi_rad)
        return (a, b) if a <= b else (b, a)
