"""``simulate``: integrate a spring (or a bank) over a time span and return the whole trajectory.

The offline entry point (studies, plots, tests). The real-time loop instead keeps one
:class:`~hilsim.dynamics.integrators.Integrator` and calls ``step`` once per tick.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hilsim._types import FloatArray
from hilsim.dynamics.held_step import Sample
from hilsim.dynamics.integrators import TargetLike, get_method
from hilsim.dynamics.springs import Spring

#: a run longer than this many steps is almost surely a unit slip in h (ms for s)
MAX_STEPS = 50_000_000

TargetArg = float | npt.ArrayLike | Callable[[float], Sample] | None


@dataclass(frozen=True, eq=False)
class Trajectory:
    """The states of a simulated spring or bank at every step.

    Attributes:
        t: times (s), shape ``(T,)`` with T = n_steps + 1; t[i] = i·h.
        x: positions (rad), shape ``(T,)`` for one spring, ``(T, n)`` for a bank.
        v: velocities (rad/s), same shape as x.
        spring: the spring or bank simulated.
        method: the integrator's name.
        h: the step (s).
    """

    t: FloatArray
    x: FloatArray
    v: FloatArray
    spring: Spring
    method: str
    h: float

    @property
    def n_steps(self) -> int:
        return len(self.t) - 1

    def energy(self) -> FloatArray:
        """Free-spring energy ½·m·v² + ½·k·x² (J) at every step, shape like x."""
        return self.spring.energy(self.x, self.v)


def _finite(name: str, value: npt.ArrayLike, shape: tuple[int, ...]) -> FloatArray:
    try:
        arr = np.asarray(value, dtype=np.float64)
        arr = np.broadcast_to(arr, shape)
    except (TypeError, ValueError):
        raise ValueError(
            f"{name} must be a number or an array broadcastable to {shape}, got {value!r}"
        ) from None
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return arr


def _positive(name: str, value: float) -> float:
    if not isinstance(value, int | float) or not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


def _target_function(spring: Spring, target: TargetArg, target_rate: TargetArg) -> TargetLike:
    """simulate's target arguments as an integrator takes them: None, (u, du) or t → (u, du)."""
    shape = spring.shape
    if target is None:
        if target_rate is not None:
            raise ValueError("target_rate was given without a target")
        return None
    if not callable(target) and not callable(target_rate):
        u = _finite("target", target, shape)
        du = _finite("target_rate", 0.0 if target_rate is None else target_rate, shape)
        return (u.reshape(spring.n), du.reshape(spring.n))
    if target_rate is None and np.any(spring.b != 0.0):
        raise ValueError(
            "target_rate is needed: the spring has b ≠ 0, so it follows the target's velocity "
            "u'(t); pass target_rate=callable or number"
        )

    def constant(value: FloatArray) -> Callable[[float], FloatArray]:
        return lambda t: value

    u_of = target if callable(target) else constant(_finite("target", target, shape))
    rate = 0.0 if target_rate is None else target_rate
    du_of = rate if callable(rate) else constant(_finite("target_rate", rate, shape))
    return lambda t: (u_of(t), du_of(t))


def simulate(
    spring: Spring,
    x0: npt.ArrayLike,
    v0: npt.ArrayLike = 0.0,
    *,
    h: float,
    t_end: float,
    method: str = "rk4",
    target: TargetArg = None,
    target_rate: TargetArg = None,
) -> Trajectory:
    """Integrate ``m·x'' + c·x' + k·x = k·u + b·u'`` from t = 0 with a fixed step.

    Takes ``round(t_end / h)`` steps, so the trajectory has that many + 1 points including t = 0,
    at t = i·h: the paper's "1000 points on [0, 10]" is ``h = 10/999, t_end = 10``.

    Args:
        spring: one spring or a bank of n.
        x0, v0: initial position (rad) and velocity (rad/s); numbers or ``(n,)`` arrays.
        h: step (s), finite and > 0.
        t_end: duration (s), finite and > 0, at least half a step.
        method: ``"euler"``, ``"semi_implicit_euler"``, ``"midpoint"`` or ``"rk4"``.
        target: u: None (u = 0, the free spring), a number or ``(n,)`` array (a constant target),
            or a callable ``u(t)`` returning a number or ``(n,)`` array (rad). A callable is
            sampled at every evaluation inside a step (t, t + h/2, t + h for RK4).
        target_rate: u'(t) (rad/s), in the same forms; 0 by default. Required when target is a
            callable and any b ≠ 0.

    Returns:
        a :class:`Trajectory` with ``t`` ``(T,)``, and ``x``, ``v`` ``(T,)`` or ``(T, n)``.

    Raises:
        ValueError: an argument is out of range or malformed; the message names it.
    """
    if not isinstance(spring, Spring):
        raise ValueError(f"spring must be a hilsim.Spring, got {type(spring).__name__}")
    h = _positive("h", h)
    t_end = _positive("t_end", t_end)
    n_steps = round(t_end / h)
    if n_steps < 1:
        raise ValueError(f"t_end must be at least half a step (h = {h!r}), got {t_end!r}")
    if n_steps > MAX_STEPS:
        raise ValueError(
            f"h = {h!r} gives {n_steps} steps over t_end = {t_end!r} (max {MAX_STEPS})"
        )
    integrator = get_method(method)(spring)
    shape = spring.shape
    x0_arr = _finite("x0", x0, shape).reshape(spring.n)
    v0_arr = _finite("v0", v0, shape).reshape(spring.n)
    forcing = _target_function(spring, target, target_rate)
    xs, vs = integrator.run(x0_arr, v0_arr, h, n_steps, 0.0, forcing)
    return Trajectory(
        t=h * np.arange(n_steps + 1, dtype=np.float64),
        x=xs.reshape((n_steps + 1, *shape)),
        v=vs.reshape((n_steps + 1, *shape)),
        spring=spring,
        method=integrator.name,
        h=h,
    )
