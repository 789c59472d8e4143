"""``hilsim compare``: reproduce the RK4 paper's examples and compare all four integrators.

Computes every number first (:func:`run_study`, plain numpy, JSON-ready), then writes the JSON, the
figures (:mod:`hilsim.studies.compare_plots`) and a Markdown report
(:mod:`hilsim.studies.compare_report`), and prints a short summary.

The cases come from the design paper, "Simulation of Realistic Motion in Computer Graphics Using
Runge-Kutta Methods"; ``docs/numerics.md`` lists them with the reference results:

* dy/dt = y, y(0) = 1, one step h = 0.1: Euler 1.1, RK4 1.10517, e^0.1.
* undamped spring m = 1, k = 10, x0 = 1: RK4 with h = 10/999 (1000 points on [0, 10], which is what
  the paper's table times 0.01001, 0.02002, … show), the table to 6 decimals.
* damped spring m = 1, c = 0.5, k = 15, x0 = 1, h = 0.01 on [0, 10] against the exact solution:
  max error and convergence order per method; ω_d = √(k/m − (c/2m)²) = 3.8649 rad/s.
* energy of the undamped spring (k = 10, h = 0.01) after 10 s and 1000 s.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from hilsim.dynamics.integrators import INTEGRATORS, RungeKutta, rk_solve
from hilsim.dynamics.simulate import simulate
from hilsim.dynamics.springs import Spring
from hilsim.dynamics.stability import critical_step, stability_boundary
from hilsim.dynamics.stability_algebra import stability_polynomial

HELP = "Reproduce the RK4 paper's examples and compare Euler, semi-implicit Euler, midpoint, RK4."

#: the paper's "snapshot table": t (s), x (m), v (m/s) for m = 1, k = 10, x0 = 1
PAPER_TABLE: tuple[tuple[float, float, float], ...] = (
    (0.00000, 1.000000, 0.000000),
    (0.01001, 0.999499, -0.100083),
    (0.02002, 0.997997, -0.200066),
    (0.03003, 0.995494, -0.299849),
    (0.04004, 0.991995, -0.399331),
    (0.05005, 0.987501, -0.498414),
    (0.06006, 0.982018, -0.596996),
    (0.07007, 0.975551, -0.694981),
    (0.08008, 0.968107, -0.792269),
    (0.09009, 0.959693, -0.888764),
)
PAPER_OMEGA_D = 3.84

#: where the paper's text and its mathematics disagree (docs/numerics.md); the study follows
#: the mathematics
PAPER_SLIPS: tuple[str, ...] = (
    "The literature review writes the RK4 update with weights (k1 + 2k2 + 3k3 + k4)·h/6; "
    "the correct weights are (k1 + 2k2 + 2k3 + k4)·h/6 (they must sum to 6).",
    "The damped natural frequency is given as ≈ 3.84 rad/s; √(15 − 0.25²) = 3.8649 rad/s.",
    "The case study writes dv/dt = −(k/m)x − γv and later −(k/m)x − (γ/m)v; they agree only for "
    "m = 1. This study uses m·x'' + c·x' + k·x = 0 with c the damping coefficient.",
    "The snapshot table's times (0.01001, 0.02002, …) show the run used 1000 points on [0, 10], "
    "i.e. h = 10/999, not the stated h = 0.01.",
    "RK4's local error is given as O(h⁴); it is O(h⁵) per step and O(h⁴) global.",
)

#: the reference results of docs/numerics.md, shown next to ours in the report
REFERENCE: dict[str, dict[str, float]] = {
    "max_error": {
        "euler": 1.31e-1,
        "semi_implicit_euler": 1.93e-2,
        "midpoint": 1.42e-3,
        "rk4": 1.07e-7,
    },
    "energy_10s": {
        "euler": 1.72,
        "semi_implicit_euler": -6.4e-3,
        "midpoint": 2.5e-4,
        "rk4": -1.40e-8,
    },
    "energy_1000s": {
        "euler": 2.8e43,
        "semi_implicit_euler": 1.6e-2,
        "midpoint": 2.5e-2,
        "rk4": -1.40e-6,
    },
}

DAMPED = {"m": 1.0, "c": 0.5, "k": 15.0, "x0": 1.0, "v0": 0.0}
UNDAMPED = {"m": 1.0, "c": 0.0, "k": 10.0, "x0": 1.0, "v0": 0.0}
#: steps for the convergence study; the order is read from the pair ORDER_PAIR, where all four
#: methods are in their asymptotic range (Euler's error at h = 0.01 is still 13 % of the amplitude)
STEPS = (0.02, 0.01, 0.005, 0.0025, 0.00125, 0.000625)
ORDER_PAIR = (0.0025, 0.00125)


def _floats(a: npt.ArrayLike) -> list[float | None]:
    """A flat list for JSON; a non-finite value (an unbounded stability ray) becomes null."""
    return [float(v) if math.isfinite(v) else None for v in np.asarray(a, dtype=float).reshape(-1)]


def exponential_example() -> dict[str, Any]:
    """dy/dt = y: one step of h = 0.1, and [0, 1] in ten steps (the paper's Fig. 2)."""
    f = lambda t, y: y  # noqa: E731
    one = {name: float(rk_solve(name, f, 1.0, 0.1, 1)[1][-1]) for name in ("euler", "rk4")}
    t = np.linspace(0.0, 1.0, 11)
    curves = {
        name: _floats(rk_solve(name, f, 1.0, 0.1, 10)[1]) for name in ("euler", "midpoint", "rk4")
    }
    return {
        "h": 0.1,
        "euler": one["euler"],
        "rk4": one["rk4"],
        "exact": math.exp(0.1),
        "euler_error": math.exp(0.1) - one["euler"],
        "rk4_error": math.exp(0.1) - one["rk4"],
        "t": _floats(t),
        "curves": curves,
        "t_exact": _floats(np.linspace(0.0, 1.0, 201)),
        "exact_curve": _floats(np.exp(np.linspace(0.0, 1.0, 201))),
    }


def undamped_table() -> dict[str, Any]:
    """RK4 on m = 1, k = 10 with 1000 points on [0, 10]: the paper's snapshot table."""
    spring = Spring(m=UNDAMPED["m"], c=UNDAMPED["c"], k=UNDAMPED["k"])
    h = 10.0 / 999.0
    traj = simulate(spring, UNDAMPED["x0"], UNDAMPED["v0"], h=h, t_end=10.0, method="rk4")
    rows = []
    for i, (pt, px, pv) in enumerate(PAPER_TABLE):
        ours = (f"{traj.t[i]:.5f}", f"{traj.x[i]:.6f}", f"{traj.v[i]:.6f}")
        paper = (f"{pt:.5f}", f"{px:.6f}", f"{pv:.6f}")
        rows.append({"t": ours[0], "x": ours[1], "v": ours[2], "matches_paper": ours == paper})
    exact = np.cos(float(spring.natural_frequency) * traj.t)
    return {
        "h": h,
        "n_points": len(traj.t),
        "rows": rows,
        "matches_paper": all(r["matches_paper"] for r in rows),
        "max_error": float(np.abs(traj.x - exact).max()),
        "t": _floats(traj.t),
        "x": _floats(traj.x),
        "v": _floats(traj.v),
    }


def damped_example(quick: bool) -> dict[str, Any]:
    """The damped spring: ω_d, every method's error at h = 0.01, and convergence over STEPS."""
    spring = Spring(m=DAMPED["m"], c=DAMPED["c"], k=DAMPED["k"])
    gamma = float(spring.decay_rate)
    omega_d = float(spring.damped_frequency)
    steps = STEPS[:-1] if quick else STEPS
    errors: dict[str, list[float]] = {}
    curves: dict[str, list[float | None]] = {}
    for name in INTEGRATORS:
        errors[name] = []
        for h in steps:
            traj = simulate(spring, DAMPED["x0"], DAMPED["v0"], h=h, t_end=10.0, method=name)
            exact, _ = spring.exact(traj.t, DAMPED["x0"], DAMPED["v0"])
            errors[name].append(float(np.abs(traj.x - exact).max()))
            if h == 0.01:
                curves[name] = _floats(traj.x)
                t_ref, x_exact = traj.t, exact
    local = {n: _floats(np.log2(np.array(e[:-1]) / np.array(e[1:]))) for n, e in errors.items()}
    i = steps.index(ORDER_PAIR[0])
    return {
        "omega_d": omega_d,
        "omega_d_paper": PAPER_OMEGA_D,
        "gamma": gamma,
        "h": 0.01,
        "t": _floats(t_ref),
        "x": curves,
        "x_exact": _floats(x_exact),
        # x = e^(−γt)·(cos ω_d t + (γ/ω_d) sin ω_d t) has amplitude e^(−γt)·ω₀/ω_d
        "envelope": _floats(np.exp(-gamma * t_ref) * float(spring.natural_frequency) / omega_d),
        "max_error": {n: e[steps.index(0.01)] for n, e in errors.items()},
        "steps": list(steps),
        "errors": errors,
        "evals": {
            n: [round(10.0 / h) * INTEGRATORS[n].evals_per_step for h in steps] for n in INTEGRATORS
        },
        "local_orders": local,
        "order_pair": list(ORDER_PAIR),
        "order": {n: o[i] for n, o in local.items()},
    }


def energy_drift(t_long: float) -> dict[str, Any]:
    """Relative energy error of the undamped spring (k = 10, h = 0.01) after 10 s and t_long."""
    spring = Spring(m=UNDAMPED["m"], c=UNDAMPED["c"], k=UNDAMPED["k"])
    h = 0.01
    window = 100  # steps per plotted point: the largest |ΔE/E₀| in each second
    out: dict[str, Any] = {"h": h, "t_long": t_long, "at_10s": {}, "at_end": {}, "max_abs": {}}
    series: dict[str, list[float | None]] = {}
    for name in INTEGRATORS:
        traj = simulate(spring, UNDAMPED["x0"], UNDAMPED["v0"], h=h, t_end=t_long, method=name)
        energy = traj.energy()
        rel = (energy - energy[0]) / energy[0]
        out["at_10s"][name] = float(rel[round(10.0 / h)])
        out["at_end"][name] = float(rel[-1])
        out["max_abs"][name] = float(np.abs(rel).max())
        # the energy error oscillates twice per period; plot its envelope, not aliased samples
        series[name] = _floats(np.abs(rel[1:]).reshape(-1, window).max(axis=1))
    # Euler's update is a rotation scaled by √(1 + h²k/m): energy gains exactly that factor² a step
    n_steps = round(t_long / h)
    out["euler_closed_form"] = math.expm1(n_steps * math.log1p(h**2 * float(spring.w2)))
    out["t_window_end"] = _floats(h * window * np.arange(1, len(series["rk4"]) + 1))
    out["series"] = series
    return out


def stability_numbers() -> dict[str, Any]:
    """Boundaries along the axes and along every damped-spring ray, and R(z) coefficients."""
    angles = np.arange(90.0, 181.0, 1.0)
    zeta = np.linspace(0.0, 2.0, 41)
    # semi-implicit Euler's critical h·ω₀ for a spring of damping ratio ζ (ω₀ = 1)
    theta = critical_step(Spring(m=1.0, c=2.0 * zeta, k=1.0), "semi_implicit_euler")
    return {
        "imag_axis": {n: float(stability_boundary(n, math.pi / 2)) for n in INTEGRATORS},
        "neg_real_axis": {n: float(stability_boundary(n, math.pi)) for n in INTEGRATORS},
        "ray_angle_deg": _floats(angles),
        "ray_boundary": {
            n: _floats(stability_boundary(n, np.radians(angles))) for n in INTEGRATORS
        },
        "polynomials": {
            n: _floats(stability_polynomial(c))
            for n, c in INTEGRATORS.items()
            if issubclass(c, RungeKutta)
        },
        "sie_zeta": _floats(zeta),
        "sie_theta_star": _floats(theta),
        "sie_theta_star_formula": "2·(√(1 + ζ²) − ζ)",
        "plot_extent": [-3.5, 1.0, -3.5, 3.5],
    }


def run_study(quick: bool = False) -> dict[str, Any]:
    """Every number the report, JSON and figures need. ``quick``: a 100 s long run, 5 steps."""
    return {
        "quick": quick,
        "methods": {
            n: {"order": c.order, "evals_per_step": c.evals_per_step}
            for n, c in INTEGRATORS.items()
        },
        "exponential": exponential_example(),
        "undamped": undamped_table(),
        "damped": damped_example(quick),
        "energy": energy_drift(100.0 if quick else 1000.0),
        "stability": stability_numbers(),
        "reference": REFERENCE,
        "paper_slips": list(PAPER_SLIPS),
    }


def summary(results: dict[str, Any]) -> str:
    """The terminal summary: the paper's checks, then one line per method."""
    ex, un, da, en = (results[k] for k in ("exponential", "undamped", "damped", "energy"))
    st = results["stability"]
    t_long = en["t_long"]
    lines = [
        f"dy/dt = y, h = 0.1:  Euler {ex['euler']:.5f}   RK4 {ex['rk4']:.5f}   "
        f"e^0.1 {ex['exact']:.5f}",
        f"undamped k = 10, h = 10/999 ({un['n_points']} points): paper's table "
        f"{'reproduced to 6 decimals' if un['matches_paper'] else 'NOT reproduced'}; "
        f"max |x − cos(√10 t)| = {un['max_error']:.2e}",
        f"damped k = 15, c = 0.5: ω_d = {da['omega_d']:.4f} rad/s (paper: ≈ {PAPER_OMEGA_D})",
        f"RK4 stability limits: imaginary axis {st['imag_axis']['rk4']:.4f} (2√2), "
        f"negative real axis −{st['neg_real_axis']['rk4']:.4f}",
        "",
        f"{'method':<20} {'max err h=0.01':>14} {'order':>6} {'ΔE/E 10 s':>11} "
        f"{f'ΔE/E {t_long:g} s':>13} {'max|ΔE/E|':>10}",
    ]
    for n in INTEGRATORS:
        lines.append(
            f"{n:<20} {da['max_error'][n]:>14.3e} {da['order'][n]:>6.2f} "
            f"{en['at_10s'][n]:>+11.2e} {en['at_end'][n]:>+13.2e} {en['max_abs'][n]:>10.2e}"
        )
    lines.append(
        f"(order from h = {da['order_pair'][0]:g} → {da['order_pair'][1]:g}; energy: undamped "
        f"k = 10, h = {en['h']:g})"
    )
    lines.append(f"{len(PAPER_SLIPS)} slips in the paper are listed in the report.")
    return "\n".join(lines)
