"""A Runge–Kutta tableau as the list path steps it, and every method's step with a held target.

:class:`hilsim.dynamics.integrators.RungeKutta` keeps each row of its tableau (and its weights) as a
:data:`Combo`: the non-zero terms of Σ a_j·K_j, scaled by the step with :func:`scale` once
per step size.

:class:`HeldStep` is the real-time loop's step. With the target held over the step (the
loop samples it once per tick), a damped spring is a linear system in (x, v, g), g = w2·u +
bm·u' the forcing, and so is any of the methods' steps on it: one step *is* a 3×3 matrix
per spring, the method's own (for RK4 the degree-4 Taylor polynomial of h·M, its stability
function; ``docs/numerics.md``). :meth:`Integrator.held_matrix
<hilsim.dynamics.integrators.Integrator.held_matrix>` works it out once per step size from the
method's tableau; a step is then two dot products of three per spring instead of RK4's four
stages. Exact arithmetic gives the same numbers as the staged step; floating point differs
from it in the last bits (``tests/hilsim/test_tick_paths.py`` holds them within 1e-13).
The list path and the array path do the same operations in the same order: the same bits.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import overload

import numpy as np
import numpy.typing as npt

from drivers.fill import Packed
from hilsim._types import FloatArray

#: a linear combination Σ a_j·K_j of stage slopes with its zero terms dropped, as
#: (first j, first a, ((j, a), …) for the rest); None when every coefficient is zero
Combo = tuple[int, float, tuple[tuple[int, float], ...]]
#: u or u' for every joint as a step takes it (rad, rad/s): one number for all, n numbers (the
#: loop's tuples, used as they are) or a float64 array broadcastable to ``(n,)``
Sample = float | Sequence[float] | FloatArray


def combo(coeffs: npt.ArrayLike) -> Combo | None:
    terms = [(j, float(a)) for j, a in enumerate(np.asarray(coeffs)) if a != 0.0]
    return (terms[0][0], terms[0][1], tuple(terms[1:])) if terms else None


@overload
def scale(c: Combo, h: float) -> Combo: ...
@overload
def scale(c: Combo | None, h: float) -> Combo | None: ...
def scale(c: Combo | None, h: float) -> Combo | None:
    if c is None:
        return None
    j0, a0, rest = c
    return (j0, h * a0, tuple((j, h * a) for j, a in rest))


def as_list(value: Sample, n: int) -> Sequence[float]:
    """A target value (a number, or anything broadcastable to ``(n,)``) as n floats (a list
    or tuple of n numbers as it is: the same arithmetic as on their float64 conversions)."""
    # type(value) is read once (this runs every substep); mypy does not narrow value through
    # kind, hence the ignores where kind says what value is
    kind = type(value)
    if kind is list or kind is tuple:
        if len(value) == n:  # type: ignore[arg-type]  # a list or tuple
            return value  # type: ignore[return-value]  # a list or tuple
    elif kind is np.ndarray and value.shape == (n,) and value.dtype.char == "d":  # type: ignore[union-attr]  # an ndarray
        floats: list[float] = value.tolist()  # type: ignore[union-attr]  # the loop's buffers
        return floats
    if isinstance(value, float | int):
        return [float(value)] * n
    arr = np.asarray(value, dtype=np.float64)
    floats = (arr if arr.shape == (n,) else np.broadcast_to(arr, (n,))).tolist()
    return floats


def tableau_matrix(A: FloatArray, B: FloatArray, M: FloatArray, h: float) -> FloatArray:
    """The step of the explicit Runge–Kutta method (A, B) on d/dt y = M·y, as a matrix per
    system (``M`` shaped ``(n, k, k)``): slope K_i = M·(I + h·Σ_j a_ij·K_j), step
    I + h·Σ_i b_i·K_i."""
    eye = np.broadcast_to(np.eye(M.shape[-1]), M.shape)
    K: list[FloatArray] = []
    for i in range(len(B)):
        K.append(M @ (eye + h * sum((a * K[j] for j, a in enumerate(A[i, :i])), np.zeros(M.shape))))
    return eye + h * sum((b * k for b, k in zip(B, K, strict=True)), np.zeros(M.shape))


def solve_tableau(
    A: FloatArray,
    B: FloatArray,
    C: FloatArray,
    f: Callable[[float, FloatArray], npt.ArrayLike],
    y0: npt.ArrayLike,
    h: float,
    n_steps: int,
    t0: float = 0.0,
) -> tuple[FloatArray, FloatArray]:
    """Integrate a general first-order system y' = f(t, y) with the explicit Runge–Kutta
    tableau (A, B, C). A plain, allocating reference implementation (the paper's dy/dt = y
    example, cross-checks of the spring steps); not for the real-time loop.

    Returns:
        (t, y): t shaped ``(n_steps + 1,)``, y shaped ``(n_steps + 1,) + shape(y0)``.
    """
    y = np.array(y0, dtype=np.float64)
    ys = [y.copy()]
    s = len(B)
    for n in range(n_steps):
        t = t0 + n * h
        k = np.zeros((s, *y.shape))
        for i in range(s):
            k[i] = f(t + C[i] * h, y + h * np.tensordot(A[i, :i], k[:i], axes=1))
        y = y + h * np.tensordot(B, k, axes=1)
        ys.append(y.copy())
    return t0 + h * np.arange(n_steps + 1, dtype=np.float64), np.array(ys)


def kick_drift_matrix(M: FloatArray, h: float) -> FloatArray:
    """Semi-implicit Euler's step on d/dt (x, v, g) = M·(x, v, g) as a matrix per spring:
    v += h·a(x, v, g), then x += h·v with the new v."""
    eye = np.broadcast_to(np.eye(3), M.shape)
    kick = eye + h * (M * np.array([0.0, 1.0, 0.0], dtype=np.float64)[:, None])
    return (eye + h * (M * np.array([1.0, 0.0, 0.0], dtype=np.float64)[:, None])) @ kick


class HeldStep:
    """One step with a held target, for springs whose step matrices are ``S`` (shaped
    ``(n, 3, 3)``, rows x, v, g) at step ``h``; ``w2``, ``bm`` as the integrator's (bm None
    when every b is 0). :meth:`step` steps float64 arrays in place, through :meth:`lists`
    (Python floats in place) or, ``vectorized``, :meth:`arrays` (buffers allocated here,
    none per step)."""

    __slots__ = ("_cols", "_rows", "_tmp", "_vv", "_xv", "bm", "h", "n", "vectorized", "w2")

    def __init__(
        self, S: FloatArray, h: float, w2: FloatArray, bm: FloatArray | None, vectorized: bool
    ) -> None:
        self.h, self.n, self.vectorized = h, len(w2), vectorized
        self.w2, self.bm = w2, bm
        self._xv = self._vv = Packed()  # the caller's x, v as the list path reads and writes them
        x_row, v_row = S[:, 0, :], S[:, 1, :]
        # per spring: (sxx, sxv, sxg, svx, svv, svg, w2, bm) as floats for the list path
        bml = [0.0] * self.n if bm is None else bm.tolist()
        self._rows = tuple(
            (*xr, *vr, w, b)
            for xr, vr, w, b in zip(x_row.tolist(), v_row.tolist(), w2.tolist(), bml, strict=True)
        )
        self._cols = tuple(np.ascontiguousarray(S[:, r, c]) for r in (0, 1) for c in (0, 1, 2))
        self._tmp = np.empty((4, self.n))

    def step(self, x: FloatArray, v: FloatArray, u: Sample, du: Sample) -> None:
        if self.vectorized:
            self.arrays(x, v, u, du)
            return
        xv, vv = self._xv, self._vv
        if xv.arr is not x or vv.arr is not v:  # the caller's arrays, viewed once
            xv, vv = self._xv, self._vv = Packed(x, self.n), Packed(v, self.n)
        xl, vl = xv.tolist(), vv.tolist()
        self.lists(xl, vl, u, du)
        xv.put(*xl)
        vv.put(*vl)

    def lists(self, x: list[float], v: list[float], u: Sample, du: Sample) -> None:
        n = self.n
        if type(u) is not tuple or len(u) != n:  # the loop's samples are tuples: as they are
            u = as_list(u, n)
        rows = self._rows
        if self.bm is None:
            for j in range(n):  # indexing, not zip: no tuple per joint
                sxx, sxv, sxg, svx, svv, svg, w, _ = rows[j]
                xj, vj, g = x[j], v[j], w * u[j]
                x[j] = sxx * xj + sxv * vj + sxg * g
                v[j] = svx * xj + svv * vj + svg * g
            return
        if type(du) is not tuple or len(du) != n:
            du = as_list(du, n)
        for j in range(n):
            sxx, sxv, sxg, svx, svv, svg, w, b = rows[j]
            xj, vj, g = x[j], v[j], w * u[j] + b * du[j]
            x[j] = sxx * xj + sxv * vj + sxg * g
            v[j] = svx * xj + svv * vj + svg * g

    def arrays(self, x: FloatArray, v: FloatArray, u: Sample, du: Sample) -> None:
        g, tmp, xn, vn = self._tmp
        np.multiply(self.w2, u, out=g)
        if self.bm is not None:
            np.multiply(self.bm, du, out=tmp)
            np.add(g, tmp, out=g)
        sxx, sxv, sxg, svx, svv, svg = self._cols
        for out, cx, cv, cg in ((xn, sxx, sxv, sxg), (vn, svx, svv, svg)):
            np.multiply(cx, x, out=out)  # (cx·x + cv·v) + cg·g, in the list path's order
            np.multiply(cv, v, out=tmp)
            np.add(out, tmp, out=out)
            np.multiply(cg, g, out=tmp)
            np.add(out, tmp, out=out)
        np.copyto(x, xn)
        np.copyto(v, vn)
