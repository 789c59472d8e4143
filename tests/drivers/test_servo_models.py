"""The servo models people build figures with, several on one bus (issue 11, part 4).

Each value is checked against the e-Manual page named in ``drivers/dxlsim/model_data.py``
(``github:ROBOTIS-GIT/emanual``, ``docs/en/dxl/x/<model>.md`` control tables and
``_data/dxl_x_info.yml`` specifications):

- the X330 pages: 20 indirect pairs (Indirect Address 1-20 at 168-206, range 64-227;
  Indirect Data 1-20 at 208-227), Protocol Type 2/20/21/22
  (``_includes/en/dxl/control_table_protocolversion.md``), 4 Mbit/s at most;
- ``2xl430-w250.md``: each axis its own ID and control table, one communication module
  ("the value of Baud Rate(8) and Protocol Version(13) is always changed at the same time"),
  and "attempting to assign an identical ID for each joint will result in Data Limit Error";
- ``control_table_protocolversion.md``: Protocol Type 1 makes the servo speak Protocol 1.0.

Every test runs on the virtual clock; nothing sleeps.
"""

from __future__ import annotations

import dynamixel_sdk as sdk
import pytest

import drivers.protocol2.control_table as ct
from drivers.dxlsim import DxlsimUrl, VirtualServo, register_bus, unregister_bus
from drivers.dxlsim.dual_axis import pair_axes
from drivers.dxlsim.model_data import MODEL_DATA
from drivers.dxlsim.model_spec import ModelSpec
from drivers.dxlsim.models import MODELS, get_model, models_by_id
from drivers.dynamixel.port import PortHandler
from drivers.dynamixel.scan import Found, scan
from drivers.protocol2.control_table import StatusError

ID, BAUD_RATE, PROTOCOL_TYPE, GOAL_POSITION, PRESENT_POSITION = 7, 8, 13, 116, 132

# (model, Model Number, Velocity Limit default, Current Limit max or None, max baud index,
#  no-load rpm, nominal V) from each model's e-Manual page and dxl_x_info.yml
PAGES = [
    ("XM430-W350", 1020, 200, 1193, 7, 46.0, 12.0),
    ("XM430-W210", 1030, 330, 1193, 7, 77.0, 12.0),
    ("XH430-W350", 1000, 130, 648, 7, 30.0, 12.0),
    ("XH430-W210", 1010, 210, 648, 7, 50.0, 12.0),
    ("XH430-V350", 1040, 135, 689, 7, 31.0, 24.0),
    ("XH430-V210", 1050, 230, 689, 7, 52.0, 24.0),  # kr/.../xh430-v210.md
    ("XL430-W250", 1060, 265, None, 7, 57.0, 11.1),
    ("2XL430-W250", 1090, 250, None, 7, 57.0, 11.1),
    ("XC430-W150", 1070, 460, None, 7, 106.0, 12.0),
    ("XC430-W240", 1080, 306, None, 7, 70.0, 12.0),
    ("XM540-W270", 1120, 128, 2047, 7, 30.0, 12.0),
    ("XM540-W150", 1130, 230, 2047, 7, 53.0, 12.0),
    ("XL330-M288", 1200, 445, 1750, 6, 103.0, 5.0),
    ("XL330-M077", 1190, 1620, 1750, 6, 383.0, 5.0),
    ("XC330-M181", 1230, 545, 2352, 6, 129.0, 5.0),
    ("XC330-M288", 1240, 350, 2352, 6, 81.0, 5.0),
    ("XC330-T181", 1210, 510, 910, 6, 104.0, 11.1),
    ("XC330-T288", 1220, 320, 910, 6, 65.0, 11.1),
]


@pytest.mark.parametrize("name, number, vlimit, climit, baud_hi, rpm, volts", PAGES)
def test_each_model_as_its_page_prints_it(name, number, vlimit, climit, baud_hi, rpm, volts):
    m = MODELS[name]
    assert (m.model_number, m.field("velocity_limit").default) == (number, vlimit)
    assert m.field("current_limit").hi == climit if climit else not m.has("current_limit")
    assert m.field("baud_rate").hi == baud_hi
    assert (m.no_load_speed_rpm, m.nominal_voltage_v) == (rpm, volts)
    assert ct.model_name(number) == name  # the host names what the emulator answers
    # Fast Sync Read and Backup per series (V46 on X330, V45 on X430/X540)
    x330 = ct.series(name) == "X330"
    assert (m.fast_read_min_firmware, m.backup_min_firmware) == ((46, 46) if x330 else (45, 45))


def test_page_details_that_differ_between_models():
    assert MODELS["XC430-W150"].field("moving_threshold").default == 20  # xc430-w150.md
    assert MODELS["XL330-M077"].field("position_i_gain").default == 400  # xl330-m077.md
    assert MODELS["XC330-T181"].field("pwm_slope").default == 255  # xc330-t181.md
    assert MODELS["XH430-V350"].current_unit_ma == 1.34  # "about 1.34 [mA]"
    assert MODELS["XH430-V350"].field("min_voltage_limit").lo == 110  # 11.0 V, 24 V servo
    assert MODELS["XC430-W240"].field(126).name == "present_load"  # no current sensing
    assert ct.series("2XL430-W250") == "X430" and ct.fast_read_min_firmware(1090) == 45
    assert get_model("XC430-T150BB") is MODELS["XC430-W150"]  # the bearing version, same number


def test_x330_indirect_block_and_protocol_types():
    xc = VirtualServo("XC330-M288", 1, baud=57_600)
    assert xc.model.field_at(206).name == "indirect_address_20"
    assert xc.model.field_at(227).name == "indirect_data_20"
    assert xc.model.field_at(228) is None and not xc.model.has(578)
    assert xc.write(168, (228).to_bytes(2, "little"), 0.0) == StatusError.DATA_RANGE  # 64-227
    assert xc.write(168, PRESENT_POSITION.to_bytes(2, "little"), 0.0) == 0
    # Protocol Type: 2, 20 (S.BUS), 21 (iBUS), 22 (RC-PWM); no Protocol 1.0 on X330
    assert xc.write(PROTOCOL_TYPE, bytes([1]), 0.0) == StatusError.DATA_RANGE
    assert xc.write(PROTOCOL_TYPE, bytes([5]), 0.0) == StatusError.DATA_RANGE
    assert xc.write(PROTOCOL_TYPE, bytes([22]), 0.0) == 0
    assert xc.listening_baud == 0  # RC-PWM: deaf to Protocol 2.0


def test_each_models_data_has_the_keys_of_a_model_spec():
    """What the type checker holds the data to, checked here too: a key the spec does not
    name would be dropped when the model is built."""
    allowed = ModelSpec.__required_keys__ | ModelSpec.__optional_keys__
    for name, data in MODEL_DATA.items():
        assert ModelSpec.__required_keys__ <= data.keys() <= allowed, name
    assert MODELS["2XL430-W250"].axes == 2 and MODELS["XM430-W350"].axes == 1


def test_several_models_on_one_url_and_scan_names_each():
    url = (
        "dxlsim://?ids=1-6&model=XM430-W350,3-4:2XL430-W250,5:XL330-M288,6:XC330-T181&clock=virtual"
    )
    parsed = DxlsimUrl.parse(url)
    assert str(parsed) == url  # already the normal form
    found = scan(url, bauds=(1_000_000,))
    assert [(f.id, f.model_name) for f in found] == [
        (1, "XM430-W350"),
        (2, "XM430-W350"),
        (3, "2XL430-W250"),
        (4, "2XL430-W250"),
        (5, "XL330-M288"),
        (6, "XC330-T181"),
    ]
    assert all(isinstance(f, Found) for f in found)


@pytest.mark.parametrize(
    "text, message",
    [
        ("XM999", "unknown servo model 'XM999'"),
        ("XM430-W350,XL330-M288", "two models for all IDs"),
        ("1:XM430-W350", "no model for ID 2-4"),
        ("XM430-W350,9:XL330-M288", "ID 9 (9:XL330-M288) is not on the bus"),
        ("1:XM430-W350,1-4:XL330-M288", "ID 1 is given two models"),
        ("XM430-W350,1:2XL430-W250", "give it an even number of IDs"),
    ],
)
def test_a_bad_model_key_is_one_line_naming_it(text, message):
    with pytest.raises(
        ValueError, match="model: .*" + message.replace("(", r"\(").replace(")", r"\)")
    ):
        DxlsimUrl.parse(f"dxlsim://?ids=1-4&model={text}")
    with pytest.raises(ValueError) as caught:
        models_by_id(text, (1, 2, 3, 4))
    assert "\n" not in str(caught.value)


def test_two_spellings_of_one_mix_are_one_bus():
    a = DxlsimUrl.parse("dxlsim://?ids=1-3&model=xl330-m288,1:xm430-w350")
    b = DxlsimUrl.parse("dxlsim://?ids=1-3&model=1:XM430-W350,2-3:XL330-M288")
    assert str(a) == str(b) == "dxlsim://?ids=1-3&model=XL330-M288,1:XM430-W350"


def _pair():
    a = VirtualServo("2XL430-W250", 1, baud=57_600)
    b = VirtualServo("2XL430-W250", 2, baud=57_600)
    pair_axes(a, b)
    return a, b


def test_2xl430_axes_share_baud_and_protocol_type():
    """2xl430-w250.md: "Only one Baud Rate can be used for the 2XL430. Attempting to change
    the Baud Rate of one joint will also affect to the other joint." (Protocol Version too.)"""
    a, b = _pair()
    assert a.write(BAUD_RATE, bytes([3]), 0.0) == 0  # 1 Mbit/s
    assert a.baud == b.baud == 1_000_000
    assert b.write(PROTOCOL_TYPE, bytes([1]), 0.0) == 0
    assert a.listening_baud == b.listening_baud == 0  # both now speak Protocol 1.0
    # everything else is per axis
    assert a.write(65, bytes([1]), 0.0) == 0
    assert b.read(65, 1, 0.0) == (0, bytes([0]))


def test_2xl430_one_id_for_both_axes_is_a_data_limit_error():
    """2xl430-w250.md: "Attempting to assign an identical ID for each joint will result in
    Data Limit Error(0x06) of the status packet." """
    a, b = _pair()
    assert a.write(ID, bytes([2]), 0.0) == StatusError.DATA_LIMIT
    assert (a.id, b.id) == (1, 2)
    assert a.write(ID, bytes([9]), 0.0) == 0 and a.id == 9
    with pytest.raises(ValueError, match="one axis"):
        pair_axes(VirtualServo("XL430-W250", 1), VirtualServo("XL430-W250", 2))


def test_2xl430_factory_reset_of_one_axis_resets_the_shared_baud():
    a, b = _pair()
    a.write(BAUD_RATE, bytes([3]), 0.0)
    assert a.factory_reset(0x01, 0.1) == 0  # all but the ID: baud back to 57600 on both
    assert a.baud == b.baud == 57_600


def test_protocol_type_1_leaves_the_servo_deaf_to_protocol_2():
    """control_table_protocolversion.md: Protocol Type 1 = Protocol 1.0. dxlsim does not speak
    1.0, so the servo stops answering 2.0 packets, as a real one does; the others answer on."""
    url = register_bus(
        "proto1",
        DxlsimUrl(ids=(1, 2), clock="virtual", baud=1_000_000).build_bus(),
    )
    try:
        port = PortHandler(url)
        port.openPort()
        ph = sdk.PacketHandler(2.0)
        assert ph.write1ByteTxRx(port, 1, PROTOCOL_TYPE, 1)[0] == sdk.COMM_SUCCESS
        assert ph.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
        assert ph.ping(port, 2)[1] == sdk.COMM_SUCCESS
        port.closePort()
    finally:
        unregister_bus("proto1")


def test_the_docs_name_every_model():
    """docs/dxlsim.md (the limits, one place) and the README list the same servos as the code."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    limits = (root / "docs" / "dxlsim.md").read_text()
    readme = " ".join((root / "README.md").read_text().split())
    for name in MODELS:
        assert name in limits, name
        family, _, variant = name.partition("-")
        assert name in readme or (family in readme and variant in readme), name
