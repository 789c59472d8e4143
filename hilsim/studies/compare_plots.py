"""Figures for ``hilsim compare``, drawn from the numbers :func:`compare.run_study` returns.

matplotlib is imported inside the functions (``import hilsim`` must not pull it in), and figures
are drawn on explicit Agg canvases, so no pyplot state or display is involved.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from hilsim.dynamics.integrators import INTEGRATORS
from hilsim.dynamics.stability_algebra import growth, stability_function

COLORS = {
    "euler": "tab:red",
    "semi_implicit_euler": "tab:purple",
    "midpoint": "tab:orange",
    "rk4": "tab:green",
    "exact": "tab:blue",
}
LABELS = {
    "euler": "explicit Euler",
    "semi_implicit_euler": "semi-implicit Euler",
    "midpoint": "explicit midpoint",
    "rk4": "RK4",
}
TITLES = {
    "euler": "explicit Euler: R(z) = 1 + z",
    "semi_implicit_euler": "semi-implicit Euler: ρ(M) of the oscillator",
    "midpoint": "explicit midpoint: R(z) = 1 + z + z²/2",
    "rk4": "RK4: R(z) = 1 + z + z²/2 + z³/6 + z⁴/24",
}


def _figure(**kwargs: Any) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(layout="constrained", **kwargs)
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Any, path: Path) -> Path:
    fig.savefig(path, dpi=120)
    return path


def _plane(extent: list[float], nx: int = 451, ny: int = 701) -> tuple[Any, Any, Any]:
    x = np.linspace(extent[0], extent[1], nx)
    y = np.linspace(extent[2], extent[3], ny)
    xx, yy = np.meshgrid(x, y)
    return xx, yy, xx + 1j * yy


def stability_regions(results: dict[str, Any], path: Path) -> Path:
    st = results["stability"]
    xx, yy, z = _plane(st["plot_extent"])
    fig = _figure(figsize=(15, 6.8))
    axes = fig.subplots(1, 4, sharex=True, sharey=True)
    for ax, name in zip(axes, INTEGRATORS, strict=True):
        g = growth(name, z)
        ax.contourf(xx, yy, g, levels=[-np.inf, 0.0], colors=[COLORS[name]], alpha=0.35)
        ax.contour(xx, yy, g, levels=[0.0], colors=[COLORS[name]], linewidths=1.5)
        ax.axhline(0.0, color="0.4", lw=0.6)
        ax.axvline(0.0, color="0.4", lw=0.6)
        imag, real = st["imag_axis"][name], st["neg_real_axis"][name]
        ax.plot([-real], [0.0], "ko", ms=4)
        ax.annotate(
            f"−{real:.4g}",
            (-real, 0.0),
            textcoords="offset points",
            xytext=(-4, 6),
            ha="right",
            fontsize=9,
        )
        if imag > 0:
            ax.plot([0.0, 0.0], [imag, -imag], "ko", ms=4)
            ax.annotate(
                f"±{imag:.4g}i",
                (0.0, imag),
                textcoords="offset points",
                xytext=(-4, 6),
                ha="right",
                fontsize=9,
            )
            note = "stable on the imaginary axis\nfor h·ω < " + f"{imag:.4g}"
        else:
            note = "unstable on the whole\nimaginary axis (undamped)"
        ax.text(0.03, 0.03, note, transform=ax.transAxes, fontsize=8.5, va="bottom")
        ax.set_title(TITLES[name], fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlabel("Re(h·λ)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("Im(h·λ)")
    axes[1].text(
        0.03,
        0.97,
        "for a spring whose\neigenvalues are z/h, z̄/h",
        transform=axes[1].transAxes,
        fontsize=8.5,
        va="top",
    )
    fig.suptitle(
        "Stability regions in the plane z = h·λ (shaded: no free mode of the spring "
        "grows from step to step)"
    )
    return _save(fig, path)


def rk4_fig1(results: dict[str, Any], path: Path) -> Path:
    st = results["stability"]
    xx, yy, z = _plane([-4.0, 2.0, -4.0, 4.0], 601, 801)
    magnitude = np.abs(stability_function("rk4", z))
    fig = _figure(figsize=(7, 7.5))
    ax = fig.subplots()
    filled = ax.contourf(
        xx, yy, np.minimum(magnitude, 3.0), levels=np.linspace(0.0, 3.0, 31), cmap="viridis"
    )
    ax.contour(xx, yy, magnitude, levels=[1.0], colors="white", linestyles=":", linewidths=2.0)
    colorbar = fig.colorbar(filled, ax=ax, shrink=0.8, ticks=np.arange(0.0, 3.01, 0.5))
    colorbar.set_label("|R(h·λ)| (clipped at 3)")
    imag, real = st["imag_axis"]["rk4"], st["neg_real_axis"]["rk4"]
    ax.plot([0.0, 0.0, -real], [imag, -imag, 0.0], "wo", ms=5)
    ax.annotate(
        f"2√2 i = {imag:.4f} i",
        (0.0, imag),
        xytext=(8, 6),
        textcoords="offset points",
        color="white",
        fontsize=9,
    )
    ax.annotate(
        f"−{real:.4f}",
        (-real, 0.0),
        xytext=(-6, 8),
        textcoords="offset points",
        color="white",
        fontsize=9,
        ha="right",
    )
    ax.set_xlabel("Re(h·λ)")
    ax.set_ylabel("Im(h·λ)")
    ax.set_aspect("equal")
    ax.set_title("RK4 stability function (the paper's Fig. 1)\ndotted: |R| = 1, stable inside")
    return _save(fig, path)


def exponential(results: dict[str, Any], path: Path) -> Path:
    ex = results["exponential"]
    t = np.array(ex["t"])
    exact = np.exp(t)
    fig = _figure(figsize=(11, 4.5))
    left, right = fig.subplots(1, 2)
    left.plot(ex["t_exact"], ex["exact_curve"], color=COLORS["exact"], label="exact eᵗ")
    for name, style in (("euler", "--o"), ("midpoint", ":s"), ("rk4", "--^")):
        y = np.array(ex["curves"][name])
        left.plot(t, y, style, color=COLORS[name], ms=4, label=LABELS[name])
        right.semilogy(
            t[1:], np.abs(y - exact)[1:], style, color=COLORS[name], ms=4, label=LABELS[name]
        )
    left.set_xlabel("t")
    left.set_ylabel("y(t)")
    left.set_title(
        f"dy/dt = y, y(0) = 1, h = 0.1: y(0.1) = {ex['euler']:.5f} (Euler), {ex['rk4']:.5f} (RK4)",
        fontsize=10,
    )
    left.legend()
    right.set_xlabel("t")
    right.set_ylabel("|y − eᵗ|")
    right.set_title("global error (log scale)", fontsize=10)
    right.legend()
    for ax in (left, right):
        ax.grid(alpha=0.3)
    fig.suptitle("Euler vs RK4 vs exact (the paper's Fig. 2)")
    return _save(fig, path)


def undamped_spring(results: dict[str, Any], path: Path) -> Path:
    un = results["undamped"]
    t, x, v = (np.array(un[k]) for k in ("t", "x", "v"))
    fig = _figure(figsize=(10, 7))
    top, bottom = fig.subplots(2, 1)
    for ax, t_max in ((top, 10.0), (bottom, 2.0)):
        keep = t <= t_max + 1e-9
        ax.plot(t[keep], x[keep], color="tab:blue", label="position x (m)")
        ax.plot(t[keep], v[keep], "--", color="tab:red", label="velocity v (m/s)")
        ax.set_xlim(0.0, t_max)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("x (m), v (m/s)")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right")
    top.set_title(
        f"Undamped spring m = 1 kg, k = 10 N/m, x₀ = 1 m: RK4, h = 10/999 s ({un['n_points']} "
        f"points); max |x − cos(√10·t)| = {un['max_error']:.2e} m",
        fontsize=10,
    )
    bottom.set_title("first 2 s (the paper's Figs. 3 and 4)", fontsize=10)
    return _save(fig, path)


def damped_spring(results: dict[str, Any], path: Path) -> Path:
    da = results["damped"]
    t = np.array(da["t"])
    exact = np.array(da["x_exact"])
    envelope = np.array(da["envelope"])
    fig = _figure(figsize=(10, 7.5))
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[3, 2])
    top.fill_between(t, -envelope, envelope, color="0.9", label="exact envelope ±(ω₀/ω_d)·e^(−γt)")
    top.plot(t, envelope, "--", color="0.4", lw=1.0)
    top.plot(t, -envelope, "--", color="0.4", lw=1.0)
    top.plot(t, da["x"]["rk4"], color=COLORS["rk4"], lw=2.0, label="RK4, h = 0.01 s")
    top.plot(t[::10], exact[::10], ".", color=COLORS["exact"], ms=4, label="exact")
    top.set_ylabel("position x (m)")
    top.set_title(
        f"Damped spring m = 1 kg, c = 0.5 N·s/m, k = 15 N/m, x₀ = 1 m: "
        f"ω_d = {da['omega_d']:.4f} rad/s, γ = {da['gamma']:.3g} 1/s",
        fontsize=10,
    )
    top.legend(loc="upper right")
    for name in INTEGRATORS:
        error = np.abs(np.array(da["x"][name]) - exact)
        bottom.semilogy(
            t[1:],
            error[1:],
            color=COLORS[name],
            label=f"{LABELS[name]} (max {da['max_error'][name]:.2e} m)",
        )
    bottom.set_xlabel("t (s)")
    bottom.set_ylabel("|x − x_exact| (m)")
    bottom.set_ylim(1e-12, 1.0)
    bottom.legend(loc="lower right", fontsize=8, ncols=2)
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    return _save(fig, path)


def error_vs_step(results: dict[str, Any], path: Path) -> Path:
    da = results["damped"]
    h = np.array(da["steps"])
    fig = _figure(figsize=(8, 6))
    ax = fig.subplots()
    for name in INTEGRATORS:
        ax.loglog(
            h,
            da["errors"][name],
            "o-",
            color=COLORS[name],
            label=f"{LABELS[name]} (order {da['order'][name]:.2f})",
        )
    # a guide of slope p a little below the method of that order
    for p, name in ((1, "semi_implicit_euler"), (2, "midpoint"), (4, "rk4")):
        anchor = 0.2 * da["errors"][name][-1]
        ax.loglog(h, anchor * (h / h[-1]) ** p, ":", color="0.45", lw=1.2)
        ax.annotate(
            f"∝ h{'¹²⁴'[(1, 2, 4).index(p)]}",
            (h[-1], anchor),
            fontsize=9,
            color="0.35",
            xytext=(-4, -2),
            textcoords="offset points",
            ha="right",
            va="top",
        )
    ax.set_xlabel("step h (s)")
    ax.set_ylabel("max |x − x_exact| over 0–10 s (m)")
    ax.set_title(
        "Convergence on the damped spring (m = 1, c = 0.5, k = 15)\norder from "
        f"h = {da['order_pair'][0]:g} → {da['order_pair'][1]:g} s; dotted: slopes h¹, h², h⁴",
        fontsize=10,
    )
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="lower right")
    return _save(fig, path)


def _evaluations(count: int) -> str:
    return f"{count} evaluation{'s' if count != 1 else ''}"


def work_precision(results: dict[str, Any], path: Path) -> Path:
    da = results["damped"]
    fig = _figure(figsize=(8, 6))
    ax = fig.subplots()
    for name in INTEGRATORS:
        ax.loglog(
            da["evals"][name],
            da["errors"][name],
            "o-",
            color=COLORS[name],
            label=f"{LABELS[name]} ({_evaluations(INTEGRATORS[name].evals_per_step)}/step)",
        )
    ax.set_xlabel("right-hand-side evaluations over 0–10 s (cost)")
    ax.set_ylabel("max |x − x_exact| (m)")
    ax.set_title("Work–precision on the damped spring: lower-left is better", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    return _save(fig, path)


def energy_drift(results: dict[str, Any], path: Path) -> Path:
    en = results["energy"]
    t = np.array(en["t_window_end"])
    fig = _figure(figsize=(9, 8))
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[2, 3])
    for ax, names in ((top, list(INTEGRATORS)), (bottom, [n for n in INTEGRATORS if n != "euler"])):
        for name in names:
            ax.semilogy(
                t,
                np.maximum(en["series"][name], 1e-300),
                color=COLORS[name],
                label=f"{LABELS[name]}: ΔE/E₀ at {en['t_long']:g} s = {en['at_end'][name]:+.2e}",
            )
        ax.set_ylabel("max |E − E₀| / E₀\nper 1 s window")
        ax.grid(alpha=0.3, which="both")
    top.set_title(
        f"Energy error on the undamped spring (m = 1 kg, k = 10 N/m), h = {en['h']:g} s",
        fontsize=10,
    )
    top.legend(fontsize=8.5, loc="center right")
    bottom.set_title(
        "without Euler: midpoint creeps up, semi-implicit Euler stays bounded, RK4 loses a little",
        fontsize=10,
    )
    bottom.legend(fontsize=8.5, loc="lower right")
    bottom.set_xlabel("t (s)")
    bottom.set_xlim(0.0, en["t_long"])
    return _save(fig, path)


#: figure file name -> drawing function
FIGURES = {
    "stability_regions.png": stability_regions,
    "rk4_stability_fig1.png": rk4_fig1,
    "exponential.png": exponential,
    "undamped_spring.png": undamped_spring,
    "damped_spring.png": damped_spring,
    "error_vs_step.png": error_vs_step,
    "work_precision.png": work_precision,
    "energy_drift.png": energy_drift,
}


def write_figures(results: dict[str, Any], out: Path) -> dict[str, Path]:
    """Draw every figure into ``out`` and return {file name: path}."""
    return {name: draw(results, out / name) for name, draw in FIGURES.items()}
