"""A Runge–Kutta tableau as the list path steps it, and RK4's step unrolled for the loop.

:class:`hilsim.integrators.RungeKutta` keeps each row of its tableau (and its weights) as a
:data:`Combo`: the non-zero terms of Σ a_j·K_j, scaled by the step with :func:`scale` once
per step size. :func:`rk4_held` is the classical RK4 step over a bank of springs with the
target held over the step (the real-time loop's case), unrolled: the operations and their
order are exactly those of the generic step (:meth:`RungeKutta._step_lists`) for RK4's
tableau, so the results are the same bits (``tests/hilsim/test_integrators.py``), in about
a third of the time.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

#: a linear combination Σ a_j·K_j of stage slopes with its zero terms dropped, as
#: (first j, first a, ((j, a), …) for the rest); None when every coefficient is zero
Combo = tuple[int, float, tuple[tuple[int, float], ...]]


def combo(coeffs: npt.ArrayLike) -> Combo | None:
    terms = [(j, float(a)) for j, a in enumerate(np.asarray(coeffs)) if a != 0.0]
    return (terms[0][0], terms[0][1], tuple(terms[1:])) if terms else None


def scale(c: Combo | None, h: float) -> Combo | None:
    if c is None:
        return None
    j0, a0, rest = c
    return (j0, h * a0, tuple((j, h * a) for j, a in rest))


def as_list(value: npt.ArrayLike, n: int) -> Sequence[float]:
    """A target value (a number, or anything broadcastable to ``(n,)``) as n floats (a list
    or tuple of n numbers as it is: the same arithmetic as on their float64 conversions)."""
    kind = type(value)
    if kind is list or kind is tuple:
        if len(value) == n:  # type: ignore[arg-type]
            return value  # type: ignore[return-value]
    elif kind is np.ndarray and value.shape == (n,) and value.dtype.char == "d":  # type: ignore[union-attr]
        return value.tolist()  # type: ignore[union-attr]  # the loop's buffers
    if isinstance(value, float | int):
        return [float(value)] * n
    arr = np.asarray(value, dtype=np.float64)
    return (arr if arr.shape == (n,) else np.broadcast_to(arr, (n,))).tolist()


def rk4_held(
    x: list[float],
    v: list[float],
    rows: tuple[Combo | None, ...],
    weights: Combo,
    neg_w2: list[float],
    neg_cm: list[float],
    w2: list[float],
    u: npt.ArrayLike,
    bm: list[float] | None = None,
    du: npt.ArrayLike = None,
) -> None:
    """One RK4 step of every spring, in place: ``rows``/``weights`` are RK4's tableau
    scaled by h (:func:`scale`); the held target's forcing is w2·u + bm·u' (bm None: w2·u),
    computed as ``Integrator._forcing_lists`` does."""
    (_, a1, _), (_, a2, _), (_, a3, _) = rows[1:]  # type: ignore[misc]
    _, b0, ((_, b1), (_, b2), (_, b3)) = weights
    n = len(x)
    if type(u) is not tuple or len(u) != n:  # the loop's samples are tuples: as they are
        u = as_list(u, n)
    if bm is not None and (type(du) is not tuple or len(du) != n):
        du = as_list(du, n)
    for j in range(len(x)):  # indexing, not zip: no tuple per joint, no keyword argument
        xj, vj, a, c = x[j], v[j], neg_w2[j], neg_cm[j]
        gj = w2[j] * u[j] if bm is None else w2[j] * u[j] + bm[j] * du[j]  # type: ignore[index]
        k0 = a * xj + c * vj + gj
        x1, v1 = xj + a1 * vj, vj + a1 * k0
        k1 = a * x1 + c * v1 + gj
        x2, v2 = xj + a2 * v1, vj + a2 * k1
        k2 = a * x2 + c * v2 + gj
        x3, v3 = xj + a3 * v2, vj + a3 * k2
        k3 = a * x3 + c * v3 + gj
        x[j] = xj + (b0 * vj + b1 * v1 + b2 * v2 + b3 * v3)
        v[j] = vj + (b0 * k0 + b1 * k1 + b2 * k2 + b3 * k3)
