"""Stability algebra of the integrators: how much one free step amplifies a spring's modes.

Functions of a method (a name or an :class:`~hilsim.dynamics.integrators.Integrator` class),
kept apart from the stepping code in :mod:`hilsim.dynamics.integrators`.
:mod:`hilsim.dynamics.stability` builds the rig's stability guard on them.
All of them describe the free spring (u = 0); the derivations and the
resulting boundaries are collected in ``docs/numerics.md``.

* An explicit Runge–Kutta method multiplies each eigen-mode e^(λt) by its stability function
  R(z), z = h·λ, every step: a polynomial of degree ≤ s read off the Butcher tableau
  (:func:`stability_polynomial`, :func:`stability_function`).
* Semi-implicit Euler is not a Runge–Kutta method and has no scalar R; its one-step update matrix
  M(h) is analysed instead (:func:`semi_implicit_euler_update_matrix`,
  :func:`semi_implicit_euler_amplification`).
* :func:`growth` (in the h·λ plane) and :func:`spectral_growth` (for a spring given by w2 = k/m
  and cm = c/m) give ρ² − 1 for either kind: ≤ 0 means no mode grows.
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from hilsim._types import FloatArray
from hilsim.dynamics.integrators import Integrator, RungeKutta, SemiImplicitEuler, get_method
from hilsim.dynamics.springs import oscillator_eigenvalues

MethodLike = str | type[Integrator]


@functools.cache
def _poly(cls: type[RungeKutta]) -> FloatArray:
    # R(z) = 1 + Σ_k (Bᵀ·A^(k−1)·1) z^k for an explicit method: a polynomial of degree ≤ s
    s = len(cls.B)
    poly, vec = [1.0], np.ones(s)
    for _ in range(s):
        poly.append(float(cls.B @ vec))
        vec = cls.A @ vec
    out = np.array(poly)
    out.flags.writeable = False
    return out


def _runge_kutta(method: MethodLike) -> type[RungeKutta]:
    cls = get_method(method)
    if not issubclass(cls, RungeKutta):
        raise ValueError(f"method must be a Runge–Kutta method, got {cls.name!r}")
    return cls


def _no_algebra(cls: type[Integrator]) -> ValueError:
    return ValueError(f"no stability analysis is known for the method {cls.name!r}")


# -- explicit Runge–Kutta methods ---------------------------------------------------------------


def stability_polynomial(method: MethodLike) -> FloatArray:
    """Coefficients of R(z), lowest degree first (RK4: 1, 1, 1/2, 1/6, 1/24).

    Raises:
        ValueError: the method is unknown or not a Runge–Kutta method.
    """
    return _poly(_runge_kutta(method)).copy()


def stability_function(method: MethodLike, z: npt.ArrayLike) -> npt.NDArray[np.complex128]:
    """R(z), z = h·λ (complex, any shape): one step multiplies the mode e^(λt) by R(h·λ).

    The method is stable for that mode when |R(z)| ≤ 1. Euler: 1 + z; midpoint: 1 + z + z²/2;
    RK4: 1 + z + z²/2 + z³/6 + z⁴/24.

    Raises:
        ValueError: the method is unknown or not a Runge–Kutta method.
    """
    poly = _poly(_runge_kutta(method))
    z = np.asarray(z, dtype=np.complex128)
    out = np.full(z.shape, poly[-1], dtype=np.complex128)
    for coeff in poly[-2::-1]:
        out = out * z + coeff
    return out


def _rk_growth(cls: type[RungeKutta], z: npt.ArrayLike) -> npt.NDArray[np.float64]:
    poly = _poly(cls)
    z = np.asarray(z, dtype=np.complex128)
    # |1 + w|² − 1 = 2·Re(w) + |w|² with w = R(z) − 1, so small growth is not lost to rounding
    w: npt.NDArray[np.complex128] = np.full(z.shape, poly[-1], dtype=np.complex128)
    for coeff in poly[-2:0:-1]:
        w = w * z + coeff
    w = w * z
    return 2.0 * w.real + (w.real**2 + w.imag**2)


# -- semi-implicit Euler ------------------------------------------------------------------------


def semi_implicit_euler_update_matrix(theta: npt.ArrayLike, zeta: npt.ArrayLike) -> FloatArray:
    """Semi-implicit Euler's free step M in the scaled state (x, v/ω₀), ``broadcast + (2, 2)``.

    With θ = h·ω₀ and damping ratio ζ::

        M = [[1 − θ²,  θ·(1 − 2ζθ)],
             [−θ,      1 − 2ζθ    ]]      trace 2 − θ² − 2ζθ, det 1 − 2ζθ
    """
    theta = np.asarray(theta, dtype=np.float64)
    zeta = np.asarray(zeta, dtype=np.float64)
    theta, zeta = np.broadcast_arrays(theta, zeta)
    damp = 1.0 - 2.0 * zeta * theta
    out = np.empty((*theta.shape, 2, 2))
    out[..., 0, 0] = 1.0 - theta**2
    out[..., 0, 1] = theta * damp
    out[..., 1, 0] = -theta
    out[..., 1, 1] = damp
    return out


def semi_implicit_euler_amplification(theta: npt.ArrayLike, zeta: npt.ArrayLike) -> FloatArray:
    """Spectral radius ρ of :func:`semi_implicit_euler_update_matrix` (θ = h·ω₀, damping ζ).

    This plays the role of |R(z)|: after many steps the free spring's amplitude scales as ρ per
    step, so ρ ≤ 1 is stable. While the eigenvalues are a complex pair, ρ = √(1 − 2ζθ) exactly:
    undamped (ζ = 0) gives ρ = 1 for every θ < 2, i.e. no numerical gain or loss of amplitude,
    only a phase error. Stability ends where an eigenvalue reaches −1:
    θ* = 2·(√(1 + ζ²) − ζ) (θ* = 2 undamped, ≈ 0.83 critically damped).
    """
    theta = np.asarray(theta, dtype=np.float64)
    damp = 2.0 * np.asarray(zeta, dtype=np.float64) * theta
    return np.sqrt(_growth_from_trace_det(2.0 - theta**2 - damp, 1.0 - damp) + 1.0)


def _growth_from_trace_det(trace: npt.ArrayLike, det: npt.ArrayLike) -> FloatArray:
    """ρ² − 1 for a real 2×2 matrix from its trace and determinant."""
    trace = np.asarray(trace, dtype=np.float64)
    det = np.asarray(det, dtype=np.float64)
    disc = 0.25 * trace**2 - det
    root = np.sqrt(np.abs(disc))
    real_rho = np.maximum(np.abs(0.5 * trace + root), np.abs(0.5 * trace - root))
    # a complex pair has |μ|² = det exactly; keeping that form makes undamped growth exactly 0
    return np.where(disc < 0.0, det - 1.0, real_rho**2 - 1.0)


# -- either kind --------------------------------------------------------------------------------


def growth(method: MethodLike, z: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """ρ² − 1 for an oscillator mode with h·λ = z (complex): > 0 means it grows every step.

    For a Runge–Kutta method this is |R(z)|² − 1, computed without cancelling against the
    leading 1. For semi-implicit Euler it is ρ² − 1 of the update matrix of the underdamped
    spring whose eigenvalue pair is (z, z̄)/h: then θ² = |z|² and 2ζθ = −2·Re z, so
    trace M = 2 + 2·Re z − |z|² and det M = 1 + 2·Re z. That maps semi-implicit Euler onto the
    same h·λ plane as the Runge–Kutta methods; it describes the oscillator, not a scalar test
    equation. ≤ 0 is stable: this is what the stability regions and the stability guard test.

    Raises:
        ValueError: the method is unknown.
    """
    cls = get_method(method)
    if issubclass(cls, RungeKutta):
        return _rk_growth(cls, z)
    if issubclass(cls, SemiImplicitEuler):
        z = np.asarray(z, dtype=np.complex128)
        return _growth_from_trace_det(2.0 + 2.0 * z.real - np.abs(z) ** 2, 1.0 + 2.0 * z.real)
    raise _no_algebra(cls)


def spectral_growth(
    method: MethodLike, h: npt.ArrayLike, w2: npt.ArrayLike, cm: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """ρ(M)² − 1 of the one-step update matrix M for the free spring x'' = −w2·x − cm·x'.

    Broadcasts over h (s),
    w2 = k/m (1/s², :attr:`Spring.w2 <hilsim.dynamics.springs.Spring.w2>`) and
    cm = c/m (1/s, :attr:`Spring.cm <hilsim.dynamics.springs.Spring.cm>`). ≤ 0: no mode grows.

    Rounding floor: the value is computed in float64 from terms of size ~(h·|λ|)², so it
    is resolved to about 1e-16·(h·|λ|)². Where the true growth is smaller than that (an
    undamped spring at a tiny step: RK4 loses −(hω)⁶/72 per step, −1e-26 at hω = 1e-4)
    the sign is rounding noise. The stability guard never asks there: it scans from
    h·|λ| = 0.005 up.

    Raises:
        ValueError: the method is unknown.
    """
    cls = get_method(method)
    if issubclass(cls, RungeKutta):
        # M = R(h·J): its eigenvalues are R(h·λ) for the two eigenvalues λ of J
        lam = oscillator_eigenvalues(w2, cm)
        g = _rk_growth(cls, np.asarray(h, dtype=np.float64)[..., np.newaxis] * lam)
        worst: FloatArray = g.max(axis=-1)  # of the pair
        return worst
    if issubclass(cls, SemiImplicitEuler):
        h = np.asarray(h, dtype=np.float64)
        hc = h * np.asarray(cm, dtype=np.float64)
        w2 = np.asarray(w2, dtype=np.float64)
        return _growth_from_trace_det(2.0 - h**2 * w2 - hc, 1.0 - hc)
    raise _no_algebra(cls)
