"""The tick's faster paths against the ways they replaced: the same numbers, bit for bit (the
springs' held step: to rounding, as it is the staged step's map, computed once).

Each test holds a per-tick path (Python floats instead of numpy calls, packed writes, lazy
books) against the plain computation it stands for."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilsim.dynamics.integrators import INTEGRATORS, make_integrator
from hilsim.dynamics.springs import Spring
from hilsim.rig.joint_map import JointMap
from hilsim.show.monitors import STALL_ALLOWANCE_S, HostStalls, SilenceBudget
from hilsim.targets import Keyframes, Sine, Step, TargetSet
from hilsim.telemetry.format import TickRecord, csv_columns
from hilsim.telemetry.ring import TickRing
from hilsim.telemetry.stats import RunStats

floats = st.floats(-1e3, 1e3, allow_nan=False)


# ------------------------------------------------------------------ springs
@settings(max_examples=60)
@given(
    n=st.integers(1, 17),
    seed=st.integers(0, 2**32 - 1),
    kind=st.sampled_from(["t", "l", "a"]),
    method=st.sampled_from(list(INTEGRATORS)),
)
def test_the_held_step_is_each_methods_staged_step(n, seed, kind, method):
    # the loop's step (the method's step as a matrix, hilsim.dynamics.held_step.HeldStep) against the
    # method's own stages: the same map, so the same numbers to rounding (not the same bits)
    rng = np.random.default_rng(seed)
    b = rng.uniform(-1, 1, n) if rng.random() < 0.7 else 0.0
    spring = Spring(
        m=rng.uniform(0.1, 3, n), c=rng.uniform(0, 2, n), k=rng.uniform(0.5, 50, n), b=b
    )
    held, staged = (make_integrator(method, spring, vectorized=False) for _ in range(2))
    x0, v0 = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    x, v = x0.copy(), v0.copy()
    xg, vg = x0.tolist(), v0.tolist()
    for step in range(20):
        u, du = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
        target = {"t": (tuple(u.tolist()), tuple(du.tolist())), "l": (u.tolist(), du), "a": (u, du)}
        held.step(x, v, 0.004, 0.004 * step, target[kind])
        xg, vg = staged._step_lists(xg, vg, 0.004, 0.004 * step, (u, du))
    np.testing.assert_allclose(x, xg, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(v, vg, rtol=1e-13, atol=1e-13)


def test_rk4s_step_matrix_is_its_stability_polynomial():
    spring = Spring(m=[1.0, 0.5], c=[0.3, 2.0], k=[40.0, 9.0])
    h = 0.004
    S = make_integrator("rk4", spring).held_matrix(h)
    for j in range(2):
        hM = h * np.array([[0.0, 1.0], [-spring.k[j] / spring.m[j], -spring.c[j] / spring.m[j]]])
        taylor = sum(np.linalg.matrix_power(hM, p) / math.factorial(p) for p in range(5))
        np.testing.assert_allclose(S[j, :2, :2], taylor, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(S[j, 2], [0.0, 0.0, 1.0])


def test_the_loops_step_on_arrays_writes_the_lists_result():
    spring = Spring.from_animation(np.full(4, 3.0), 0.7, 0.4)
    integ = make_integrator("rk4", spring)
    x, v = np.linspace(-0.5, 0.5, 4), np.zeros(4)
    xl, vl = x.tolist(), v.tolist()
    target = ((0.1, 0.2, 0.3, 0.4), (1.0, 0.0, -1.0, 0.5))
    for _ in range(5):
        integ.step(x, v, 0.002, 0.0, target)
        integ.held_step(0.002).lists(xl, vl, *target)
    assert x.tolist() == xl and v.tolist() == vl
    vec = make_integrator("rk4", spring, vectorized=True)  # the array path: the same bits
    xa, va = np.linspace(-0.5, 0.5, 4), np.zeros(4)
    for _ in range(5):
        vec.step(xa, va, 0.002, 0.0, target)
    assert xa.tolist() == xl and va.tolist() == vl
    other = np.zeros(4)  # another array: viewed anew
    integ.step(other, v.copy(), 0.002, 0.0, target)
    assert other.any()


# ------------------------------------------------------------------ the joint map
@settings(max_examples=100)
@given(data=st.data(), n=st.integers(1, 16))
def test_the_joint_maps_list_path_is_its_array_path(data, n):
    home = data.draw(st.lists(floats, min_size=n, max_size=n))
    direction = data.draw(st.lists(st.sampled_from([1.0, -1.0]), min_size=n, max_size=n))
    x = np.array(data.draw(st.lists(floats, min_size=n, max_size=n)))
    jm = JointMap(home, direction)
    servo = jm.to_servo(x, np.empty(n))
    assert jm.to_servo_list(x.tolist()) == servo.tolist()
    servo[0] = math.nan
    joint = jm.to_joint(servo, np.empty(n))
    assert np.array_equal(np.array(jm.to_joint_list(servo.tolist())), joint, equal_nan=True)
    with pytest.raises(ValueError, match="joints"):
        jm.to_servo_list([0.0] * (n + 1))


# ------------------------------------------------------------------ targets
def test_sample_into_writes_and_returns_what_sample_writes():
    tracks = [
        Sine(0.3, 0.7, 0.2, 0.1),
        Step(0.5, 0.0, 1.0),
        Keyframes([0, 1, 2], [0, 1, -1], "smooth"),
    ]
    ts = TargetSet(tracks)
    for t in np.linspace(-1, 3, 41):
        u, du, u2, du2 = np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
        ts.sample(float(t), u, du)
        pos, vel = ts.sample_into(float(t), u2, du2)
        assert u.tolist() == u2.tolist() == list(pos) and du.tolist() == du2.tolist() == list(vel)
    only = np.zeros(3)
    ts.sample_into(0.25, only)
    assert only.tolist() == [tr.sample(0.25)[0] for tr in tracks]


# ------------------------------------------------------------------ the host-stall books
class OldHostStalls:
    """HostStalls' work rule as it was: the least of a numpy ring of the last 64 works."""

    def __init__(self) -> None:
        self.work, self.i = np.full(64, np.inf), 0

    def stall(self, work: float) -> float:
        usual = float(self.work.min())
        self.work[self.i % 64] = work
        self.i += 1
        return work - usual if math.isfinite(usual) and work - usual > STALL_ALLOWANCE_S else 0.0


@settings(max_examples=60)
@given(seed=st.integers(0, 2**32 - 1))
def test_host_stalls_sees_the_stalls_the_numpy_ring_saw(seed):
    rng = random.Random(seed)
    new, old = HostStalls(), OldHostStalls()
    for _ in range(300):
        work = rng.choice([rng.uniform(1e-5, 2e-4), rng.uniform(-1e-4, 5e-3), rng.uniform(0, 2e-3)])
        expect = old.stall(work)
        got = new.tick_stall(0.0, work, 0.0)
        assert got == (expect if expect > STALL_ALLOWANCE_S else 0.0)


def test_silence_budget_books_every_ok_tick_when_looked_at():
    lazy, eager = SilenceBudget(3, 0.05), SilenceBudget(3, 0.05)
    for t in range(1, 40):
        now, stalls = t * 0.01, t * 0.001
        if t % 7 == 0:
            got = lazy.failed(1, now, stalls, host_late=False)
            assert got == eager.failed(1, now, stalls, host_late=False)
        elif t % 5 == 0:
            lazy.ok(2, now, stalls)
            eager.ok(2, now, stalls)
        else:
            lazy.all_ok(now, stalls)
            eager.all_ok(now, stalls)
            eager._settle()
        for i in range(3):
            assert lazy.silent_s(i, now, stalls) == eager.silent_s(i, now, stalls)
            assert lazy.failed_reads(i) == eager.failed_reads(i)


# ------------------------------------------------------------------ telemetry rows
def _record(n: int, block: bool, rng: np.random.Generator) -> TickRecord:
    data = np.zeros(5 * n)
    arrays = (
        [data[k * n : (k + 1) * n] for k in range(5)] if block else [np.zeros(n) for _ in range(5)]
    )
    for a in arrays:
        a[:] = rng.normal(size=n)
    return TickRecord(
        *arrays,
        status=rng.integers(0, 4, n).astype(np.uint8),
        tick=7,
        t_sched=0.014,
        t_actual=0.0141,
        t_sim_us=3.5,
        t_safety_us=1.25,
        t_bus_us=40.0,
        t_telemetry_us=math.nan,
        overrun=True,
        comm_errors=12,
        host_stall_us=0.0,
        joint_block=data if block else None,
    )


@pytest.mark.parametrize("n", [1, 4, 16])
def test_a_stacked_record_makes_the_row_a_record_of_separate_arrays_makes(n):
    rng = np.random.default_rng(n)
    stacked = _record(n, True, rng)
    assert stacked.stacked()
    loose = TickRecord(
        *(
            a.copy()
            for a in (stacked.target, stacked.sim_x, stacked.sim_v, stacked.cmd, stacked.present)
        ),
        status=stacked.status.copy(),
        **{
            k: getattr(stacked, k)
            for k in (
                "tick",
                "t_sched",
                "t_actual",
                "t_sim_us",
                "t_safety_us",
                "t_bus_us",
                "t_telemetry_us",
                "overrun",
                "comm_errors",
                "host_stall_us",
            )
        },
    )
    assert not loose.stacked()
    cols = len(csv_columns([f"j{i}" for i in range(n)]))
    rows = []
    for rec in (stacked, loose):
        ring = TickRing(4, n, cols)
        for _ in range(2):
            ring.put(rec)
        rec.t_telemetry_us = 2.0
        assert ring.amend(rec)
        rows.append(ring.rows[1].tobytes())
    assert rows[0] == rows[1]
    stacked.sim_x = np.zeros(n)  # no longer a view of the block: the ring notices
    assert not stacked.stacked()
    ring = TickRing(4, n, cols)
    ring.put(stacked)
    assert ring.rows[0][4 + n : 4 + 2 * n].tolist() == [0.0] * n


def test_run_stats_packs_what_it_assigned():
    rng = np.random.default_rng(3)
    rec = _record(4, True, rng)
    stats = RunStats(["a", "b", "c", "d"], chunk_ticks=2)
    statuses = []
    for k in range(5):
        rec.tick, rec.t_actual = k, 0.002 * k
        rec.status = rng.integers(0, 4, 4).astype(np.uint8) if k % 2 else rec.status
        stats.add(rec)
        rec.overrun, rec.t_sim_us = bool(k % 2), 1.0 + k
        stats.amend(rec)
        statuses.append(rec.status.tolist())
    f, s = stats.arrays()
    assert s.tolist() == statuses
    assert f[:, 0].tolist() == [0.002 * k for k in range(5)]
    assert f[:, 2].tolist() == [0.0, 1.0, 0.0, 1.0, 0.0] and f[:, 3].tolist() == [
        1.0,
        2.0,
        3.0,
        4.0,
        5.0,
    ]
    loose = RunStats(["a", "b"])
    rec2 = _record(2, False, rng)
    rec2.status = [0, 3]  # not an array: assigned as it is
    loose.add(rec2)
    assert loose.arrays()[1].tolist() == [[0, 3]]
