"""Integrators: tableaus, convergence, the two stepping paths, targets, stability functions."""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilsim.dynamics.integrators import (
    INTEGRATORS,
    RK4,
    Integrator,
    RungeKutta,
    get_method,
    make_integrator,
    rk_solve,
)
from hilsim.dynamics.springs import Spring
from hilsim.dynamics.stability_algebra import (
    growth,
    semi_implicit_euler_amplification,
    semi_implicit_euler_update_matrix,
    stability_function,
    stability_polynomial,
)

RK_METHODS = [cls for cls in INTEGRATORS.values() if issubclass(cls, RungeKutta)]
EXPECTED_ORDER = {"euler": 1, "semi_implicit_euler": 1, "midpoint": 2, "rk4": 4}


@pytest.fixture
def damped() -> Spring:
    return Spring(m=1.0, c=0.5, k=15.0)


def max_error(spring: Spring, method: str, h: float, t_end: float = 10.0) -> float:
    n_steps = round(t_end / h)
    xs, _ = make_integrator(method, spring).run(1.0, 0.0, h, n_steps)
    exact, _ = spring.exact(h * np.arange(n_steps + 1), 1.0, 0.0)
    return float(np.abs(xs[:, 0] - exact).max())


# -- tableaus ---------------------------------------------------------------------------------


@pytest.mark.parametrize("cls", RK_METHODS, ids=lambda c: c.name)
def test_tableau_invariants(cls: type[RungeKutta]) -> None:
    s = len(cls.B)
    assert cls.A.shape == (s, s)
    assert np.sum(cls.B) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(cls.A.sum(axis=1), cls.C, atol=1e-15)
    assert np.all(np.triu(cls.A) == 0.0), "explicit: A strictly lower triangular"
    assert cls.evals_per_step == s
    assert not cls.A.flags.writeable


def test_rk4_stability_polynomial_is_the_exponential_series() -> None:
    np.testing.assert_allclose(
        stability_polynomial(RK4), [1.0, 1.0, 1 / 2, 1 / 6, 1 / 24], rtol=1e-15
    )


def test_a_tableau_that_is_not_explicit_is_refused() -> None:
    with pytest.raises(TypeError, match="strictly lower triangular"):

        class Implicit(RungeKutta):  # defining it is the test
            name = "implicit"
            order = 1
            A = np.array([[1.0]])
            B = np.array([1.0])
            C = np.array([1.0])


# -- choosing a method ------------------------------------------------------------------------


def test_methods_by_name() -> None:
    assert list(INTEGRATORS) == ["euler", "semi_implicit_euler", "midpoint", "rk4"]
    for name, cls in INTEGRATORS.items():
        assert get_method(name) is cls
        assert get_method(cls) is cls
        assert cls.order == EXPECTED_ORDER[name]


def test_unknown_method_lists_the_choices(damped: Spring) -> None:
    with pytest.raises(ValueError, match=r"^method must be one of 'euler', .*'rk4', got 'rk5'"):
        make_integrator("rk5", damped)


# -- accuracy ---------------------------------------------------------------------------------


@pytest.mark.parametrize("method", list(INTEGRATORS))
def test_convergence_order_on_the_damped_spring(damped: Spring, method: str) -> None:
    # h = 0.0025 -> 0.00125 is inside every method's asymptotic range (docs/numerics.md, compare)
    order = math.log2(max_error(damped, method, 0.0025) / max_error(damped, method, 0.00125))
    assert order == pytest.approx(EXPECTED_ORDER[method], abs=0.1)


def test_rk4_error_at_h_001_on_the_damped_spring(damped: Spring) -> None:
    assert max_error(damped, "rk4", 0.01) <= 1.2e-7


@pytest.mark.parametrize(
    ("method", "reference"),
    [("euler", 1.31e-1), ("semi_implicit_euler", 1.93e-2), ("midpoint", 1.42e-3), ("rk4", 1.07e-7)],
)
def test_max_errors_match_the_reference_table(
    damped: Spring, method: str, reference: float
) -> None:
    assert max_error(damped, method, 0.01) == pytest.approx(reference, rel=0.01)


def test_paper_exponential_example() -> None:
    def f(t: float, y: np.ndarray) -> np.ndarray:
        return y

    assert rk_solve("euler", f, 1.0, 0.1, 1)[1][-1] == pytest.approx(1.1, abs=1e-15)
    y_rk4 = rk_solve("rk4", f, 1.0, 0.1, 1)[1][-1]
    assert round(y_rk4, 5) == 1.10517
    assert y_rk4 == pytest.approx(1.0 + 0.1 * 6.31025 / 6.0, abs=1e-15)
    with pytest.raises(ValueError, match="Runge–Kutta"):
        rk_solve("semi_implicit_euler", f, 1.0, 0.1, 1)


# -- the two stepping paths ---------------------------------------------------------------------


def sine_target(n: int):
    gains = np.linspace(0.2, 1.0, n)

    def target(t: float) -> tuple[np.ndarray, np.ndarray]:
        return gains * np.sin(3.0 * t), 3.0 * gains * np.cos(3.0 * t)

    return target


@settings(max_examples=25, deadline=None)
@given(
    method=st.sampled_from(list(INTEGRATORS)),
    n=st.integers(1, 6),
    seed=st.integers(0, 2**32 - 1),
    target_kind=st.sampled_from(["none", "held", "callable"]),
)
def test_python_and_numpy_paths_are_bit_identical(
    method: str, n: int, seed: int, target_kind: str
) -> None:
    rng = np.random.default_rng(seed)
    spring = Spring(
        m=rng.uniform(0.1, 3.0, n),
        c=rng.uniform(0.0, 2.0, n),
        k=rng.uniform(0.5, 50.0, n),
        b=rng.uniform(-1.0, 1.0, n),
    )
    target = {
        "none": None,
        "held": (rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)),
        "callable": sine_target(n),
    }[target_kind]
    x0, v0 = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    slow = make_integrator(method, spring, vectorized=False).run(x0, v0, 0.01, 50, 0.3, target)
    fast = make_integrator(method, spring, vectorized=True).run(x0, v0, 0.01, 50, 0.3, target)
    np.testing.assert_array_equal(slow[0], fast[0])
    np.testing.assert_array_equal(slow[1], fast[1])


@pytest.mark.parametrize("method", ["euler", "midpoint", "rk4"])
def test_spring_steps_match_the_generic_tableau_solver(method: str) -> None:
    n = 3
    spring = Spring(m=[1.0, 2.0, 0.5], c=[0.3, 0.0, 1.0], k=[10.0, 4.0, 8.0], b=[0.5, 0.0, -0.2])
    target = sine_target(n)
    w2, cm, bm = spring.k / spring.m, spring.c / spring.m, spring.b / spring.m

    def f(t: float, y: np.ndarray) -> np.ndarray:
        u, du = target(t)
        return np.stack([y[1], w2 * (u - y[0]) + bm * du - cm * y[1]])

    _, ys = rk_solve(method, f, np.stack([np.full(n, 0.5), np.full(n, -0.2)]), 0.01, 200)
    xs, vs = make_integrator(method, spring).run(0.5, -0.2, 0.01, 200, 0.0, target)
    np.testing.assert_allclose(xs, ys[:, 0], rtol=0, atol=1e-13)
    np.testing.assert_allclose(vs, ys[:, 1], rtol=0, atol=1e-13)


def test_step_updates_in_place_and_run_records_it(damped: Spring) -> None:
    integ = make_integrator("rk4", damped)
    x, v = np.array([1.0]), np.array([0.0])
    x_id, v_id = id(x), id(v)
    for i in range(10):
        integ.step(x, v, 0.01, i * 0.01)
    xs, vs = integ.run(1.0, 0.0, 0.01, 10)
    assert (id(x), id(v)) == (x_id, v_id)
    assert x[0] == xs[-1, 0] and v[0] == vs[-1, 0]


def test_small_banks_step_in_python_and_large_ones_in_numpy() -> None:
    small = make_integrator("rk4", Spring(m=1.0, c=0.1, k=np.ones(Integrator.small_bank_limit)))
    large = make_integrator("rk4", Spring(m=1.0, c=0.1, k=np.ones(Integrator.small_bank_limit + 1)))
    assert not small.vectorized and large.vectorized


@pytest.mark.parametrize("method", list(INTEGRATORS))
def test_vectorised_step_allocates_no_arrays(method: str) -> None:
    n = 10_000  # one state array is 80 kB; a step may allocate only small Python objects
    spring = Spring(m=1.0, c=0.2, k=np.linspace(1.0, 20.0, n))
    integ = make_integrator(method, spring)
    x, v = np.ones(n), np.zeros(n)
    target = (np.zeros(n), np.zeros(n))
    integ.step(x, v, 1e-3, 0.0, target)  # warm the h-scaled tableau cache
    tracemalloc.start()
    try:
        for i in range(5):
            integ.step(x, v, 1e-3, i * 1e-3, target)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 8 * n / 4


def test_a_held_target_is_an_equilibrium() -> None:
    spring = Spring(m=2.0, c=0.7, k=9.0, b=0.3)
    xs, vs = make_integrator("rk4", spring).run(0.4, 0.0, 0.01, 100, 0.0, (0.4, 0.0))
    np.testing.assert_allclose(xs, 0.4, rtol=0, atol=1e-15)
    np.testing.assert_allclose(vs, 0.0, rtol=0, atol=1e-15)


def test_velocity_feed_forward_tracks_a_ramp_without_lag() -> None:
    # with b = c the spring follows u = a·t exactly: m·x'' + c·(x' − a) + k·(x − a·t) = 0
    spring = Spring(m=1.0, c=0.8, k=4.0, b=0.8)
    rate = 0.5

    def ramp(t: float) -> tuple[float, float]:
        return rate * t, rate

    xs, vs = make_integrator("rk4", spring).run(0.0, rate, 0.01, 300, 0.0, ramp)
    t = 0.01 * np.arange(301)
    np.testing.assert_allclose(xs[:, 0], rate * t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(vs[:, 0], rate, rtol=0, atol=1e-12)


# -- stability functions ----------------------------------------------------------------------


@pytest.mark.parametrize("cls", RK_METHODS, ids=lambda c: c.name)
def test_growth_is_the_squared_stability_function_minus_one(cls: type[RungeKutta]) -> None:
    rng = np.random.default_rng(3)
    z = rng.uniform(-3, 1, 200) + 1j * rng.uniform(-3, 3, 200)
    np.testing.assert_allclose(
        growth(cls, z), np.abs(stability_function(cls, z)) ** 2 - 1.0, rtol=1e-12, atol=1e-12
    )


@pytest.mark.parametrize("cls", RK_METHODS, ids=lambda c: c.name)
def test_one_step_multiplies_a_free_mode_by_r(cls: type[RungeKutta]) -> None:
    spring = Spring(m=1.0, c=0.6, k=12.0)
    h = 0.05
    lam = spring.eigenvalues[0]
    # the mode with x = 1, v = λ evolves as e^(λt); one step scales it by R(hλ)
    x, v = np.array([1.0 + 0j]).real, np.array([lam]).real
    xi, vi = np.array([0.0]), np.array([lam.imag])
    integ = make_integrator(cls, spring)
    integ.step(x, v, h)
    integ.step(xi, vi, h)
    r = stability_function(cls, h * lam)
    assert complex(x[0], xi[0]) == pytest.approx(r, abs=1e-14)
    assert complex(v[0], vi[0]) == pytest.approx(r * lam, abs=1e-13)


def test_semi_implicit_euler_update_matrix_is_its_step() -> None:
    spring = Spring(m=1.0, c=0.9, k=16.0)
    h = 0.03
    theta, zeta = h * float(spring.natural_frequency), float(spring.damping_ratio)
    w0 = float(spring.natural_frequency)
    m = semi_implicit_euler_update_matrix(theta, zeta)
    x, v = np.array([0.3]), np.array([-1.2])
    expected = m @ np.array([0.3, -1.2 / w0])
    make_integrator("semi_implicit_euler", spring).step(x, v, h)
    np.testing.assert_allclose([x[0], v[0] / w0], expected, rtol=1e-14)
    rho = max(abs(np.linalg.eigvals(m)))
    assert semi_implicit_euler_amplification(theta, zeta) == pytest.approx(rho, rel=1e-12)


def test_the_stability_function_belongs_to_runge_kutta_methods_only() -> None:
    with pytest.raises(ValueError, match="Runge–Kutta"):
        stability_polynomial("semi_implicit_euler")
    with pytest.raises(ValueError, match="Runge–Kutta"):
        stability_function("semi_implicit_euler", 0.1j)


@pytest.mark.parametrize("theta", [0.1, 1.0, 1.9, 1.999])
def test_semi_implicit_euler_neither_gains_nor_loses_amplitude_undamped(theta: float) -> None:
    assert semi_implicit_euler_amplification(theta, 0.0) == 1.0
    assert semi_implicit_euler_amplification(2.001, 0.0) > 1.0
