"""simulate(): the paper's table, step counting, targets, argument checks."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

import hilsim
from hilsim.dynamics.simulate import simulate
from hilsim.dynamics.springs import Spring

# the paper's snapshot table: t, x, v for m = 1, k = 10, x0 = 1, v0 = 0
PAPER_TABLE = [
    ("0.00000", "1.000000", "0.000000"),
    ("0.01001", "0.999499", "-0.100083"),
    ("0.02002", "0.997997", "-0.200066"),
    ("0.03003", "0.995494", "-0.299849"),
    ("0.04004", "0.991995", "-0.399331"),
    ("0.05005", "0.987501", "-0.498414"),
    ("0.06006", "0.982018", "-0.596996"),
    ("0.07007", "0.975551", "-0.694981"),
    ("0.08008", "0.968107", "-0.792269"),
    ("0.09009", "0.959693", "-0.888764"),
]


@pytest.fixture
def undamped() -> Spring:
    return Spring(m=1.0, c=0.0, k=10.0)


def test_the_papers_table_to_six_decimals(undamped: Spring) -> None:
    traj = hilsim.simulate(undamped, 1.0, 0.0, h=10 / 999, t_end=10.0, method="rk4")
    assert len(traj.t) == 1000  # "1000 steps" on [0, 10] are 1000 points
    ours = [
        (f"{t:.5f}", f"{x:.6f}", f"{v:.6f}") for t, x, v in zip(traj.t, traj.x, traj.v, strict=True)
    ]
    assert ours[:10] == PAPER_TABLE
    exact = np.cos(math.sqrt(10.0) * traj.t)
    assert np.abs(traj.x - exact).max() == pytest.approx(2.50e-7, rel=0.01)


@pytest.mark.parametrize(
    ("h", "t_end", "points"), [(0.01, 10.0, 1001), (10 / 999, 10.0, 1000), (0.3, 1.0, 4)]
)
def test_round_t_end_over_h_steps(undamped: Spring, h: float, t_end: float, points: int) -> None:
    traj = simulate(undamped, 1.0, h=h, t_end=t_end)
    assert traj.t.shape == traj.x.shape == traj.v.shape == (points,)
    assert traj.n_steps == points - 1
    np.testing.assert_array_equal(traj.t, h * np.arange(points))
    assert traj.method == "rk4" and traj.h == h


def test_a_bank_simulates_like_its_springs_one_by_one() -> None:
    bank = Spring(m=[1.0, 2.0], c=[0.5, 0.1], k=[15.0, 3.0])
    traj = simulate(bank, [1.0, -0.5], [0.0, 0.2], h=0.01, t_end=2.0, method="midpoint")
    assert traj.x.shape == (201, 2)
    for i in range(2):
        single = Spring(m=bank.m[i], c=bank.c[i], k=bank.k[i])
        one = simulate(single, [1.0, -0.5][i], [0.0, 0.2][i], h=0.01, t_end=2.0, method="midpoint")
        np.testing.assert_array_equal(traj.x[:, i], one.x)
    assert traj.energy().shape == (201, 2)


def test_a_constant_target_is_approached() -> None:
    spring = Spring.from_animation(2.0, 0.7)
    traj = simulate(spring, 0.0, h=0.001, t_end=5.0, target=0.8)
    assert traj.x[-1] == pytest.approx(0.8, abs=1e-6)


def test_a_callable_target_with_its_rate() -> None:
    # b = c: the spring tracks a ramp exactly when it starts on it
    spring = Spring(m=1.0, c=0.8, k=4.0, b=0.8)
    traj = simulate(
        spring, 0.0, 0.5, h=0.01, t_end=3.0, target=lambda t: 0.5 * t, target_rate=lambda t: 0.5
    )
    np.testing.assert_allclose(traj.x, 0.5 * traj.t, atol=1e-12)


def test_a_callable_target_without_feed_forward_needs_no_rate() -> None:
    spring = Spring(m=1.0, c=2.0, k=1.0)
    traj = simulate(spring, 0.0, h=0.01, t_end=20.0, target=lambda t: 1.0 if t > 1 else 0.0)
    assert traj.x[-1] == pytest.approx(1.0, abs=1e-5)


BAD = [
    (dict(h=0.0), "h"),
    (dict(h=-0.01), "h"),
    (dict(h=math.nan), "h"),
    (dict(h="0.01"), "h"),
    (dict(t_end=0.0), "t_end"),
    (dict(t_end=math.inf), "t_end"),
    (dict(t_end=1e-6), "t_end"),
    (dict(x0=math.nan), "x0"),
    (dict(v0="fast"), "v0"),
    (dict(x0=[1.0, 2.0]), "x0"),
    (dict(method="rk45"), "method"),
    (dict(target=math.inf), "target"),
    (dict(target_rate=1.0), "target_rate"),
    (dict(spring=Spring(1.0, 0.5, 15.0, b=0.1), target=math.sin), "target_rate"),
    (dict(spring="spring"), "spring"),
    (dict(h=1e-9, t_end=1000.0), "h"),
]


@pytest.mark.parametrize(("overrides", "name"), BAD)
def test_bad_arguments_raise_value_error_naming_them(overrides: dict, name: str) -> None:
    kwargs = dict(spring=Spring(1.0, 0.5, 15.0), x0=1.0, v0=0.0, h=0.01, t_end=1.0) | overrides
    with pytest.raises(ValueError, match=rf"^{re.escape(name)}\b"):
        simulate(**kwargs)
