"""Bottango's curves, solved exactly: one :class:`BezierSegment` per ``sC``/``sCI`` command,
and a :class:`BezierTrack` (a :class:`~hilsim.targets.tracks.Track`) through one effector's
segments in one animation. Parsing the exports is :mod:`hilsim.targets.formats.bottango`.

A segment is a cubic Bézier in (time, value), value in Bottango's 0..8192. The firmware
bisects for the curve parameter to 1 ms; here it is solved to rounding (the monotone pieces of
x(u), then safeguarded Newton). Velocity is exact, dy/dt = y'(u)/x'(u).

* A curve whose handles stay within the segment in time is a function of time (the solution
  is unique).
* Otherwise the track takes the first time the curve reaches t, and the value may jump there;
  :attr:`BezierSegment.monotone` says which segments do this.

The value is clamped to 0..8192, as the firmware clamps the signal. The track holds its first
start value before, each end value in a gap, and its last end value after.

The curve, the proof of monotonicity and the edge cases: ``docs/targets.md`` (Bottango curves).
Before the first segment the track holds its ``start_y`` (the registration's start signal);
the driver's speed limit on top is :mod:`.bottango_slew`.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import pairwise

from hilsim.targets.tracks import Track

#: Bottango's full scale: movement = y / Y_MAX (``COMPRESSED_SIGNAL_MAX``)
Y_MAX = 8192.0

_EPS = 2.0**-52


@dataclass(frozen=True)
class BezierSegment:
    """One curve in the file's own units: times in ms from the animation's start, values in
    0..8192 (control values absolute: ``c1y`` is y0 + the command's start control Y).
    ``where`` names the command in its file, for messages (not compared: segments are equal
    when their curves are)."""

    start_ms: float
    dur_ms: float
    y0: float
    c1x: float
    c1y: float
    c2x: float
    c2y: float
    y1: float
    where: str = field(default="", compare=False)
    _pieces: tuple[tuple[float, float, float, float], ...] = field(
        init=False, repr=False, compare=False
    )
    _poly: tuple[float, ...] = field(init=False, repr=False, compare=False)

    @classmethod
    def from_command(
        cls,
        start: int,
        dur: int,
        y0: int,
        c1x: int,
        c1y: int,
        y1: int,
        c2x: int,
        c2y: int,
        where: str = "",
    ) -> BezierSegment:
        """From ``sC``'s fields in their order (control X relative to start/end, control Y
        relative to y0/y1)."""
        return cls(start, dur, y0, c1x, y0 + c1y, dur + c2x, y1 + c2y, y1, where)

    @classmethod
    def instant(cls, at_ms: float, y: float, where: str = "") -> BezierSegment:
        """``sCI``: a jump to ``y`` at ``at_ms`` (a zero-length curve)."""
        return cls(at_ms, 0.0, y, 0.0, y, 0.0, y, y, where)

    def __post_init__(self) -> None:
        a, b, d = float(self.c1x), float(self.c2x), float(self.dur_ms)
        y0, y1, y2, y3 = float(self.y0), float(self.c1y), float(self.c2y), float(self.y1)
        # power form, for the solver: x = ((ax u + bx) u + cx) u, y = ((ay u + by) u + cy) u + y0
        poly = (
            *(3.0 * a - 3.0 * b + d, 3.0 * b - 6.0 * a, 3.0 * a),
            *(y3 - y0 + 3.0 * (y1 - y2), 3.0 * (y2 - 2.0 * y1 + y0), 3.0 * (y1 - y0), y0),
        )
        object.__setattr__(self, "_poly", poly)
        if d <= 0.0:
            object.__setattr__(self, "_pieces", ())
            return
        # x'(u)/3 = (1-u)^2 a + 2(1-u)u (b - a) + u^2 (d - b)  =  p u^2 + q u + r
        p, q, r = a - 2.0 * (b - a) + (d - b), 2.0 * (b - a) - 2.0 * a, a
        cuts = sorted(u for u in quadratic_roots(p, q, r) if 0.0 < u < 1.0)
        knots = [0.0, *cuts, 1.0]
        pieces = [(lo, hi, self._x(lo), self._x(hi)) for lo, hi in pairwise(knots) if hi > lo]
        object.__setattr__(self, "_pieces", tuple(pieces))

    @property
    def end_ms(self) -> float:
        return self.start_ms + self.dur_ms

    @property
    def monotone(self) -> bool:
        """True when time runs forward along the whole curve (x(u) never decreases)."""
        tol = 1e-9 * max(self.dur_ms, abs(self.c1x), abs(self.c2x))
        return all(x1 >= x0 - tol for _, _, x0, x1 in self._pieces)

    # ------------------------------------------------------------------ the polynomials
    def _x(self, u: float) -> float:
        v = 1.0 - u
        return 3.0 * v * v * u * self.c1x + 3.0 * v * u * u * self.c2x + u * u * u * self.dur_ms

    def _dx(self, u: float) -> float:
        v = 1.0 - u
        a, b, d = self.c1x, self.c2x, self.dur_ms
        return 3.0 * (v * v * a + 2.0 * v * u * (b - a) + u * u * (d - b))

    def _y(self, u: float) -> float:
        v = 1.0 - u
        return (
            v * v * v * self.y0
            + 3.0 * v * v * u * self.c1y
            + 3.0 * v * u * u * self.c2y
            + u * u * u * self.y1
        )

    def _dy(self, u: float) -> float:
        v = 1.0 - u
        return 3.0 * (
            v * v * (self.c1y - self.y0)
            + 2.0 * v * u * (self.c2y - self.c1y)
            + u * u * (self.y1 - self.c2y)
        )

    def solve_u(self, x: float) -> float:
        """The smallest u in [0, 1] with x(u) = x (x in ms from the segment's start, clamped
        to [0, dur]); to rounding."""
        d = self.dur_ms
        if d <= 0.0:
            return 1.0
        x = min(max(x, 0.0), d)
        for lo, hi, x_lo, x_hi in self._pieces:
            if min(x_lo, x_hi) <= x <= max(x_lo, x_hi):
                return self._solve_monotone(x, lo, hi, x_lo, x_hi)
        return 1.0  # unreachable: x(0) = 0, x(1) = d and x is continuous

    def _solve_monotone(self, x: float, lo: float, hi: float, x_lo: float, x_hi: float) -> float:
        """Newton on x(u) = x inside [lo, hi], bisecting when a step would leave the bracket;
        stops when a step is below 1e-15 (Newton's error is then far below rounding) or the
        bracket is a few ulps wide."""
        if x == x_lo:
            return lo
        if x == x_hi:
            return hi
        ax, bx, cx = self._poly[:3]
        rising = x_hi > x_lo
        u = lo + (hi - lo) * (x - x_lo) / (x_hi - x_lo)
        for _ in range(200):
            f = ((ax * u + bx) * u + cx) * u - x
            if f == 0.0:
                return u
            if (f < 0.0) == rising:
                lo = u
            else:
                hi = u
            slope = (3.0 * ax * u + 2.0 * bx) * u + cx
            nxt = u - f / slope if slope != 0.0 else lo - 1.0
            if not lo < nxt < hi:
                nxt = 0.5 * (lo + hi)
            if abs(nxt - u) <= 1e-15 or hi - lo <= 4.0 * _EPS:
                return nxt
            u = nxt
        return u

    def value_rate(self, t_ms: float) -> tuple[float, float]:
        """(y, dy/dt in 1/ms) at ``t_ms`` within the segment (unclamped)."""
        if self.dur_ms <= 0.0:
            return float(self.y1), 0.0
        x = t_ms - self.start_ms
        u = self.solve_u(x)
        ax, bx, cx, ay, by, cy, y0 = self._poly
        y = ((ay * u + by) * u + cy) * u + y0
        dx = (3.0 * ax * u + 2.0 * bx) * u + cx
        dy = (3.0 * ay * u + 2.0 * by) * u + cy
        if abs(dx) > 1e-9 * self.dur_ms:
            return y, dy / dx
        if dy == 0.0:
            return y, 0.0
        h0, h1 = max(x - 0.5, 0.0), min(x + 0.5, self.dur_ms)
        ya, yb = self._y(self.solve_u(h0)), self._y(self.solve_u(h1))
        return y, (yb - ya) / (h1 - h0) if h1 > h0 else 0.0


def quadratic_roots(p: float, q: float, r: float) -> list[float]:
    """Real roots of p u^2 + q u + r (stable form; the linear case when p = 0)."""
    if p == 0.0:
        return [-r / q] if q != 0.0 else []
    disc = q * q - 4.0 * p * r
    if disc < 0.0:
        return []
    s = math.sqrt(disc)
    k = -0.5 * (q + math.copysign(s, q))
    roots = [k / p]
    if k != 0.0:
        roots.append(r / k)
    return roots


class BezierTrack(Track):
    """One effector's segments in one animation as a track in joint radians.

    ``segments`` sorted by start, none starting before the previous one ends (the reader
    checks); ``offset_rad`` and ``rad_per_y`` map Bottango's 0..8192 to joint radians
    (``rad = offset_rad + rad_per_y·y``, from the setup's signal range and the rig's unit map);
    ``start_y`` (0..8192) is held before the first segment, where the driver parks the
    effector at its registered start signal (None: the first segment's start value).
    """

    __slots__ = ("_ends", "_starts", "offset_rad", "rad_per_y", "segments", "source", "start_y")

    def __init__(
        self,
        segments: Sequence[BezierSegment],
        offset_rad: float,
        rad_per_y: float,
        source: str = "",
        start_y: float | None = None,
    ) -> None:
        if not segments:
            raise ValueError(f"{source or 'a Bottango track'}: no curve segments")
        if not (math.isfinite(offset_rad) and math.isfinite(rad_per_y)):
            raise ValueError("offset_rad and rad_per_y must be finite")
        if start_y is not None and not 0.0 <= start_y <= Y_MAX:
            raise ValueError(f"start_y must be in 0..{Y_MAX:g}, got {start_y!r}")
        self.segments = tuple(segments)
        self.offset_rad, self.rad_per_y, self.source = float(offset_rad), float(rad_per_y), source
        #: the value held before the first segment (None: the first segment's start value)
        self.start_y = None if start_y is None else float(start_y)
        self._starts = [s.start_ms for s in self.segments]
        self._ends = [s.end_ms for s in self.segments]
        for i in range(1, len(self.segments)):
            if self._starts[i] < self._ends[i - 1]:
                raise ValueError(f"{source}: segment {i} starts before segment {i - 1} ends")

    def sample_y(self, t: float) -> tuple[float, float]:
        """(y in 0..8192, dy/dt in 1/s) at show time ``t`` (s), clamped as the firmware does."""
        ms = t * 1000.0
        i = bisect_right(self._starts, ms) - 1
        if i < 0:
            y = float(self.segments[0].y0) if self.start_y is None else self.start_y
            rate = 0.0
        elif ms <= self._ends[i]:
            y, rate = self.segments[i].value_rate(ms)
        else:
            y, rate = float(self.segments[i].y1), 0.0
        if y < 0.0 or y > Y_MAX:
            return (0.0 if y < 0.0 else Y_MAX), 0.0
        return y, rate * 1000.0

    def sample(self, t: float) -> tuple[float, float]:
        y, rate = self.sample_y(t)
        return self.offset_rad + self.rad_per_y * y, self.rad_per_y * rate

    @property
    def duration(self) -> float:
        return self._ends[-1] / 1000.0
