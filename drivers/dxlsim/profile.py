"""Dynamixel velocity profiles: the trajectory a goal produces, as pure math.

A plan is a list of :data:`Segment` pieces of constant acceleration in the servo's pulse units
(pulse, pulse/s, pulse/s²), the last one possibly endless. :func:`plan_profile` plans a move to a
position (Position modes: trapezoid or triangle from rest, as in the e-Manual, and braking first
when already moving), :func:`plan_time_profile` the time-based move of Drive Mode bit 2,
:func:`plan_velocity` a ramp to a velocity (Velocity, PWM and Current
modes). No control table here: :mod:`drivers.dxlsim.servo` turns registers into these arguments
and steps the horn after the plan.
"""

from __future__ import annotations

import math
from enum import IntEnum


class ProfileType(IntEnum):
    """Moving Status (addr 123) bits 4-5."""

    STEP = 0
    RECTANGULAR = 1
    TRIANGULAR = 2
    TRAPEZOIDAL = 3


#: One trajectory piece: (t_start, t_end, p_start, v_start, accel); s, pulse, pulse/s, pulse/s².
Segment = tuple[float, float, float, float, float]


def plan_profile(
    t0: float, p0: float, v0: float, goal: float, v_max: float, a_max: float
) -> tuple[list[Segment], ProfileType]:
    """Plan a velocity-continuous move from ``(p0, v0)`` at ``t0`` to rest at ``goal``.

    ``v_max`` > 0 pulse/s caps the speed; ``a_max`` pulse/s² bounds the acceleration
    (``math.inf``: rectangular profile, the velocity jumps). From rest this is the
    e-Manual profile: trapezoid when ``|Δ| >= v²/a`` (time ``|Δ|/v + v/a``), else
    triangle (time ``2·sqrt(|Δ|/a)``). Moving away from the goal, or too fast to stop in
    time, it first brakes to zero and then plans from rest (it overshoots).
    """
    segs: list[Segment] = []
    d = goal - p0
    if a_max == math.inf:
        if d == 0.0:
            return segs, ProfileType.RECTANGULAR
        t1 = t0 + abs(d) / v_max
        segs.append((t0, t1, p0, math.copysign(v_max, d), 0.0))
        return segs, ProfileType.RECTANGULAR
    a = a_max
    s = 1.0 if d > 0.0 or (d == 0.0 and v0 < 0.0) else -1.0
    u = v0 * s  # speed towards the goal
    dist = abs(d)
    if u < 0.0 or u * u / (2.0 * a) > dist:
        tb = abs(v0) / a
        segs.append((t0, t0 + tb, p0, v0, -math.copysign(a, v0)))
        p0 += 0.5 * v0 * tb
        t0 += tb
        d = goal - p0
        s = 1.0 if d >= 0.0 else -1.0
        u, dist = 0.0, abs(d)
    if u <= v_max:
        vp = min(v_max, math.sqrt(a * dist + 0.5 * u * u))
        t1 = (vp - u) / a
        d1 = (vp * vp - u * u) / (2.0 * a)
        a1 = s * a
    else:  # slower profile than the present speed: decelerate to it first
        vp = v_max
        t1 = (u - vp) / a
        d1 = (u * u - vp * vp) / (2.0 * a)
        a1 = -s * a
    t3 = vp / a
    d2 = max(0.0, dist - d1 - vp * vp / (2.0 * a))
    t2 = d2 / vp if vp > 0.0 else 0.0
    p, t = p0, t0
    if t1 > 0.0:
        segs.append((t, t + t1, p, s * u, a1))
        p += s * d1
        t += t1
    if t2 > 0.0:
        segs.append((t, t + t2, p, s * vp, 0.0))
        p += s * d2
        t += t2
    if t3 > 0.0:
        segs.append((t, t + t3, p, s * vp, -s * a))
    kind = ProfileType.TRAPEZOIDAL if d2 > 1e-9 * max(1.0, dist) else ProfileType.TRIANGULAR
    return segs, kind


def plan_time_profile(
    t0: float, p0: float, v0: float, goal: float, t_span: float, t_acc: float
) -> tuple[list[Segment], ProfileType]:
    """Plan a time-based move (Drive Mode bit 2): from ``(p0, v0)`` at ``t0`` to rest at
    ``goal`` in exactly ``t_span`` s, accelerating for ``t_acc`` s and decelerating for
    ``t_acc`` s (e-Manual ``control_table_profile_velocity.md``: Profile Velocity(112) is
    the time span t3, Profile Acceleration(108) the accelerating time t1, "will not exceed
    50 % of Profile Velocity").

    ``t_acc`` is clamped to ``t_span / 2`` here; ``t_acc`` 0 is a rectangular profile (the
    velocity jumps), ``t_acc == t_span / 2`` a triangle, anything between a trapezoid. The
    move takes ``t_span`` whatever its distance: the peak velocity ``vp`` solves
    ``goal - p0 = v0·t_acc/2 + vp·(t_span - t_acc)`` (velocity continuous from ``v0``, so a
    new goal mid-move keeps the Velocity Override). No speed cap: the motor bounds the horn,
    which falls behind when the distance cannot be covered in the time.
    """
    segs: list[Segment] = []
    t_acc = min(max(t_acc, 0.0), 0.5 * t_span)
    t_cruise = t_span - 2.0 * t_acc
    if t_acc == 0.0:
        kind = ProfileType.RECTANGULAR
    else:
        kind = ProfileType.TRAPEZOIDAL if t_cruise > 0.0 else ProfileType.TRIANGULAR
    d = goal - p0
    if d == 0.0 and v0 == 0.0:
        return segs, kind
    if t_acc == 0.0:
        segs.append((t0, t0 + t_span, p0, d / t_span, 0.0))
        return segs, kind
    vp = (d - 0.5 * v0 * t_acc) / (t_span - t_acc)
    p, t = p0, t0
    segs.append((t, t + t_acc, p, v0, (vp - v0) / t_acc))
    p += 0.5 * (v0 + vp) * t_acc
    t += t_acc
    if t_cruise > 0.0:
        segs.append((t, t + t_cruise, p, vp, 0.0))
        p += vp * t_cruise
        t += t_cruise
    segs.append((t, t0 + t_span, p, vp, -vp / t_acc))
    return segs, kind


def plan_velocity(t0: float, p0: float, v0: float, v_goal: float, a_max: float) -> list[Segment]:
    """Ramp the velocity from ``v0`` to ``v_goal`` (pulse/s) at ``a_max`` pulse/s², then
    hold it forever (last segment ends at ``math.inf`` unless ``v_goal`` is 0)."""
    segs: list[Segment] = []
    if a_max != math.inf and v_goal != v0:
        ta = abs(v_goal - v0) / a_max
        segs.append((t0, t0 + ta, p0, v0, math.copysign(a_max, v_goal - v0)))
        p0 += 0.5 * (v0 + v_goal) * ta
        t0 += ta
    if v_goal != 0.0:
        segs.append((t0, math.inf, p0, v_goal, 0.0))
    return segs


def _segments_end(segs: list[Segment], p_default: float) -> float:
    """Position where a finite plan comes to rest."""
    if not segs:
        return p_default
    ts, te, p, v, a = segs[-1]
    tau = te - ts
    return p + (v + 0.5 * a * tau) * tau
