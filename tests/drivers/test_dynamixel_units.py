"""Units, control-table data and the exception tree of the Dynamixel driver (no I/O)."""

from __future__ import annotations

import math

import dynamixel_sdk as sdk
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.dynamixel import units
from drivers.dynamixel.errors import (
    CommError,
    CommTimeout,
    CorruptPacket,
    DynamixelError,
    ExitNotConfirmed,
    Mismatch,
    PortBusy,
    PortGone,
    ServoError,
    StartupMismatch,
)
from drivers.dynamixel.sdk_result import port_gone, raise_for
from drivers.protocol2 import control_table as ct
from drivers.servo_bus import ExitPolicy, ExitReport, ServoBusError


# ------------------------------------------------------------------ units
def test_centre_and_quarter_turns():
    assert units.rad_to_ticks(0.0) == 2048
    assert units.rad_to_ticks(math.pi / 2) == 3072
    assert units.rad_to_ticks(-math.pi) == 0
    assert units.ticks_to_rad(2048) == 0.0
    assert units.ticks_to_rad(1024) == pytest.approx(-math.pi / 2)


@pytest.mark.parametrize(
    ("raw", "ticks"),
    [(0, 0), (2048, 2048), (0x7FFF_FFFF, 2**31 - 1), (0xFFFF_FFFF, -1), (0x8000_0000, -(2**31))],
)
def test_decode_position_is_signed_32_bit(raw, ticks):
    assert units.decode_position(raw) == ticks
    item = ct.PRESENT_POSITION
    assert units.decode_position(raw) == item.decode(raw.to_bytes(4, "little"), item.addr)


def test_rounding_is_to_nearest_tick():
    half = units.RAD_PER_TICK / 2
    assert units.rad_to_ticks(0.49 * units.RAD_PER_TICK) == 2048
    assert units.rad_to_ticks(0.51 * units.RAD_PER_TICK) == 2049
    assert units.rad_to_ticks(-0.51 * units.RAD_PER_TICK) == 2047
    assert units.rad_to_ticks(np.array([half * 0.98, -half * 0.98])).tolist() == [2048, 2048]


def test_clipping_only_when_asked():
    assert units.rad_to_ticks(4.0) > 4095  # no silent clipping
    assert units.rad_to_ticks(4.0, lo=0, hi=4095) == 4095
    assert units.rad_to_ticks(np.array([-4.0, 0.0]), lo=0, hi=4095).tolist() == [0, 2048]


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_never_becomes_a_tick(bad):
    with pytest.raises(ValueError, match="non-finite"):
        units.rad_to_ticks(bad)
    with pytest.raises(ValueError):
        units.rad_to_ticks(np.array([0.0, bad]))
    with pytest.raises(ValueError):
        units.rad_s_to_velocity(bad)


@given(st.integers(min_value=-1_048_575, max_value=1_048_575))
def test_ticks_round_trip_exactly(tick):
    assert units.rad_to_ticks(units.ticks_to_rad(tick)) == tick


@given(st.floats(min_value=-1000.0, max_value=1000.0))
def test_rad_round_trip_within_half_a_tick(rad):
    back = units.ticks_to_rad(units.rad_to_ticks(rad))
    assert abs(back - rad) <= units.RAD_PER_TICK / 2 + 1e-12


def test_array_shapes_and_types():
    t = units.rad_to_ticks(np.zeros((3,)))
    assert t.dtype == np.int64 and t.shape == (3,)
    r = units.ticks_to_rad(np.array([0, 2048, 4095]))
    assert r.dtype == np.float64 and r.shape == (3,)


def test_velocity_unit():
    assert units.velocity_to_rad_s(1) == pytest.approx(0.023981, abs=1e-6)
    assert units.rad_s_to_velocity(units.velocity_to_rad_s(200)) == 200
    assert units.rad_s_to_velocity(np.array([-0.024, 0.0])).tolist() == [-1, 0]


def test_goal_tick_range_by_mode():
    assert units.goal_tick_range(ct.OperatingMode.POSITION, 100, 3000) == (100, 3000)
    assert units.goal_tick_range(4) == (-1_048_575, 1_048_575)
    assert units.goal_tick_range(5) == (-1_048_575, 1_048_575)
    with pytest.raises(ValueError, match="VELOCITY"):
        units.goal_tick_range(1)


def test_fold_ticks():
    assert units.fold_ticks(4096 + 10) == 10
    assert units.fold_ticks(np.array([-1, 8192])).tolist() == [4095, 0]


# ------------------------------------------------------------------ control table
@pytest.mark.parametrize(
    ("number", "name"),
    [
        (1020, "XM430-W350"),
        (1030, "XM430-W210"),
        (1060, "XL430-W250"),
        (1120, "XM540-W270"),
        (1200, "XL330-M288"),
        (1190, "XL330-M077"),
        (1240, "XC330-M288"),
        (1000, "XH430-W350"),
    ],
)
def test_model_numbers(number, name):
    assert ct.model_name(number) == name
    assert ct.model_number(name) == number
    assert ct.model_number(name.lower() + "-t") == number


def test_unknown_model():
    assert ct.model_name(9999) == "unknown model 9999"
    with pytest.raises(ValueError, match="XM430-W350"):
        ct.model_number("XM999")
    assert not ct.supports_fast_read(9999, 99)


@pytest.mark.parametrize(
    ("number", "firmware", "fast"),
    [
        (1020, 44, False),
        (1020, 45, True),
        (1120, 45, True),
        (1060, 45, True),
        (1200, 45, False),
        (1200, 46, True),
        (1240, 46, True),
    ],
)
def test_fast_read_thresholds(number, firmware, fast):
    assert ct.supports_fast_read(number, firmware) is fast


def test_baud_index_and_items():
    assert ct.BAUD_RATES[1] == 57_600 and ct.BAUD_INDEX[1_000_000] == 3
    assert (ct.GOAL_POSITION.addr, ct.GOAL_POSITION.size) == (116, 4)
    assert (ct.PRESENT_POSITION.addr, ct.BUS_WATCHDOG.addr, ct.TORQUE_ENABLE.addr) == (132, 98, 64)
    assert ct.BUS_WATCHDOG.decode(b"\xff", 98) == -1
    assert ct.GOAL_POSITION.encode(-1) == b"\xff\xff\xff\xff"
    assert ct.STARTUP_BLOCK.size == 136


def test_hardware_error_text():
    assert ct.describe_hardware_error(0x24) == "overheating, overload"
    assert ct.describe_hardware_error(0) == "none"
    assert ct.describe_hardware_error(0x42) == "0x42"


# ------------------------------------------------------------------ exceptions
@pytest.mark.parametrize(
    ("result", "exc"),
    [
        (sdk.COMM_RX_TIMEOUT, CommTimeout),
        (sdk.COMM_RX_CORRUPT, CorruptPacket),
        (sdk.COMM_PORT_BUSY, PortBusy),
        (sdk.COMM_TX_FAIL, CommError),
        (sdk.COMM_RX_FAIL, CommError),
        (sdk.COMM_TX_ERROR, CommError),
        (sdk.COMM_NOT_AVAILABLE, CommError),
    ],
)
def test_result_codes_become_exceptions(result, exc):
    with pytest.raises(exc) as info:
        raise_for(result, 0, 3, "Read 4 B at 132")
    assert type(info.value) is exc
    assert info.value.servo_id == 3 and "servo 3" in str(info.value)
    assert str(result) not in str(info.value)  # callers never see the SDK's codes


def test_status_error_numbers_become_servo_errors():
    raise_for(sdk.COMM_SUCCESS, 0, 1, "x")  # fine
    raise_for(sdk.COMM_SUCCESS, 0x80, 1, "x")  # Alert alone: the instruction worked
    with pytest.raises(ServoError) as info:
        raise_for(sdk.COMM_SUCCESS, 0x84, 5, "Write 4 B at 116")
    e = info.value
    assert (e.servo_id, e.error, e.number, e.alert) == (5, 0x84, 4, True)
    assert e.name == "Data Range Error"
    assert "servo 5: Data Range Error (4) on Write 4 B at 116" in str(e)
    assert "Alert" in str(e)


def test_port_gone_wraps_the_serial_error():
    cause = OSError("device reports readiness to read but returned no data")
    exc = port_gone(cause, "/dev/ttyUSB0", "Sync Read")
    assert isinstance(exc, PortGone)
    assert str(exc) == f"/dev/ttyUSB0: adapter gone during Sync Read: {cause}"


def test_exception_tree_uses_builtin_bases():
    assert issubclass(CommTimeout, TimeoutError) and issubclass(CommTimeout, CommError)
    assert issubclass(PortGone, ConnectionError) and issubclass(PortGone, DynamixelError)
    for cls in (CommError, PortGone, ServoError, StartupMismatch, ExitNotConfirmed):
        assert issubclass(cls, DynamixelError) and issubclass(cls, ServoBusError)


def test_startup_mismatch_renders_one_aligned_table():
    rows = [
        Mismatch(3, "Operating Mode", "position (3)", "velocity (1)", "write addr 11"),
        Mismatch(1, "model", "XM430-W350 (1020)", "XL430-W250 (1060)"),
    ]
    exc = StartupMismatch(rows, port="/dev/ttyUSB0")
    assert exc.servo_ids == (1, 3)
    assert [r.servo_id for r in exc.rows] == [1, 3]
    lines = str(exc).splitlines()
    assert "2 mismatch(es)" in lines[0] and "/dev/ttyUSB0" in lines[0]
    header, rule, first, second = lines[1:]
    assert header.split() == ["id", "item", "expected", "found", "fix"]
    col = header.index("expected")
    assert first[col:].startswith("XM430-W350") and second[col:].startswith("position (3)")
    assert set(rule.replace(" ", "")) == {"-"}


def test_exit_not_confirmed_names_servos():
    report = ExitReport(ExitPolicy.RELAX, (1, 2), ((3, "timeout"), (4, "adapter gone")))
    exc = ExitNotConfirmed(report)
    assert exc.servo_ids == (3, 4) and not report.ok
    assert "servo 3: timeout" in str(exc) and "servo 4: adapter gone" in str(exc)
    assert "2 servo(s) confirmed" in str(exc)
