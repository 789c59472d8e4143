"""Fixed-step integrators that advance a bank of damped springs in place: how to step.

Each joint obeys x' = v, v' = a with a = (k·(u − x) + b·u' − c·v) / m
(see :mod:`hilsim.dynamics.springs`).
Four methods, chosen by name (:data:`INTEGRATORS`; each class has its ``order`` and
``evals_per_step``): "euler" (explicit Euler, order 1), "semi_implicit_euler" (symplectic Euler,
order 1), "midpoint" (explicit midpoint, order 2) and "rk4" (classical Runge–Kutta, order 4).

The explicit Runge–Kutta methods are data: a Butcher tableau (class attributes ``A``, ``B``, ``C``,
``order``) drives one generic step. Semi-implicit Euler is not a Runge–Kutta method and has its
own step. Their stability (how much a step amplifies a free spring) is
:mod:`hilsim.dynamics.stability_algebra`. Tableaux, orders and stability boundaries:
``docs/numerics.md``.

State is two float64 arrays shaped ``(n,)``, positions x and velocities v, updated in place; all
buffers are allocated when the integrator is built, none in :meth:`Integrator.step`. A small bank
(n ≤ ``small_bank_limit``, 16) steps in pure Python on floats, because numpy spends ~1 µs per
ufunc call and a step is a few dozen calls; a large bank steps with ``out=`` ufuncs. Both paths
perform the same floating-point operations in the same order, so they give bit-identical results.
With a held target (the loop's case) each method's step is a linear map, worked out once per step
size from the method (:meth:`Integrator.held_matrix`; applied by :class:`~.rk_lists.HeldStep`).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import ClassVar

import numpy as np
import numpy.typing as npt

from drivers.fill import Packed
from hilsim._types import FloatArray
from hilsim.dynamics.held_step import Combo as _Combo
from hilsim.dynamics.held_step import (
    HeldStep,
    Sample,
    kick_drift_matrix,
    solve_tableau,
    tableau_matrix,
)
from hilsim.dynamics.held_step import as_list as _as_list
from hilsim.dynamics.held_step import combo as _combo
from hilsim.dynamics.held_step import scale as _scale
from hilsim.dynamics.springs import Spring

#: u(t), u'(t) for every joint at time t (floats or arrays broadcastable to ``(n,)``; rad, rad/s).
Target = Callable[[float], tuple[Sample, Sample]]
#: what :meth:`Integrator.step` accepts: None (u = u' = 0), (u, u') held over the step, or u(t)
TargetLike = Target | tuple[Sample, Sample] | None


class Integrator(ABC):
    """A fixed-step method bound to one spring bank, with its buffers preallocated.

    Build one with :func:`make_integrator`; call :meth:`step` every tick. ``vectorized`` forces the
    numpy path (True) or the pure-Python path (False); by default small banks use pure Python.
    """

    name: ClassVar[str]
    #: global order of accuracy: the error at a fixed time falls as h**order
    order: ClassVar[int]
    #: right-hand-side (acceleration) evaluations per step: the cost unit of a work–precision plot
    evals_per_step: ClassVar[int]
    #: the fraction c of the step at which each evaluation samples the target
    stage_times: ClassVar[tuple[float, ...]]
    #: largest bank that steps in pure Python (docs/numerics.md: pure Python wins below ~16)
    small_bank_limit: ClassVar[int] = 16

    def __init__(self, spring: Spring, *, vectorized: bool | None = None) -> None:
        self.spring, self.n = spring, (n := spring.n)
        self.vectorized = n > self.small_bank_limit if vectorized is None else bool(vectorized)
        w2 = np.reshape(spring.w2, n)
        self._w2 = w2
        self._bm = np.reshape(spring.bm, n)
        self._neg_w2 = -w2
        self._neg_cm = -np.reshape(spring.cm, n)
        self._has_b = bool(np.any(self._bm != 0.0))
        self._w2_l: list[float] = w2.tolist()
        self._bm_l: list[float] = self._bm.tolist()
        self._neg_w2_l: list[float] = self._neg_w2.tolist()
        self._neg_cm_l: list[float] = self._neg_cm.tolist()
        # distinct target sampling instants, and which one each evaluation uses
        self._sample_c = tuple(sorted(set(self.stage_times)))
        self._stage_slot = tuple(self._sample_c.index(c) for c in self.stage_times)
        self._g = np.empty((len(self._sample_c), n))  # forcing w2·u + bm·u' per sampling instant
        self._acc = np.empty(n)
        self._tmp = np.empty(n)
        self._xv = self._vv = Packed()  # x, v as the list path reads and writes them
        self._held: HeldStep | None = None  # the held-target step at the last h

    # -- public -----------------------------------------------------------------------------------

    def step(
        self, x: FloatArray, v: FloatArray, h: float, t: float = 0.0, target: TargetLike = None
    ) -> None:
        """Advance every spring from t to t + h, writing the new state into ``x`` and ``v``.

        Args:
            x: positions, float64 array shaped ``(n,)`` (rad), updated in place.
            v: velocities, float64 array shaped ``(n,)`` (rad/s), updated in place.
            h: step (s), > 0. Not checked here: this is the real-time hot path; check the rig once
                with :func:`hilsim.dynamics.stability.check_stability`.
            t: time at the start of the step (s); only a callable target reads it.
            target: ``None`` (u = u' = 0), a pair ``(u, du)`` held over the step (the real-time
                loop's case: targets sampled once per tick), or a callable ``t -> (u, du)`` sampled
                at each evaluation's time t + c·h. u in rad, du in rad/s; floats or ``(n,)`` arrays.
        """
        if type(target) is tuple:  # held over the step (the loop's case): the linear map
            held = self._held
            (held if held is not None and held.h == h else self.held_step(h)).step(x, v, *target)
        elif self.vectorized:
            self._step_arrays(x, v, h, t, target)
        else:
            # a numpy-scalar h would turn every float operation below into a slower numpy one
            xv, vv = self._xv, self._vv
            if xv.arr is not x or vv.arr is not v:  # the caller's arrays, viewed once
                xv, vv = self._xv, self._vv = Packed(x, self.n), Packed(v, self.n)
            xl, vl = self._step_lists(xv.tolist(), vv.tolist(), float(h), float(t), target)
            xv.put(*xl)
            vv.put(*vl)

    def run(
        self,
        x0: npt.ArrayLike,
        v0: npt.ArrayLike,
        h: float,
        n_steps: int,
        t0: float = 0.0,
        target: TargetLike = None,
    ) -> tuple[FloatArray, FloatArray]:
        """Take ``n_steps`` steps from (x0, v0) at t0 and record every state.

        Step i starts at t0 + i·h (a product, not a running sum, so times do not drift).

        Returns:
            (X, V), each shaped ``(n_steps + 1, n)``; row 0 is the initial state.
        """
        n, h, t0 = self.n, float(h), float(t0)
        x = np.array(np.broadcast_to(np.asarray(x0, dtype=np.float64), (n,)))
        v = np.array(np.broadcast_to(np.asarray(v0, dtype=np.float64), (n,)))
        if not self.vectorized and type(target) is not tuple:  # (held: through step)
            xl, vl = x.tolist(), v.tolist()
            xs, vs = [xl], [vl]
            for i in range(n_steps):
                xl, vl = self._step_lists(xl[:], vl[:], h, t0 + i * h, target)
                xs.append(xl)
                vs.append(vl)
            return np.array(xs, dtype=np.float64), np.array(vs, dtype=np.float64)
        xs_a = np.empty((n_steps + 1, n))
        vs_a = np.empty((n_steps + 1, n))
        xs_a[0], vs_a[0] = x, v
        for i in range(n_steps):
            self.step(x, v, h, t0 + i * h, target)
            xs_a[i + 1], vs_a[i + 1] = x, v
        return xs_a, vs_a

    def held_matrix(self, h: float) -> FloatArray:
        """One step of each spring with the target held, as a matrix: shaped ``(n, 3, 3)``,
        mapping (x, v, g) to (x', v', g), g = w2·u + bm·u' the forcing (the last row is
        (0, 0, 1)). The method's own step on a linear system is linear, so this is exactly
        what it computes (:class:`hilsim.dynamics.held_step.HeldStep`)."""
        M = np.zeros((self.n, 3, 3))  # d/dt (x, v, g) = M·(x, v, g)
        M[:, 0, 1], M[:, 1, 0], M[:, 1, 1], M[:, 1, 2] = 1.0, self._neg_w2, self._neg_cm, 1.0
        return self._step_matrix(M, float(h))

    def held_step(self, h: float) -> HeldStep:
        """The held-target step at ``h``, built now (the loop builds its own before tick 0)."""
        bm = self._bm if self._has_b else None
        self._held = HeldStep(self.held_matrix(h), h, self._w2, bm, self.vectorized)
        return self._held

    # -- hooks ------------------------------------------------------------------------------------

    @abstractmethod
    def _step_matrix(self, M: FloatArray, h: float) -> FloatArray:
        """The step's matrix for d/dt y = M·y (``M`` shaped ``(n, 3, 3)``)."""

    @abstractmethod
    def _step_lists(
        self, x: list[float], v: list[float], h: float, t: float, target: TargetLike
    ) -> tuple[list[float], list[float]]:
        """One step on Python floats; may reuse and return the given lists."""

    @abstractmethod
    def _step_arrays(
        self, x: FloatArray, v: FloatArray, h: float, t: float, target: TargetLike
    ) -> None:
        """One step in place with ``out=`` ufuncs on the preallocated buffers."""

    def _forcing_lists(self, target: TargetLike, t: float, h: float) -> list[list[float]] | None:
        """w2·u + bm·u' per evaluation (list of per-spring lists), or None without a target."""
        if target is None:
            return None
        n, w2, bm = self.n, self._w2_l, self._bm_l
        slots = []
        for c in self._sample_c:
            u, du = target(t + c * h) if callable(target) else target
            ul = _as_list(u, n)
            if self._has_b:
                dul = _as_list(du, n)
                slots.append([w2[j] * ul[j] + bm[j] * dul[j] for j in range(n)])
            else:
                slots.append([w2[j] * ul[j] for j in range(n)])
            if not callable(target):  # held: one sample serves every evaluation
                return [slots[0]] * len(self.stage_times)
        return [slots[s] for s in self._stage_slot]

    def _forcing_arrays(self, target: TargetLike, t: float, h: float) -> list[FloatArray] | None:
        """As :meth:`_forcing_lists`, written into the preallocated ``_g`` rows."""
        if target is None:
            return None
        for i, c in enumerate(self._sample_c):
            u, du = target(t + c * h) if callable(target) else target
            g = self._g[i]
            np.multiply(self._w2, u, out=g)
            if self._has_b:
                np.multiply(self._bm, du, out=self._tmp)
                np.add(g, self._tmp, out=g)
            if not callable(target):
                return [self._g[0]] * len(self.stage_times)
        return [self._g[s] for s in self._stage_slot]

    def __repr__(self) -> str:
        path = "vectorized" if self.vectorized else "pure-Python"
        return f"{type(self).__name__}(n={self.n}, {path})"


class RungeKutta(Integrator):
    """An explicit Runge–Kutta method given by its Butcher tableau.

    Class attributes: ``A`` (s, s) strictly lower triangular, ``B`` (s,) weights summing to 1,
    ``C`` (s,) = A.sum(axis=1), ``order``. The stage state of stage i is y + h·Σⱼ A[i, j]·Kⱼ,
    its slope Kᵢ = f(t + C[i]·h, stage state), and the step is y + h·Σᵢ B[i]·Kᵢ.
    """

    A: ClassVar[FloatArray]
    B: ClassVar[FloatArray]
    C: ClassVar[FloatArray]
    _rows: ClassVar[tuple[_Combo | None, ...]]
    _weights: ClassVar[_Combo]

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        for name in ("A", "B", "C"):
            arr = np.array(getattr(cls, name), dtype=np.float64)
            arr.flags.writeable = False
            setattr(cls, name, arr)
        s = len(cls.B)
        if cls.A.shape != (s, s) or cls.C.shape != (s,) or np.any(np.triu(cls.A) != 0.0):
            raise TypeError(f"{cls.__name__}: A must be strictly lower triangular (s, s), C (s,)")
        cls.evals_per_step = s
        cls.stage_times = tuple(float(c) for c in cls.C)
        cls._rows = tuple(_combo(cls.A[i, :i]) for i in range(s))
        weights = _combo(cls.B)
        if weights is None:
            raise TypeError(f"{cls.__name__}: B must not be all zero")
        cls._weights = weights

    def __init__(self, spring: Spring, *, vectorized: bool | None = None) -> None:
        super().__init__(spring, vectorized=vectorized)
        s, n = len(self.B), self.n
        self._K = np.empty((s, 2, self.n))  # slopes: K[i, 0] = dx/dt, K[i, 1] = dv/dt
        self._D = np.empty((2, n))  # h·Σ a·K, the increment to a stage state or to the step
        self._T = np.empty((2, n))
        self._S = np.empty((2, n))  # stage state [x, v]
        self._kx, self._kv = [0.0] * s, [0.0] * s  # the list path's slopes, reused throughout
        self._scaled_h = math.nan
        self._hrows = self._rows
        self._hweights = self._weights

    def _scaled(self, h: float) -> None:
        # the real-time loop steps with one h; scale the tableau by it once, not every step
        if h != self._scaled_h:
            self._hrows = tuple(_scale(row, h) for row in self._rows)
            self._hweights = _scale(self._weights, h)
            self._scaled_h = h

    def _step_lists(
        self, x: list[float], v: list[float], h: float, t: float, target: TargetLike
    ) -> tuple[list[float], list[float]]:
        self._scaled(h)
        later = tuple(enumerate(self._hrows))[1:]  # stage 0 reads the state itself
        w0, b0, wrest = self._hweights
        forcing = self._forcing_lists(target, t, h)
        kx, kv = self._kx, self._kv
        nw2, ncm = self._neg_w2_l, self._neg_cm_l
        for j in range(self.n):
            xj, vj, a, c = x[j], v[j], nw2[j], ncm[j]
            kx[0] = vj
            acc = a * xj + c * vj
            kv[0] = acc if forcing is None else acc + forcing[0][j]
            for i, combo in later:
                if combo is None:
                    xs, vs = xj, vj
                else:
                    m0, ha, rest = combo
                    dx, dv = ha * kx[m0], ha * kv[m0]
                    for m1, ha1 in rest:
                        dx, dv = dx + ha1 * kx[m1], dv + ha1 * kv[m1]
                    xs, vs = xj + dx, vj + dv
                kx[i] = vs
                acc = a * xs + c * vs
                kv[i] = acc if forcing is None else acc + forcing[i][j]
            dx, dv = b0 * kx[w0], b0 * kv[w0]
            for m1, hb in wrest:
                dx, dv = dx + hb * kx[m1], dv + hb * kv[m1]
            x[j], v[j] = xj + dx, vj + dv
        return x, v

    def _step_matrix(self, M: FloatArray, h: float) -> FloatArray:
        return tableau_matrix(self.A, self.B, M, h)

    def _step_arrays(
        self, x: FloatArray, v: FloatArray, h: float, t: float, target: TargetLike
    ) -> None:
        self._scaled(h)
        forcing = self._forcing_arrays(target, t, h)
        K, D, T, S, acc = self._K, self._D, self._T, self._S, self._acc
        for i, combo in enumerate(self._hrows):
            xs, vs = x, v
            if combo is not None:
                self._combine(combo, D, T)
                np.add(x, D[0], out=S[0])
                np.add(v, D[1], out=S[1])
                xs, vs = S[0], S[1]
            np.copyto(K[i, 0], vs)
            kv = K[i, 1]
            np.multiply(self._neg_w2, xs, out=kv)
            np.multiply(self._neg_cm, vs, out=acc)
            np.add(kv, acc, out=kv)
            if forcing is not None:
                np.add(kv, forcing[i], out=kv)
        self._combine(self._hweights, D, T)
        np.add(x, D[0], out=x)
        np.add(v, D[1], out=v)

    def _combine(self, combo: _Combo, out: FloatArray, tmp: FloatArray) -> None:
        """out = Σ a·K[j] over the combination's terms, in the list path's order."""
        j0, a0, rest = combo
        np.multiply(self._K[j0], a0, out=out)
        for j, a in rest:
            np.multiply(self._K[j], a, out=tmp)
            np.add(out, tmp, out=out)


class Euler(RungeKutta):
    """Explicit (forward) Euler: y + h·f(t, y). Order 1; pumps energy into undamped springs."""

    name = "euler"
    order = 1
    A = np.array([[0.0]])
    B = np.array([1.0])
    C = np.array([0.0])


class Midpoint(RungeKutta):
    """Explicit midpoint: a half Euler step, then a full step with the midpoint slope. Order 2."""

    name = "midpoint"
    order = 2
    A = np.array([[0.0, 0.0], [0.5, 0.0]])
    B = np.array([0.0, 1.0])
    C = np.array([0.0, 0.5])


class RK4(RungeKutta):
    """Classical fourth-order Runge–Kutta: weights (1, 2, 2, 1)/6. Order 4 (local error O(h⁵))."""

    name = "rk4"
    order = 4
    A = np.array(
        [[0.0, 0.0, 0.0, 0.0], [0.5, 0.0, 0.0, 0.0], [0.0, 0.5, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
    )
    B = np.array([1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0])
    C = np.array([0.0, 0.5, 0.5, 1.0])


class SemiImplicitEuler(Integrator):
    """Semi-implicit (symplectic) Euler: v ← v + h·a(t, x, v), then x ← x + h·v with the new v.

    Order 1, one evaluation per step, and symplectic: on an undamped spring it does not drift in
    energy but keeps it within O(h·ω) of the true value for ever, which is why game engines
    (Bullet, Box2D) use it. It is not a Runge–Kutta method (it treats x and v differently), so it
    has no scalar stability function; see
    :func:`hilsim.dynamics.stability_algebra.semi_implicit_euler_amplification`.
    """

    name = "semi_implicit_euler"
    order = 1
    evals_per_step = 1
    stage_times = (0.0,)

    def _step_lists(
        self, x: list[float], v: list[float], h: float, t: float, target: TargetLike
    ) -> tuple[list[float], list[float]]:
        forcing = self._forcing_lists(target, t, h)
        g = None if forcing is None else forcing[0]
        nw2, ncm = self._neg_w2_l, self._neg_cm_l
        for j in range(self.n):
            xj, vj = x[j], v[j]
            acc = nw2[j] * xj + ncm[j] * vj
            if g is not None:
                acc = acc + g[j]
            vj = vj + h * acc
            x[j], v[j] = xj + h * vj, vj
        return x, v

    def _step_matrix(self, M: FloatArray, h: float) -> FloatArray:
        return kick_drift_matrix(M, h)

    def _step_arrays(
        self, x: FloatArray, v: FloatArray, h: float, t: float, target: TargetLike
    ) -> None:
        forcing = self._forcing_arrays(target, t, h)
        acc, tmp = self._acc, self._tmp
        np.multiply(self._neg_w2, x, out=acc)
        np.multiply(self._neg_cm, v, out=tmp)
        np.add(acc, tmp, out=acc)
        if forcing is not None:
            np.add(acc, forcing[0], out=acc)
        np.multiply(acc, h, out=acc)
        np.add(v, acc, out=v)
        np.multiply(v, h, out=acc)
        np.add(x, acc, out=x)


#: the methods by name, in the order the study reports them
INTEGRATORS: dict[str, type[Integrator]] = {
    cls.name: cls for cls in (Euler, SemiImplicitEuler, Midpoint, RK4)
}


def get_method(method: str | type[Integrator]) -> type[Integrator]:
    """The integrator class for a name (or the class itself). Unknown names raise ValueError."""
    if isinstance(method, type) and issubclass(method, Integrator):
        return method
    try:
        return INTEGRATORS[method]
    except (KeyError, TypeError):
        choices = ", ".join(repr(name) for name in INTEGRATORS)
        raise ValueError(f"method must be one of {choices}, got {method!r}") from None


def make_integrator(
    method: str | type[Integrator], spring: Spring, *, vectorized: bool | None = None
) -> Integrator:
    """An integrator of the named method for ``spring`` (one spring or a bank), buffers ready."""
    return get_method(method)(spring, vectorized=vectorized)


def rk_solve(
    method: str | type[Integrator],
    f: Callable[[float, FloatArray], npt.ArrayLike],
    y0: npt.ArrayLike,
    h: float,
    n_steps: int,
    t0: float = 0.0,
) -> tuple[FloatArray, FloatArray]:
    """y' = f(t, y) integrated with a Runge–Kutta method's tableau: a plain reference
    (:func:`hilsim.dynamics.held_step.solve_tableau`), not for the real-time loop.
    Returns (t, y)."""
    cls = get_method(method)
    if not issubclass(cls, RungeKutta):
        raise ValueError(f"method must be a Runge–Kutta method, got {cls.name!r}")
    return solve_tableau(cls.A, cls.B, cls.C, f, y0, h, n_steps, t0)
