"""Safety filter: nothing non-finite, out of range, too fast or too jerky ever leaves it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from hilsim.safety import SafetyEvent, SafetyFault, SafetyFilter, SafetyParams

DT = 0.002
LOWER = np.array([-1.0, -0.5, 0.0])
UPPER = np.array([1.0, 0.8, 0.6])
NAMES = ("head_pan", "head_tilt", "jaw")
# a few ulp of a position of magnitude ≤ ~3 rad: rounding in the speed/accel bookkeeping
ROUNDING = 1e-14


def make(speed=2.0, accel=50.0, soft_start_s=0.0, **kw) -> SafetyFilter:
    kw.setdefault("joint_names", NAMES)
    return SafetyFilter(LOWER, UPPER, speed, accel, DT, soft_start_s=soft_start_s, **kw)


def run(f: SafetyFilter, desired_rows) -> np.ndarray:
    out = np.empty(f.n_joints)
    rows = []
    for d in desired_rows:
        f.filter(np.asarray(d, dtype=np.float64), out)
        rows.append(out.copy())
    return np.array(rows)


def check_limits(f: SafetyFilter, start: np.ndarray, outputs: np.ndarray) -> None:
    """Finite, speed and acceleration limited from the start pose at rest; in range, except that
    a joint that starts outside only ever moves towards the range until it is in it."""
    p = f.params
    lo, hi = p.lower_rad, p.upper_rad
    assert np.isfinite(outputs).all()
    path = np.vstack([np.asarray(start, dtype=np.float64), outputs])
    # rounding: a few ulp of the largest position involved (≈ ROUNDING for |x| of a few rad)
    with np.errstate(over="ignore"):  # spacing(max float) is inf: no claim that far out
        tol = ROUNDING + 8 * np.spacing(np.abs(path).max(axis=0))
    steps = np.diff(path, axis=0)
    assert (np.abs(steps) <= p.max_speed_rad_s * p.dt_s + tol).all()
    steps = np.vstack([np.zeros(f.n_joints), steps])  # at rest before the first tick
    assert (np.abs(np.diff(steps, axis=0)) <= p.max_accel_rad_s2 * p.dt_s**2 + tol).all()
    before, after = path[:-1], path[1:]
    # never further out: within [min(lower, previous), max(upper, previous)]
    assert (after >= np.minimum(lo, before)).all() and (after <= np.maximum(hi, before)).all()
    # once inside, inside for good
    inside = (path >= lo) & (path <= hi)
    assert not (inside[:-1] & ~inside[1:]).any()


# ----------------------------------------------------------------------------- parameters


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"upper_rad": [1.0, -0.5, 0.6]}, r"head_tilt: need finite limits with lower < upper"),
        ({"lower_rad": [-1.0, -0.5, math.nan]}, r"jaw: need finite limits"),
        ({"max_speed_rad_s": [1.0, 0.0, 1.0]}, r"head_tilt: max_speed_rad_s must be finite and >"),
        ({"max_accel_rad_s2": math.inf}, r"head_pan: max_accel_rad_s2 must be finite and > 0"),
        ({"dt_s": 0.0}, r"dt_s must be finite and > 0"),
        ({"soft_start_s": -1.0}, r"soft_start_s must be finite and >= 0"),
        ({"upper_rad": [1.0, 1.0]}, r"upper_rad must be a number or an array shaped \(3,\)"),
        ({"lower_rad": []}, r"lower_rad must be a non-empty 1-D array"),
        ({"joint_names": ["a"]}, r"1 joint_names for 3 joints"),
        ({"max_accel_rad_s2": 1e-310}, r"too small to compute with"),
    ],
)  # fmt: skip
def test_parameters_are_validated_up_front(kw, match):
    args = {
        "lower_rad": LOWER,
        "upper_rad": UPPER,
        "max_speed_rad_s": 2.0,
        "max_accel_rad_s2": 50.0,
        "dt_s": DT,
        "joint_names": NAMES,
    }
    args.update(kw)
    with pytest.raises(ValueError, match=match):
        SafetyFilter(**args)


def test_params_are_frozen_arrays():
    f = make(speed=[1.0, 2.0, 3.0])
    p = f.params
    assert isinstance(p, SafetyParams) and p.n_joints == 3
    np.testing.assert_array_equal(p.max_accel_rad_s2, [50.0, 50.0, 50.0])  # a number broadcasts
    with pytest.raises(ValueError):
        p.lower_rad[0] = -5.0


# -------------------------------------------------------------------------------- start


def test_filter_before_start_is_an_error():
    with pytest.raises(RuntimeError, match="start"):
        make().filter(np.zeros(3), np.zeros(3))


def test_start_needs_a_finite_pose_and_names_the_joint():
    f = make()
    with pytest.raises(ValueError, match=r"no finite present position for jaw \(nan\)"):
        f.start(np.array([0.0, 0.0, math.nan]))
    with pytest.raises(ValueError, match=r"head_pan \(inf\), head_tilt \(-inf\)"):
        f.start(np.array([math.inf, -math.inf, 0.0]))
    with pytest.raises(ValueError, match=r"shaped \(3,\)"):
        f.start(np.zeros(2))
    assert not f.started


def test_start_outside_the_limits_is_walked_back_in_and_reported():
    # the review's case: a jaw found 14 deg beyond its limit must not jump there in one tick
    speed, accel = 2.0, 50.0
    f = make(speed=speed, accel=accel)
    start = np.array([0.0, 0.9, -0.25])
    event = f.start(start)
    assert isinstance(event, SafetyEvent) and not event.fatal
    assert event.kind is SafetyFault.START_OUTSIDE_LIMITS
    assert event.joints == ("head_tilt", "jaw") and event.values == (0.9, -0.25)
    assert "head_tilt (0.9 rad)" in str(event) and "walked back in" in str(event)
    out = run(f, [start] * 400)  # the desired pose is the start pose, clamped by step 2
    check_limits(f, start, out)
    v, a = speed * DT, accel * DT * DT
    # from rest: the first step is one acceleration step, then they grow by a each tick
    np.testing.assert_allclose(np.diff(np.concatenate([[-0.25], out[:3, 2]])), a * np.arange(1, 4))
    np.testing.assert_allclose(out[0, 1], 0.9 - a)
    # never a jump; inwards only while outside (it arrives moving, so it may pass the limit
    # inwards and come back to it, like any speed-limited step); then resting on the limits
    assert np.abs(np.diff(out, axis=0)).max() <= v + ROUNDING
    first_in = [int(np.argmax(out[:, 1] <= 0.8)), int(np.argmax(out[:, 2] >= 0.0))]
    assert (np.diff(out[: first_in[0] + 1, 1]) < 0).all()
    assert (np.diff(out[: first_in[1] + 1, 2]) > 0).all()
    # 0.25 rad: 20 ticks ramping up to 2 rad/s at 50 rad/s² (0.042 rad), then 52 at full speed
    assert 68 <= first_in[1] <= 74
    np.testing.assert_array_equal(out[-1], [0.0, 0.8, 0.0])
    assert (out[:, 0] == 0.0).all()
    c = f.counters
    assert c.outside.tolist() == [0, *first_in]
    assert c.position.tolist() == [0, 400, 400]  # the desired pose (the start) was outside
    assert make().start(np.zeros(3)) is None


def test_start_outside_walks_in_through_the_soft_start():
    # a soft start long enough for the excess: the output is the blend from the present pose,
    # outside the limits, to the desired one: smooth, monotone, no limit acting, arriving at rest
    soft = 1.0
    f = make(speed=5.0, accel=50.0, soft_start_s=soft)
    start = np.array([-1.3, 0.0, 0.0])  # 0.3 rad below head_pan's lower limit
    assert f.start(start) is not None
    desired = np.array([0.5, 0.0, 0.3])
    k_end = round(soft / DT)
    out = run(f, [desired] * (k_end + 50))
    check_limits(f, start, out)
    u = np.arange(k_end) / k_end
    blend = start[0] + u * u * (3 - 2 * u) * (desired[0] - start[0])
    np.testing.assert_allclose(out[:k_end, 0], blend, rtol=0, atol=1e-15)
    assert (np.diff(out[:, 0]) >= 0).all()
    np.testing.assert_array_equal(out[k_end:], np.tile(desired, (50, 1)))  # then bit for bit
    c = f.counters
    assert not c.speed.any() and not c.accel.any() and not c.brake.any()
    assert c.outside[0] == int(np.argmax(out[:, 0] >= -1.0)) > 0


def test_start_outside_with_a_range_narrower_than_one_speed_step():
    # vmax·dt = 0.1 > the whole 0.05 range: the step cap is the range; no overshoot through it
    f = SafetyFilter([0.0], [0.05], 50.0, 5000.0, DT, soft_start_s=0.0)
    start = np.array([0.4])
    f.start(start)
    out = run(f, [[0.05]] * 200)
    check_limits(f, start, out)
    assert out[-1, 0] == 0.05


def test_nan_while_walking_back_in_keeps_walking_in_and_stops_on_the_limit():
    f = make(speed=2.0, accel=50.0)
    start = np.array([0.0, 1.2, 0.0])
    f.start(start)
    out = run(f, [start] * 20)
    held = run(f, [[math.nan, 0.0, 0.0]] * 400)
    check_limits(f, start, np.vstack([out, held]))
    assert out[-1, 1] > 0.8  # still outside when the NaN came
    assert -0.5 <= held[-1, 1] <= 0.8 and held[-1, 1] == held[-2, 1]  # in, and at rest


# ------------------------------------------------------------------------- pass-through


def test_motion_within_every_limit_passes_through_bit_for_bit():
    # accel·dt = 2 rad/s per tick: enough to reach the desired 1 rad/s from rest in one tick
    f = make(speed=5.0, accel=1000.0)
    t = np.arange(2000) * DT
    desired = np.stack([0.5 * np.sin(2 * t), 0.3 * np.cos(3 * t) - 0.1, 0.3 + 0.2 * np.sin(t)], 1)
    f.start(desired[0])
    out = run(f, desired)
    np.testing.assert_array_equal(out, desired)
    c = f.counters
    assert c.ticks == 2000 and c.fault_ticks == 0
    for name in ("position", "speed", "brake", "accel", "nonfinite"):
        assert not getattr(c, name).any(), name


def test_out_may_be_the_desired_array():
    f = make()
    f.start(np.zeros(3))
    x = np.array([5.0, math.nan, 0.1])
    event = f.filter(x, x)
    assert event is not None and event.joints == ("head_tilt",)
    np.testing.assert_array_equal(x, [0.0, 0.0, 0.0])


# ---------------------------------------------------------------------------- non-finite


def test_nan_holds_every_joint_at_rest_exactly():
    f = make()
    f.start(np.array([0.2, -0.1, 0.3]))
    out = run(f, [[0.2, -0.1, 0.3]] * 3)
    before = out[-1].copy()
    cmd = np.empty(3)
    event = f.filter(np.array([0.25, math.nan, -math.inf]), cmd)
    np.testing.assert_array_equal(cmd, before)
    assert event.fatal and event.kind is SafetyFault.NONFINITE
    assert event.joints == ("head_tilt", "jaw") and event.tick == 3
    assert math.isnan(event.values[0]) and event.values[1] == -math.inf
    assert "head_tilt (nan rad), jaw (-inf rad)" in str(event)
    c = f.counters
    assert c.fault_ticks == 1 and list(c.nonfinite) == [0, 1, 1]


def test_nan_while_moving_brakes_at_the_acceleration_limit():
    f = make(speed=2.0, accel=50.0)
    f.start(np.zeros(3))
    ramp = [[k * 0.002, 0.0, 0.3] for k in range(1, 200)]  # 1 rad/s on head_pan
    out = run(f, ramp)
    held = run(f, [[math.nan, 0.0, 0.0]] * 30)
    steps = np.diff(np.vstack([out[-2:], held])[:, 0])
    a = 50.0 * DT * DT
    expected = np.maximum(steps[0] - a * np.arange(1, 11), 0.0)
    np.testing.assert_allclose(steps[1:11], expected, atol=1e-15)
    assert steps[-1] == 0.0  # standing still, where it stopped
    check_limits(f, np.zeros(3), np.vstack([out, held]))


def test_a_finite_but_overflowing_sum_is_not_a_fault():
    f = make()
    f.start(np.zeros(3))
    assert f.filter(np.array([1e308, 1e308, -1e308]), np.empty(3)) is None


floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
anything = hnp.arrays(np.float64, 3, elements=floats)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(anything, min_size=1, max_size=40),
    hnp.arrays(np.float64, 3, elements=st.floats(-2, 2)),
)
def test_any_float_input_gives_a_finite_limited_output(rows, start):
    f = make(speed=3.0, accel=400.0, soft_start_s=0.01)
    f.start(start)
    out = np.empty(3)
    outputs = []
    for d in rows:
        event = f.filter(d, out)
        bad = ~np.isfinite(d)
        if bad.any():
            assert event is not None and event.fatal
            assert event.joints == tuple(n for n, b in zip(NAMES, bad, strict=True) if b)
        else:
            assert event is None
        outputs.append(out.copy())
    check_limits(f, start, np.array(outputs))
    assert f.counters.fault_ticks == sum(int((~np.isfinite(d)).any()) for d in rows)


limits = st.tuples(
    st.floats(-3.0, 2.0), st.floats(0.01, 3.0), st.floats(0.05, 20.0), st.floats(1.0, 5000.0)
)


@settings(max_examples=150, deadline=None)
@given(
    st.lists(limits, min_size=1, max_size=4),
    st.sampled_from([0.001, 0.002, 0.01]),
    st.data(),
)
def test_limits_hold_for_generated_target_sequences(joints, dt, data):
    lower = np.array([j[0] for j in joints])
    upper = lower + np.array([j[1] for j in joints])
    f = SafetyFilter(
        lower, upper, [j[2] for j in joints], [j[3] for j in joints], dt, soft_start_s=0.05
    )
    n = len(joints)
    start = data.draw(hnp.arrays(np.float64, n, elements=st.floats(-5.0, 5.0)))
    f.start(start)
    # targets that jump around, sit on or beyond the limits, and sweep smoothly
    target = st.one_of(
        hnp.arrays(np.float64, n, elements=st.floats(-10.0, 10.0)),
        st.just(upper + 1.0),
        st.just(lower - 1.0),
        hnp.arrays(np.float64, n, elements=floats),
    )
    rows = data.draw(st.lists(target, min_size=1, max_size=20))
    rows = [r for r in rows for _ in range(data.draw(st.integers(1, 30)))]  # hold each a while
    check_limits(f, start, run(f, rows))


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(limits, min_size=1, max_size=3),
    st.sampled_from([0.001, 0.004, 0.01]),
    st.floats(0.0, 0.1),
    st.data(),
)
def test_from_any_finite_start_the_output_walks_in_and_stays_in(joints, dt, soft, data):
    """From any finite start, inside or outside, and any desired inputs: steps within the speed
    limit, step changes within the acceleration limit (from rest), never away from the range while
    outside, inside for good once in; and inside within the bound when the desired motion is."""
    lower = np.array([j[0] for j in joints])
    upper = lower + np.array([j[1] for j in joints])
    speed, accel = np.array([j[2] for j in joints]), np.array([j[3] for j in joints])
    f = SafetyFilter(lower, upper, speed, accel, dt, soft_start_s=soft)
    n = len(joints)
    start = data.draw(
        st.one_of(
            hnp.arrays(np.float64, n, elements=st.floats(-10.0, 10.0)),
            hnp.arrays(np.float64, n, elements=finite),
        )
    )
    f.start(start)
    # first anything at all, then a desired motion inside the limits, for long enough to get in
    wild = data.draw(st.lists(hnp.arrays(np.float64, n, elements=floats), max_size=10))
    fractions = data.draw(
        st.lists(hnp.arrays(np.float64, n, elements=st.floats(0.0, 1.0)), min_size=1, max_size=5)
    )
    out = run(f, wild)
    vmax = np.minimum(speed * dt, upper - lower)
    excess = np.maximum(np.maximum(lower - start, start - upper), 0.0) + (upper - lower)
    # from rest to the speed limit, across the excess (plus the range), and the soft start
    with np.errstate(over="ignore"):
        ticks = float(np.max(np.ceil(excess / vmax + vmax / (accel * dt * dt)))) + 4
    bound = int(min(ticks, 1e9)) + int(np.ceil(soft / dt))
    if bound > 20_000:  # a start far outside: check the walk only
        tail = run(f, [lower + fractions[0] * (upper - lower)] * 200)
        check_limits(f, start, np.vstack([out, tail]) if len(out) else tail)
        return
    per = -(-bound // len(fractions))
    inside = [lower + fr * (upper - lower) for fr in fractions for _ in range(per)]
    tail = run(f, inside)
    both = np.vstack([out, tail]) if len(out) else tail
    check_limits(f, start, both)
    end = both[len(out) + bound - 1 :]
    assert ((end >= lower) & (end <= upper)).all()


# ------------------------------------------------------------------------------- limits


def test_position_clamp_and_counters():
    f = make(speed=100.0, accel=1e6)
    f.start(np.zeros(3))
    out = run(f, [[5.0, -5.0, 0.3]] * 200)
    np.testing.assert_array_equal(out[-1], [1.0, -0.5, 0.3])
    c = f.counters
    assert c.position[0] == 200 and c.position[1] == 200 and c.position[2] == 0
    summary = c.as_dict()
    assert summary["ticks"] == 200 and summary["fault_ticks"] == 0
    assert summary["position"] == {"head_pan": 200, "head_tilt": 200, "jaw": 0}
    assert all(type(v) is int for v in summary["position"].values())


def test_speed_limit_lags_then_catches_up():
    f = make(speed=1.0, accel=1e6)
    f.start(np.zeros(3))
    out = run(f, [[0.5, 0.0, 0.0]] * 300)
    steps = np.diff(np.concatenate([[0.0], out[:, 0]]))
    assert steps.max() == pytest.approx(1.0 * DT)
    assert out[-1, 0] == 0.5  # caught up: the last step was shortened to land exactly
    assert f.counters.speed[0] == int(np.ceil(0.5 / (1.0 * DT))) - 1


def test_acceleration_limit_ramps_the_speed():
    f = make(speed=100.0, accel=100.0)
    f.start(np.zeros(3))
    # a desired speed of 5 rad/s from rest: the step grows by accel·dt² a tick
    out = run(f, [[0.01 * k, 0.0, 0.0] for k in range(1, 6)])
    a = 100.0 * DT * DT
    np.testing.assert_allclose(np.diff(np.concatenate([[0.0], out[:, 0]])), a * np.arange(1, 6))
    c = f.counters
    assert c.accel[0] == 5 and c.speed[0] == 0


def test_running_into_a_limit_brakes_early_and_stops_on_it():
    f = make(speed=4.0, accel=40.0)
    f.start(np.array([-1.0, 0.0, 0.0]))
    out = run(f, [[50.0, 0.0, 0.0]] * 1500)
    check_limits(f, np.array([-1.0, 0.0, 0.0]), out)
    assert out[-1, 0] == 1.0
    c = f.counters
    assert c.brake[0] > 0 and c.position[0] == 1500
    # it arrived by braking (check_limits: within the acceleration limit), and came to rest
    steps = np.diff(out[:, 0])
    assert steps[-1] == 0.0 and np.argmax(out[:, 0] == 1.0) < 1400


def test_long_braking_runs_do_not_pile_up_rounding():
    # ~1350 ticks of braking: with the brake applied before the acceleration limit, each tick's
    # rounding carried into all later steps and the final clamp had to stop the joint 7.7e-11 rad
    # harder than the limit allows; found by hypothesis
    lo, hi, accel = 0.8730870539936513, 2.9464595640588858, 1.1199562780237813
    f = SafetyFilter([lo], [hi], 4.41440856744365, accel, 0.001, soft_start_s=0.0)
    f.start(np.array([0.9]))
    out = run(f, [[5.0]] * 3000)
    steps = np.diff(np.concatenate([[0.9], out[:, 0]]))
    assert out[-1, 0] == hi
    assert np.abs(np.diff(np.concatenate([[0.0], steps]))).max() <= accel * 1e-6 + 1e-15


def test_counters_restart_with_start():
    f = make()
    f.start(np.zeros(3))
    run(f, [[5.0, 0.0, 0.0]] * 10)
    assert f.counters.position[0] == 10
    f.start(np.zeros(3))
    c = f.counters
    assert c.ticks == 0 and not c.position.any()


# ---------------------------------------------------------------------------- soft start


def test_soft_start_begins_at_the_present_pose_and_ends_on_the_desired():
    soft = 0.5
    f = make(speed=10.0, accel=1000.0, soft_start_s=soft)
    present = np.array([0.3, -0.2, 0.5])
    desired = np.array([-0.4, 0.6, 0.1])
    f.start(present)
    k_end = round(soft / DT)
    out = run(f, [desired] * (k_end + 10))
    np.testing.assert_array_equal(out[0], present)
    np.testing.assert_array_equal(out[k_end], desired)
    assert not np.array_equal(out[k_end - 1], desired)
    # smoothstep: halfway in time, halfway in space; monotone throughout
    np.testing.assert_allclose(out[k_end // 2], (present + desired) / 2, atol=1e-12)
    assert np.all(np.diff(out[:, 0]) <= 0) and np.all(np.diff(out[:, 1]) >= 0)
    assert not f.counters.speed.any() and not f.counters.accel.any()
    check_limits(f, present, out)


def test_soft_start_follows_a_moving_desired_pose():
    f = make(speed=10.0, accel=1000.0, soft_start_s=0.2)
    f.start(np.zeros(3))
    t = np.arange(300) * DT
    desired = np.stack([0.5 * np.sin(3 * t), np.zeros_like(t), 0.3 + 0.1 * np.sin(t)], 1)
    out = run(f, desired)
    np.testing.assert_array_equal(out[100:], desired[100:])  # 0.2 s = 100 ticks


def test_soft_start_is_still_speed_limited():
    f = make(speed=0.5, accel=1000.0, soft_start_s=0.1)
    f.start(np.array([-1.0, 0.0, 0.0]))
    out = run(f, [[1.0, 0.0, 0.0]] * 2500)
    assert np.abs(np.diff(out[:, 0])).max() <= 0.5 * DT + ROUNDING
    assert out[-1, 0] == 1.0  # it gets there in the end, 4 s later
    assert f.counters.speed[0] > 0


def test_no_soft_start():
    f = make(speed=100.0, accel=1e7, soft_start_s=0.0)
    f.start(np.zeros(3))
    out = run(f, [[0.1, 0.1, 0.1]])
    np.testing.assert_array_equal(out[0], [0.1, 0.1, 0.1])
