"""Motion features of the emulated servo from the ROBOTIS e-Manual (issue 11, part 2).

Each test names the e-Manual page it follows (ROBOTIS-GIT/emanual, ``_includes/en/dxl/``).
Time is passed explicitly (the servo's own grid): nothing sleeps.
"""

from __future__ import annotations

import math

import pytest

from drivers.dxlsim.models import PULSE_PER_S_PER_VELOCITY_UNIT
from drivers.dxlsim.motion import FOLLOWING_ERROR_PULSES
from drivers.dxlsim.profile import ProfileType, plan_time_profile
from drivers.dxlsim.servo import ALERT, VirtualServo
from drivers.dxlsim.thermal import THERMAL_STALL_RISE_K, THERMAL_TIME_CONSTANT_S
from drivers.protocol2.control_table import HardwareError
from tests.drivers.test_servo import get, put

DT = 0.001  # the servo's control period (motion grid)
OK = 0
TIME_BASED, TORQUE_ON_BY_GOAL = 0x04, 0x08
FOLLOWING = 0x08


def run_until(s: VirtualServo, pred, t: float, limit: float = 10.0) -> float:
    """Step on the grid until ``pred(s)``; the first grid time it held."""
    k = 0
    while not pred(s):
        k += 1
        assert k * DT < limit, "condition never met"
        s.advance(t + k * DT)
    return t + k * DT


def profile_over(s: VirtualServo) -> bool:
    return not get(s, "moving_status") & 0x02


def servo_on(model: str = "XM430-W350", **kw) -> VirtualServo:
    s = VirtualServo(model, 1, t=0.0, **kw)
    assert put(s, "torque_enable", 1, 0.0) == OK
    return s


# --- time-based profile: control_table_drivemode.md (bit 2), control_table_profile_velocity.md
@pytest.mark.parametrize("delta", [1000, 2000, -1500, 3])
def test_time_based_move_takes_profile_velocity_ms_whatever_the_distance(delta):
    """ "If Time-based Profile is selected, Profile Velocity(112) sets the time span for the
    Profile"; Profile Acceleration(108) the accelerating time t1 (profile_velocity page)."""
    s = servo_on(drive_mode=TIME_BASED, profile_velocity=1500, profile_acceleration=300)
    t_goal = 0.0105  # between grid points on purpose
    assert put(s, "goal_position", 2048 + delta, t_goal) == OK
    assert get(s, "moving_status") >> 4 == ProfileType.TRAPEZOIDAL
    t_end = run_until(s, profile_over, t_goal)
    assert abs(t_end - (t_goal + 1.5)) <= DT
    assert get(s, "position_trajectory") == 2048 + delta
    # the horn (8 ms lag) is in position within a few control periods of the profile's end
    t_in = run_until(s, lambda s: get(s, "moving_status") & 0x01, t_end, limit=0.05)
    assert t_in - t_end <= 0.02
    assert not get(s, "moving_status") & FOLLOWING


def test_time_based_velocity_is_distance_over_span_minus_acceleration_time():
    s = servo_on(
        operating_mode=4, drive_mode=TIME_BASED, profile_velocity=1500, profile_acceleration=300
    )
    assert put(s, "goal_position", 2048 + 2400, 0.0) == OK
    s.advance(0.15)  # half way through t1: half the cruise velocity
    assert get(s, "velocity_trajectory") == round(1000 / PULSE_PER_S_PER_VELOCITY_UNIT)
    s.advance(0.75)  # mid cruise: 2400 pulses / (1.5 - 0.3) s = 2000 pulse/s
    assert get(s, "velocity_trajectory") == round(2000 / PULSE_PER_S_PER_VELOCITY_UNIT)


def test_time_based_acceleration_over_half_the_span_is_a_triangle():
    """ "Profile Acceleration(108) will not exceed 50% of Profile Velocity(112)": PA 1000
    with PV 1500 accelerates for 750 ms and decelerates for 750 ms (a triangle, Moving
    Status 0x20); the register keeps what was written."""
    s = servo_on(drive_mode=TIME_BASED, profile_velocity=1500, profile_acceleration=1000)
    assert put(s, "goal_position", 2048 + 1500, 0.0) == OK
    assert get(s, "moving_status") >> 4 == ProfileType.TRIANGULAR
    assert get(s, "profile_acceleration") == 1000
    s.advance(0.75)  # peak: 2·1500/1.5 = 2000 pulse/s
    assert get(s, "velocity_trajectory") == round(2000 / PULSE_PER_S_PER_VELOCITY_UNIT)
    assert abs(run_until(s, profile_over, 0.75) - 1.5) <= DT


def test_time_based_without_acceleration_is_rectangular_and_zero_span_is_a_step():
    """Profile table (profile_velocity page): A = 0 rectangular; Profile Velocity 0 "stands
    for an infinite velocity" (Step, Moving Status 0x00)."""
    s = servo_on(drive_mode=TIME_BASED, profile_velocity=1000)
    assert put(s, "goal_position", 2048 + 500, 0.0) == OK
    assert get(s, "moving_status") >> 4 == ProfileType.RECTANGULAR
    s.advance(0.4)
    assert get(s, "velocity_trajectory") == round(500 / PULSE_PER_S_PER_VELOCITY_UNIT)
    assert abs(run_until(s, profile_over, 0.4) - 1.0) <= DT
    assert put(s, "profile_velocity", 0) == OK
    assert put(s, "goal_position", 2048) == OK
    assert get(s, "moving_status") >> 4 == ProfileType.STEP


def test_time_based_new_goal_mid_move_keeps_velocity_continuous_and_the_span():
    """Velocity Override (profile_velocity page) with a time-based profile."""
    s = servo_on(drive_mode=TIME_BASED, profile_velocity=1000, profile_acceleration=200)
    assert put(s, "goal_position", 2048 + 1000, 0.0) == OK
    s.advance(0.5)
    before = s.motion.trajectory_velocity
    assert put(s, "goal_position", 2048 - 500, 0.5) == OK
    s.advance(0.5 + DT)
    assert before == pytest.approx(1000 / 0.8)
    assert abs(s.motion.trajectory_velocity - before) < 20  # one period at -13 281 pulse/s²
    assert abs(run_until(s, profile_over, 0.501) - 1.5) <= DT
    assert get(s, "position_trajectory") == 2048 - 500


def test_time_based_velocity_mode_ramp_takes_profile_acceleration_ms():
    """Velocity Control Mode, "Time-based Profile: t1 = Profile Acceleration(108)"."""
    s = servo_on(operating_mode=1, drive_mode=TIME_BASED)
    assert put(s, "profile_acceleration", 500) == OK
    for goal in (100, 40):
        t0 = s.now
        assert put(s, "goal_velocity", goal, t0) == OK
        s.advance(t0 + 0.5)
        assert get(s, "velocity_trajectory") == goal
    assert put(s, "goal_velocity", 0, s.now) == OK  # 40 -> 0 takes 500 ms too
    s.advance(s.now + 0.25)
    assert get(s, "velocity_trajectory") == 20


def test_plan_time_profile_ends_at_the_goal_at_the_span():
    for v0 in (0.0, 800.0, -800.0):
        segs, _ = plan_time_profile(1.0, 100.0, v0, 900.0, 1.2, 0.3)
        ts, te, p, v, a = segs[-1]
        assert te == pytest.approx(2.2)
        assert p + (v + 0.5 * a * (te - ts)) * (te - ts) == pytest.approx(900.0)
        assert v + a * (te - ts) == pytest.approx(0.0, abs=1e-9)
        assert segs[0][3] == v0  # starts at the present velocity


# --- Drive Mode bit 3, Torque On by Goal Update: control_table_drivemode.md (fw 45, XL330 46)
def test_goal_write_with_torque_off_turns_torque_on_and_moves():
    """ "If the value of Torque Enable(64) is '0' and the command is given, the Torque
    Enable(64) switches to '1' and perform the command.\""""
    s = VirtualServo("XM430-W350", 1, t=0.0, drive_mode=TORQUE_ON_BY_GOAL)
    assert get(s, "torque_enable") == 0
    assert put(s, "goal_position", 3000, 0.01) == OK
    assert get(s, "torque_enable") == 1
    assert get(s, "goal_position") == 3000
    run_until(s, lambda s: get(s, "present_position") == 3000, 0.01, limit=2.0)


def test_without_bit_3_a_goal_with_torque_off_is_only_stored():
    """Bit 3 = 0: "Performing a given command only if the value of Torque Enable(64) is 1"."""
    s = VirtualServo("XM430-W350", 1, t=0.0)
    assert put(s, "goal_position", 3000, 0.0) == OK
    s.advance(1.0)
    assert get(s, "torque_enable") == 0 and get(s, "present_position") == 2048


def test_only_the_goal_of_the_operating_mode_turns_torque_on():
    """The manual's "given command" is read as the goal the Operating Mode executes."""
    s = VirtualServo("XM430-W350", 1, t=0.0, drive_mode=TORQUE_ON_BY_GOAL, operating_mode=1)
    assert put(s, "goal_position", 3000, 0.0) == OK
    assert get(s, "torque_enable") == 0
    assert put(s, "goal_velocity", 50, 0.0) == OK
    assert get(s, "torque_enable") == 1
    s.advance(0.5)
    assert get(s, "present_velocity") == 50


def test_torque_on_by_goal_not_with_a_shutdown_error_latched():
    """Torque Enable is refused while a Shutdown error is latched (shutdown page): so is the
    torque-on of bit 3; the goal is stored."""
    s = VirtualServo("XM430-W350", 1, t=0.0, drive_mode=TORQUE_ON_BY_GOAL)
    s.inject_hardware_error(int(HardwareError.OVERHEATING), 0.0)
    assert put(s, "goal_position", 3000, 0.0) == ALERT
    assert get(s, "torque_enable") == 0


# --- Following Error: control_table_moving_status.md bit 3 --------------------------------
def test_profile_faster_than_the_motor_sets_following_error():
    """ "Dynamixel fails to reach desired position trajectory": Profile Velocity 600
    (137 rpm) on a 46 rpm motor."""
    s = VirtualServo("XM430-W350", 1, t=0.0, velocity_limit=1023)
    assert put(s, "torque_enable", 1, 0.0) == OK
    assert put(s, "profile_velocity", 600, 0.0) == OK
    assert put(s, "goal_position", 2048 + 2000, 0.0) == OK
    t_set = run_until(s, lambda s: get(s, "moving_status") & FOLLOWING, 0.0, limit=0.5)
    lag = s.motion.trajectory_position - s.motion.position
    assert lag > FOLLOWING_ERROR_PULSES
    # cleared once the horn has caught up with the finished trajectory
    run_until(s, lambda s: not get(s, "moving_status") & FOLLOWING, t_set, limit=2.0)
    assert abs(get(s, "present_position") - (2048 + 2000)) <= FOLLOWING_ERROR_PULSES


def test_time_based_profile_too_short_for_the_distance_sets_following_error():
    s = servo_on(drive_mode=TIME_BASED, profile_velocity=200, profile_acceleration=50)
    assert put(s, "goal_position", 2048 + 2000, 0.0) == OK  # 13 300 pulse/s wanted
    run_until(s, lambda s: get(s, "moving_status") & FOLLOWING, 0.0, limit=0.2)


def test_a_load_slows_the_horn_into_following_error():
    """The motor's speed falls with load (speed-torque line): a profile it follows unloaded
    (200 units = 45.8 rpm on a 46 rpm motor) lags with 60 % of the stall torque on it."""
    free = servo_on(operating_mode=4, profile_velocity=200)
    loaded = servo_on(operating_mode=4, profile_velocity=200)
    loaded.set_load(0.6 * loaded.model.stall_torque_nm, 0.0)
    for s in (free, loaded):
        assert put(s, "goal_position", 2048 + 3000, 0.0) == OK
    worst = 0
    for k in range(1, 1000):
        free.advance(k * DT)
        worst |= get(free, "moving_status") & FOLLOWING
    assert not worst
    run_until(loaded, lambda s: get(s, "moving_status") & FOLLOWING, 0.0, limit=1.0)


def test_following_error_is_never_set_by_a_followable_profile_or_a_step():
    s = servo_on(profile_velocity=100, profile_acceleration=20)
    assert put(s, "goal_position", 2048 + 1500, 0.0) == OK
    step = servo_on()
    assert put(step, "goal_position", 2048 + 1500, 0.0) == OK
    for k in range(1, 2500):
        for x in (s, step):
            x.advance(k * DT)
            assert not get(x, "moving_status") & FOLLOWING


# --- Homing Offset: control_table_homingoffset.md ------------------------------------------
@pytest.mark.parametrize(
    ("mode", "offset", "present"),
    [(3, 2000, 2048), (3, -1025, 2048), (3, 1024, 3072), (3, -1024, 1024), (4, 2000, 4048)],
)
def test_homing_offset_outside_1024_is_ignored_in_position_control_mode(mode, offset, present):
    """ "In case of the Position Control Mode (Joint Mode) that rotates less than 360
    degrees, any invalid Homing Offset(20) values will be ignored (valid range: -1,024 ~
    1,024)"; other modes apply it (Present Position = Actual Position + Homing Offset)."""
    s = VirtualServo("XM430-W350", 1, t=0.0, operating_mode=mode)
    assert put(s, "homing_offset", offset, 0.0) == OK
    assert get(s, "homing_offset") == offset  # stored, only its effect is ignored
    assert get(s, "present_position") == present
    assert put(s, "torque_enable", 1) == OK
    target = 2500 if mode == 3 and abs(offset) > 1024 else present + 300
    assert put(s, "goal_position", target) == OK
    run_until(s, lambda s: get(s, "present_position") == target, 0.0, limit=2.0)


# --- temperature: control_table_alarm_shutdown.md (Overheating), Temperature Limit(31) -----
def test_idle_or_moving_servo_stays_near_ambient_for_an_hour():
    s = servo_on(profile_velocity=150, profile_acceleration=30)
    assert get(s, "present_temperature") == 30
    t = 0.0
    for k in range(1200):  # 1200 moves of 3 s each, back and forth: an hour
        assert put(s, "goal_position", 2048 + (1500 if k % 2 == 0 else -1500), t) == OK
        for j in range(1, 31):
            s.advance(t + 0.1 * j)
        t += 3.0
    assert get(s, "present_temperature") <= 31
    assert get(s, "hardware_error_status") == 0


def test_held_stall_heats_the_motor_to_an_overheating_shutdown():
    """A horn held at its stall torque draws the stall current; the first-order thermal
    model (estimates) trips Temperature Limit 80 °C after τ·ln(100/49.5) s; Overheating is
    in the default Shutdown, so torque is cut and the motor cools again."""
    s = servo_on()
    s.set_load(s.model.stall_torque_nm, 0.0)
    limit = get(s, "temperature_limit")
    expected = -THERMAL_TIME_CONSTANT_S * math.log(1 - (limit + 0.5 - 30) / THERMAL_STALL_RISE_K)
    t = 0.0
    while not get(s, "hardware_error_status"):
        t += 0.01
        assert t < 1000.0
        s.advance(t)
    assert abs(t - expected) <= 0.01
    assert get(s, "hardware_error_status") == HardwareError.OVERHEATING
    assert get(s, "torque_enable") == 0
    assert get(s, "present_temperature") == limit + 1
    s.advance(t + 600.0)
    assert get(s, "present_temperature") < 40  # no current: back towards ambient


def test_thermal_model_does_not_depend_on_how_time_is_stepped():
    a, b = servo_on(), servo_on()
    for s in (a, b):
        s.set_load(0.5 * s.model.stall_torque_nm, 0.0)
    a.advance(100.0)
    for k in range(1, 1001):
        b.advance(0.1 * k)
    rise = THERMAL_STALL_RISE_K * 0.25 * (1.0 - math.exp(-100.0 / THERMAL_TIME_CONSTANT_S))
    assert get(a, "present_temperature") == get(b, "present_temperature") == round(30 + rise)


def test_a_move_and_a_long_silence_after_it_heat_as_the_move_does():
    """The last packet while the horn speeds up (stall current) and none for ten minutes (an
    idle `hilsim emulate`): heated at each stretch's current, not the first one's for the
    whole gap (it read 116 °C and latched Overheating; 48 °C after a minute)."""
    stepped, silent = servo_on(), servo_on()
    for s in (stepped, silent):
        assert put(s, "goal_position", 2200, 0.0) == OK
        s.advance(0.001)
    assert abs(silent._mo.current_a()) == silent.model.stall_current_a  # speeding up
    for k in range(1, 101):  # a packet every 10 ms for the first second, then silence
        stepped.advance(0.001 + 0.01 * k)
    stepped.advance(600.001)
    silent.advance(600.001)
    for s in (stepped, silent):
        assert get(s, "present_position") == 2200
        assert get(s, "present_temperature") == 30 and get(s, "hardware_error_status") == 0
    assert abs(silent._temp_c - stepped._temp_c) < 0.01  # (a 1 s stretch would be 0.2 °C)
