"""Springs: parameters, the animator mapping, derived quantities, exact free motion."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hilsim.dynamics.integrators import make_integrator
from hilsim.dynamics.springs import Spring


def test_a_single_spring_holds_scalars() -> None:
    s = Spring(m=1.0, c=0.5, k=15.0)
    assert s.shape == () and s.n == 1 and len(s) == 1
    assert float(s.b) == 0.0
    assert repr(s) == "Spring(m=1.0, c=0.5, k=15.0, b=0.0)"


def test_a_bank_broadcasts_scalars_and_is_read_only() -> None:
    s = Spring(m=[1.0, 2.0, 3.0], c=0.1, k=4.0)
    assert s.shape == (3,) and s.n == 3
    np.testing.assert_array_equal(s.c, [0.1, 0.1, 0.1])
    with pytest.raises(ValueError):
        s.m[0] = 5.0
    with pytest.raises(AttributeError):
        s.m = np.ones(3)  # type: ignore[misc]


def test_stack_builds_one_bank_in_order() -> None:
    bank = Spring.stack([Spring(1.0, 0.1, 2.0), Spring([3.0, 4.0], 0.2, 5.0, b=1.0)])
    np.testing.assert_array_equal(bank.m, [1.0, 3.0, 4.0])
    np.testing.assert_array_equal(bank.b, [0.0, 1.0, 1.0])
    with pytest.raises(ValueError, match=r"^springs"):
        Spring.stack([])


def test_paper_damped_spring_frequencies() -> None:
    s = Spring(m=1.0, c=0.5, k=15.0)
    assert float(s.damped_frequency) == pytest.approx(math.sqrt(15 - 0.0625), rel=1e-15)
    assert round(float(s.damped_frequency), 4) == 3.8649
    assert float(s.natural_frequency) == pytest.approx(math.sqrt(15.0))
    assert float(s.damping_ratio) == pytest.approx(0.5 / (2 * math.sqrt(15.0)))
    assert float(s.decay_rate) == 0.25


def test_rates_per_unit_mass_are_named_once() -> None:
    s = Spring(m=[2.0, 4.0], c=[0.5, 1.0], k=[10.0, 3.0], b=[0.2, -0.4])
    np.testing.assert_array_equal(s.w2, [5.0, 0.75])
    np.testing.assert_array_equal(s.cm, [0.25, 0.25])
    np.testing.assert_array_equal(s.bm, [0.1, -0.1])
    np.testing.assert_allclose(s.natural_frequency**2, s.w2, rtol=1e-15)  # ω₀² = k/m
    np.testing.assert_array_equal(s.system_matrix[:, 1], np.stack([-s.w2, -s.cm], axis=-1))


def test_damped_frequency_is_zero_from_critical_damping_on() -> None:
    s = Spring(m=1.0, c=[2.0, 5.0], k=1.0)
    np.testing.assert_array_equal(s.damped_frequency, [0.0, 0.0])


def test_eigenvalues_of_the_system_matrix() -> None:
    s = Spring(m=[1.0, 2.0, 1.0, 1.0], c=[0.0, 0.5, 2.0, 1e4], k=[10.0, 15.0, 1.0, 1.0])
    for i in range(4):
        expected = np.sort_complex(np.linalg.eigvals(s.system_matrix[i]))
        # numpy's general eigensolver loses ~1e-9 relative on the slow overdamped root
        np.testing.assert_allclose(np.sort_complex(s.eigenvalues[i]), expected, rtol=1e-8)
    assert s.eigenvalues[0, 0].real == 0.0  # undamped: exactly on the imaginary axis
    # overdamped: the slow root keeps full precision (λ₁·λ₂ = k/m)
    assert s.eigenvalues[3, 0] * s.eigenvalues[3, 1] == pytest.approx(1.0, rel=1e-15)


def test_energy() -> None:
    s = Spring(m=2.0, c=0.0, k=8.0)
    assert float(s.energy(0.5, 3.0)) == pytest.approx(0.5 * 2 * 9 + 0.5 * 8 * 0.25)
    assert float(s.energy(0.5, 0.0, u=0.5)) == 0.0


# -- animator terms ---------------------------------------------------------------------------


def test_from_animation_maps_to_the_documented_terms() -> None:
    f, zeta, r = 2.0, 0.4, 1.5
    s = Spring.from_animation(f, zeta, r)
    k1 = zeta / (math.pi * f)
    k2 = 1.0 / (2.0 * math.pi * f) ** 2
    k3 = r * zeta / (2.0 * math.pi * f)
    assert float(s.m) == pytest.approx(k2, rel=1e-15)
    assert float(s.c) == pytest.approx(k1, rel=1e-15)
    assert float(s.k) == 1.0
    assert float(s.b) == pytest.approx(k3, rel=1e-15)


@given(
    f=st.floats(0.01, 200.0),
    zeta=st.floats(0.0, 5.0),
    r=st.floats(-3.0, 3.0),
)
def test_from_animation_round_trips_frequency_and_damping(f: float, zeta: float, r: float) -> None:
    s = Spring.from_animation(f, zeta, r)
    assert float(s.natural_frequency) == pytest.approx(2 * math.pi * f, rel=1e-12)
    assert float(s.damping_ratio) == pytest.approx(zeta, rel=1e-12, abs=1e-15)


def test_from_animation_accepts_arrays() -> None:
    s = Spring.from_animation([1.0, 2.0], 0.5)
    np.testing.assert_allclose(s.natural_frequency, [2 * math.pi, 4 * math.pi])


# -- validation -------------------------------------------------------------------------------

BAD = [
    (lambda: Spring(m=0.0, c=0.0, k=1.0), "m"),
    (lambda: Spring(m=-1.0, c=0.0, k=1.0), "m"),
    (lambda: Spring(m=math.nan, c=0.0, k=1.0), "m"),
    (lambda: Spring(m=1.0, c=-0.1, k=1.0), "c"),
    (lambda: Spring(m=1.0, c=math.inf, k=1.0), "c"),
    (lambda: Spring(m=1.0, c=0.0, k=0.0), "k"),
    (lambda: Spring(m=1.0, c=0.0, k=math.inf), "k"),
    (lambda: Spring(m=1.0, c=0.0, k=1.0, b=math.nan), "b"),
    (lambda: Spring(m=[1.0, 0.0], c=0.0, k=1.0), "m[1]"),
    (lambda: Spring(m="heavy", c=0.0, k=1.0), "m"),
    (lambda: Spring(m=[[1.0]], c=0.0, k=1.0), "m"),
    (lambda: Spring.from_animation(0.0, 0.5), "frequency_hz"),
    (lambda: Spring.from_animation(1.0, -0.5), "damping_ratio"),
    (lambda: Spring.from_animation(1.0, 0.5, math.nan), "response"),
]


@pytest.mark.parametrize(("build", "name"), BAD)
def test_bad_parameters_raise_value_error_naming_them(build, name: str) -> None:
    with pytest.raises(ValueError, match=rf"^{re.escape(name)} must be"):
        build()


def test_bank_shapes_must_agree() -> None:
    with pytest.raises(ValueError, match="one bank shape"):
        Spring(m=[1.0, 2.0], c=[0.1, 0.2, 0.3], k=1.0)


def test_zero_damping_is_allowed() -> None:
    assert float(Spring(m=1.0, c=0.0, k=1.0).damping_ratio) == 0.0


# -- exact solution ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("zeta", "regime"), [(0.0, "undamped"), (0.2, "under"), (1.0, "critical"), (3.0, "over")]
)
def test_exact_solution_agrees_with_fine_rk4(zeta: float, regime: str) -> None:
    m, k = 1.5, 6.0
    s = Spring(m=m, c=2.0 * zeta * math.sqrt(k * m), k=k)
    assert (float(s.damping_ratio) == 1.0) == (regime == "critical")
    h, n_steps = 1e-3, 5000
    xs, vs = make_integrator("rk4", s).run(0.7, -1.3, h, n_steps)
    x, v = s.exact(h * np.arange(n_steps + 1), 0.7, -1.3)
    np.testing.assert_allclose(xs[:, 0], x, rtol=0, atol=1e-11)
    np.testing.assert_allclose(vs[:, 0], v, rtol=0, atol=1e-10)


def test_exact_solution_is_continuous_through_critical_damping() -> None:
    t = np.linspace(0.0, 5.0, 101)
    near = [Spring(m=1.0, c=2.0 * z, k=1.0).exact(t, 1.0, 0.5) for z in (1 - 1e-9, 1.0, 1 + 1e-9)]
    for x, v in near:
        np.testing.assert_allclose(x, near[1][0], atol=1e-8)
        np.testing.assert_allclose(v, near[1][1], atol=1e-8)


def test_exact_solution_of_a_bank_and_long_times() -> None:
    s = Spring(m=1.0, c=[0.5, 2.0, 50.0], k=1.0)
    t = np.array([0.0, 1.0, 2000.0])
    x, v = s.exact(t, 1.0)
    assert x.shape == v.shape == (3, 3)
    np.testing.assert_array_equal(x[0], 1.0)
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(v))  # no cosh overflow
    assert abs(x[2, 2]) < 1e-15
