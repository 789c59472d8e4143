"""A hand on a torque-off emulated servo (drivers.dxlsim.hand), at the register level, and
the per-servo torque switch of the Dynamixel bus that teach-by-hand needs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.dxlsim import VirtualServo
from drivers.dynamixel.bus import DynamixelBus
from drivers.dynamixel.units import CENTER_TICK, TICKS_PER_RAD

PRESENT_VELOCITY, PRESENT_POSITION, GOAL_POSITION, MOVING = 128, 132, 116, 122
TORQUE_ENABLE, HOMING_OFFSET = 64, 20
PULSE_PER_S_PER_UNIT = 0.229 * 4096 / 60  # Present Velocity unit, pulse/s


def reg(s: VirtualServo, addr: int, t: float, size: int = 4) -> int:
    err, data = s.read(addr, size, t)
    assert err == 0
    return int.from_bytes(data, "little", signed=True)


def ramp(t: float) -> float:
    return 2048.0 + 300.0 * t  # pulses, 300 pulse/s


def test_torque_off_present_position_and_velocity_follow_the_hand() -> None:
    s = VirtualServo(id=1)
    s.hand(ramp)
    for t in (0.0, 0.25, 0.5, 1.0, 2.0):
        assert reg(s, PRESENT_POSITION, t) == math.floor(ramp(t) + 0.5)
        assert reg(s, PRESENT_VELOCITY, t) == round(300.0 / PULSE_PER_S_PER_UNIT)
    assert reg(s, MOVING, 2.0, 1) == 1  # the encoder sees the horn turn
    assert reg(s, TORQUE_ENABLE, 2.0, 1) == 0  # the hand switches nothing on


def test_a_sine_by_hand_is_read_to_the_count() -> None:
    s = VirtualServo(id=1)
    amp = 20.0 * 4096 / 360

    def sine(t: float) -> float:
        return 2048.0 + amp * math.sin(math.pi * t)

    s.hand(sine)
    for k in range(401):
        t = k * 0.01
        assert abs(reg(s, PRESENT_POSITION, t) - sine(t)) <= 0.5


def test_multi_turn_by_hand_then_torque_on_folds_into_one_turn() -> None:
    s = VirtualServo(id=1)
    s.hand(lambda t: 2048.0 + 4096.0 * t)  # one turn a second
    assert reg(s, PRESENT_POSITION, 1.5) == 2048 + 6144  # the turns are counted
    assert s.write(TORQUE_ENABLE, b"\x01", 1.5) == 0
    assert reg(s, PRESENT_POSITION, 1.5) == (2048 + 6144) % 4096  # Position mode folds
    assert reg(s, GOAL_POSITION, 1.5) == (2048 + 6144) % 4096  # and holds there


def test_homing_offset_is_part_of_what_the_hand_gives() -> None:
    s = VirtualServo(id=1, homing_offset=100)
    s.hand(lambda t: 3000.0)
    assert reg(s, PRESENT_POSITION, 0.1) == 3000
    assert s.motion.position == pytest.approx(3000.0)


def test_with_torque_on_the_hand_does_nothing() -> None:
    s = VirtualServo(id=1, torque_enable=1)
    held = reg(s, PRESENT_POSITION, 0.0)
    s.hand(ramp)
    for t in (0.1, 0.5, 1.0):
        assert reg(s, PRESENT_POSITION, t) == held
        assert reg(s, PRESENT_VELOCITY, t) == 0
    # torque off: the hand (still on the horn) takes it from where the motor left it
    assert s.write(TORQUE_ENABLE, b"\x00", 1.0) == 0
    assert reg(s, PRESENT_POSITION, 1.2) == math.floor(ramp(1.2) + 0.5)


def test_let_go_the_horn_stays_where_it_was_left() -> None:
    s = VirtualServo(id=1)
    s.hand(lambda t: ramp(t) if t < 1.0 else None)  # the hand lets go at 1 s
    assert reg(s, PRESENT_POSITION, 0.999) == math.floor(ramp(0.999) + 0.5)
    for t in (1.0, 1.5, 3.0):
        assert reg(s, PRESENT_POSITION, t) == math.floor(ramp(0.999) + 0.5)
        assert reg(s, PRESENT_VELOCITY, t) == 0
    s.hand(ramp, t=3.0)  # grabbed again: the horn goes where the hand is
    assert reg(s, PRESENT_POSITION, 3.0) == math.floor(ramp(3.0) + 0.5)
    s.hand(None, t=3.5)  # the hand taken away
    left = reg(s, PRESENT_POSITION, 3.5)
    assert reg(s, PRESENT_POSITION, 5.0) == left
    assert reg(s, PRESENT_VELOCITY, 5.0) == 0


def test_a_goal_written_with_torque_off_is_stored_and_moves_nothing() -> None:
    s = VirtualServo(id=1)
    assert s.write(GOAL_POSITION, (3000).to_bytes(4, "little"), 0.1) == 0
    assert reg(s, GOAL_POSITION, 1.0) == 3000
    assert reg(s, PRESENT_POSITION, 1.0) == 2048
    assert reg(s, MOVING, 1.0, 1) == 0
    assert not s.torque_enabled
    s.hand(ramp, t=1.0)  # and the goal does not fight the hand
    assert s.write(GOAL_POSITION, (1000).to_bytes(4, "little"), 1.5) == 0
    assert reg(s, PRESENT_POSITION, 2.0) == math.floor(ramp(2.0) + 0.5)


def test_a_hand_that_is_not_a_position_is_refused() -> None:
    s = VirtualServo(id=1)
    with pytest.raises(ValueError, match="not a position"):
        s.hand(lambda t: math.nan)
    with pytest.raises(ValueError, match="function of time"):
        s.hand(2048)  # type: ignore[arg-type]


# ------------------------------------------------------------------ through a DynamixelBus
@pytest.fixture
def url_bus():
    bus = DynamixelBus.open(
        "dxlsim://?ids=1-2&rdt_us=0&clock=virtual", baud=1_000_000, ids=[1, 2], read_mode="fast"
    )
    yield bus
    bus.close()


def test_set_torque_on_some_servos_only_and_the_hand_through_the_url_bus(url_bus) -> None:
    bus = url_bus
    dx = bus.link.port.ser.bus  # the emulated bus behind any dxlsim:// port
    bus.set_torque(True)
    bus.set_torque(False, ids=[1])
    assert [s.torque_enabled for s in dx.servos] == [False, True]
    t0 = bus.clock.now()
    dx.servo(1).hand(lambda t: 2048.0 + 1000.0 * (t - t0))
    dx.servo(2).hand(lambda t: 0.0)  # torque on: ignored
    bus.clock.advance(0.5)
    r = bus.read_present()
    assert r.all_ok
    ticks = np.rint(r.positions * TICKS_PER_RAD) + CENTER_TICK
    assert abs(ticks[0] - (2048 + 1000.0 * (r.t - t0))) <= 2  # read just after r.t
    assert ticks[1] == 2048
    bus.set_torque(True, ids=(1,))
    assert [s.torque_enabled for s in dx.servos] == [True, True]


def test_set_torque_refuses_an_unknown_id_and_writes_nothing(url_bus) -> None:
    bus = url_bus
    dx = bus.link.port.ser.bus
    with pytest.raises(ValueError, match=r"\[7\]"):
        bus.set_torque(True, ids=[1, 7])
    assert [s.torque_enabled for s in dx.servos] == [False, False]
    bus.set_torque(True, ids=[])  # nobody: nothing
    assert [s.torque_enabled for s in dx.servos] == [False, False]
