"""Animation targets: where each joint should be at show time t, and how fast it is moving there.

A *track* is one joint's target: :meth:`Track.sample` gives u(t) (rad) and u'(t) (rad/s), the
velocity analytic (the springs with response r ≠ 0 feed it forward). A :class:`TargetSet` holds one
track per joint in joint order and fills preallocated ``(n_joints,)`` arrays every tick.

Tracks::

    Keyframes(times_s, values_rad, easing)   keys with a named easing per segment
    CsvCurve(times_s, values_rad)            one CSV column, linear (in hilsim.targets.csv_file)
    Hold(value_rad)   Step(at_s, before_rad, after_rad)   Sine(amplitude_rad, frequency_hz, ...)

Keyframes and CSV curves hold their first value before the first key and their last value after
the last (velocity 0 there); their :attr:`~Track.duration` is the time of the last key.
Generators have no end: their duration is None. The easings and their top speeds:
:class:`Keyframes`.

Rig files describe tracks in degrees; :func:`hilsim.targets.spec.track_from_spec` turns one spec
dict into a track. Tracks read from other tools' files: :mod:`hilsim.targets.formats`.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from drivers.fill import Packed
from hilsim._types import FloatArray

#: easing names accepted by :class:`Keyframes`
EASINGS = ("linear", "step", "ease_in", "ease_out", "ease_in_out", "sine_in_out", "smooth")


class Track(ABC):
    """One joint's target u(t) in rad and u'(t) in rad/s; t is show time in s (finite)."""

    @abstractmethod
    def sample(self, t: float) -> tuple[float, float]:
        """(u(t), u'(t)) as Python floats: position (rad) and velocity (rad/s)."""

    def value(self, t: float) -> float:
        """u(t) (rad)."""
        return self.sample(t)[0]

    def velocity(self, t: float) -> float:
        """u'(t) (rad/s)."""
        return self.sample(t)[1]

    def sample_array(self, t: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """(u, u') at many times at once, float64 arrays shaped like ``t``; for checks at load
        time, not for the tick. Vectorised by the tracks here; this default calls :meth:`sample`
        once per time. Agrees with :meth:`sample` to rounding (numpy's sin/cos may differ from
        :mod:`math`'s by an ulp)."""
        times = np.asarray(t, dtype=np.float64)
        pos, vel = np.empty(times.shape), np.empty(times.shape)
        for i, ti in enumerate(times.flat):
            pos.flat[i], vel.flat[i] = self.sample(float(ti))
        return pos, vel

    @property
    def duration(self) -> float | None:
        """Time (s) after which the track holds still; None if it never ends."""
        return None


def _finite(name: str, value: Any) -> float:
    x = float(value)
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x!r}")
    return x


def frozen_array(arr: FloatArray) -> FloatArray:
    arr = np.array(arr, dtype=np.float64)
    arr.flags.writeable = False
    return arr


#: the most turns (degrees) a track's value may hold: Extended Position Mode's ±1,048,575 ticks
MAX_TRACK_DEG = 360 * (MAX_TRACK_TURNS := 256)


def times_values(times: npt.ArrayLike, values: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Validated read-only copies: 1-D, same length ≥ 1, finite, times strictly increasing,
    values (rad) within ±:data:`MAX_TRACK_TURNS` turns."""
    t = np.asarray(times, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    if t.ndim != 1 or t.size == 0 or v.shape != t.shape:
        raise ValueError(
            f"times and values must be 1-D, non-empty and of one length, got shapes "
            f"{t.shape} and {v.shape}"
        )
    for name, arr in (("time", t), ("value", v)):
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise ValueError(f"key {bad[0]}: {name} must be finite, got {float(arr[bad[0]])!r}")
    if (bad := np.flatnonzero(np.abs(v) > MAX_TRACK_TURNS * 2.0 * math.pi)).size:
        raise ValueError(
            f"key {bad[0]}: value {math.degrees(float(v[bad[0]])):.6g}° is beyond "
            f"±{MAX_TRACK_DEG}° ({MAX_TRACK_TURNS} turns, the most a servo reaches)"
        )
    with np.errstate(divide="ignore", over="ignore"):
        # 1/Δt overflows for subnormal gaps; treat those as not increasing
        bad = np.flatnonzero(~(np.isfinite(1.0 / np.diff(t)) & (np.diff(t) > 0)))
    if bad.size:
        i = int(bad[0]) + 1
        raise ValueError(
            f"times must strictly increase: key {i} (t = {float(t[i])!r} s) is not after "
            f"key {i - 1} (t = {float(t[i - 1])!r} s)"
        )
    return frozen_array(t), frozen_array(v)


# --------------------------------------------------------------------------------- generators


@dataclass(frozen=True)
class Hold(Track):
    """A constant target: u = value_rad, u' = 0."""

    value_rad: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "value_rad", _finite("value_rad", self.value_rad))

    def sample(self, t: float) -> tuple[float, float]:
        return self.value_rad, 0.0

    def sample_array(self, t: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        shape = np.shape(t)
        return np.full(shape, self.value_rad), np.zeros(shape)


@dataclass(frozen=True)
class Step(Track):
    """before_rad until at_s, after_rad from at_s on (velocity 0: the jump carries no impulse)."""

    at_s: float
    before_rad: float
    after_rad: float

    def __post_init__(self) -> None:
        for name in ("at_s", "before_rad", "after_rad"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))

    def sample(self, t: float) -> tuple[float, float]:
        return (self.before_rad if t < self.at_s else self.after_rad), 0.0

    def sample_array(self, t: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        times = np.asarray(t, dtype=np.float64)
        return np.where(times < self.at_s, self.before_rad, self.after_rad), np.zeros(times.shape)


@dataclass(frozen=True)
class Sine(Track):
    """u = offset + amplitude·sin(2π·f·t + phase); u' = amplitude·2π·f·cos(2π·f·t + phase).

    Args: amplitude_rad (rad, any sign), frequency_hz (Hz, ≥ 0), phase_rad (rad), offset_rad (rad).
    """

    amplitude_rad: float
    frequency_hz: float
    phase_rad: float = 0.0
    offset_rad: float = 0.0
    _omega: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("amplitude_rad", "frequency_hz", "phase_rad", "offset_rad"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        if self.frequency_hz < 0.0:
            raise ValueError(f"frequency_hz must be >= 0, got {self.frequency_hz!r}")
        object.__setattr__(self, "_omega", 2.0 * math.pi * self.frequency_hz)

    def sample(self, t: float) -> tuple[float, float]:
        arg = self._omega * t + self.phase_rad
        return (
            self.offset_rad + self.amplitude_rad * math.sin(arg),
            self.amplitude_rad * self._omega * math.cos(arg),
        )

    def sample_array(self, t: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        arg = self._omega * np.asarray(t, dtype=np.float64) + self.phase_rad
        return (
            self.offset_rad + self.amplitude_rad * np.sin(arg),
            self.amplitude_rad * self._omega * np.cos(arg),
        )


# ---------------------------------------------------------------------------------- keyframes


def easing_names(easing: str | Sequence[str], n_segments: int) -> tuple[str, ...]:
    names = (easing,) * n_segments if isinstance(easing, str) else tuple(easing)
    if len(names) != n_segments:
        raise ValueError(
            f"easing: one name, or one per segment ({n_segments}), got {len(names)} names"
        )
    for i, name in enumerate(names):
        if name not in EASINGS:
            where = "" if isinstance(easing, str) else f" (segment {i})"
            raise ValueError(f"unknown easing {name!r}{where}; choose one of {', '.join(EASINGS)}")
    return names


def _tangents(t: FloatArray, v: FloatArray) -> list[float]:
    """Clamped Catmull-Rom tangents (rad/s) at every key (see :class:`Keyframes`)."""
    k = len(t)
    m = [0.0] * k
    for i in range(1, k - 1):
        left = (v[i] - v[i - 1]) / (t[i] - t[i - 1])
        right = (v[i + 1] - v[i]) / (t[i + 1] - t[i])
        if left * right <= 0.0:  # an extremum or a flat neighbour: a non-zero tangent overshoots
            continue
        cr = (v[i + 1] - v[i - 1]) / (t[i + 1] - t[i - 1])
        limit = 3.0 * min(abs(left), abs(right))  # Fritsch–Carlson: monotone within each segment
        m[i] = float(math.copysign(min(abs(cr), limit), cr))
    return m


# one piece of a keyframe track: start time, 1/duration, then u(τ) = c0 + c1·τ + c2·τ² + c3·τ³,
# or, when the flag is set, c0 + c1·(1 − cos πτ)/2 (sine_in_out is not a polynomial); τ ∈ [0, 1)
_Piece = tuple[float, float, float, float, float, float, bool]


def _pieces(t: FloatArray, v: FloatArray, easing: tuple[str, ...]) -> list[_Piece]:
    """Every segment as polynomial pieces in τ (ease_in_out splits at its middle)."""
    tangents = _tangents(t, v) if "smooth" in easing else []
    pieces: list[_Piece] = [(float(t[0]), 0.0, float(v[0]), 0.0, 0.0, 0.0, False)]
    for i, name in enumerate(easing):
        t0, h, v0, dv = float(t[i]), float(t[i + 1] - t[i]), float(v[i]), float(v[i + 1] - v[i])
        inv = 1.0 / h
        if name == "linear":
            pieces.append((t0, inv, v0, dv, 0.0, 0.0, False))
        elif name == "step":
            pieces.append((t0, inv, v0, 0.0, 0.0, 0.0, False))
        elif name == "ease_in":
            pieces.append((t0, inv, v0, 0.0, 0.0, dv, False))
        elif name == "ease_out":
            pieces.append((t0, inv, v0, 3.0 * dv, -3.0 * dv, dv, False))
        elif name == "ease_in_out":
            # in the local τ of each half: v0 + dv/2·τ³, then v0 + dv/2 + dv/2·(1 − (1 − τ)³)
            half = 0.5 * dv
            pieces.append((t0, 2.0 * inv, v0, 0.0, 0.0, half, False))
            pieces.append((t0 + 0.5 * h, 2.0 * inv, v0 + half, 3 * half, -3 * half, half, False))
        elif name == "sine_in_out":
            pieces.append((t0, inv, v0, dv, 0.0, 0.0, True))
        else:  # smooth: cubic Hermite with tangents m0, m1 scaled to the segment
            a, b = h * tangents[i], h * tangents[i + 1]
            pieces.append((t0, inv, v0, a, 3.0 * dv - 2.0 * a - b, -2.0 * dv + a + b, False))
    pieces.append((float(t[-1]), 0.0, float(v[-1]), 0.0, 0.0, 0.0, False))
    return pieces


@dataclass(frozen=True, eq=False, init=False)
class Keyframes(Track):
    """Keys (t, value) joined by named easings.

    A segment from (t0, v0) to (t1, v1) follows v0 + (v1 − v0)·e(τ), τ = (t − t0)/(t1 − t0).
    Its top speed is peak·|v1 − v0|/(t1 − t0): check it against the joint's speed limit. ::

        name          e(τ)                                  e'(0)  e'(1)  peak
        linear        τ                                     1      1      1
        step          0, jumping to v1 at t1 (velocity 0)   0      0      -
        ease_in       τ³                                    0      3      3
        ease_out      1 − (1 − τ)³                          3      0      3
        ease_in_out   4τ³, then 1 − (2 − 2τ)³/2             0      0      3
        sine_in_out   (1 − cos πτ)/2                        0      0      π/2
        smooth        cubic Hermite through the keys        tangents from the keys, below

    ``smooth`` uses Catmull-Rom tangents (v[i+1] − v[i−1])/(t[i+1] − t[i−1]). They are zero at
    the first and last key and at every local extremum, and clamped to three times the smaller
    neighbouring secant (Fritsch–Carlson). So the curve never overshoots its keys: keys inside
    a joint's limits give a curve inside them. A run of smooth segments is C¹; where a smooth
    segment meets another easing, the velocity is continuous only if the two agree.

    Args:
        times_s: key times, shape ``(k,)``, k ≥ 1, finite and strictly increasing (s).
        values_rad: key values, shape ``(k,)``, finite (rad).
        easing: one name for every segment, or a sequence of k − 1 names (segment i runs from
            key i to key i + 1). One of :data:`EASINGS`.

    Raises:
        ValueError: bad shapes, a non-finite key, times not strictly increasing (names the key),
            or an unknown easing (lists the choices).
    """

    times_s: FloatArray
    values_rad: FloatArray
    easing: tuple[str, ...]
    _starts: list[float] = field(init=False, repr=False)
    _pieces: list[_Piece] = field(init=False, repr=False)

    def __init__(
        self,
        times_s: npt.ArrayLike,
        values_rad: npt.ArrayLike,
        easing: str | Sequence[str] = "linear",
    ) -> None:
        # written out (not generated) so the fields are typed as what they hold after it
        t, v = times_values(times_s, values_rad)
        easing = easing_names(easing, len(t) - 1)
        pieces = _pieces(t, v, easing)
        object.__setattr__(self, "times_s", t)
        object.__setattr__(self, "values_rad", v)
        object.__setattr__(self, "easing", easing)
        object.__setattr__(self, "_pieces", pieces)
        # the first piece (the hold before the first key) must catch every t, however early
        object.__setattr__(self, "_starts", [-math.inf] + [p[0] for p in pieces[1:]])

    def sample(self, t: float) -> tuple[float, float]:
        t0, inv, c0, c1, c2, c3, sine = self._pieces[bisect_right(self._starts, t) - 1]
        tau = (t - t0) * inv
        if sine:
            a = math.pi * tau
            return c0 + 0.5 * c1 * (1.0 - math.cos(a)), 0.5 * math.pi * c1 * math.sin(a) * inv
        value = c0 + tau * (c1 + tau * (c2 + tau * c3))
        return value, (c1 + tau * (2.0 * c2 + 3.0 * c3 * tau)) * inv

    def sample_array(self, t: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        times = np.asarray(t, dtype=np.float64)
        cols = np.array([p[:6] for p in self._pieces], dtype=np.float64)
        sine = np.array([p[6] for p in self._pieces])
        which = np.searchsorted(np.array(self._starts), times, side="right") - 1
        t0, inv, c0, c1, c2, c3 = np.moveaxis(cols[which], -1, 0)
        tau = (times - t0) * inv
        value = c0 + tau * (c1 + tau * (c2 + tau * c3))
        vel = (c1 + tau * (2.0 * c2 + 3.0 * c3 * tau)) * inv
        if sine.any():
            s = sine[which]
            a = np.pi * tau
            value = np.where(s, c0 + 0.5 * c1 * (1.0 - np.cos(a)), value)
            vel = np.where(s, 0.5 * np.pi * c1 * np.sin(a) * inv, vel)
        return np.asarray(value, dtype=np.float64), np.asarray(vel, dtype=np.float64)

    @property
    def duration(self) -> float:
        return float(self.times_s[-1])


# -------------------------------------------------------------------------------- layers


@dataclass(frozen=True, eq=False)
class Layered(Track):
    """Several tracks on one joint, added: u = Σ uᵢ, u' = Σ u'ᵢ (e.g. a jaw from audio plus a
    keyframed offset). It ends when its last finite layer ends, or never if every layer is
    endless."""

    layers: tuple[Track, ...]

    def __post_init__(self) -> None:
        layers = tuple(self.layers)
        if not layers or not all(isinstance(tr, Track) for tr in layers):
            raise ValueError("layers must be one or more tracks")
        object.__setattr__(self, "layers", layers)

    def sample(self, t: float) -> tuple[float, float]:
        pos = vel = 0.0
        for tr in self.layers:
            p, v = tr.sample(t)
            pos += p
            vel += v
        return pos, vel

    def sample_array(self, t: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        times = np.asarray(t, dtype=np.float64)
        pos, vel = np.zeros(times.shape), np.zeros(times.shape)
        for tr in self.layers:
            p, v = tr.sample_array(times)
            pos += p
            vel += v
        return pos, vel

    @property
    def duration(self) -> float | None:
        ends = [d for d in (tr.duration for tr in self.layers) if d is not None]
        return max(ends) if ends else None


# -------------------------------------------------------------------------------- target set


class TargetSet:
    """One track per joint, in a fixed joint order; fills preallocated arrays every tick.

    Args:
        tracks: n ≥ 1 tracks; track i drives joint i.
        names: joint names, for messages and telemetry (default ``joint0``, ``joint1``, …).
    """

    def __init__(self, tracks: Sequence[Track], names: Sequence[str] | None = None) -> None:
        self.tracks = tuple(tracks)
        if not self.tracks:
            raise ValueError("a TargetSet needs at least one track")
        for i, tr in enumerate(self.tracks):
            if not isinstance(tr, Track):
                raise ValueError(f"track {i} is not a Track, got {type(tr).__name__}")
        n = len(self.tracks)
        self.names = tuple(names) if names is not None else tuple(f"joint{i}" for i in range(n))
        if len(self.names) != n:
            raise ValueError(f"{len(self.names)} names for {n} tracks")
        #: what the files behind the tracks say that the user should read (set by the builder)
        self.notes: tuple[str, ...] = ()
        self._samplers = tuple(enumerate(tr.sample for tr in self.tracks))
        self._sample = tuple(tr.sample for tr in self.tracks)
        self._pos = np.zeros(n)
        self._vel = np.zeros(n)
        self._pos_view = self._vel_view = Packed()  # the tick's arrays (drivers.fill)

    @property
    def n_joints(self) -> int:
        return len(self.tracks)

    @property
    def duration(self) -> float | None:
        """The end of the longest keyframe or CSV track (s); None if every track is a generator."""
        ends = [d for d in (tr.duration for tr in self.tracks) if d is not None]
        return max(ends) if ends else None

    def sample(self, t: float, out_pos: FloatArray, out_vel: FloatArray | None = None) -> None:
        """Write u(t) into ``out_pos`` and, if given, u'(t) into ``out_vel``.

        Both are float64 arrays shaped ``(n_joints,)`` (rad, rad/s), not checked here (the
        real-time path). Allocates no arrays.
        """
        if out_vel is None:
            for i, sample in self._samplers:
                out_pos[i] = sample(t)[0]
        else:
            for i, sample in self._samplers:
                out_pos[i], out_vel[i] = sample(t)

    def sample_into(
        self, t: float, out_pos: FloatArray, out_vel: FloatArray | None = None
    ) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """:meth:`sample`, also returning u(t) and u'(t) as tuples of floats (the tick hands
        them to the integrator as they are); the arrays are written in one packed step each
        (:mod:`drivers.fill`)."""
        pos, vel = zip(*[sample(t) for sample in self._sample])  # noqa: B905 (pairs)
        view = self._pos_view
        if view.arr is not out_pos:
            view = self._pos_view = Packed(out_pos, len(pos))
        view.put(*pos)
        if out_vel is not None:
            view = self._vel_view
            if view.arr is not out_vel:
                view = self._vel_view = Packed(out_vel, len(vel))
            view.put(*vel)
        return pos, vel

    def __call__(self, t: float) -> tuple[FloatArray, FloatArray]:
        """(u(t), u'(t)) in buffers owned by the set, overwritten by the next call.

        This is the integrator's callable target (``integrator.step(x, v, h, t, targets)``
        samples it at every stage time).
        """
        self.sample(t, self._pos, self._vel)
        return self._pos, self._vel
