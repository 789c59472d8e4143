"""Servo model tables: layout invariants, per-model differences, lookups."""

from __future__ import annotations

import itertools

import pytest

from drivers.dxlsim.models import (
    EEPROM_END,
    MODELS,
    PULSE_PER_S2_PER_ACCEL_UNIT,
    PULSE_PER_S_PER_VELOCITY_UNIT,
    get_model,
    normalize_name,
)

ALL = sorted(MODELS)
# Addresses every X-series model defines (XL430 lacks 38 and 102: no current control).
COMMON = (
    0,
    2,
    6,
    7,
    8,
    9,
    10,
    11,
    12,
    13,
    20,
    24,
    31,
    32,
    34,
    36,
    44,
    48,
    52,
    63,
    64,
    65,
    68,
    69,
    70,
    76,
    78,
    80,
    82,
    84,
    88,
    90,
    98,
    100,
    104,
    108,
    112,
    116,
    120,
    122,
    123,
    124,
    126,
    128,
    132,
    136,
    140,
    144,
    146,
)


@pytest.mark.parametrize("name", ALL)
def test_fields_are_sorted_and_do_not_overlap(name):
    fields = MODELS[name].fields
    for a, b in itertools.pairwise(fields):
        assert a.end <= b.addr, (a, b)
    assert fields[0].addr == 0
    # the last field: Indirect Data 56 at 661 (X430/X540), Indirect Data 20 at 227 (X330)
    assert MODELS[name].table_end == (228 if name.startswith(("XL330", "XC330")) else 662)


@pytest.mark.parametrize("name", ALL)
def test_fields_are_well_formed(name):
    m = MODELS[name]
    names = [f.name for f in m.fields]
    assert len(names) == len(set(names))
    for f in m.fields:
        assert f.size in (1, 2, 4)
        assert f.access in ("R", "RW")
        assert f.lo <= f.hi
        assert f.accepts(f.default), f
        assert f.eeprom == (f.addr < EEPROM_END)
        bits = 8 * f.size
        if f.signed:
            assert -(2 ** (bits - 1)) <= f.lo and f.hi < 2 ** (bits - 1), f
        else:
            assert f.lo >= 0 and f.hi < 2**bits, f


@pytest.mark.parametrize("name", ALL)
def test_common_layout_is_present(name):
    m = MODELS[name]
    for addr in COMMON:
        assert m.has(addr), (name, addr)
    assert m.field("model_number").default == m.model_number
    assert m.field("firmware_version").default == m.firmware
    assert m.field("operating_mode").default == 3
    assert m.field("bus_watchdog").signed and m.field("bus_watchdog").hi == 127


@pytest.mark.parametrize("name", ALL)
def test_goal_ranges_follow_the_limit_fields(name):
    m = MODELS[name]
    for goal, limit in (
        ("goal_pwm", "pwm_limit"),
        ("goal_velocity", "velocity_limit"),
        ("goal_current", "current_limit"),
    ):
        if m.has(goal):
            hi = m.field(limit).hi
            assert (m.field(goal).lo, m.field(goal).hi) == (-hi, hi)


def test_the_hosts_no_load_speeds_are_the_emulators():
    """The rig's speed check (control_table) and the emulator's motor use one figure."""
    import drivers.protocol2.control_table as ct

    assert {m.name: m.no_load_speed_rpm for m in MODELS.values()} == ct.NO_LOAD_SPEED_RPM
    assert ct.no_load_speed_deg_s("xm430-w350-t") == 276.0
    assert ct.no_load_speed_deg_s("XL430-W250") == 342.0


def test_model_numbers_and_per_model_differences():
    """The emulator's models and the host's Model Number table name the same servos (the
    numbers: each e-Manual page's Model Number row)."""
    import drivers.protocol2.control_table as ct

    assert {m.model_number: m.name for m in MODELS.values()} == ct.MODEL_NAMES
    assert len(MODELS) == 18
    xl430, xl330 = MODELS["XL430-W250"], MODELS["XL330-M288"]
    assert not xl430.has("current_limit") and not xl430.has("goal_current")
    assert xl430.field(126).name == "present_load"
    assert 0 not in xl430.field("operating_mode").choices
    assert (xl330.field("max_voltage_limit").default, xl330.field("min_voltage_limit").default) == (
        70,
        35,
    )
    assert xl330.baud_rates[-1] == 4_000_000 and MODELS["XM430-W350"].baud_rates[-1] == 4_500_000
    assert [
        MODELS[n].field("velocity_limit").default
        for n in ("XM430-W350", "XL430-W250", "XL330-M288")
    ] == [200, 265, 445]
    assert MODELS["XM540-W270"].field("current_limit").hi == 2047
    assert MODELS["XM430-W350"].field_at(14) is None  # a gap
    assert MODELS["XM430-W350"].field_at(134).name == "present_position"


def test_unit_constants_match_the_emanual():
    assert abs(PULSE_PER_S_PER_VELOCITY_UNIT - 15.633) < 5e-4
    assert abs(PULSE_PER_S2_PER_ACCEL_UNIT - 244.14) < 5e-3


def test_fast_read_firmware_thresholds():
    xm, xl330 = MODELS["XM430-W350"], MODELS["XL330-M288"]
    assert xm.supports_fast_read(45) and not xm.supports_fast_read(44)
    assert xl330.supports_fast_read(46) and not xl330.supports_fast_read(45)
    assert MODELS["XM540-W270"].supports_fast_read(45)
    assert all(m.supports_fast_read() for m in MODELS.values())


def test_get_model_by_name_number_and_spelling():
    assert get_model("XM430-W350") is MODELS["XM430-W350"]
    assert get_model("xl330-m288-t") is MODELS["XL330-M288"]
    assert get_model(1060) is MODELS["XL430-W250"]
    assert get_model("1120") is MODELS["XM540-W270"]
    m = get_model("XM430-W210")
    assert get_model(m) is m
    with pytest.raises(ValueError, match="known: XM430-W350, "):
        get_model("AX-12")
    with pytest.raises(ValueError):
        get_model(9999)


def test_field_lookup_accepts_emanual_names():
    m = MODELS["XM430-W350"]
    assert m.field("Goal Position") is m.field(116) is m.field("goal_position")
    assert normalize_name("Feedforward 2nd Gain") == "feedforward_2nd_gain"
    with pytest.raises(KeyError):
        m.field("no_such_field")
    with pytest.raises(KeyError):
        m.field(14)
    assert m.baud_index(1_000_000) == 3
    with pytest.raises(ValueError, match="bps"):
        MODELS["XL330-M288"].baud_index(4_500_000)


def test_the_hosts_items_and_the_emulators_table_agree():
    """Two tables, two jobs: the host's Items (drivers.protocol2.control_table: what the driver
    reads and writes) and the emulator's full X-series table (defaults, ranges, access). Every
    field both name has one address and one size."""
    import drivers.protocol2.control_table as ct
    from drivers.dxlsim.model_data import X_TABLE as _X_TABLE
    from drivers.dxlsim.models import normalize_name

    rows = {name: (addr, size) for addr, size, name, *_ in _X_TABLE}
    items = [v for v in vars(ct).values() if isinstance(v, ct.Item)]
    matched = 0
    for item in items:
        key = normalize_name(item.name)
        if key in rows:
            assert rows[key] == (item.addr, item.size), item.name
            matched += 1
    assert matched >= 20  # every single field the host uses; the blocks are spans, not fields


def test_the_driver_knows_what_register_126_holds_as_the_emulator_does():
    """Present Current (its mA unit) or Present Load (None), per model."""
    import drivers.protocol2.control_table as ct

    assert {m.name: m.current_unit_ma for m in MODELS.values()} == ct.LOAD_REGISTER_MA
