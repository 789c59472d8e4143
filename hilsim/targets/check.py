"""Load-time track checks: where a joint's target goes beyond its limits or its speed limit.

The safety filter (:mod:`hilsim.safety.filter`) makes such a target safe on the wire,
silently, tick by tick. :func:`check_tracks` says so before the show: it samples every
joint's target at the loop's
tick times ``t_k = k·period`` (as the loop does), over the show, and returns one
:class:`TrackWarning` per joint and kind of excess, e.g.::

    jaw: target 42.0° at t = 3.20 s is beyond max_deg 35° (1.40 s beyond in all)
    jaw: target speed 412°/s at t = 1.10 s exceeds max_speed_deg_s 270°/s (0.20 s faster in all)

(with "worst 50.0° at t = 3.50 s; " before the total when the worst is not the first).

Angles are in the joint frame and in degrees, named by the rig file's keys. The target's speed is
the tick-to-tick difference over the period, ``|u(t_k+1) − u(t_k)| / period``: what the loop sees
of it, jumps (step easing, step targets) included. Excesses smaller than rounding (1e-9 rad, or a
relative 1e-9 of the speed limit) are not reported. The target is only where the spring is
pulled to; the spring may smooth a brief excess, so a warning says the command *may* be limited
there, and the run's summary (``safety_limits``) counts what the filter actually did.

What is sampled, and for how long (the show lasts ``duration_s``, else the longest keyframe or CSV
track, else it is endless): a keyframe or CSV track up to its last key (after it, it holds its last
value; the time beyond a limit after the last key is added exactly); a generator (sine, step, hold,
or any other track without an end) over the whole show, or, when the show is endless (no
duration and no keyframe or CSV track), over ``horizon_s``: its totals then say "of the first
H s" (and a step later than that is not seen).

Vectorised: a 10-minute show at 1 kHz (600,000 ticks per joint) takes well under a second; the
samples are taken in chunks, so memory stays bounded for any duration.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hilsim.targets import FloatArray, TargetSet, Track
from hilsim.targets.csv_file import CsvCurve
from hilsim.targets.formats.common import AUDIO_JAW_SOURCE

#: default span over which endless generators are checked (s)
HORIZON_S = 60.0
#: excess below which nothing is reported: rounding, not animation (rad; relative for speed)
POSITION_TOLERANCE_RAD = 1e-9
SPEED_TOLERANCE = 1e-9
#: ticks sampled at once
CHUNK_TICKS = 1 << 17


class JointLimits(Protocol):
    """What :func:`check_tracks` needs of a joint (:class:`hilsim.rig.JointConfig` has it);
    read-only, so a frozen dataclass fits."""

    @property
    def name(self) -> str: ...
    @property
    def min_rad(self) -> float: ...
    @property
    def max_rad(self) -> float: ...
    @property
    def max_speed_rad_s(self) -> float: ...


@dataclass(frozen=True)
class TrackWarning:
    """One joint's target beyond one limit. Angles in rad (joint frame), speeds in rad/s, times s.

    ``kind`` is ``"max"`` (above max_deg), ``"min"`` (below min_deg) or ``"speed"``; ``limit`` the
    limit crossed; ``first_t``/``first_value`` the first tick beyond it and the target there
    (for speed: the speed, signed, of the tick starting at ``first_t``); ``worst_t``/``worst_value``
    the farthest beyond; ``total_s`` the time beyond it (ticks × period); ``checked_s`` the span
    checked when that was less than the show (a generator past the horizon), else None.
    """

    joint: str
    kind: str
    limit: float
    first_t: float
    first_value: float
    worst_t: float
    worst_value: float
    total_s: float
    checked_s: float | None = None
    #: what to change, for a speed warning (the audio jaw has its own knob)
    fix: str = ""

    def __str__(self) -> str:
        of = "" if self.checked_s is None else f" of the first {_secs(self.checked_s)} s"
        if self.kind == "speed":
            first, worst, limit = abs(self.first_value), abs(self.worst_value), self.limit
            unit, key, verb, adj = "°/s", "max_speed_deg_s", "exceeds", "faster"
            what = "target speed"
        else:
            first, worst, limit = self.first_value, self.worst_value, self.limit
            unit, key, verb, adj = "°", f"{self.kind}_deg", "is beyond", "beyond"
            what = "target"
        more = ""
        if _deg(worst, limit) != _deg(first, limit):  # only a worst that reads differently
            more = f"worst {_deg(worst, limit)}{unit} at t = {_secs(self.worst_t)} s; "
        return (
            f"{self.joint}: {what} {_deg(first, limit)}{unit} at t = {_secs(self.first_t)} s "
            f"{verb} {key} {_deg(limit)}{unit} ({more}{_secs(self.total_s)} s {adj} in all{of})"
            + (f": {self.fix}" if self.fix else "")
        )


def _deg(rad: float, limit_rad: float | None = None) -> str:
    """Degrees. A limit: exactly as the rig would say it, to 6 decimals (35, 35.25). A value
    beyond ``limit_rad``: one decimal, or as many more as it takes to still read beyond it
    (35.004 beside 35); no ".0"."""
    d = math.degrees(rad)
    if limit_rad is None:
        return f"{d:.6f}".rstrip("0").rstrip(".")
    lim = round(math.degrees(limit_rad), 9)  # as the rig said it: -60, not -59.99999999999999
    side = 1.0 if d >= lim else -1.0
    for places in range(1, 7):
        text = f"{d:.{places}f}"
        if (float(text) - lim) * side > 0:
            return text[:-2] if text.endswith(".0") else text
    return f"{d:.12g}"


def _secs(s: float) -> str:
    return f"{s:.2f}" if s >= 0.995 or s == 0 else f"{s:.3g}"


class _Excess:
    """First, worst and count of the samples beyond one limit, accumulated over chunks."""

    def __init__(self) -> None:
        self.count = 0
        self.first: tuple[float, float] | None = None
        self.worst: tuple[float, float] | None = None
        self.worst_by = -math.inf

    def add(self, t: FloatArray, values: FloatArray, by: FloatArray, beyond: np.ndarray) -> None:
        """``by``: how far beyond (> 0 where ``beyond``), to pick the worst."""
        idx = np.flatnonzero(beyond)
        if not idx.size:
            return
        self.count += int(idx.size)
        if self.first is None:
            self.first = (float(t[idx[0]]), float(values[idx[0]]))
        w = idx[int(np.argmax(by[idx]))]
        if by[w] > self.worst_by:
            self.worst_by = float(by[w])
            self.worst = (float(t[w]), float(values[w]))


def _sample(track: Track, t: FloatArray) -> FloatArray:
    if isinstance(track, CsvCurve):  # the same arithmetic as CsvCurve.sample, vectorised
        ts, vs = track.times_s, track.values_rad
        if ts.size < 2:
            return np.full(t.shape, float(vs[0]))
        i = np.searchsorted(ts, t, side="right")
        inner = np.clip(i - 1, 0, ts.size - 2)
        slope = np.diff(vs) / np.diff(ts)
        out = vs[inner] + slope[inner] * (t - ts[inner])
        out = np.where(i == 0, vs[0], out)
        return np.where(i == ts.size, vs[-1], out)
    return track.sample_array(t)[0]


def _span_ticks(track: Track, period_s: float, show_ticks: int | None, horizon_s: float) -> int:
    """How many ticks of this track to sample (from tick 0); ``show_ticks`` None: endless."""
    if track.duration is None:  # a generator: the whole show, or the horizon if it is endless
        return math.floor(horizon_s / period_s) + 1 if show_ticks is None else show_ticks
    want = math.floor(track.duration / period_s) + 3  # past the last key: it then holds
    return want if show_ticks is None else min(show_ticks, want)


def check_tracks(
    targets: TargetSet,
    joints: Sequence[JointLimits],
    period_s: float,
    *,
    duration_s: float | None = None,
    horizon_s: float = HORIZON_S,
) -> list[TrackWarning]:
    """Sample each joint's target at the tick times and report where it leaves its limits.

    Args:
        targets: one track per joint, in joint order (:func:`hilsim.show.parts.build_targets`).
        joints: the rig's joints in the same order (``rig.joints``): name, min_rad, max_rad,
            max_speed_rad_s, joint frame.
        period_s: the loop's tick period (``rig.loop.period_s``), > 0.
        duration_s: the show's length as the loop will run it (``--duration``); None: the
            longest keyframe or CSV track, or endless if there is none.
        horizon_s: how far endless generators are checked (s), > 0.

    Returns:
        The warnings, per joint in joint order: below min, above max, then speed; empty when every
        target stays within every limit. ``str(w)`` is the one line to print.

    Raises:
        ValueError: a joint count that differs from the tracks', or a bad period, duration or
            horizon.
    """
    if len(joints) != targets.n_joints:
        raise ValueError(f"{len(joints)} joints for {targets.n_joints} tracks")
    for name, value in (("period_s", period_s), ("horizon_s", horizon_s)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s >= 0):
        raise ValueError(f"duration_s must be finite and >= 0, got {duration_s!r}")
    show_s = targets.duration if duration_s is None else duration_s
    show_ticks = None if show_s is None else round(show_s / period_s) + 1  # as the loop counts
    warnings: list[TrackWarning] = []
    for track, joint in zip(targets.tracks, joints, strict=True):
        warnings += _check_one(track, joint, period_s, show_ticks, horizon_s)
    return warnings


def _check_one(
    track: Track, joint: JointLimits, period_s: float, show_ticks: int | None, horizon_s: float
) -> list[TrackWarning]:
    lo, hi, vmax = float(joint.min_rad), float(joint.max_rad), float(joint.max_speed_rad_s)
    n = _span_ticks(track, period_s, show_ticks, horizon_s)
    below, above, fast = _Excess(), _Excess(), _Excess()
    speed_cap = vmax * (1.0 + SPEED_TOLERANCE)
    prev: float | None = None
    last = math.nan
    for k0 in range(0, n, CHUNK_TICKS):
        k1 = min(n, k0 + CHUNK_TICKS)
        t = np.arange(k0, k1, dtype=np.float64) * period_s  # k·period, as the loop computes it
        u = _sample(track, t)
        below.add(t, u, lo - u, u < lo - POSITION_TOLERANCE_RAD)
        above.add(t, u, u - hi, u > hi + POSITION_TOLERANCE_RAD)
        # the speed of the tick from t_k to t_k+1, (u_k+1 - u_k) / period, at t_k; the first
        # of a chunk continues the last chunk's last sample
        ext = u if prev is None else np.concatenate([[prev], u])
        ts = np.arange(k1 - (ext.size - 1) - 1, k1 - 1, dtype=np.float64) * period_s
        speed = np.diff(ext) / period_s
        fast.add(ts, speed, np.abs(speed), np.abs(speed) > speed_cap)
        prev = float(u[-1])
        last = prev
    # ticks of the show after the sampled span: a keyframe/CSV track holds its last value there
    rest = 0 if show_ticks is None else max(0, show_ticks - n)
    checked_s = None
    if show_ticks is None:
        checked_s = (n - 1) * period_s  # an endless show: generators checked to the horizon
    elif rest:
        if last < lo - POSITION_TOLERANCE_RAD:
            below.count += rest
        elif last > hi + POSITION_TOLERANCE_RAD:
            above.count += rest
    out = []
    for kind, limit, ex in (("min", lo, below), ("max", hi, above), ("speed", vmax, fast)):
        if ex.first is None or ex.worst is None:
            continue
        fix = ""
        if kind == "speed":
            audio = str(getattr(track, "source", "")).endswith(AUDIO_JAW_SOURCE)
            fix = (
                "raise max_speed_deg_s (within the servo's), "
                + ("lengthen attack_ms" if audio else "slow the animation")
                + ", or accept it (the safety filter holds the joint to its limit)"
            )
        out.append(
            TrackWarning(
                joint=joint.name,
                kind=kind,
                limit=limit,
                first_t=ex.first[0],
                first_value=ex.first[1],
                worst_t=ex.worst[0],
                worst_value=ex.worst[1],
                total_s=ex.count * period_s,
                fix=fix,
                checked_s=checked_s,
            )
        )
    return out
