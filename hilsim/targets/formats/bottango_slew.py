"""What Bottango's driver does with an effector's curves: the start signal and the speed limit.

A registration (``rSVPin,<pin>,<min>,<max>,<maxPerSec>,<start>`` and its kin) gives a start
signal and a speed limit in signal units per second. The driver (Bottango's Arduino driver,
EvanBottango/Bottango 0.8.0c1, ``LoopDrivenEffector.cpp``) writes the start signal when the
effector registers and keeps it until a curve starts: no curve, no change. Each loop it then
moves the signal toward the curve's value (after a curve: toward its end value) by at most
``maxPerSec`` times the time since the signal last changed (``speedLimitSingal``; the
networked driver's ``Effector.speedLimitSignal`` is the same rule). The signal is a slew-rate
limited copy of the curve: where the curve (or a jump: the first curve starting elsewhere than
the start signal, an instant ``sCI``, a curve starting after a gap elsewhere than the last one
ended) moves faster than the limit, the signal runs behind in a straight line at the limit
until it meets the curve again.

:func:`driver_track` gives that signal as a track, exactly: on the curve where the curve is
slower than the limit, on a straight line at the limit elsewhere. Where the line meets the
curve is a root of a cubic in the curve parameter u, and where the curve first gets faster
than the limit a root of a quadratic; both are found to rounding (bisection on pieces where
the polynomial is monotone), not by stepping in time. Not modelled: the driver's whole-number
signal (it rounds to 1 µs) and its loop period (the limit counts whole signal units per
loop, so a fast loop moves a little slower than the limit); steppers step toward the curve in
67 ms chunks, here they follow the same continuous limit.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from itertools import pairwise
from typing import TYPE_CHECKING, Any, NamedTuple

from hilsim.targets.formats.bottango_curve import (
    Y_MAX,
    BezierSegment,
    BezierTrack,
    quadratic_roots,
)
from hilsim.targets.tracks import Track

if TYPE_CHECKING:
    from collections.abc import Callable

#: how close (in 0..8192) the signal must be to the curve to count as on it
_ON = 1e-9 * Y_MAX
#: the curve must be this much (relative) faster than the limit before the signal falls behind
_FASTER = 1e-9
#: events (a fall behind, a catch up) one piece may hold: a cubic's roots bound them well below
_MAX_EVENTS = 64

_FOLLOW, _LINE = 0, 1


def driver_terms(eff: Any) -> tuple[float | None, float | None]:
    """A registered effector's (start, speed limit) in Bottango's 0..8192 and 0..8192 per
    second: the start signal as a movement of its range (clamped to it), the limit
    ``maxPerSec · 8192 / |max - min|`` (a curved event: ``maxMovementPerSec · 8192``). None
    for what the registration does not give (a limit <= 0, a range of zero width)."""
    if eff is None:
        return None, None
    if eff.signal_min is None:  # a curved event: start and limit are movements
        lo, hi = 0.0, 1.0
    else:
        lo, hi = float(eff.signal_min), float(eff.signal_max)
    if hi == lo:
        return None, None
    start = min(max((float(eff.start) - lo) / (hi - lo), 0.0), 1.0) * Y_MAX
    speed = eff.max_per_s
    rate = float(speed) * Y_MAX / abs(hi - lo) if speed is not None and speed > 0 else None
    return start, rate


class _Piece(NamedTuple):
    """A stretch of the curve's value in ms: ``seg`` from ``ua`` to ``ub`` (x increasing), or
    the constant ``c`` (``seg`` None)."""

    ta: float
    tb: float
    seg: BezierSegment | None = None
    ua: float = 0.0
    ub: float = 0.0
    c: float = 0.0

    def value(self, u: float) -> float:
        return self.c if self.seg is None else _y(self.seg, u)


def _x(seg: BezierSegment, u: float) -> float:
    ax, bx, cx = seg._poly[:3]
    return ((ax * u + bx) * u + cx) * u


def _y(seg: BezierSegment, u: float) -> float:
    ay, by, cy, y0 = seg._poly[3:]
    return ((ay * u + by) * u + cy) * u + y0


def _cubic_roots(c: tuple[float, float, float, float], a: float, b: float) -> list[float]:
    """The roots of c0 + c1 u + c2 u² + c3 u³ in (a, b), ascending: the cubic is monotone
    between its derivative's roots, and each sign change there is bisected to rounding."""
    c0, c1, c2, c3 = c

    def f(u: float) -> float:
        return ((c3 * u + c2) * u + c1) * u + c0

    knots = [a, *sorted(r for r in quadratic_roots(3.0 * c3, 2.0 * c2, c1) if a < r < b), b]
    out = []
    for p, q in pairwise(knots):
        fp, fq = f(p), f(q)
        if (fp < 0.0) != (fq < 0.0) and fp != 0.0:
            out.append(_bisect(f, p, q))
    return [u for u in out if a < u < b]


def _bisect(f: Callable[[float], float], lo: float, hi: float) -> float:
    """The point where f (monotone on [lo, hi], changing sign) crosses zero, to rounding;
    the end of the bracket on f(hi)'s side."""
    neg = f(lo) < 0.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        if (f(mid) < 0.0) == neg:
            lo = mid
        else:
            hi = mid
    return hi


def _pieces(track: BezierTrack, start: float) -> list[_Piece]:
    """The track's value as pieces from show time 0 on: ``start`` until the first curve, each
    curve followed forward in time (split where it leaves 0..8192: clamped there, as the
    driver clamps), a curve's end value in a gap, the last end value to the end of time."""
    out: list[_Piece] = []
    t, c = 0.0, start
    for seg in track.segments:
        if seg.start_ms > t:
            out.append(_Piece(t, seg.start_ms, c=c))
        if seg.dur_ms > 0.0:
            out += _curve_pieces(seg)
        t, c = max(t, seg.end_ms), min(max(float(seg.y1), 0.0), Y_MAX)
    out.append(_Piece(t, math.inf, c=c))
    return out


def _curve_pieces(seg: BezierSegment) -> list[_Piece]:
    out: list[_Piece] = []
    # followed forward: u(t) is the smallest u with x(u) = t, for t up to the segment's end
    reached, dur = 0.0, seg.dur_ms
    ys = (seg.y0, seg.c1y, seg.c2y, seg.y1)
    if len(seg._pieces) == 1 and min(ys) >= 0.0 and max(ys) <= Y_MAX:  # the usual curve
        return [_Piece(seg.start_ms, seg.end_ms, seg, 0.0, 1.0)]
    for lo, hi, x_lo, x_hi in seg._pieces:
        if x_hi <= reached or reached >= dur:
            continue
        ua = lo if x_lo >= reached else seg._solve_monotone(reached, lo, hi, x_lo, x_hi)
        x_from = max(x_lo, reached)
        if x_hi > dur:
            hi, x_hi = seg._solve_monotone(dur, lo, hi, x_lo, x_hi), dur
        reached = x_hi
        ay, by, cy, y0 = seg._poly[3:]
        cuts = []
        if not (min(ys) >= 0.0 and max(ys) <= Y_MAX):  # else within its control points' hull
            cuts = _cubic_roots((y0, cy, by, ay), ua, hi)
            cuts += _cubic_roots((y0 - Y_MAX, cy, by, ay), ua, hi)
        knots = [ua, *sorted(cuts), hi]
        times = [x_from, *(_x(seg, u) for u in knots[1:-1]), x_hi]
        for (p, q), (xa, xb) in zip(pairwise(knots), pairwise(times), strict=True):
            if q <= p:
                continue
            ta, tb = seg.start_ms + xa, seg.start_ms + xb
            mid = _y(seg, 0.5 * (p + q))
            if 0.0 <= mid <= Y_MAX:
                out.append(_Piece(ta, tb, seg, p, q))
            else:
                out.append(_Piece(ta, tb, c=0.0 if mid < 0.0 else Y_MAX))
    return out


def _falls_behind(seg: BezierSegment, u0: float, ub: float, r: float) -> tuple[float, int] | None:
    """The first u in [u0, ub) from which the curve is faster than ``r`` (0..8192 per ms),
    and its direction; None if it never is. |dy/dx| > r is the quadratic ±y' - r·x' > 0."""
    ax, bx, cx, ay, by, cy, _ = seg._poly
    k = r * (1.0 + _FASTER)
    best: tuple[float, int] | None = None
    for s in (1, -1):
        q2, q1, q0 = 3.0 * (s * ay - k * ax), 2.0 * (s * by - k * bx), s * cy - k * cx
        top = max((q2 * u + q1) * u + q0 for u in (u0, ub))
        if q2 < 0.0 and u0 < (vertex := -q1 / (2.0 * q2)) < ub:
            top = max(top, (q2 * vertex + q1) * vertex + q0)
        if top <= 0.0:  # never faster than the limit this way: the usual case, decided fast
            continue
        knots = [u0, *sorted(x for x in quadratic_roots(q2, q1, q0) if u0 < x < ub), ub]
        for p, q in pairwise(knots):
            m = 0.5 * (p + q)
            if q - p > 1e-12 and (q2 * m + q1) * m + q0 > 0.0:
                if best is None or p < best[0]:
                    best = (p, s)
                break
    return best


def _meets(seg: BezierSegment, u0: float, ub: float, v0: float, s: int, r: float) -> float | None:
    """The first u in (u0, ub] where the line from (x(u0), v0) at slope s·r meets the curve,
    coming from the curve's side s; None if it does not. f(u) = s·(y(u) - line) is a cubic;
    its first fall to <= 0 after it has been > 0 is the meeting."""
    ax, bx, cx, ay, by, cy, y0 = seg._poly
    coef = (s * (y0 - v0) + r * _x(seg, u0), s * cy - r * cx, s * by - r * bx, s * ay - r * ax)

    def f(u: float) -> float:
        return ((coef[3] * u + coef[2]) * u + coef[1]) * u + coef[0]

    roots = quadratic_roots(3.0 * coef[3], 2.0 * coef[2], coef[1])
    knots = [u0, *sorted(x for x in roots if u0 < x < ub), ub]
    ahead = f(u0) > 0.0
    for p, q in pairwise(knots):
        if f(q) <= 0.0:
            if ahead:
                return _bisect(f, p, q)
        else:
            ahead = True
    return None


def _sweep(pieces: list[_Piece], v: float, r: float) -> tuple[list[tuple], float]:
    """The signal through ``pieces`` from ``v``, limited to ``r`` per ms: spans ``(t0,
    _FOLLOW)`` on the curve, ``(t0, _LINE, v0, slope)`` behind it; and when it last settles
    (ms)."""
    spans: list[tuple] = [(-math.inf, _LINE, v, 0.0)]  # parked at the start before time 0
    settled = 0.0
    for pc in pieces:
        t, u, s = pc.ta, pc.ua, 0
        for _ in range(_MAX_EVENTS):
            if t >= pc.tb:
                break
            if s == 0 and abs(pc.value(u) - v) <= _ON:  # on the curve
                spans.append((t, _FOLLOW))
                seg = pc.seg
                hit = None if seg is None else _falls_behind(seg, u, pc.ub, r)
                if seg is None or hit is None:
                    t, v = pc.tb, pc.value(pc.ub)
                    break
                u, s = hit
                t, v = seg.start_ms + _x(seg, u), _y(seg, u)
                continue
            s = s or (1 if pc.value(u) > v else -1)
            spans.append((t, _LINE, v, s * r))
            if pc.seg is None:
                meet = t + abs(pc.c - v) / r
                if meet >= pc.tb:
                    v += s * r * (pc.tb - t)
                    t = pc.tb
                else:
                    t, v, settled = meet, pc.c, max(settled, meet)
            else:
                m = _meets(pc.seg, u, pc.ub, v, s, r)
                if m is None:
                    v += s * r * (pc.tb - t)
                    t = pc.tb
                else:
                    u, t, v = m, pc.seg.start_ms + _x(pc.seg, m), _y(pc.seg, m)
                    settled = max(settled, t)
            s = 0
        else:  # not reached (a cubic has few roots); a guard: follow the curve from here
            spans.append((t, _FOLLOW))
            v = pc.value(pc.ub)
    return _merged(spans), settled


def _merged(spans: list[tuple]) -> list[tuple]:
    out: list[tuple] = []
    for sp in spans:
        if out and sp[0] <= out[-1][0]:
            out[-1] = sp  # an empty span: the later one starts there
        elif not (out and sp[1] == _FOLLOW and out[-1][1] == _FOLLOW):
            out.append(sp)
    return out


class DriverTrack(Track):
    """A :class:`BezierTrack` as Bottango's driver plays it (see the module docstring):
    ``base`` where its curve is within the speed limit, straight lines at the limit where the
    driver's signal runs behind. ``behind`` lists those stretches ``(start_s, end_s)``."""

    __slots__ = ("_end_s", "_spans", "_starts", "base", "behind", "limit")

    def __init__(self, base: BezierTrack, spans: list[tuple], settled_ms: float, limit: str):
        self.base, self.limit, self._spans = base, limit, spans
        self._starts = [sp[0] for sp in spans]
        self._end_s = max(base.duration, settled_ms / 1000.0)
        behind: list[tuple[float, float]] = []
        since = None  # a run of lines: from its first to the curve it meets
        for sp in (*spans[1:], (math.inf, _FOLLOW)):
            if sp[1] == _LINE and since is None:
                since = sp[0]
            elif sp[1] == _FOLLOW and since is not None:
                behind.append((since / 1000.0, min(sp[0], settled_ms) / 1000.0))
                since = None
        self.behind = tuple(behind)

    def sample_y(self, t: float) -> tuple[float, float]:
        """(signal in 0..8192, its rate in 1/s) at show time ``t`` (s)."""
        ms = t * 1000.0
        sp = self._spans[bisect_right(self._starts, ms) - 1]
        if sp[1] == _FOLLOW:
            return self.base.sample_y(t)
        if sp[3] == 0.0:  # parked at the start (from time -inf)
            return sp[2], 0.0
        return sp[2] + sp[3] * (ms - sp[0]), sp[3] * 1000.0

    def sample(self, t: float) -> tuple[float, float]:
        y, rate = self.sample_y(t)
        return self.base.offset_rad + self.base.rad_per_y * y, self.base.rad_per_y * rate

    @property
    def duration(self) -> float:
        return self._end_s


def driver_track(base: BezierTrack, rate: float | None, limit: str = "") -> Track:
    """``base`` (its ``start_y`` the start signal, or None) limited to ``rate`` (0..8192 per
    second; None: no limit) as the driver limits it: ``base`` itself when the limit never
    holds the signal back, else a :class:`DriverTrack`. ``limit`` says the limit in the
    registration's units, for messages."""
    if rate is None:
        return base
    start = base.start_y if base.start_y is not None else float(base.segments[0].y0)
    start = min(max(start, 0.0), Y_MAX)
    spans, settled = _sweep(_pieces(base, start), start, rate / 1000.0)
    if all(sp[1] == _FOLLOW for sp in spans[1:]):
        return base
    return DriverTrack(base, spans, settled, limit)
