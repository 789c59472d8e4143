"""The safety filter's data: the parameters it validates, the events and counters it reports.

The filter itself, the per-tick hot path, is :mod:`hilsim.safety.filter`. The package
:mod:`hilsim.safety` exports every name here; import them from there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
import numpy.typing as npt

from hilsim._types import FloatArray, IntArray

#: the rig's default soft start (s): a ramp from where the figure is to where the show starts
DEFAULT_SOFT_START_S = 1.0


class SafetyFault(StrEnum):
    NONFINITE = "nonfinite_desired"  # NaN or inf in the desired positions: all joints hold
    START_OUTSIDE_LIMITS = "start_outside_limits"  # starts outside its limits, walked back in


@dataclass(frozen=True)
class SafetyEvent:
    """Something the loop should log; ``fatal`` says whether it should stop the show.

    ``joints`` names the joints concerned and ``values`` gives their offending positions (rad);
    ``tick`` counts :meth:`~hilsim.safety.filter.SafetyFilter.filter` calls since
    :meth:`~hilsim.safety.filter.SafetyFilter.start` (−1: start).
    """

    kind: SafetyFault
    tick: int
    joints: tuple[str, ...]
    values: tuple[float, ...]
    fatal: bool

    def __str__(self) -> str:
        which = ", ".join(f"{n} ({v!r} rad)" for n, v in zip(self.joints, self.values, strict=True))
        if self.kind is SafetyFault.NONFINITE:
            return f"tick {self.tick}: non-finite desired position for {which}; all joints hold"
        return (
            f"start pose outside the limits for {which}; walked back in at the speed and "
            "acceleration limits"
        )


#: the kinds of :class:`SafetyCounters`, in the order summaries list them
COUNTER_KINDS = ("position", "speed", "accel", "brake", "nonfinite", "outside")


@dataclass(frozen=True)
class SafetyCounters:
    """How often each limit acted, per joint (int arrays shaped ``(n,)``), since start.

    ``position``: the desired position was outside the limits; ``speed``: the speed limit shortened
    the step; ``accel``: the acceleration limit changed it; ``brake``: the brake bound near a
    position limit shortened it; ``nonfinite``: the desired value was NaN or inf; ``outside``: the
    output itself was outside the limits (a start outside them, walking back in). One tick may
    count under several limits.
    ``ticks`` counts filter calls, ``fault_ticks`` those that held every joint.
    """

    joint_names: tuple[str, ...]
    ticks: int
    fault_ticks: int
    position: IntArray
    speed: IntArray
    brake: IntArray
    accel: IntArray
    nonfinite: IntArray
    outside: IntArray

    def by_kind(self) -> dict[str, dict[str, int]]:
        """Plain ints, kind (:data:`COUNTER_KINDS`) -> joint name -> count, every joint listed."""
        return {
            kind: dict(zip(self.joint_names, getattr(self, kind).tolist(), strict=True))
            for kind in COUNTER_KINDS
        }

    def as_dict(self) -> dict[str, object]:
        """Plain ints keyed by limit and joint name, with ``ticks`` and ``fault_ticks``."""
        return {"ticks": self.ticks, "fault_ticks": self.fault_ticks, **self.by_kind()}


def _array(name: str, value: npt.ArrayLike, n: int | None) -> FloatArray:
    arr = np.asarray(value, dtype=np.float64)
    if n is not None and arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.ndim != 1 or arr.size == 0 or (n is not None and arr.shape != (n,)):
        want = "a non-empty 1-D array" if n is None else f"a number or an array shaped ({n},)"
        raise ValueError(f"{name} must be {want}, got shape {arr.shape}")
    arr = arr.copy()
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True, eq=False, init=False)
class SafetyParams:
    """Validated safety parameters; arrays are read-only float64 shaped ``(n,)``.

    Args:
        lower_rad, upper_rad: position limits (rad), finite, lower < upper for every joint.
        max_speed_rad_s: speed limit (rad/s), finite, > 0; a number applies to every joint.
        max_accel_rad_s2: acceleration limit (rad/s²), finite, > 0; a number applies to every joint.
        dt_s: the tick period (s), > 0.
        soft_start_s: duration of the soft start (s), ≥ 0 (0: none).
        joint_names: for messages; default ``joint0``, ``joint1``, …
    """

    lower_rad: FloatArray
    upper_rad: FloatArray
    max_speed_rad_s: FloatArray
    max_accel_rad_s2: FloatArray
    dt_s: float
    soft_start_s: float
    joint_names: tuple[str, ...]

    def __init__(
        self,
        lower_rad: npt.ArrayLike,
        upper_rad: npt.ArrayLike,
        max_speed_rad_s: npt.ArrayLike,
        max_accel_rad_s2: npt.ArrayLike,
        dt_s: float,
        soft_start_s: float = 1.0,
        joint_names: Sequence[str] | None = None,
    ) -> None:
        # written out (not generated) so the fields are typed as what they hold after it
        lower = _array("lower_rad", lower_rad, None)
        n = lower.size
        upper = _array("upper_rad", upper_rad, n)
        speed = _array("max_speed_rad_s", max_speed_rad_s, n)
        accel = _array("max_accel_rad_s2", max_accel_rad_s2, n)
        names = tuple(f"joint{i}" for i in range(n)) if joint_names is None else joint_names
        names = tuple(str(s) for s in names)
        if len(names) != n:
            raise ValueError(f"{len(names)} joint_names for {n} joints")
        dt, soft = float(dt_s), float(soft_start_s)
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt_s must be finite and > 0, got {dt_s!r}")
        if not (math.isfinite(soft) and soft >= 0.0):
            raise ValueError(f"soft_start_s must be finite and >= 0, got {soft_start_s!r}")
        for name, lo, hi, v, a in zip(
            names, lower.tolist(), upper.tolist(), speed.tolist(), accel.tolist(), strict=True
        ):
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(
                    f"{name}: need finite limits with lower < upper, got {lo!r}..{hi!r}"
                )
            for what, x in (("max_speed_rad_s", v), ("max_accel_rad_s2", a)):
                if not (math.isfinite(x) and x > 0.0):
                    raise ValueError(f"{name}: {what} must be finite and > 0, got {x!r}")
            # the per-tick quantities must be usable floats, not 0 or inf
            if not (
                v * dt > 0.0
                and a * dt * dt > 0.0
                and math.isfinite(8.0 * (hi - lo) / (a * dt * dt))
            ):
                raise ValueError(
                    f"{name}: max_speed·dt or max_accel·dt² is too small to compute with "
                    f"(speed {v!r}, accel {a!r}, dt {dt!r})"
                )
        for name, value in (
            ("lower_rad", lower),
            ("upper_rad", upper),
            ("max_speed_rad_s", speed),
            ("max_accel_rad_s2", accel),
            ("dt_s", dt),
            ("soft_start_s", soft),
            ("joint_names", names),
        ):
            object.__setattr__(self, name, value)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)
