"""The virtual servo: control table semantics, instruction errors, faults and motion.

Time is passed explicitly; nothing sleeps.
"""

from __future__ import annotations

import math
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.dxlsim.models import (
    PULSE_PER_S2_PER_ACCEL_UNIT,
    PULSE_PER_S_PER_VELOCITY_UNIT,
)
from drivers.dxlsim.profile import ProfileType, plan_profile
from drivers.dxlsim.servo import (
    ALERT,
    CLEAR_MULTI_TURN,
    StatusError,
    VirtualServo,
)
from drivers.protocol2.control_table import HardwareError

DT = 0.001
OK = 0
RANGE, LENGTH, LIMIT, ACCESS, FAIL = (
    StatusError.DATA_RANGE,
    StatusError.DATA_LENGTH,
    StatusError.DATA_LIMIT,
    StatusError.ACCESS,
    StatusError.RESULT_FAIL,
)


def le(value: int, size: int) -> bytes:
    return (value & (1 << 8 * size) - 1).to_bytes(size, "little")


def get(s: VirtualServo, name: str, t: float | None = None) -> int:
    """Read one field by name, decoded (signed where the field is)."""
    f = s.model.field(name)
    err, data = s.read(f.addr, f.size, s.now if t is None else t)
    assert err & 0x7F == 0, (name, err)
    return int.from_bytes(data, "little", signed=f.signed)


def put(s: VirtualServo, name: str, value: int, t: float | None = None) -> int:
    f = s.model.field(name)
    return s.write(f.addr, le(value, f.size), s.now if t is None else t)


def run_until(s: VirtualServo, pred, t: float, limit: float = 10.0, dt: float = DT) -> float:
    """Step the servo on its grid until ``pred(s)``; returns the time it first held."""
    k = 0
    while not pred(s):
        k += 1
        t_k = t + k * dt
        assert k * dt < limit, "condition never met"
        s.advance(t_k)
    return t + k * dt


@pytest.fixture
def servo():
    return VirtualServo("XM430-W350", 1, t=0.0)


@pytest.fixture
def on(servo):
    assert put(servo, "torque_enable", 1, 0.0) == OK
    return servo


# --- construction and identity -------------------------------------------------------------
def test_ping_returns_model_number_and_firmware():
    s = VirtualServo("XL330-M288", 7, firmware=44)
    assert s.ping(0.0) == (OK, b"\xb0\x04\x2c")  # 1200 LE, firmware 44
    assert not s.supports_fast_read
    assert VirtualServo("XM430-W350").supports_fast_read


def test_constructor_maps_baud_delay_and_overrides():
    s = VirtualServo("XM430-W350", 5, baud=1_000_000, return_delay_us=0, velocity_limit=300)
    assert (s.id, s.baud, s.return_delay_s) == (5, 1_000_000, 0.0)
    assert get(s, "baud_rate") == 3 and get(s, "velocity_limit") == 300
    assert VirtualServo(return_delay_us=500.0).return_delay_s == pytest.approx(500e-6)
    assert get(VirtualServo("XL330-M288"), "present_input_voltage") == 50
    assert get(VirtualServo("XM430-W350"), "present_input_voltage") == 120


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"model": "XL330-M288", "baud": 4_500_000}, "bps"),
        ({"baud": 12345}, "bps"),
        ({"return_delay_us": 3}, "multiple of 2"),
        ({"return_delay_us": 510}, "multiple of 2"),
        ({"no_such_field": 1}, "no control-table field 'no_such_field'$"),
        ({"moving": 1}, "read-only"),
        ({"led": 2}, "outside"),
        ({"operating_mode": 2}, "outside"),
        ({"goal_position": 5000}, "DATA_LIMIT"),
        ({"baud_rate": 3}, "baud="),
        ({"step_s": 0.0}, "step_s"),
    ],
)
def test_constructor_rejects_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        VirtualServo(**kwargs)


def test_constructor_can_start_with_torque_on_at_a_pose():
    s = VirtualServo(torque_enable=1, present_position=1000, profile_velocity=50)
    assert s.torque_enabled and get(s, "present_position") == 1000
    assert get(s, "goal_position") == 1000  # holds where it is
    s.advance(1.0)
    assert get(s, "present_position") == 1000


def test_eeprom_overrides_survive_reboot_ram_ones_do_not():
    s = VirtualServo(velocity_limit=100, led=1)
    assert s.reboot(0.1) == OK
    assert get(s, "velocity_limit") == 100 and get(s, "led") == 0


# --- reads ---------------------------------------------------------------------------------
def test_read_single_fields_of_each_size(servo):
    assert servo.read(7, 1, 0.0) == (OK, b"\x01")
    assert servo.read(0, 2, 0.0) == (OK, le(1020, 2))
    assert servo.read(132, 4, 0.0) == (OK, le(2048, 4))
    assert servo.read(31, 1, 0.0) == (OK, b"\x50")


def test_multi_field_read_matches_single_reads(on):
    put(on, "goal_position", 3000, 0.0)
    t = 0.05
    err, block = on.read(120, 27, t)
    assert err == OK and len(block) == 27
    for addr, size in (
        (120, 2),
        (122, 1),
        (123, 1),
        (124, 2),
        (126, 2),
        (128, 4),
        (132, 4),
        (136, 4),
        (140, 4),
        (144, 2),
        (146, 1),
    ):
        assert block[addr - 120 : addr - 120 + size] == on.read(addr, size, t)[1], addr


def test_read_gaps_as_zero_and_slices_partial_fields(servo):
    err, data = servo.read(12, 12, 0.0)  # 12, 13, then the 14..19 gap, then homing offset
    assert err == OK and data == b"\xff\x02" + bytes(6) + bytes(4)
    assert servo.read(133, 2, 0.0) == (OK, b"\x08\x00")  # middle bytes of 2048
    assert servo.read(14, 1, 0.0) == (OK, b"\x00")


@pytest.mark.parametrize(
    ("addr", "length", "code"),
    # past Indirect Data 56 (661), the last field since the indirect blocks (issue 11)
    [(661, 2, ACCESS), (662, 1, ACCESS), (700, 4, ACCESS), (-1, 2, ACCESS), (64, 0, LENGTH)],
)
def test_read_errors_return_no_data(servo, addr, length, code):
    assert servo.read(addr, length, 0.0) == (code, b"")


# --- writes --------------------------------------------------------------------------------
def test_write_fields_of_each_size(servo):
    assert put(servo, "led", 1) == OK and get(servo, "led") == 1
    assert put(servo, "position_p_gain", 1234) == OK and get(servo, "position_p_gain") == 1234
    assert put(servo, "homing_offset", -1000) == OK and get(servo, "homing_offset") == -1000
    assert get(servo, "present_position") == 1048  # actual 2048 + offset


def test_multi_field_write_sets_profile_acceleration_and_velocity(servo):
    assert servo.write(108, le(20, 4) + le(150, 4), 0.0) == OK
    assert (get(servo, "profile_acceleration"), get(servo, "profile_velocity")) == (20, 150)


@pytest.mark.parametrize(
    ("addr", "data", "code"),
    [
        (70, b"\x01", ACCESS),  # read-only
        (132, le(0, 4), ACCESS),  # read-only
        (14, b"\x00", ACCESS),  # undefined address
        (146, b"\x00\x00", ACCESS),  # past the table end
        (65, b"\x00\x00", ACCESS),  # LED, then undefined 66
        (116, le(0, 2), LENGTH),  # half of Goal Position
        (117, le(0, 3), LENGTH),  # starts inside a field
        (64, b"", LENGTH),
        (65, b"\x02", RANGE),  # LED is 0..1
        (98, b"\xff", RANGE),  # -1 is the tripped state, not a value to write
        (11, b"\x02", RANGE),  # not an operating mode
        (116, le(2_000_000, 4), RANGE),  # beyond ±1,048,575
        (116, le(4096, 4), LIMIT),  # outside Max Position Limit in mode 3
        (104, le(201, 4), LIMIT),  # above Velocity Limit (200)
        (104, le(-201, 4), LIMIT),
        (102, le(1194, 2), RANGE),  # beyond the field's own range
        (36, le(886, 2), RANGE),
    ],
)
def test_write_error_codes(servo, addr, data, code):
    before = servo.read(0, 147, 0.0)[1]
    assert servo.write(addr, data, 0.0) == code
    assert servo.read(0, 147, 0.0)[1] == before  # nothing written


def test_goal_limits_follow_the_limit_registers(servo):
    assert put(servo, "current_limit", 500) == OK
    assert put(servo, "pwm_limit", 300) == OK
    assert put(servo, "goal_current", 501) == LIMIT
    assert put(servo, "goal_current", -500) == OK
    assert put(servo, "goal_pwm", 301) == LIMIT
    assert put(servo, "goal_pwm", 300) == OK
    assert put(servo, "max_position_limit", 3000) == OK
    assert put(servo, "goal_position", 3001) == LIMIT
    assert put(servo, "operating_mode", 4) == OK  # extended: limits not used
    assert put(servo, "goal_position", -100_000) == OK


def test_write_is_atomic_across_fields(servo):
    # 108..119: profile acceleration, velocity, then a goal beyond the position limit
    assert servo.write(108, le(10, 4) + le(50, 4) + le(5000, 4), 0.0) == LIMIT
    assert get(servo, "profile_acceleration") == 0 and get(servo, "profile_velocity") == 0
    # 64..65 spans torque and LED; 65 out of range spoils the torque write too
    assert servo.write(64, b"\x01\x05", 0.0) == RANGE
    assert not servo.torque_enabled


def test_eeprom_is_locked_while_torque_is_on(on):
    assert put(on, "velocity_limit", 100) == ACCESS
    assert put(on, "id", 9) == ACCESS
    assert put(on, "torque_enable", 0) == OK
    assert put(on, "velocity_limit", 100) == OK
    assert put(on, "id", 9) == OK and on.id == 9


def test_operating_mode_change_resets_the_profile(servo):
    servo.write(108, le(10, 4) + le(50, 4), 0.0)
    assert put(servo, "operating_mode", 1) == OK
    assert get(servo, "profile_acceleration") == 0 and get(servo, "profile_velocity") == 0


def test_id_baud_and_return_delay_properties_follow_writes(servo):
    assert put(servo, "baud_rate", 4) == OK and servo.baud == 2_000_000
    assert put(servo, "return_delay_time", 10) == OK and servo.return_delay_s == pytest.approx(
        20e-6
    )
    assert put(servo, "status_return_level", 1) == OK and servo.status_return_level == 1
    assert put(servo, "secondary_id", 20) == OK and servo.secondary_id == 20
    assert put(servo, "baud_rate", 8) == RANGE


def test_xl430_has_no_current_registers():
    s = VirtualServo("XL430-W250")
    assert s.write(102, le(0, 2), 0.0) == ACCESS
    assert s.write(38, le(0, 2), 0.0) == ACCESS
    assert s.model.field(126).name == "present_load"
    assert put(s, "operating_mode", 0) == RANGE  # no current mode


# --- torque, hold and alert ----------------------------------------------------------------
def test_torque_on_holds_present_position_and_copies_it_to_goal(servo):
    put(servo, "goal_position", 100, 0.0)  # stored while torque is off...
    assert put(servo, "torque_enable", 1, 0.1) == OK
    assert get(servo, "goal_position") == 2048  # ...but torque-on holds where it is
    servo.advance(2.0)
    assert get(servo, "present_position") == 2048


def test_torque_on_in_position_mode_folds_present_position_into_one_turn():
    s = VirtualServo(operating_mode=4, present_position=10_000)
    assert get(s, "present_position") == 10_000
    assert put(s, "torque_enable", 1) == OK
    assert get(s, "present_position") == 10_000  # extended mode keeps turns
    s = VirtualServo(present_position=10_000)
    assert put(s, "torque_enable", 1) == OK
    assert get(s, "present_position") == 10_000 % 4096


def test_hardware_error_sets_alert_in_every_error_byte_and_cuts_torque(on):
    on.inject_hardware_error(HardwareError.OVERLOAD, 0.1)
    assert on.alert and not on.torque_enabled
    assert on.ping(0.2)[0] == ALERT
    assert on.read(132, 4, 0.2)[0] == ALERT
    assert on.read(700, 4, 0.2) == (ALERT | ACCESS, b"")
    assert put(on, "led", 1, 0.2) == ALERT
    assert put(on, "torque_enable", 1, 0.2) == ALERT | FAIL  # refused until reboot
    assert get(on, "torque_enable") == 0 and get(on, "hardware_error_status") == 0x20
    assert on.reboot(0.3) == ALERT  # the reply left before the reboot
    assert not on.alert and put(on, "torque_enable", 1, 0.4) == OK


def test_error_outside_the_shutdown_mask_keeps_torque(on):
    on.set_input_voltage(8.0)  # below Min Voltage Limit 9.5 V; bit 0 is not in Shutdown 52
    assert on.hardware_error_status == HardwareError.INPUT_VOLTAGE
    assert on.torque_enabled and on.ping(0.1)[0] == ALERT
    assert get(on, "present_input_voltage") == 80


def test_overheating_cuts_torque(on):
    on.set_temperature(85.0, t=0.2)
    assert on.hardware_error_status == HardwareError.OVERHEATING and not on.torque_enabled
    assert get(on, "present_temperature") == 85


def test_cut_torque_is_silent(on):
    on.cut_torque(0.5)
    assert get(on, "torque_enable") == 0 and not on.alert


# --- reg write / action, reboot, factory reset, clear -------------------------------------------
def test_reg_write_waits_for_action(servo):
    assert servo.reg_write(65, b"\x01", 0.0) == OK
    assert get(servo, "registered_instruction") == 1 and get(servo, "led") == 0
    assert servo.action(0.1) == OK
    assert get(servo, "registered_instruction") == 0 and get(servo, "led") == 1
    assert servo.action(0.2) == StatusError.INSTRUCTION  # nothing pending (protocol2.md)


def test_reg_write_validates_and_action_revalidates(servo):
    assert servo.reg_write(65, b"\x02", 0.0) == RANGE
    assert get(servo, "registered_instruction") == 0
    assert servo.reg_write(44, le(100, 4), 0.0) == OK  # EEPROM, torque off: fine now
    put(servo, "torque_enable", 1, 0.1)
    assert servo.action(0.2) == ACCESS  # ...but locked by Action time
    assert get(servo, "velocity_limit") == 200 and get(servo, "registered_instruction") == 0


def test_reboot_resets_ram_keeps_eeprom_and_the_horn(on):
    put(on, "goal_position", 3000, 0.0)
    put(on, "led", 1, 0.0)
    on.advance(0.5)
    pos = get(on, "present_position")
    assert on.reboot(0.5) == OK
    assert not on.torque_enabled and get(on, "led") == 0
    assert get(on, "present_position") == pos  # within one turn already: no teleport
    assert get(on, "goal_position") == pos
    assert get(on, "realtime_tick", 0.5) == 0 and get(on, "realtime_tick", 0.6) == 100


def test_brownout_resets_ram_like_a_reboot(on):
    put(on, "bus_watchdog", 10, 0.0)
    on.brownout(0.1)
    assert not on.torque_enabled and get(on, "bus_watchdog") == 0


@pytest.mark.parametrize(
    ("option", "id_", "baud"),
    [(0xFF, 1, 57_600), (0x01, 9, 57_600), (0x02, 9, 1_000_000)],
)
def test_factory_reset_options(option, id_, baud):
    s = VirtualServo(id=9, baud=1_000_000, velocity_limit=50, led=1)
    assert s.factory_reset(option, 0.1) == OK
    assert (s.id, s.baud) == (id_, baud)
    assert get(s, "velocity_limit") == 200 and get(s, "led") == 0


def test_factory_reset_refuses_bad_options_and_torque_on(on):
    assert on.factory_reset(0x03, 0.0) == RANGE
    assert on.factory_reset(0xFF, 0.0) == ACCESS


def test_clear_multi_turn():
    s = VirtualServo(operating_mode=4, torque_enable=1, profile_velocity=200)
    put(s, "goal_position", 10_000, 0.0)
    assert s.clear(CLEAR_MULTI_TURN, 0.1) == FAIL  # still moving
    s.advance(5.0)
    assert get(s, "present_position") == 10_000
    assert s.clear(b"\x01\x44\x58\x4c", 5.0) == LENGTH
    assert s.clear(b"\x02\x44\x58\x4c\x22", 5.0) == RANGE
    assert s.clear(CLEAR_MULTI_TURN, 5.0) == OK
    assert get(s, "present_position") == 10_000 % 4096 == get(s, "goal_position")
    s.advance(6.0)
    assert get(s, "present_position") == 10_000 % 4096  # it holds, does not unwind


# --- bus watchdog --------------------------------------------------------------------------
def test_watchdog_trips_after_its_period_and_locks_goals_until_cleared(on):
    assert put(on, "bus_watchdog", 5, 0.0) == OK  # 100 ms
    assert put(on, "profile_velocity", 100, 0.0) == OK
    assert put(on, "goal_position", 4000, 0.0) == OK
    on.touch(0.09)
    on.advance(0.189)
    assert get(on, "bus_watchdog") == 5  # 99 ms since the last packet
    on.advance(0.191)
    assert get(on, "bus_watchdog") == -1
    assert on.read(98, 1, 0.2) == (OK, b"\xff")
    stopped = get(on, "present_position", 0.5)
    assert stopped < 4000 and get(on, "present_position", 1.0) == stopped
    for name, value in (
        ("goal_position", 100),
        ("goal_velocity", 0),
        ("goal_pwm", 0),
        ("goal_current", 0),
    ):
        assert put(on, name, value, 1.0) == RANGE, name
    assert put(on, "bus_watchdog", 3, 1.0) == RANGE
    assert put(on, "bus_watchdog", 0, 1.0) == OK
    assert put(on, "goal_position", 100, 1.0) == OK


def test_watchdog_is_armed_only_with_torque_on(servo):
    put(servo, "bus_watchdog", 1, 0.0)
    servo.advance(10.0)
    assert get(servo, "bus_watchdog") == 1
    put(servo, "torque_enable", 1, 10.0)
    servo.advance(10.019)
    assert get(servo, "bus_watchdog") == 1
    servo.advance(10.021)
    assert get(servo, "bus_watchdog") == -1 and servo.torque_enabled


def test_trip_watchdog_fault(on):
    on.trip_watchdog(0.5)
    assert get(on, "bus_watchdog") == -1 and put(on, "goal_position", 0) == RANGE


# --- realtime tick and idle cost ---------------------------------------------------------------
def test_realtime_tick_counts_ms_and_wraps():
    s = VirtualServo(t=0.0)
    assert get(s, "realtime_tick", 0.0125) == 12
    assert get(s, "realtime_tick", 32.767) == 32767
    assert get(s, "realtime_tick", 32.768) == 0
    assert get(s, "realtime_tick", 40.0) == (40_000 % 32_768)


def test_long_idle_advance_is_cheap_and_correct(on):
    start = time.perf_counter()
    on.advance(1e6)
    assert time.perf_counter() - start < 0.01
    assert get(on, "present_position") == 2048 and get(on, "moving") == 0
    assert get(on, "realtime_tick") == 1_000_000_000 % 32_768


def test_time_cannot_go_back(servo):
    servo.advance(1.0)
    with pytest.raises(ValueError, match="back"):
        servo.advance(0.5)


# --- motion --------------------------------------------------------------------------------
def profile_end(s: VirtualServo, t: float) -> float:
    """First grid time at which Moving Status says the profile is over."""
    return run_until(s, lambda s: not get(s, "moving_status") & 0x02, t)


@pytest.mark.parametrize(
    ("v_units", "a_units", "delta", "kind"),
    [
        (100, 20, 1500, ProfileType.TRAPEZOIDAL),
        (200, 5, 900, ProfileType.TRIANGULAR),
        (50, 50, -2000, ProfileType.TRAPEZOIDAL),
        (150, 10, -300, ProfileType.TRIANGULAR),
    ],
)
def test_trapezoid_and_triangle_durations_match_the_formulas(on, v_units, a_units, delta, kind):
    on.write(108, le(a_units, 4) + le(v_units, 4), 0.0)
    t_goal = 0.0105  # between grid points on purpose
    assert put(on, "goal_position", 2048 + delta, t_goal) == OK
    v = v_units * PULSE_PER_S_PER_VELOCITY_UNIT
    a = a_units * PULSE_PER_S2_PER_ACCEL_UNIT
    d = abs(delta)
    expected = d / v + v / a if d >= v * v / a else 2.0 * math.sqrt(d / a)
    assert get(on, "moving_status") >> 4 == kind
    t_end = profile_end(on, t_goal)
    assert abs(t_end - (t_goal + expected)) <= DT
    assert get(on, "position_trajectory") == 2048 + delta
    run_until(on, lambda s: get(s, "present_position") == 2048 + delta, t_end, limit=1.0)


def test_constant_velocity_profile(on):
    assert put(on, "profile_velocity", 100, 0.0) == OK  # acceleration 0: rectangular
    assert put(on, "goal_position", 3048, 0.0) == OK
    assert get(on, "moving_status") >> 4 == ProfileType.RECTANGULAR
    on.advance(0.3)
    assert get(on, "velocity_trajectory") == 100
    assert abs(on.motion.velocity - 100 * PULSE_PER_S_PER_VELOCITY_UNIT) < 1.0  # lag settled
    t_end = profile_end(on, 0.3)
    assert abs(t_end - 1000 / (100 * PULSE_PER_S_PER_VELOCITY_UNIT)) <= DT


def test_step_move_is_limited_by_motor_speed_and_lags(on):
    vmax = 46.0 * 4096 / 60  # XM430-W350 no-load speed at 12 V, pulse/s
    assert put(on, "goal_position", 4000, 0.0) == OK  # profile velocity 0: a step
    assert get(on, "position_trajectory", 0.001) == 4000
    assert get(on, "moving_status") >> 4 == ProfileType.STEP
    on.advance(0.2)
    assert on.motion.velocity == pytest.approx(vmax)
    assert get(on, "present_velocity") == round(vmax / PULSE_PER_S_PER_VELOCITY_UNIT)
    t_done = run_until(on, lambda s: get(s, "present_position") == 4000, 0.2)
    assert t_done >= 1952 / vmax
    assert t_done <= 1952 / vmax + 0.1  # a few lag time constants more
    assert get(on, "moving_status") & 0x01  # in position


def test_present_position_lags_the_trajectory_by_a_few_ms(on):
    on.write(108, le(0, 4) + le(100, 4), 0.0)
    put(on, "goal_position", 4000, 0.0)
    on.advance(0.5)
    m = on.motion
    lag_s = (m.trajectory_position - m.position) / m.trajectory_velocity
    assert 0.003 < lag_s < 0.012


def test_regoal_mid_move_keeps_trajectory_velocity_continuous(on):
    on.write(108, le(30, 4) + le(150, 4), 0.0)
    put(on, "goal_position", 4000, 0.0)
    a = 30 * PULSE_PER_S2_PER_ACCEL_UNIT
    prev = on.motion.trajectory_velocity
    goals = {0.4: 500, 0.9: 3500, 1.1: 3400, 1.5: 2048}
    for k in range(1, 4000):
        t = k * DT
        goal = goals.get(round(t, 3))
        if goal is not None:
            assert put(on, "goal_position", goal, t) == OK
        on.advance(t)
        v = on.motion.trajectory_velocity
        assert abs(v - prev) <= a * DT * (1 + 1e-9) + 1e-9, t
        prev = v
    assert get(on, "present_position") == 2048


def test_velocity_mode_ramps_and_holds_speed():
    s = VirtualServo(operating_mode=1, torque_enable=1)
    put(s, "profile_acceleration", 10, 0.0)
    assert put(s, "goal_velocity", 100, 0.0) == OK
    t_ramp = 0.064 * 100 / 10  # e-Manual: t1 = 64 ms × Goal Velocity / Profile Acceleration
    s.advance(t_ramp / 2)
    assert get(s, "velocity_trajectory") == 50
    s.advance(t_ramp + 0.2)
    assert get(s, "present_velocity") == 100 and get(s, "moving") == 1
    x0, t0 = s.motion.position, s.now
    s.advance(t0 + 100.0)  # an endless cruise is cheap to advance and exact
    assert s.motion.position - x0 == pytest.approx(100 * PULSE_PER_S_PER_VELOCITY_UNIT * 100.0)
    put(s, "goal_velocity", 0, s.now)
    s.advance(s.now + 2.0)
    assert get(s, "present_velocity") == 0 and get(s, "moving") == 0


def test_pwm_mode_duty_and_voltage_set_the_speed():
    full = 46.0 * 4096 / 60  # XM430-W350 no-load speed at 12 V, pulse/s
    s = VirtualServo(operating_mode=16, pwm_limit=600, torque_enable=1)
    assert put(s, "goal_pwm", 601, 0.0) == LIMIT
    assert put(s, "goal_pwm", -442, 0.0) == OK  # 50 % duty, reversed
    s.advance(1.0)
    assert s.motion.velocity == pytest.approx(-full * 442 / 885)
    s.set_input_voltage(6.0, t=1.0)  # below Min Voltage Limit: the error latches
    s.advance(2.0)
    assert s.alert and s.torque_enabled  # bit 0 is not in the default Shutdown mask
    assert s.motion.velocity == pytest.approx(-full * 0.5 * 600 / 885)  # PWM Limit caps


def test_narrowing_a_limit_latches_the_matching_error(servo):
    assert put(servo, "temperature_limit", 25) == ALERT  # below 30 °C ambient: its reply alerts
    assert servo.hardware_error_status == HardwareError.OVERHEATING


def test_torque_off_stops_the_horn_where_it_is(on):
    put(on, "goal_position", 4000, 0.0)
    on.advance(0.1)
    pos = get(on, "present_position")
    put(on, "torque_enable", 0, 0.1)
    on.advance(1.0)
    assert get(on, "present_position") == pos and get(on, "present_velocity") == 0
    assert get(on, "position_trajectory") == pos


def test_present_current_follows_acceleration(on):
    on.write(108, le(50, 4) + le(100, 4), 0.0)
    put(on, "goal_position", 4000, 0.0)
    accelerating = get(on, "present_current", 0.05)
    cruising = get(on, "present_current", 0.5)
    assert accelerating > cruising > 0
    on.advance(3.0)
    assert get(on, "present_current") == 0


def test_moving_status_in_position_band(on):
    assert get(on, "moving_status") & 0x01
    put(on, "goal_position", 2100, 0.0)
    assert not get(on, "moving_status", 0.001) & 0x01
    on.advance(0.5)
    assert get(on, "moving_status") & 0x01


def test_plan_profile_from_motion_brakes_first_when_reversing():
    # brakes 1000 -> 0 pulse/s over 250 pulses, then 750 back >= v²/a = 500: a trapezoid
    segs, kind = plan_profile(0.0, 0.0, 1000.0, -500.0, 1000.0, 2000.0)
    assert len(segs) == 4 and segs[0][4] == -2000.0  # braking segment first
    assert segs[1][0] == pytest.approx(0.5)
    ts, te, p, v, a = segs[-1]
    tau = te - ts
    assert p + v * tau + 0.5 * a * tau * tau == pytest.approx(-500.0)
    assert v + a * tau == pytest.approx(0.0, abs=1e-9)
    assert kind == ProfileType.TRAPEZOIDAL
    _, kind = plan_profile(0.0, 0.0, 1000.0, 0.0, 1000.0, 2000.0)  # back to where it was
    assert kind == ProfileType.TRIANGULAR


@settings(max_examples=40, deadline=None)
@given(
    model=st.sampled_from(["XM430-W350", "XL330-M288", "XM540-W270"]),
    v_units=st.one_of(st.just(0), st.integers(20, 1023)),  # >= 20: done within 15 s
    a_units=st.integers(0, 300),
    goals=st.lists(st.tuples(st.integers(0, 4095), st.integers(1, 400)), min_size=1, max_size=6),
)
def test_speed_never_exceeds_the_motor_limit(model, v_units, a_units, goals):
    s = VirtualServo(model, torque_enable=1, velocity_limit=1023 if model != "XL330-M288" else 2047)
    s.write(108, le(a_units, 4) + le(v_units, 4), 0.0)
    vmax = s.model.no_load_speed_pulse_s
    t = 0.0
    for goal, ms in goals:
        assert put(s, "goal_position", goal, t) == OK
        for _ in range(ms):
            t += DT
            s.advance(t)
            assert abs(s.motion.velocity) <= vmax * (1 + 1e-12)
    s.advance(t + 15.0)
    assert get(s, "present_position") == goals[-1][0]
