"""hilsim.show.session: a rig into running parts — the spin window reaching the clock, the port's
clock, and the joint map every conversion goes through."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.clock import DEFAULT_SPIN_S, MonotonicClock, VirtualClock
from drivers.dxlsim.url import DxlsimUrl
from hilsim.rig import load_rig
from hilsim.rig.joint_map import JointMap
from hilsim.show.parts import build_parts
from hilsim.show.session import expectations, port_for, real_clock

RIG = """
name = "s"
[bus]
port = "{port}"
baud = 1000000
[loop]
rate_hz = 250
{spin}
[[joints]]
name = "pan"
servo_id = 1
model = "XM430-W350"
home_deg = 30
direction = -1
min_deg = -40
max_deg = 60
max_speed_deg_s = 200
max_accel_deg_s2 = 3000
spring = {{ frequency_hz = 2.0, damping_ratio = 0.7 }}
target = {{ type = "hold", value_deg = 0 }}
"""


def rig(tmp_path: Path, port: str = "dxlsim://?ids=1", spin_us: float | None = None):
    spin = "" if spin_us is None else f"spin_us = {spin_us}"
    path = tmp_path / "s.toml"
    path.write_text(RIG.format(port=port, spin=spin))
    return load_rig(path)


def measured_spin_window(clock: MonotonicClock, deadline: float = 0.01) -> float:
    """Run ``clock.wait_until(deadline)`` with a virtual clock as its time source (each look at
    the clock costs 1 µs, a sleep jumps): the time it spent spinning after its sleep (s)."""
    vc = VirtualClock()
    woke: list[float] = []

    def now() -> float:
        return vc.advance(1e-6)

    def sleep(d: float) -> None:
        woke.append(vc.advance(d))

    clock._now, clock._sleep = now, sleep  # the clock's time source, virtual
    end = clock.wait_until(deadline)
    assert end >= deadline and len(woke) == 1
    return end - woke[0]


@pytest.mark.parametrize("spin_us", [None, 0, 700, 2500])
def test_loop_spin_us_is_the_measured_spin_window_on_hardware(tmp_path, spin_us):
    r = rig(tmp_path, port="/dev/ttyUSB0", spin_us=spin_us)
    want = DEFAULT_SPIN_S if spin_us is None else spin_us * 1e-6
    assert measured_spin_window(real_clock(r)) == pytest.approx(want, abs=2e-6)


@pytest.mark.parametrize("spin_us", [None, 700])
def test_loop_spin_us_reaches_the_emulators_real_clock(tmp_path, spin_us):
    r = rig(tmp_path, spin_us=spin_us)
    bus = DxlsimUrl.parse(port_for(r, virtual=False)).build_bus()
    assert not bus.clock.virtual
    want = DEFAULT_SPIN_S if spin_us is None else spin_us * 1e-6
    assert measured_spin_window(bus.clock) == pytest.approx(want, abs=2e-6)


def test_the_spin_windows_differ_by_what_the_rig_says(tmp_path):
    """The two measurements are of the rig key, not of a default: 700 µs vs the default."""
    a = measured_spin_window(real_clock(rig(tmp_path, port="/dev/x", spin_us=700)))
    b = measured_spin_window(real_clock(rig(tmp_path, port="/dev/x")))
    assert a - b == pytest.approx(700e-6 - DEFAULT_SPIN_S, abs=3e-6)


def test_port_for_picks_the_emulators_clock(tmp_path):
    r = rig(tmp_path)
    assert DxlsimUrl.parse(port_for(r, virtual=True)).build_bus().clock.virtual
    with pytest.raises(ValueError, match="--virtual-time needs the emulator"):
        port_for(rig(tmp_path, port="/dev/ttyUSB0"), virtual=True)
    assert port_for(rig(tmp_path, port="/dev/ttyUSB0"), virtual=False) == "/dev/ttyUSB0"


def test_parts_carry_the_rigs_joint_map_and_limits(tmp_path):
    r = rig(tmp_path)
    parts = build_parts(r)
    assert parts.joint_map.home.tolist() == [math.radians(30)]
    assert parts.joint_map.direction.tolist() == [-1.0]
    (exp,) = expectations(r)
    lo, hi = exp.position_range_rad
    # joint [-40, 60] deg through home 30, direction -1: servo [-30, 70] deg
    assert math.degrees(lo) == pytest.approx(-30) and math.degrees(hi) == pytest.approx(70)


finite = st.floats(-10.0, 10.0, allow_nan=False)


@given(st.lists(st.tuples(finite, st.sampled_from([1.0, -1.0]), finite), min_size=1, max_size=8))
def test_joint_map_is_bit_for_bit_the_loops_old_formula(rows):
    """cmd·direction + home out, (present − home)·direction back: the operation order the loop
    always used, so the wire sees the same bits."""
    home = np.array([r[0] for r in rows])
    direction = np.array([r[1] for r in rows])
    x = np.array([r[2] for r in rows])
    jm = JointMap(home, direction)
    servo = jm.to_servo(x, np.empty_like(x))
    assert servo.tobytes() == (x * direction + home).tobytes()
    back = jm.to_joint(servo, np.empty_like(x))
    assert back.tobytes() == ((servo - home) * direction).tobytes()
    for i in range(len(rows)):
        assert jm.joint_angle(i, float(servo[i])) == float(back[i])


def test_joint_map_refuses_what_it_cannot_invert():
    with pytest.raises(ValueError, match="direction must be"):
        JointMap([0.0], [2.0])
    with pytest.raises(ValueError, match="one length"):
        JointMap([0.0, 1.0], [1.0])
    with pytest.raises(ValueError, match="finite"):
        JointMap([math.nan], [1.0])
    nan_in = JointMap([0.5], [-1.0]).to_joint(np.array([math.nan]), np.empty(1))
    assert math.isnan(nan_in[0])  # no reading stays no reading
