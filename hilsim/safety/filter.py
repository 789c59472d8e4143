"""Safety: the one place between the simulation and the wire.

Every tick the loop passes the simulated joint positions through :meth:`SafetyFilter.filter`;
only its output becomes servo ticks. Per tick, in order:

1. **Finite**: a NaN or ±inf anywhere makes every joint hold (a fatal :class:`SafetyEvent`).
2. **Position**: clamp to ``[lower, upper]``; during soft start, blend from the start pose.
3. **Speed**: a step of at most ``max_speed·dt``.
4. **Acceleration**: a step changes by at most ``max_accel·dt²``.
5. **Brake**: towards a limit, a step from which the joint can still stop on it.
6. Clamp to ``[lower, upper]`` again.

A joint found outside its limits is walked back in, never clamped in one jump. Within every
limit (after the soft start) the output is the input, bit for bit. The per-tick path uses
Python lists, not numpy: cheaper for a few joints.

The steps, how they interact and the guarantees: ``docs/safety.md``. The parameters, events and
counters are in :mod:`hilsim.safety.limits`, re-exported here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from drivers.fill import Packed
from hilsim._types import FloatArray
from hilsim.safety.limits import (
    COUNTER_KINDS,
    SafetyCounters,
    SafetyEvent,
    SafetyFault,
    SafetyParams,
)

__all__ = ["SafetyFilter"]


def _brake_step(room: float, a: float) -> float:
    """Largest step Δ ≥ 0 such that the steps Δ, Δ − a, Δ − 2a, … (down to 0) travel ≤ room.

    With m = ⌊Δ/a⌋ those steps travel (m + 1)·Δ − a·m(m + 1)/2, piecewise linear and increasing
    in Δ; this inverts it. ``a`` is max_accel·dt² (the most a step may shrink per tick).
    A room ≤ 0 (at the limit, or beyond it: a joint walking back in) allows no step towards the
    limit; a room too large to compute with bounds nothing.
    """
    if room <= 0.0:
        return 0.0
    r = 8.0 * room / a
    if r > 1e300:
        return math.inf
    m = math.floor((math.sqrt(1.0 + r) - 1.0) * 0.5)
    return room / (m + 1) + 0.5 * a * m


class SafetyFilter:
    """Position, speed and acceleration limits, soft start and NaN hold for one bus's joints.

    Args: as :class:`SafetyParams` (arrays shaped ``(n,)``; speed and acceleration may be numbers).

    Use::

        safety = SafetyFilter(lower, upper, max_speed, max_accel, dt_s=0.002, soft_start_s=1.0)
        safety.start(present)                    # the pose read from the servos, rad, (n,)
        every tick:
            event = safety.filter(x, cmd)        # x: simulated positions; cmd: preallocated (n,)
            if event is not None: log it; stop if event.fatal

    Raises:
        ValueError: invalid parameters (names the joint and the parameter).
    """

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
        p = SafetyParams(
            lower_rad, upper_rad, max_speed_rad_s, max_accel_rad_s2, dt_s, soft_start_s, joint_names
        )
        self.params = p
        self.n_joints = n = p.n_joints
        dt = p.dt_s
        # per-tick limits as Python floats, for the list-based hot path
        self._lo: list[float] = p.lower_rad.tolist()
        self._hi: list[float] = p.upper_rad.tolist()
        # a step longer than the whole range is never taken: capping it keeps the arithmetic finite
        self._vmax: list[float] = np.minimum(
            p.max_speed_rad_s * dt, p.upper_rad - p.lower_rad
        ).tolist()
        self._amax: list[float] = (p.max_accel_rad_s2 * dt * dt).tolist()
        # braking distance from a full-speed step: farther from a limit, the brake bound is idle
        # ((m + 1)·(v − a·m/2) has no cancellation; inf, if it overflows, only means "always check")
        self._dstop: list[float] = []
        for v, a in zip(self._vmax, self._amax, strict=True):
            m = float(math.floor(v / a))
            self._dstop.append((m + 1.0) * (v - 0.5 * a * m))
        self._ramp_ticks = math.ceil(p.soft_start_s / dt - 1e-9) if p.soft_start_s > 0 else 0
        self._p: list[float] | None = None  # last output (rad)
        self._p0: list[float] = [0.0] * n  # soft-start pose
        self._dp: list[float] = [0.0] * n  # last step (rad per tick)
        self._tick = 0
        self._faults = 0
        self._count: dict[str, list[int]] = {}
        self._reset_counters()
        self._desired = self._out = Packed()  # views of the caller's arrays (drivers.fill)

    def _reset_counters(self) -> None:
        n = self.n_joints
        self._count = {k: [0] * n for k in COUNTER_KINDS}

    # -- public -----------------------------------------------------------------------------------

    def start(self, present_rad: npt.ArrayLike) -> SafetyEvent | None:
        """Begin (or restart) from the pose read from the servos; resets the counters.

        Args:
            present_rad: present joint positions (rad), shape ``(n,)``, finite.

        Returns:
            None, or a non-fatal :class:`SafetyEvent` naming the joints outside their limits and
            their present positions: the filter starts from that pose as it is and walks those
            joints back in, through the soft start and within the speed and acceleration limits
            (``docs/safety.md``).

        Raises:
            ValueError: wrong shape, or a non-finite position (names the joints): the filter cannot
                soft-start from an unknown pose.
        """
        x = np.asarray(present_rad, dtype=np.float64)
        names = self.params.joint_names
        if x.shape != (self.n_joints,):
            raise ValueError(f"present_rad must be shaped ({self.n_joints},), got {x.shape}")
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            which = ", ".join(f"{names[i]} ({float(x[i])!r})" for i in bad)
            raise ValueError(f"cannot soft-start: no finite present position for {which}")
        pose = np.clip(x, self.params.lower_rad, self.params.upper_rad)
        self._p = x.tolist()  # as it is: a joint outside its limits is walked back in
        self._p0 = x.tolist()  # and the soft start blends from there
        self._dp = [0.0] * self.n_joints
        self._tick = 0
        self._faults = 0
        self._reset_counters()
        outside = np.flatnonzero(pose != x)
        if not outside.size:
            return None
        return SafetyEvent(
            SafetyFault.START_OUTSIDE_LIMITS,
            -1,
            tuple(names[i] for i in outside),
            tuple(float(x[i]) for i in outside),
            fatal=False,
        )

    # long on purpose: hot path: one pass over the joints, every limit in order
    def filter(self, desired_rad: FloatArray, out: FloatArray) -> SafetyEvent | None:  # noqa: C901, PLR0912, PLR0915
        """Make one tick's desired positions safe; write them into ``out``.

        Args:
            desired_rad: desired joint positions (rad), float ndarray shaped ``(n,)``; any values.
            out: preallocated float64 array shaped ``(n,)``, written in full (may be
                ``desired_rad`` itself).

        Returns:
            None, or a fatal :class:`SafetyEvent` when the desired positions were not all finite
            (the output then holds every joint; see the module docstring).

        Raises:
            RuntimeError: :meth:`start` was not called.
        """
        p = self._p
        if p is None:
            raise RuntimeError("SafetyFilter.start(present) must be called before filter()")
        n = self.n_joints
        view = self._desired
        if view.arr is not desired_rad:  # the caller's array, viewed once (drivers.fill)
            view = self._desired = Packed(desired_rad)
        d = view.tolist()
        if len(d) != n:
            raise ValueError(f"desired_rad must be shaped ({n},), got {np.shape(desired_rad)}")
        event = None
        total = sum(d)
        if total - total != 0.0:  # a NaN or inf somewhere, or merely a finite sum that overflowed
            event = self._nonfinite(d)
            if event is not None:
                d = p.copy()
        k = self._tick
        self._tick = k + 1
        blend = -1.0
        if k < self._ramp_ticks and event is None:
            u = k / self._ramp_ticks
            blend = u * u * (3.0 - 2.0 * u)
        lower, upper, vmax, amax, dstop, p0, dp = (
            self._lo,
            self._hi,
            self._vmax,
            self._amax,
            self._dstop,
            self._p0,
            self._dp,
        )
        c = self._count
        n_pos, n_speed, n_brake, n_accel = c["position"], c["speed"], c["brake"], c["accel"]
        n_out = c["outside"]
        for j in range(n):
            lo, hi, pj, x = lower[j], upper[j], p[j], d[j]
            if x > hi:
                x = hi
                n_pos[j] += 1
            elif x < lo:
                x = lo
                n_pos[j] += 1
            if blend >= 0.0:
                x = p0[j] + blend * (x - p0[j])
            e = x - pj
            v, a = vmax[j], amax[j]
            step = e
            if step > v:
                step = v
                n_speed[j] += 1
            elif step < -v:
                step = -v
                n_speed[j] += 1
            prev = dp[j]
            if step > prev + a:
                step = prev + a
                n_accel[j] += 1
            elif step < prev - a:
                step = prev - a
                n_accel[j] += 1
            # brake last, from the actual distance left: it then absorbs each tick's rounding
            # instead of letting it pile up over a long braking run (a room < 0, beyond the
            # limit, bounds the step to 0: a joint walking back in never steps further out)
            if step > 0.0:
                room = hi - pj
                if room < dstop[j]:
                    bound = _brake_step(room, a)
                    if step > bound:
                        step = bound
                        n_brake[j] += 1
            elif step < 0.0:
                room = pj - lo
                if room < dstop[j]:
                    bound = -_brake_step(room, a)
                    if step < bound:
                        step = bound
                        n_brake[j] += 1
            q = x if step == e else pj + step  # untouched: pass the input through bit for bit
            # the last word; only rounding gets this far, so it is not counted. A joint that was
            # beyond a limit (walking back in, never outwards) may still be beyond it
            if q > hi:
                if pj > hi:
                    n_out[j] += 1
                else:
                    q = hi
            elif q < lo:
                if pj < lo:
                    n_out[j] += 1
                else:
                    q = lo
            dp[j] = q - pj
            p[j] = q
        view = self._out
        if view.arr is not out:
            view = self._out = Packed(out, n)
        view.put(*p)
        return event

    def rejoin(self, joint: int, position_rad: float) -> None:
        """Continue joint ``joint`` from ``position_rad``, at rest: a servo that stopped by
        itself (a tripped Bus Watchdog) rejoins the show from where it is, within the speed and
        acceleration limits, instead of jumping to where its command had got to.

        Raises ValueError for a non-finite position; RuntimeError before :meth:`start`.
        """
        if self._p is None:
            raise RuntimeError("SafetyFilter.start(present) must be called before rejoin()")
        if not math.isfinite(position_rad):
            raise ValueError(
                f"cannot rejoin {self.params.joint_names[joint]} from {position_rad!r}"
            )
        self._p[joint] = float(position_rad)
        self._dp[joint] = 0.0
        self._p0[joint] = float(position_rad)  # as start(): a soft start blends from here

    @property
    def started(self) -> bool:
        return self._p is not None

    @property
    def counters(self) -> SafetyCounters:
        """A snapshot of the limit counters since :meth:`start` (allocates; not for every tick)."""
        c = self._count
        return SafetyCounters(
            self.params.joint_names,
            self._tick,
            self._faults,
            **{k: np.array(v, dtype=np.int64) for k, v in c.items()},
        )

    # -- private ----------------------------------------------------------------------------------

    def _nonfinite(self, d: list[float]) -> SafetyEvent | None:
        bad = [j for j, x in enumerate(d) if not math.isfinite(x)]
        if not bad:
            return None
        self._faults += 1
        count = self._count["nonfinite"]
        for j in bad:
            count[j] += 1
        names = self.params.joint_names
        return SafetyEvent(
            SafetyFault.NONFINITE,
            self._tick,
            tuple(names[j] for j in bad),
            tuple(float(d[j]) for j in bad),
            fatal=True,
        )

    def __repr__(self) -> str:
        return f"SafetyFilter(n={self.n_joints}, dt={self.params.dt_s}, started={self.started})"
