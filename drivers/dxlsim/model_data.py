"""The e-Manual's X-series control tables and motor figures, as data.

One shared table, :data:`X_TABLE` (the XM430-W350 layout, Protocol 2.0: addresses 0-146 and
the two Indirect Address / Indirect Data blocks, 168-251 and 578-661), and per model only
what differs from it (:data:`MODEL_DATA`): changed defaults and ranges, dropped rows (the
XL430/XC430/2XL430 have no current control) and added rows. :mod:`drivers.dxlsim.models`
builds each :class:`~drivers.dxlsim.models.ServoModel` from these; nothing here is code.

Sources. Every control-table row comes from the model's e-Manual page
(``github:ROBOTIS-GIT/emanual``, ``docs/en/dxl/x/<model>.md``; the commit read is named at
each model, and where the stored pages differ the newer firmware's layout is used: the one
with a Range column and Startup Configuration(60) / Backup Ready(147)). Stall torque, stall
current, no-load speed and the recommended voltage come from ``_data/dxl_x_info.yml`` (the
figures the pages render). The model numbers agree with ROBOTIS'
``dynamixel_hardware_interface`` model table.

Estimates, not e-Manual figures: ``reflected_inertia_kgm2`` (the rotor inertia of the
nearest existing motor × gear ratio²) and ``running_current_a`` (4-8 % of stall current):
the manual gives neither; they only make Present Current plausible while the horn turns.

Row: ``(addr, size, name, access, default, lo, hi, signed)``; names are snake_case of the
e-Manual names. Per model: ``"table": {name: (default, lo, hi)}``, ``"drop"``: names
removed, ``"add"``: extra rows, ``"choices"``: {name: the only accepted values} (Operating
Mode always, from ``"modes"``), ``"axes"``: 2 for a dual-axis case (2XL430).
"""

from __future__ import annotations

import drivers.protocol2.control_table as _ct
from drivers.dxlsim.model_spec import ModelOptions, ModelSpec

Row = tuple[int, int, str, str, int, int, int, bool]

_INT32_LO, _INT32_HI = -(2**31), 2**31 - 1
_R, _RW = "R", "RW"

#: Indirect Address n points anywhere in the RAM area (e-Manual XL430-W250/XM430-W350 tables).
INDIRECT_TARGET_LO, INDIRECT_TARGET_HI = 64, 661
#: The two blocks: (first n, Indirect Address n's address, Indirect Data n's address, count).
INDIRECT_BLOCKS = (
    (1, _ct.INDIRECT_ADDRESS_1.addr, _ct.INDIRECT_DATA_1.addr, _ct.INDIRECT_COUNT // 2),
    (29, _ct.INDIRECT_ADDRESS_29.addr, _ct.INDIRECT_DATA_29.addr, _ct.INDIRECT_COUNT // 2),
)


def _indirect_rows() -> list[Row]:
    """Indirect Address 1-56 (2 bytes, RW, default: the address of Indirect Data n, range
    64-661) and Indirect Data 1-56 (1 byte, RW, 0-255), both in the RAM area."""
    lo, hi, rows = INDIRECT_TARGET_LO, INDIRECT_TARGET_HI, []
    for first, addr_at, data_at, count in INDIRECT_BLOCKS:
        for k in range(count):
            n, a, d = first + k, addr_at + 2 * k, data_at + k
            rows.append((a, 2, f"indirect_address_{n}", _RW, d, lo, hi, False))
            rows.append((d, 1, f"indirect_data_{n}", _RW, 0, 0, 255, False))
    return rows


# The X-series control table (XM430-W350 as reference).
# Goal PWM/Current/Velocity ranges are derived from the matching limit field's maximum.
X_TABLE: tuple[Row, ...] = (
    (0, 2, "model_number", _R, 0, 0, 65535, False),
    (2, 4, "model_information", _R, 0, 0, 2**32 - 1, False),
    (6, 1, "firmware_version", _R, 0, 0, 255, False),
    (7, 1, "id", _RW, 1, 0, 252, False),
    (8, 1, "baud_rate", _RW, 1, 0, 7, False),
    (9, 1, "return_delay_time", _RW, 250, 0, 254, False),
    (10, 1, "drive_mode", _RW, 0, 0, 5, False),
    (11, 1, "operating_mode", _RW, 3, 0, 16, False),
    (12, 1, "secondary_id", _RW, 255, 0, 255, False),
    (13, 1, "protocol_type", _RW, 2, 1, 2, False),
    (20, 4, "homing_offset", _RW, 0, -1_044_479, 1_044_479, True),
    (24, 4, "moving_threshold", _RW, 10, 0, 1023, False),
    (31, 1, "temperature_limit", _RW, 80, 0, 100, False),
    (32, 2, "max_voltage_limit", _RW, 160, 95, 160, False),
    (34, 2, "min_voltage_limit", _RW, 95, 95, 160, False),
    (36, 2, "pwm_limit", _RW, 885, 0, 885, False),
    (38, 2, "current_limit", _RW, 1193, 0, 1193, False),
    (44, 4, "velocity_limit", _RW, 200, 0, 1023, False),
    (48, 4, "max_position_limit", _RW, 4095, 0, 4095, False),
    (52, 4, "min_position_limit", _RW, 0, 0, 4095, False),
    (63, 1, "shutdown", _RW, 52, 0, 255, False),
    (64, 1, "torque_enable", _RW, 0, 0, 1, False),
    (65, 1, "led", _RW, 0, 0, 1, False),
    (68, 1, "status_return_level", _RW, 2, 0, 2, False),
    (69, 1, "registered_instruction", _R, 0, 0, 1, False),
    (70, 1, "hardware_error_status", _R, 0, 0, 255, False),
    (76, 2, "velocity_i_gain", _RW, 1920, 0, 16383, False),
    (78, 2, "velocity_p_gain", _RW, 100, 0, 16383, False),
    (80, 2, "position_d_gain", _RW, 0, 0, 16383, False),
    (82, 2, "position_i_gain", _RW, 0, 0, 16383, False),
    (84, 2, "position_p_gain", _RW, 800, 0, 16383, False),
    (88, 2, "feedforward_2nd_gain", _RW, 0, 0, 16383, False),
    (90, 2, "feedforward_1st_gain", _RW, 0, 0, 16383, False),
    (98, 1, "bus_watchdog", _RW, 0, 0, 127, True),  # reads -1 once tripped
    (100, 2, "goal_pwm", _RW, 0, 0, 0, True),
    (102, 2, "goal_current", _RW, 0, 0, 0, True),
    (104, 4, "goal_velocity", _RW, 0, 0, 0, True),
    (108, 4, "profile_acceleration", _RW, 0, 0, 32767, False),
    (112, 4, "profile_velocity", _RW, 0, 0, 32767, False),
    (116, 4, "goal_position", _RW, 0, -1_048_575, 1_048_575, True),
    (120, 2, "realtime_tick", _R, 0, 0, 32767, False),
    (122, 1, "moving", _R, 0, 0, 1, False),
    (123, 1, "moving_status", _R, 0, 0, 255, False),
    (124, 2, "present_pwm", _R, 0, -885, 885, True),
    (126, 2, "present_current", _R, 0, -32768, 32767, True),
    (128, 4, "present_velocity", _R, 0, _INT32_LO, _INT32_HI, True),
    (132, 4, "present_position", _R, 0, _INT32_LO, _INT32_HI, True),
    (136, 4, "velocity_trajectory", _R, 0, _INT32_LO, _INT32_HI, True),
    (140, 4, "position_trajectory", _R, 0, _INT32_LO, _INT32_HI, True),
    (144, 2, "present_input_voltage", _R, 0, 0, 65535, False),
    (146, 1, "present_temperature", _R, 0, 0, 255, False),
    *_indirect_rows(),
)

#: Address of every X-series field by name (the same on every model that has the field).
X_ADDRESSES: dict[str, int] = {row[2]: row[0] for row in X_TABLE}

#: Which limit field bounds each goal field's own range (± the limit's maximum).
GOAL_RANGE_FROM = {
    "goal_pwm": "pwm_limit",
    "goal_current": "current_limit",
    "goal_velocity": "velocity_limit",
}

#: First firmware with Control Table Backup (0x20), Backup Ready, Startup Configuration and
#: Drive Mode bit 3, by series (``control_table_drivemode.md``: V46 on xl330/xc330, V45 on the
#: other X groups); the Fast Sync Read thresholds are the host's, in
#: :data:`drivers.protocol2.control_table.FAST_READ_MIN_FIRMWARE`.
BACKUP_MIN_FIRMWARE = {"X330": 46, "X430": 45, "X540": 45}

_ALL_MODES = (0, 1, 3, 4, 5, 16)
_NO_CURRENT_MODES = (1, 3, 4, 16)  # velocity, position, extended position, PWM

#: X330 servos have 20 indirect pairs, not 56: Indirect Address 1-20 at 168-206 (default the
#: address of Indirect Data n, range 64-227) and Indirect Data 1-20 at 208-227 (e-Manual
#: docs/en/dxl/x/xl330-m288.md, xc330-*.md control tables).
_X330_INDIRECT_DROP = tuple(f"indirect_address_{n}" for n in range(21, 57)) + tuple(
    f"indirect_data_{n}" for n in range(21, 57)
)
_X330_INDIRECT_ADD = tuple(
    (168 + 2 * k, 2, f"indirect_address_{k + 1}", _RW, 208 + k, 64, 227, False) for k in range(20)
) + tuple((208 + k, 1, f"indirect_data_{k + 1}", _RW, 0, 0, 255, False) for k in range(20))

_STARTUP: Row = (60, 1, "startup_configuration", _RW, 0, 0, 3, False)
_BACKUP_READY: Row = (147, 1, "backup_ready", _R, 0, 0, 1, False)
_PRESENT_LOAD: Row = (126, 2, "present_load", _R, 0, -1000, 1000, True)  # 0.1 % of stall
_NO_CURRENT = ("current_limit", "goal_current", "present_current")
_EXTERNAL_PORT_MODES: tuple[Row, ...] = tuple(
    (55 + n, 1, f"external_port_mode_{n}", _RW, 3, 0, 3, False) for n in (1, 2, 3)
)


def _x330(pwm_slope: int, *rows: Row) -> ModelOptions:
    """What every X330 shares: 4 Mbit/s at most, Protocol Type 2 or the RC protocols
    (``control_table_protocolversion.md``: 2, 20 S.BUS, 21 iBUS, 22 RC-PWM; no Protocol 1.0),
    Temperature Limit 70, 20 indirect pairs, Startup Configuration, PWM Slope, Backup Ready."""
    return {
        "choices": {"protocol_type": (2, 20, 21, 22)},
        "drop": _X330_INDIRECT_DROP,
        "add": (
            *_X330_INDIRECT_ADD,
            _STARTUP,
            (62, 1, "pwm_slope", _RW, pwm_slope, 1, 255, False),
            _BACKUP_READY,
            *rows,
        ),
    }


# Drive Mode bits 0 (reverse), 2 (time-based profile, fw 42+) and 3 (torque on by goal
# update, fw 45/46) on every X group (``control_table_drivemode.md``): 0..13. Older page
# layouts print 0 ~ 1 or 0 ~ 5; the firmware gates of bits 2/3 are in registers.py.
_DRIVE_MODE = {"drive_mode": (0, 0, 13)}
_X330_TABLE = {
    **_DRIVE_MODE,
    "baud_rate": (1, 0, 6),
    "protocol_type": (2, 2, 22),
    "temperature_limit": (70, 0, 100),
}
_X330_5V = {"max_voltage_limit": (70, 31, 70), "min_voltage_limit": (35, 31, 70)}
_X330_12V = {"max_voltage_limit": (140, 55, 140), "min_voltage_limit": (55, 55, 140)}
_XL430_CLASS_VOLTS = {"max_voltage_limit": (140, 60, 140), "min_voltage_limit": (60, 60, 140)}
_XC430_VOLTS = {"max_voltage_limit": (160, 60, 160), "min_voltage_limit": (60, 60, 160)}
_24V = {"max_voltage_limit": (300, 110, 300), "min_voltage_limit": (110, 110, 300)}

#: Per model: motor figures and the rows that differ from :data:`X_TABLE`.
MODEL_DATA: dict[str, ModelSpec] = {
    # --- X430 -------------------------------------------------------------------------
    # xm430-w350.md @ 08551725 (its voltage range "110 ~ 300" is a slip: defaults 160/95)
    "XM430-W350": {
        "model_number": 1020,
        "no_load_speed_rpm": 46.0,
        "nominal_voltage_v": 12.0,
        "current_unit_ma": 2.69,
        "stall_torque_nm": 4.1,
        "stall_current_a": 2.3,
        "reflected_inertia_kgm2": 0.012,
        "running_current_a": 0.12,
        "modes": _ALL_MODES,
        "table": {**_DRIVE_MODE},
    },
    # xm430-w210.md @ 8bb7656a
    "XM430-W210": {
        "model_number": 1030,
        "no_load_speed_rpm": 77.0,
        "nominal_voltage_v": 12.0,
        "current_unit_ma": 2.69,
        "stall_torque_nm": 3.0,
        "stall_current_a": 2.3,
        "reflected_inertia_kgm2": 0.0045,
        "running_current_a": 0.12,
        "modes": _ALL_MODES,
        "table": {**_DRIVE_MODE, "velocity_limit": (330, 0, 1023)},
    },
    # xh430-w350.md @ 028a13d2 (Maxon coreless; TTL or RS-485; the layout with Startup
    # Configuration(60) and Backup Ready(147), as on the XL430; 6aca77e9 was the one before)
    "XH430-W350": {
        "model_number": 1000,
        "no_load_speed_rpm": 30.0,
        "nominal_voltage_v": 12.0,
        "current_unit_ma": 2.69,
        "stall_torque_nm": 3.4,
        "stall_current_a": 1.3,
        "reflected_inertia_kgm2": 0.012,  # estimate: as XM430-W350 (353.5:1)
        "running_current_a": 0.07,  # estimate
        "modes": _ALL_MODES,
        "table": {
            **_DRIVE_MODE,
            "current_limit": (648, 0, 648),
            "velocity_limit": (130, 0, 1023),
            "position_p_gain": (900, 0, 16383),
        },
        "add": (_STARTUP, _BACKUP_READY),
    },
    # xh430-w210.md @ 028a13d2 (Startup Configuration and Backup Ready; 1cf2abe6 had neither)
    "XH430-W210": {
        "model_number": 1010,
        "no_load_speed_rpm": 50.0,
        "nominal_voltage_v": 12.0,
        "current_unit_ma": 2.69,
        "stall_torque_nm": 2.5,
        "stall_current_a": 1.3,
        "reflected_inertia_kgm2": 0.0045,  # estimate: XM430-class rotor × 212.6²
        "running_current_a": 0.07,  # estimate
        "modes": _ALL_MODES,
        "table": {
            **_DRIVE_MODE,
            "current_limit": (648, 0, 648),
            "velocity_limit": (210, 0, 1023),
            "position_p_gain": (900, 0, 16383),
        },
        "add": (_STARTUP, _BACKUP_READY),
    },
    # xh430-v350.md @ 7f0be97a (24 V, RS-485 only; current unit 1.34 mA; Startup Configuration
    # and Backup Ready, which 6058d277 lacked)
    "XH430-V350": {
        "model_number": 1040,
        "no_load_speed_rpm": 31.0,
        "nominal_voltage_v": 24.0,
        "current_unit_ma": 1.34,
        "stall_torque_nm": 3.3,
        "stall_current_a": 0.7,
        "reflected_inertia_kgm2": 0.012,  # estimate: as XH430-W350 (353.5:1)
        "running_current_a": 0.04,  # estimate
        "modes": _ALL_MODES,
        "table": {
            **_DRIVE_MODE,
            **_24V,
            "current_limit": (689, 0, 689),
            "velocity_limit": (135, 0, 1023),
        },
        "add": (_STARTUP, _BACKUP_READY),
    },
    # docs/kr/dxl/x/xh430-v210.md @ 01ba9719: the stored English pages (b6bee155 and older)
    # are all the old layout, without Startup Configuration(60) and Backup Ready(147), and
    # print Velocity Limit 380; the Korean page in the current layout has both rows, as the
    # other XH430 pages do, and 230 (about the no-load speed, as on the other XH430s)
    "XH430-V210": {
        "model_number": 1050,
        "no_load_speed_rpm": 52.0,
        "nominal_voltage_v": 24.0,
        "current_unit_ma": 1.34,
        "stall_torque_nm": 2.6,
        "stall_current_a": 0.7,
        "reflected_inertia_kgm2": 0.0045,  # estimate: as XH430-W210 (212.6:1)
        "running_current_a": 0.04,  # estimate
        "modes": _ALL_MODES,
        "table": {
            **_DRIVE_MODE,
            **_24V,
            "current_limit": (689, 0, 689),
            "velocity_limit": (230, 0, 1023),
        },
        "add": (_STARTUP, _BACKUP_READY),
    },
    # xl430-w250.md @ 00a4b781 (no current sensing: addr 126 is Present Load)
    "XL430-W250": {
        "model_number": 1060,
        "no_load_speed_rpm": 57.0,
        "nominal_voltage_v": 11.1,
        "current_unit_ma": None,
        "stall_torque_nm": 1.4,
        "stall_current_a": 1.3,
        "reflected_inertia_kgm2": 0.004,
        "running_current_a": 0.1,
        "modes": _NO_CURRENT_MODES,
        "table": {
            **_DRIVE_MODE,
            **_XL430_CLASS_VOLTS,
            "temperature_limit": (72, 0, 100),
            "velocity_limit": (265, 0, 1023),
            "velocity_i_gain": (1000, 0, 16383),
            "position_d_gain": (4000, 0, 16383),
            "position_p_gain": (640, 0, 16383),
        },
        "drop": _NO_CURRENT,
        "add": (_STARTUP, _PRESENT_LOAD, _BACKUP_READY),
    },
    # 2xl430-w250.md @ 4103eaba: two axes in one case, each its own ID and control table,
    # one communication module: Baud Rate and Protocol Type change on both at once, and
    # giving both axes one ID is a Data Limit Error (the servo's pairing: servo.py).
    "2XL430-W250": {
        "model_number": 1090,
        "axes": 2,
        "no_load_speed_rpm": 57.0,
        "nominal_voltage_v": 11.1,
        "current_unit_ma": None,
        "stall_torque_nm": 1.4,
        "stall_current_a": 1.3,
        "reflected_inertia_kgm2": 0.004,  # estimate: XL430 rotor × 257.4²
        "running_current_a": 0.1,  # estimate: as XL430, per axis
        "modes": _NO_CURRENT_MODES,
        "table": {
            **_DRIVE_MODE,
            **_XL430_CLASS_VOLTS,
            "temperature_limit": (72, 0, 100),
            "velocity_limit": (250, 0, 1023),
            "velocity_i_gain": (1800, 0, 16383),
            "position_d_gain": (2000, 0, 16383),
            "position_p_gain": (640, 0, 16383),
        },
        "drop": _NO_CURRENT,
        "add": (_PRESENT_LOAD,),
    },
    # xc430-w150.md @ 028a13d2 (XC430-T150BB, bearings, is the same servo: xc430-t150bb.md)
    "XC430-W150": {
        "model_number": 1070,
        "no_load_speed_rpm": 106.0,
        "nominal_voltage_v": 12.0,
        "current_unit_ma": None,
        "stall_torque_nm": 1.6,
        "stall_current_a": 1.4,
        "reflected_inertia_kgm2": 0.0015,  # estimate: XL430-class rotor × 159.59²
        "running_current_a": 0.08,  # estimate
        "modes": _NO_CURRENT_MODES,
        "table": {
            **_DRIVE_MODE,
            **_XC430_VOLTS,
            "moving_threshold": (20, 0, 1023),
            "velocity_limit": (460, 0, 1023),
            "position_p_gain": (460, 0, 16383),
        },
        "drop": _NO_CURRENT,
        "add": (_STARTUP, _PRESENT_LOAD, _BACKUP_READY),
    },
    # xc430-w240.md @ 036d44f4 (XC430-T240BB is the same servo)
    "XC430-W240": {
        "model_number": 1080,
        "no_load_speed_rpm": 70.0,
        "nominal_voltage_v": 12.0,
        "current_unit_ma": None,
        "stall_torque_nm": 1.9,
        "stall_current_a": 1.4,
        "reflected_inertia_kgm2": 0.0036,  # estimate: XL430-class rotor × 245.22²
        "running_current_a": 0.08,  # estimate
        "modes": _NO_CURRENT_MODES,
        "table": {
            **_DRIVE_MODE,
            **_XC430_VOLTS,
            "velocity_limit": (306, 0, 1023),
            "position_p_gain": (700, 0, 16383),
        },
        "drop": _NO_CURRENT,
        "add": (_STARTUP, _PRESENT_LOAD, _BACKUP_READY),
    },
    # --- X540 -------------------------------------------------------------------------
    # xm540-w270.md @ 7d10aced (External Port Data 152-156: no range or default on the page)
    "XM540-W270": {
        "model_number": 1120,
        "no_load_speed_rpm": 30.0,
        "nominal_voltage_v": 12.0,
        "current_unit_ma": 2.69,
        "stall_torque_nm": 10.6,
        "stall_current_a": 4.4,
        "reflected_inertia_kgm2": 0.03,
        "running_current_a": 0.2,
        "modes": _ALL_MODES,
        "table": {
            **_DRIVE_MODE,
            "current_limit": (2047, 0, 2047),
            "velocity_limit": (128, 0, 1023),
        },
        "add": _EXTERNAL_PORT_MODES,
    },
    # xm540-w150.md @ 089162d6
    "XM540-W150": {
        "model_number": 1130,
        "no_load_speed_rpm": 53.0,
        "nominal_voltage_v": 12.0,
        "current_unit_ma": 2.69,
        "stall_torque_nm": 7.3,
        "stall_current_a": 4.4,
        "reflected_inertia_kgm2": 0.0094,  # estimate: XM540 rotor × 152.3²
        "running_current_a": 0.2,  # estimate: as XM540-W270
        "modes": _ALL_MODES,
        "table": {
            **_DRIVE_MODE,
            "current_limit": (2047, 0, 2047),
            "velocity_limit": (230, 0, 1023),
        },
        "add": _EXTERNAL_PORT_MODES,
    },
    # --- X330 (5 V "M" and 12 V "T" motors) -------------------------------------------
    # xl330-m288.md @ c72095b1
    "XL330-M288": {
        "model_number": 1200,
        "no_load_speed_rpm": 103.0,
        "nominal_voltage_v": 5.0,
        "current_unit_ma": 1.0,
        "stall_torque_nm": 0.52,
        "stall_current_a": 1.47,
        "reflected_inertia_kgm2": 0.0008,
        "running_current_a": 0.06,
        "modes": _ALL_MODES,
        "table": {
            **_X330_TABLE,
            **_X330_5V,
            "current_limit": (1750, 0, 1750),
            "velocity_limit": (445, 0, 2047),
            "shutdown": (53, 0, 255),
            "velocity_i_gain": (1600, 0, 16383),
            "velocity_p_gain": (180, 0, 16383),
            "position_p_gain": (400, 0, 16383),
        },
        **_x330(pwm_slope=140),
    },
    # xl330-m077.md @ 01ba9719 (Position I Gain 400 by default: unusual, as printed)
    "XL330-M077": {
        "model_number": 1190,
        "no_load_speed_rpm": 383.0,
        "nominal_voltage_v": 5.0,
        "current_unit_ma": 1.0,
        "stall_torque_nm": 0.215,
        "stall_current_a": 1.47,
        "reflected_inertia_kgm2": 0.00006,  # estimate: XL330 rotor × 77.5²
        "running_current_a": 0.07,  # estimate
        "modes": _ALL_MODES,
        "table": {
            **_X330_TABLE,
            **_X330_5V,
            "current_limit": (1750, 0, 1750),
            "velocity_limit": (1620, 0, 2047),
            "shutdown": (53, 0, 255),
            "velocity_i_gain": (400, 0, 16383),
            "velocity_p_gain": (40, 0, 16383),
            "position_i_gain": (400, 0, 16383),
            "position_p_gain": (400, 0, 16383),
        },
        **_x330(pwm_slope=140),
    },
    # xc330-m181.md @ 08b586c5
    "XC330-M181": {
        "model_number": 1230,
        "no_load_speed_rpm": 129.0,
        "nominal_voltage_v": 5.0,
        "current_unit_ma": 1.0,
        "stall_torque_nm": 0.60,
        "stall_current_a": 1.80,
        "reflected_inertia_kgm2": 0.0003,  # estimate: X330 rotor × 180.62²
        "running_current_a": 0.08,  # estimate
        "modes": _ALL_MODES,
        "table": {
            **_X330_TABLE,
            **_X330_5V,
            "current_limit": (2352, 0, 2352),
            "velocity_limit": (545, 0, 2047),
            "velocity_i_gain": (1400, 0, 16383),
            "position_d_gain": (500, 0, 16383),
            "position_p_gain": (1200, 0, 16383),
        },
        **_x330(pwm_slope=140),
    },
    # xc330-m288.md @ 5a94d0e6
    "XC330-M288": {
        "model_number": 1240,
        "no_load_speed_rpm": 81.0,
        "nominal_voltage_v": 5.0,
        "current_unit_ma": 1.0,
        "stall_torque_nm": 0.93,
        "stall_current_a": 1.80,
        "reflected_inertia_kgm2": 0.0008,  # estimate: X330 rotor × 288.35²
        "running_current_a": 0.08,  # estimate
        "modes": _ALL_MODES,
        "table": {
            **_X330_TABLE,
            **_X330_5V,
            "current_limit": (2352, 0, 2352),
            "velocity_limit": (350, 0, 2047),
            "velocity_i_gain": (1600, 0, 16383),
            "velocity_p_gain": (50, 0, 16383),
            "position_d_gain": (500, 0, 16383),
            "position_p_gain": (1100, 0, 16383),
        },
        **_x330(pwm_slope=140),
    },
    # xc330-t181.md @ 207d2e05 (12 V motor, 5 V logic; PWM Slope unit 3.955 mV/ms)
    "XC330-T181": {
        "model_number": 1210,
        "no_load_speed_rpm": 104.0,
        "nominal_voltage_v": 11.1,
        "current_unit_ma": 1.0,
        "stall_torque_nm": 0.76,
        "stall_current_a": 0.80,
        "reflected_inertia_kgm2": 0.0003,  # estimate: as XC330-M181 (180.62:1)
        "running_current_a": 0.05,  # estimate
        "modes": _ALL_MODES,
        "table": {
            **_X330_TABLE,
            **_X330_12V,
            "current_limit": (910, 0, 910),
            "velocity_limit": (510, 0, 2047),
            "velocity_i_gain": (1200, 0, 16383),
            "velocity_p_gain": (40, 0, 16383),
            "position_p_gain": (900, 0, 16383),
        },
        **_x330(pwm_slope=255),
    },
    # xc330-t288.md @ b0f9fcc7
    "XC330-T288": {
        "model_number": 1220,
        "no_load_speed_rpm": 65.0,
        "nominal_voltage_v": 11.1,
        "current_unit_ma": 1.0,
        "stall_torque_nm": 0.92,
        "stall_current_a": 0.80,
        "reflected_inertia_kgm2": 0.0008,  # estimate: as XC330-M288 (288.35:1)
        "running_current_a": 0.05,  # estimate
        "modes": _ALL_MODES,
        "table": {
            **_X330_TABLE,
            **_X330_12V,
            "current_limit": (910, 0, 910),
            "velocity_limit": (320, 0, 2047),
            "velocity_i_gain": (1200, 0, 16383),
            "velocity_p_gain": (40, 0, 16383),
            "position_p_gain": (900, 0, 16383),
        },
        **_x330(pwm_slope=255),
    },
}

#: Other names of a model: the same servo, the same Model Number (the bearing versions).
ALIASES = {"XC430-T150BB": "XC430-W150", "XC430-T240BB": "XC430-W240"}
