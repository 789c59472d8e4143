"""Stability guard: boundaries along rays, critical steps, the smallest substep count."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from hilsim.dynamics.integrators import INTEGRATORS, make_integrator
from hilsim.dynamics.springs import Spring
from hilsim.dynamics.stability import (
    GROWTH_FLOOR,
    MAX_SUBSTEPS,
    check_stability,
    critical_step,
    stability_boundary,
)
from hilsim.dynamics.stability_algebra import spectral_growth


def test_rk4_limits_on_the_axes() -> None:
    assert stability_boundary("rk4", math.pi / 2) == pytest.approx(2 * math.sqrt(2), abs=1e-3)
    assert stability_boundary("rk4", math.pi) == pytest.approx(2.7853, abs=1e-3)
    assert stability_boundary("rk4", math.pi / 2) == pytest.approx(2 * math.sqrt(2), rel=1e-12)


@pytest.mark.parametrize(
    ("method", "imaginary", "negative_real"),
    [("euler", 0.0, 2.0), ("midpoint", 0.0, 2.0), ("semi_implicit_euler", 2.0, 2 * (2**0.5 - 1))],
)
def test_other_methods_on_the_axes(method: str, imaginary: float, negative_real: float) -> None:
    assert stability_boundary(method, math.pi / 2) == pytest.approx(imaginary, abs=1e-12)
    assert stability_boundary(method, math.pi) == pytest.approx(negative_real, rel=1e-12)


def test_euler_boundary_along_a_damped_ray_is_a_chord_of_its_disk() -> None:
    # |1 + r·e^(iφ)| = 1  <=>  r = −2·cos φ
    angles = np.radians([100.0, 120.0, 150.0, 170.0])
    np.testing.assert_allclose(stability_boundary("euler", angles), -2 * np.cos(angles), rtol=1e-12)


@pytest.mark.parametrize("zeta", [0.0, 0.1, 0.5, 1.0, 2.0])
def test_semi_implicit_euler_critical_step_has_a_closed_form(zeta: float) -> None:
    w0 = 7.0
    spring = Spring(m=1.0, c=2 * zeta * w0, k=w0**2)
    theta_star = 2 * (math.sqrt(1 + zeta**2) - zeta)
    assert critical_step(spring, "semi_implicit_euler")[0] * w0 == pytest.approx(theta_star)


def test_check_stability_of_a_stable_rig() -> None:
    spring = Spring(m=1.0, c=0.5, k=15.0)
    report = check_stability(spring, 0.001, "rk4")
    assert report.stable and report.min_substeps == 1
    assert report.h_lambda[0] == pytest.approx(0.001 * math.sqrt(15.0))
    assert "stable" in report.message and "UNSTABLE" not in report.message
    assert str(report) == report.message


def test_check_stability_of_an_unstable_bank_names_the_spring_and_the_fix() -> None:
    bank = Spring.from_animation([1.0, 60.0], [0.2, 0.2])
    report = check_stability(bank, 0.01, "rk4")
    assert not report.stable
    assert list(report.stable_springs) == [True, False]
    assert report.min_substeps == math.ceil(0.01 / report.critical_step[1])
    assert "spring 1 (f = 60 Hz" in report.message
    assert f"Use {report.min_substeps} substeps" in report.message


def test_no_substep_count_makes_euler_stable_on_an_undamped_spring() -> None:
    report = check_stability(Spring(m=1.0, c=0.0, k=4.0), 1e-4, "euler")
    assert not report.stable and report.min_substeps is None
    assert report.boundary[0] == 0.0
    assert "No number of substeps" in report.message


@settings(max_examples=60, deadline=None)
@given(
    method=st.sampled_from(list(INTEGRATORS)),
    log_w0=st.floats(-1.0, 3.0),
    zeta=st.floats(0.0, 4.0),
    h=st.floats(1e-3, 0.5),
)
@example(method="rk4", log_w0=-0.977, zeta=0.0, h=0.001)  # growth −1e-26 is below rounding
# the oracle's floor (1e-14·z²) once differed from the guard's (0): at n − 1 = 202481 the growth
# 8.1e-28 was "stable" to one and "unstable" to the other (2-3 % of random runs failed)
@example(method="midpoint", log_w0=0.0, zeta=1.882114222445593e-18, h=0.5)
def test_substep_count_is_the_smallest_that_works(
    method: str, log_w0: float, zeta: float, h: float
) -> None:
    w0 = 10.0**log_w0
    spring = Spring(m=1.0, c=2.0 * zeta * w0, k=w0**2)
    report = check_stability(spring, h, method)
    n = report.min_substeps
    assume(n is not None)
    # the spring's own coefficient arrays, as the guard reads them
    w2, cm = np.reshape(spring.w2, 1), np.reshape(spring.cm, 1)
    lam_max = np.abs(np.reshape(spring.eigenvalues, (1, 2))).max(axis=1)

    def stable(step: float) -> bool:
        # below ~1e-16·(h|λ|)² the growth is float64 rounding noise (see spectral_growth); the
        # guard and this oracle use the one floor, GROWTH_FLOOR·(h|λ|)²
        growth = spectral_growth(method, step, w2, cm)
        return bool((growth <= GROWTH_FLOOR * (step * lam_max) ** 2).all())

    assert stable(h / n)
    if n > 1:
        assert not stable(h / (n - 1))
    assert report.stable == (n == 1)


@pytest.mark.parametrize("method", ["rk4", "semi_implicit_euler"])
def test_the_boundary_separates_bounded_from_growing_motion(method: str) -> None:
    spring = Spring(m=1.0, c=0.3, k=100.0)
    h_star = critical_step(spring, method)[0]
    peaks = []
    for h in (0.98 * h_star, 1.02 * h_star):
        xs, _ = make_integrator(method, spring).run(1.0, 0.0, h, 3000)
        peaks.append(np.nan_to_num(np.abs(xs[-300:]).max(), nan=np.inf))  # nan: overflowed
    assert peaks[0] < 1.0 < peaks[1]


def test_bad_step_is_refused() -> None:
    with pytest.raises(ValueError, match=r"^h must be"):
        check_stability(Spring(1.0, 0.5, 15.0), 0.0)
    with pytest.raises(ValueError, match=r"^method must be one of"):
        check_stability(Spring(1.0, 0.5, 15.0), 0.01, "leapfrog")


def test_the_substep_search_is_bounded_for_an_absurdly_stiff_spring() -> None:
    # k = 1e300 once hung here: substeps += 1 on a ~1e147 integer never changed the quotient
    report = check_stability(Spring(m=1.0, c=0.8, k=1e300), 0.004, "rk4")
    assert not report.stable and report.min_substeps is None
    assert report.substeps_needed == pytest.approx(0.004 / report.critical_step[0])
    assert report.substeps_needed > MAX_SUBSTEPS
    assert "It would take about 1.41e+147 substeps" in report.message
    assert "No number of substeps" not in report.message


def test_a_count_just_under_the_cap_is_still_reported() -> None:
    # midpoint on a barely damped spring needs ~2e5 substeps: counted, not given up on
    report = check_stability(Spring(m=1.0, c=2 * 1.882114222445593e-18, k=1.0), 0.5, "midpoint")
    assert report.min_substeps is not None and 1e5 < report.min_substeps <= MAX_SUBSTEPS


def test_overflowing_spring_rates_are_refused() -> None:
    with pytest.raises(ValueError, match="overflow float64"):
        check_stability(Spring(m=1e-300, c=0.0, k=1e300), 0.004)


def test_the_ci_profile_is_derandomized_and_keeps_no_example_database() -> None:
    # tests/conftest.py: loaded when CI is set; no .hypothesis/ replay can make a failure stick
    from hypothesis import settings

    ci = settings.get_profile("hilsim-ci")
    assert ci.derandomize and ci.database is None and ci.deadline is None
