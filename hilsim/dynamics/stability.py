"""Stability guard: will a fixed step h blow a spring bank up, and how many substeps would not?

An explicit method multiplies each free mode of a spring by a growth factor every step (|R(h·λ)| for
a Runge–Kutta method, the spectral radius of the update matrix for semi-implicit Euler). As h grows,
h·λ moves out from 0 along the ray of λ (the direction set by the damping ratio: 90° undamped, 180°
critically or overdamped) and leaves the stability region at some radius r*. A rig is stable when
h·|λ| ≤ r* for every spring; otherwise n substeps of h/n are needed, n = the smallest integer with
h/n ≤ r*/|λ|.

Boundaries are computed numerically from each method's growth function
(:mod:`hilsim.dynamics.stability_algebra`), so they are right for damped
springs, whose rays are not the axes the textbooks tabulate: a scan of r on a grid finds the first
unstable radius, and bisection pins the crossing to rounding. The growth is evaluated as
|R|² − 1 = 2·Re(R − 1) + |R − 1|², which keeps its sign even when |R| is within 1e-15 of 1.

One rounding floor decides "does this step grow?" everywhere (:func:`grows`): the boundary
search, the substep count and the tests' oracle all call a step stable when its growth is at most
:data:`GROWTH_FLOOR`·(h·|λ|)². Below that the sign of the computed growth is float64 noise.

The substep count is computed once as the ceiling of h / h*, then settled by ±1 with that same
test, and not searched above :data:`MAX_SUBSTEPS` (a spring that needs more is reported with
the count it would need, never looped over).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hilsim._types import FloatArray
from hilsim.dynamics.integrators import Integrator, get_method
from hilsim.dynamics.springs import Spring
from hilsim.dynamics.stability_algebra import growth, spectral_growth

#: scan limit in h·|λ|: explicit methods with up to four stages are unstable well before 10
R_MAX = 10.0
#: scan resolution (grid step R_MAX / N_GRID = 0.005), then bisection to rounding
N_GRID = 2000
_BISECTIONS = 60
#: boundaries below this are reported as exactly 0: the method amplifies the mode at any step size
#: (e.g. Euler or midpoint on an undamped spring), and rounding alone decides where below it
ZERO_FLOOR = 1e-6
#: growth at most GROWTH_FLOOR·(h·|λ|)² counts as "does not grow": spectral_growth sums terms of
#: size ~(h·|λ|)², so it is resolved to ~1e-16 of that; 1e-14 leaves a factor 100 above the noise
GROWTH_FLOOR = 1e-14
#: the largest substep count check_stability reports; above it ``min_substeps`` is None and
#: ``substeps_needed`` says how many it would take (10⁶ steps of an explicit method per tick is
#: seconds of CPU per tick: no real-time loop runs that)
MAX_SUBSTEPS = 1_000_000
#: how many ±1 corrections may follow the ceiling (it is off by at most one in practice)
_SETTLE_STEPS = 8


def grows(growth: npt.ArrayLike, h_lambda: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """True where ``growth`` (ρ² − 1) is above the rounding floor for a step of size h·|λ|.

    The one test of "does this step amplify?" shared by the boundary search, the substep count
    and the test suite's oracle, so they cannot disagree about a step.
    """
    floor = GROWTH_FLOOR * np.square(np.asarray(h_lambda, dtype=np.float64))
    return ~(np.asarray(growth) <= floor)  # nan (an overflowed growth) grows too


def _first_crossing(growth_of_r: Callable[[FloatArray], FloatArray], width: int) -> FloatArray:
    """Per column, the radius where ``growth_of_r`` first turns positive (inf if not by R_MAX).

    ``growth_of_r`` maps radii shaped (G, 1) or (1, width) to growth shaped (G, width).
    """
    r = np.linspace(R_MAX / N_GRID, R_MAX, N_GRID)[:, np.newaxis]
    unstable = grows(growth_of_r(r), r)
    first = np.argmax(unstable, axis=0)
    hi = r[first, 0]
    lo = np.where(first > 0, r[np.maximum(first - 1, 0), 0], 0.0)
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        bad = grows(growth_of_r(mid[np.newaxis, :])[0], mid)
        hi = np.where(bad, mid, hi)
        lo = np.where(bad, lo, mid)  # lo stays a radius known to be stable
    r_star = np.where(unstable.any(axis=0), lo, np.inf)
    return np.where(r_star < ZERO_FLOOR, 0.0, r_star).reshape(width)


def stability_boundary(method: str | type[Integrator], angle: npt.ArrayLike) -> float | FloatArray:
    """Radius r* where the ray z = r·e^(i·angle) first leaves the method's stability region.

    Args:
        method: a method name or class.
        angle: direction of h·λ in radians (π/2 the imaginary axis, π the negative real axis);
            number or array.

    Returns:
        r* (same shape as ``angle``); 0.0 when the method is unstable arbitrarily close to 0 along
        the ray, inf when stable out to :data:`R_MAX`. RK4: 2√2 ≈ 2.8284 at π/2, ≈ 2.7853 at π.
        For semi-implicit Euler the ray is read as an underdamped spring's eigenvalue pair
        (see :func:`hilsim.dynamics.stability_algebra.growth`): 2 at π/2.
    """
    cls = get_method(method)
    angle_arr = np.asarray(angle, dtype=np.float64)
    flat = angle_arr.reshape(-1)
    # cos(π/2) is 6e-17, not 0: enough to tip a method that is exactly neutral on the axis
    # (semi-implicit Euler, undamped) into "growing". Snap the axes to exact directions.
    re, im = np.cos(flat), np.sin(flat)
    re[np.abs(re) < 1e-12] = 0.0
    im[np.abs(im) < 1e-12] = 0.0
    direction = re + 1j * im
    r_star = _first_crossing(lambda r: growth(cls, r * direction), direction.size)
    return float(r_star[0]) if angle_arr.ndim == 0 else r_star.reshape(angle_arr.shape)


def _coefficients(spring: Spring) -> tuple[FloatArray, FloatArray, FloatArray]:
    n = spring.n
    w2 = np.reshape(spring.w2, n)
    cm = np.reshape(spring.cm, n)
    lam_max = np.abs(np.reshape(spring.eigenvalues, (n, 2))).max(axis=1)
    return w2, cm, lam_max


def critical_step(spring: Spring, method: str | type[Integrator] = "rk4") -> FloatArray:
    """Largest step h* (s) per spring such that every h ≤ h* is stable, shape ``(n,)``.

    0 when no step is stable (Euler or midpoint on an undamped spring).
    """
    cls = get_method(method)
    w2, cm, lam_max = _coefficients(spring)
    r_star = _first_crossing(lambda r: spectral_growth(cls, r / lam_max, w2, cm), spring.n)
    return r_star / lam_max


@dataclass(frozen=True, eq=False)
class StabilityReport:
    """Whether ``method`` with step ``h`` is stable for every spring of a bank. Arrays are ``(n,)``.

    Attributes:
        method: the method's name.
        h: the step checked (s).
        spring: the bank checked.
        h_lambda: h·|λ|max per spring, |λ|max the largest eigenvalue magnitude (rad/s).
        boundary: r* per spring: the largest stable h·|λ|max along that spring's eigenvalue ray.
        critical_step: r* / |λ|max, the largest stable step per spring (s).
        angle: direction of the spring's eigenvalue λ in degrees (90 undamped, 180 overdamped).
        stable_springs: per spring, h does not grow it (:func:`grows`; the same as
            h ≤ critical_step, up to rounding).
        min_substeps: smallest n ≥ 1 with h/n stable for every spring; None if no n works, or
            if more than :data:`MAX_SUBSTEPS` would be needed.
        substeps_needed: h / min(critical_step): about how many substeps it takes (1 or less
            when stable; inf when no step is stable); says how far off a capped spring is.
    """

    method: str
    h: float
    spring: Spring
    h_lambda: FloatArray
    boundary: FloatArray
    critical_step: FloatArray
    angle: FloatArray
    stable_springs: npt.NDArray[np.bool_]
    min_substeps: int | None
    substeps_needed: float = math.nan

    @property
    def stable(self) -> bool:
        """True when h is stable for every spring (then ``min_substeps == 1``)."""
        return bool(self.stable_springs.all())

    @property
    def message(self) -> str:
        """A paragraph a rig loader can print when it refuses (or accepts) a rig."""
        n = self.spring.n
        f_hz = np.reshape(self.spring.natural_frequency, n) / (2.0 * math.pi)
        zeta = np.reshape(self.spring.damping_ratio, n)

        def who(j: int) -> str:
            label = "the spring" if n == 1 else f"spring {j}"
            return f"{label} (f = {f_hz[j]:.3g} Hz, ζ = {zeta[j]:.3g})"

        head = f"{self.method} with h = {_ms(self.h)}"
        if self.stable:
            j = int(np.argmax(self.h_lambda / self.boundary))
            where = f"{who(j)}" if n == 1 else f"all {n} springs; the tightest is {who(j)}"
            return (
                f"{head} is stable for {where}: h·|λ| = {self.h_lambda[j]:.4g} against a "
                f"boundary of {self.boundary[j]:.4g} along arg λ = {self.angle[j]:.1f}°; "
                f"largest stable step {_ms(float(self.critical_step.min()))}."
            )
        bad = np.flatnonzero(~self.stable_springs)
        count = "" if n == 1 else f" for {len(bad)} of {n} springs"
        lines = [f"{head} is UNSTABLE{count}:"]
        for j in bad[:5]:
            if self.boundary[j] == 0.0:
                lines.append(
                    f"  {who(j)}: no step is stable; arg λ = {self.angle[j]:.1f}° lies where "
                    f"{self.method} amplifies at every step size."
                )
            else:
                lines.append(
                    f"  {who(j)}: h·|λ| = {self.h_lambda[j]:.4g} exceeds the boundary "
                    f"{self.boundary[j]:.4g} along arg λ = {self.angle[j]:.1f}° "
                    f"(largest stable step {_ms(float(self.critical_step[j]))})."
                )
        if len(bad) > 5:
            lines.append(f"  … and {len(bad) - 5} more.")
        if self.min_substeps is None and math.isfinite(self.substeps_needed):
            lines.append(
                f"It would take about {self.substeps_needed:.3g} substeps (more than "
                f"{MAX_SUBSTEPS:,} are not searched): soften the spring or add damping."
            )
        elif self.min_substeps is None:
            lines.append(
                "No number of substeps helps: add damping or choose 'rk4' or 'semi_implicit_euler'."
            )
        else:
            lines.append(
                f"Use {self.min_substeps} substeps (h/{self.min_substeps} = "
                f"{_ms(self.h / self.min_substeps)}) or a step ≤ "
                f"{_ms(float(self.critical_step.min()))}."
            )
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.message


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:.4g} ms"


def check_stability(
    spring: Spring, h: float, method: str | type[Integrator] = "rk4"
) -> StabilityReport:
    """Check that a fixed step h is stable for every spring of ``spring`` under ``method``.

    Args:
        spring: one spring or a bank.
        h: step (s), finite and > 0.
        method: method name or class.

    Returns:
        a :class:`StabilityReport`; ``str(report)`` explains the verdict.

    Raises:
        ValueError: h is not finite and positive, the method is unknown, or the spring's rates
            (k/m, c/m, its eigenvalues) overflow float64.
    """
    if not (isinstance(h, int | float) and math.isfinite(h) and h > 0.0):
        raise ValueError(f"h must be finite and > 0, got {h!r}")
    cls = get_method(method)
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported just below
        w2, cm, lam_max = _coefficients(spring)
    if not (np.isfinite(w2).all() and np.isfinite(cm).all() and np.isfinite(lam_max).all()):
        raise ValueError(
            "the spring's rates overflow float64 (k/m, c/m or its eigenvalues are not finite): "
            "no step size can integrate it"
        )
    h_star = critical_step(spring, cls)
    lam = np.reshape(spring.eigenvalues, (spring.n, 2))[:, 0]

    def stable_at(step: float) -> npt.NDArray[np.bool_]:
        # per spring: a boundary exists (not "unstable at every step"), the step lies within the
        # scanned range (every method here is unstable beyond R_MAX) and does not grow the mode
        h_lambda = step * lam_max
        with np.errstate(over="ignore", invalid="ignore"):  # far outside: inf/nan, i.e. grows
            g = spectral_growth(cls, step, w2, cm)
        return (h_star > 0.0) & (h_lambda <= R_MAX) & ~grows(g, h_lambda)

    stable = stable_at(float(h))
    h_min = float(h_star.min())
    needed = h / h_min if h_min > 0.0 else math.inf
    substeps: int | None
    if stable.all():
        substeps = 1
    elif not needed <= MAX_SUBSTEPS:
        substeps = None  # no step is stable, or too many substeps to be worth counting
    else:
        # the ceiling once, then settle it by ±1 with the very test the report uses: the
        # rounded quotient can be one off either way, never more
        substeps = max(2, math.ceil(needed))
        for _ in range(_SETTLE_STEPS):
            if stable_at(h / substeps).all():
                break
            substeps += 1
        for _ in range(_SETTLE_STEPS):
            if substeps <= 2 or not stable_at(h / (substeps - 1)).all():
                break
            substeps -= 1
    return StabilityReport(
        method=cls.name,
        h=float(h),
        spring=spring,
        h_lambda=h * lam_max,
        boundary=h_star * lam_max,
        critical_step=h_star,
        angle=np.degrees(np.angle(lam)),
        stable_springs=stable,
        min_substeps=substeps,
        substeps_needed=needed,
    )
