"""Damped springs: the joint model.

Every joint is a damped spring following a target u(t)::

    m·x'' + c·x' + k·x = k·u + b·u'

x is the joint position (rad for a rotary joint, m for a linear one), u the animation target in
the same unit, m the mass (kg, or the inertia kg·m²), c the damping coefficient (N·s/m or
N·m·s/rad), k the stiffness (N/m or N·m/rad) and b a velocity feed-forward gain in the unit of c
(b = 0 is a plain spring pulled towards u; b > 0 makes it react to how fast the target moves,
b < 0 makes it anticipate). The integrators advance it as the first-order system
x' = v, v' = (k·(u − x) + b·u' − c·v) / m.

A :class:`Spring` holds scalars (one spring) or 1-D arrays (a *bank*: one entry per joint, all
arrays shaped ``(n,)``); the real-time loop holds one bank for all joints on a bus.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from hilsim._types import FloatArray


def _parameter(name: str, value: Any, *, lower: float, strict: bool) -> FloatArray:
    """``value`` as a float64 array (ndim ≤ 1), finite and above ``lower``; else a ValueError."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"{name} must be a number or a 1-D array of numbers, got {value!r}"
        ) from None
    if arr.ndim > 1:
        raise ValueError(f"{name} must be a number or a 1-D array, got shape {arr.shape}")
    bad = ~np.isfinite(arr)
    if lower != -math.inf:
        bad |= (arr <= lower) if strict else (arr < lower)
    if bad.any():
        where = f"[{int(np.flatnonzero(bad)[0])}]" if arr.ndim else ""
        got = arr[bad][0] if arr.ndim else float(arr)
        need = "finite" if lower == -math.inf else f"finite and {'>' if strict else '>='} {lower:g}"
        raise ValueError(f"{name}{where} must be {need}, got {got!r}")
    return arr


def _frozen(arr: FloatArray, shape: tuple[int, ...]) -> FloatArray:
    out = np.array(np.broadcast_to(arr, shape), dtype=np.float64)
    out.flags.writeable = False
    return out


def oscillator_eigenvalues(w2: npt.ArrayLike, cm: npt.ArrayLike) -> npt.NDArray[np.complex128]:
    """Eigenvalues of [[0, 1], [−w2, −cm]] (w2 = k/m, cm = c/m), shape ``broadcast + (2,)``.

    Underdamped pairs come out as −cm/2 ± i·√(w2 − cm²/4) with an exact real part (exactly 0 when
    undamped); real pairs take the smaller root from λ₁λ₂ = w2 so it keeps full precision.
    """
    gamma = 0.5 * np.asarray(cm, dtype=np.float64)
    w2 = np.asarray(w2, dtype=np.float64)
    disc = gamma**2 - w2
    root = np.sqrt(np.abs(disc))
    under = disc < 0.0
    fast = -gamma - root
    lam1 = np.where(under, -gamma + 1j * root, fast + 0j)
    lam2 = np.where(under, -gamma - 1j * root, w2 / fast + 0j)
    return np.stack([lam1, lam2], axis=-1)


@dataclass(frozen=True, eq=False, init=False)
class Spring:
    """One damped spring, or a bank of them, following targets: ``m·x'' + c·x' + k·x = k·u + b·u'``.

    Parameters may be numbers (one spring) or 1-D arrays shaped ``(n,)`` (a bank; numbers
    broadcast across it). After construction each is a read-only float64 ndarray of shape
    :attr:`shape`, which is ``()`` for one spring and ``(n,)`` for a bank.

    Args:
        m: mass, > 0 (kg; kg·m² for a rotary joint).
        c: damping coefficient, ≥ 0 (N·s/m; N·m·s/rad).
        k: stiffness, > 0 (N/m; N·m/rad).
        b: target-velocity feed-forward, any finite value (unit of c). 0 for a plain spring.

    Raises:
        ValueError: a parameter is non-finite or out of range (the message names it and, for a bank,
            the first offending index), or the parameters do not broadcast to one bank shape.

    Derived quantities (all of shape :attr:`shape`): ``natural_frequency`` ω₀ = √(k/m) rad/s,
    ``damping_ratio`` ζ = c / (2√(k·m)), ``decay_rate`` γ = c / (2m) 1/s, ``damped_frequency``
    ω_d = √(ω₀² − γ²) rad/s (0 when ζ ≥ 1), ``eigenvalues`` λ₁,₂ = −γ ± √(γ² − ω₀²). The rates
    the integrators and the stability guard work with are named once: ``w2`` = k/m (= ω₀², 1/s²),
    ``cm`` = c/m (= 2γ, 1/s) and ``bm`` = b/m (1/s).
    """

    m: FloatArray
    c: FloatArray
    k: FloatArray
    b: FloatArray

    def __init__(
        self, m: npt.ArrayLike, c: npt.ArrayLike, k: npt.ArrayLike, b: npt.ArrayLike = 0.0
    ) -> None:
        # written out (not generated) so the fields are typed as what they hold after it
        params = {
            "m": _parameter("m", m, lower=0.0, strict=True),
            "c": _parameter("c", c, lower=0.0, strict=False),
            "k": _parameter("k", k, lower=0.0, strict=True),
            "b": _parameter("b", b, lower=-math.inf, strict=False),
        }
        try:
            shape = np.broadcast_shapes(*(p.shape for p in params.values()))
        except ValueError:
            shapes = ", ".join(f"{n}: {p.shape}" for n, p in params.items())
            raise ValueError(f"m, c, k and b must share one bank shape, got {shapes}") from None
        for name, arr in params.items():
            object.__setattr__(self, name, _frozen(arr, shape))

    # -- construction -----------------------------------------------------------------------------

    @classmethod
    def from_animation(
        cls,
        frequency_hz: npt.ArrayLike,
        damping_ratio: npt.ArrayLike,
        response: npt.ArrayLike = 0.0,
    ) -> Spring:
        """The animators' "second-order dynamics" spring: frequency f, damping ratio ζ, response r.

        Animation tools write ``y + k1·y' + k2·y'' = x + k3·x'`` (y the joint, x the target) with::

            k1 = ζ / (π·f)        k2 = 1 / (2π·f)²        k3 = r·ζ / (2π·f)

        which is this class's equation with ``m = k2``, ``c = k1``, ``k = 1``, ``b = k3``; then
        ω₀ = 2π·f and the damping ratio is ζ. ``r = 0`` follows the target like a plain spring,
        ``r = 1`` reacts to the target's velocity at once, ``r > 1`` overshoots the target's motion
        and ``r < 0`` anticipates it (starts the other way).

        Args:
            frequency_hz: natural frequency f, > 0 (Hz); number or ``(n,)`` array.
            damping_ratio: ζ, ≥ 0 (0 undamped, 1 critically damped); number or ``(n,)`` array.
            response: r, any finite value (dimensionless); number or ``(n,)`` array.
        """
        f = _parameter("frequency_hz", frequency_hz, lower=0.0, strict=True)
        zeta = _parameter("damping_ratio", damping_ratio, lower=0.0, strict=False)
        r = _parameter("response", response, lower=-math.inf, strict=False)
        omega = 2.0 * math.pi * f
        return cls(m=1.0 / omega**2, c=2.0 * zeta / omega, k=1.0, b=r * zeta / omega)

    @classmethod
    def stack(cls, springs: Sequence[Spring]) -> Spring:
        """One bank from several springs or banks, in order (e.g. one per joint on a bus)."""
        if not springs:
            raise ValueError("springs must not be empty")
        return cls(
            **{
                name: np.concatenate([np.atleast_1d(getattr(s, name)) for s in springs])
                for name in ("m", "c", "k", "b")
            }
        )

    # -- shape ------------------------------------------------------------------------------------

    @property
    def shape(self) -> tuple[int, ...]:
        """``()`` for one spring, ``(n,)`` for a bank."""
        return np.shape(self.m)

    @property
    def n(self) -> int:
        """Number of springs (1 for a single spring)."""
        return int(np.size(self.m))

    def __len__(self) -> int:
        return self.n

    # -- physics ----------------------------------------------------------------------------------

    @property
    def w2(self) -> FloatArray:
        """k/m in 1/s² (= ω₀²): the stiffness per unit mass, x'' = −w2·x − cm·x' for u = 0."""
        return self.k / self.m

    @property
    def cm(self) -> FloatArray:
        """c/m in 1/s (= 2γ): the damping per unit mass."""
        return self.c / self.m

    @property
    def bm(self) -> FloatArray:
        """b/m in 1/s: the target-velocity feed-forward per unit mass."""
        return self.b / self.m

    @property
    def natural_frequency(self) -> FloatArray:
        """ω₀ = √(k/m) in rad/s."""
        return np.sqrt(self.w2)

    @property
    def damping_ratio(self) -> FloatArray:
        """ζ = c / (2√(k·m)): < 1 underdamped, 1 critically damped, > 1 overdamped."""
        return self.c / (2.0 * np.sqrt(self.k * self.m))

    @property
    def decay_rate(self) -> FloatArray:
        """γ = c / (2m) in 1/s: an underdamped spring's amplitude falls as e^(−γt)."""
        return self.c / (2.0 * self.m)

    @property
    def damped_frequency(self) -> FloatArray:
        """ω_d = √(ω₀² − γ²) = ω₀·√(1 − ζ²) in rad/s for ζ < 1; 0 when critically or overdamped."""
        return np.sqrt(np.maximum(self.w2 - self.decay_rate**2, 0.0))

    @property
    def system_matrix(self) -> FloatArray:
        """J = [[0, 1], [−k/m, −c/m]], shape ``shape + (2, 2)``: d/dt [x, v] = J·[x, v] (u = 0)."""
        out = np.zeros((*self.shape, 2, 2))
        out[..., 0, 1] = 1.0
        out[..., 1, 0] = -self.w2
        out[..., 1, 1] = -self.cm
        return out

    @property
    def eigenvalues(self) -> npt.NDArray[np.complex128]:
        """λ₁,₂ of :attr:`system_matrix`, shape ``shape + (2,)`` (rad/s); +Im first for a pair.

        Underdamped: −γ ± i·ω_d (real part exactly −γ, so an undamped spring's λ is exactly
        imaginary). Overdamped: two negative reals, the small one from Vieta (λ₁λ₂ = k/m) so it
        keeps full precision when γ ≫ ω₀.
        """
        return oscillator_eigenvalues(self.w2, self.cm)

    def energy(self, x: npt.ArrayLike, v: npt.ArrayLike, u: npt.ArrayLike = 0.0) -> FloatArray:
        """Mechanical energy ½·m·v² + ½·k·(x − u)² (J), broadcast over x, v (e.g. ``(T, n)``).

        With the default ``u = 0`` this is the free spring's energy, which only damping removes; an
        integrator that changes it on an undamped spring is adding or destroying energy.
        """
        xa = np.asarray(x, dtype=np.float64)
        va = np.asarray(v, dtype=np.float64)
        return 0.5 * self.m * va**2 + 0.5 * self.k * (xa - np.asarray(u, dtype=np.float64)) ** 2

    def exact(
        self, t: npt.ArrayLike, x0: npt.ArrayLike, v0: npt.ArrayLike = 0.0
    ) -> tuple[FloatArray, FloatArray]:
        """Closed-form free motion (u = 0) from x(0) = x0, v(0) = v0.

        With γ = c/2m and ω₀² = k/m, for every damping regime::

            x(t) = e^(−γt)·[x0·C(t) + (v0 + γ·x0)·S(t)]
            v(t) = e^(−γt)·[v0·C(t) − (ω₀²·x0 + γ·v0)·S(t)]

        where C, S = cos(ω_d t), sin(ω_d t)/ω_d (underdamped, ω_d = √(ω₀² − γ²)); 1, t (critically
        damped); cosh(s t), sinh(s t)/s (overdamped, s = √(γ² − ω₀²)). The overdamped terms are
        evaluated as e^(−(γ−s)t)·(1 ± e^(−2st))/… with expm1, so they neither overflow for long t
        nor lose precision near critical damping. Times are t ≥ 0.

        Args:
            t: times (s), any shape ``T``.
            x0, v0: initial position and velocity, broadcast to :attr:`shape`.

        Returns:
            (x, v), each of shape ``T + shape`` (e.g. ``(len(t), n)`` for a bank).
        """
        t = np.asarray(t, dtype=np.float64)[(...,) + (np.newaxis,) * len(self.shape)]
        gamma = self.decay_rate
        w2 = self.w2
        q = w2 - gamma**2
        w = np.sqrt(np.abs(q))
        # decay·C and decay·S per regime; the overdamped pair is written with e^(−(γ−s)t) and
        # expm1 so it neither overflows (cosh) for long t nor cancels as s → 0.
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            decay = np.exp(-gamma * t)
            slow = np.exp(-(gamma - w) * t)
            fast = np.exp(-2.0 * w * t)
            dc = np.where(
                q > 0, decay * np.cos(w * t), np.where(q < 0, 0.5 * slow * (1.0 + fast), decay)
            )
            ds = np.where(
                q > 0,
                decay * np.sin(w * t) / w,
                np.where(q < 0, slow * -np.expm1(-2.0 * w * t) / (2.0 * w), decay * t),
            )
        x0 = np.asarray(x0, dtype=np.float64)
        v0 = np.asarray(v0, dtype=np.float64)
        x = x0 * dc + (v0 + gamma * x0) * ds
        v = v0 * dc - (w2 * x0 + gamma * v0) * ds
        return x, v

    def __repr__(self) -> str:
        if not self.shape:
            return (
                f"Spring(m={float(self.m)!r}, c={float(self.c)!r}, "
                f"k={float(self.k)!r}, b={float(self.b)!r})"
            )
        return f"Spring(n={self.n}, m={self.m!r}, c={self.c!r}, k={self.k!r}, b={self.b!r})"
