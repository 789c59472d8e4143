"""Rig files: the demo loads; every error names the file, the key and what is allowed."""

from __future__ import annotations

import math
import pathlib

import pytest

from hilsim.rig import ExitPolicy, ReadMode, RigError, load_rig

CONFIGS = pathlib.Path(__file__).resolve().parents[2] / "configs"

BASE = """
[bus]
port = "dxlsim://?ids=1-2"
baud = 1000000

[loop]
rate_hz = 500

[[joints]]
name = "pan"
servo_id = 1
min_deg = -60
max_deg = 60
spring = { frequency_hz = 3.0, damping_ratio = 0.7 }
target = { type = "hold", value_deg = 0 }

[[joints]]
name = "tilt"
servo_id = 2
min_deg = -30
max_deg = 30
spring = { m = 1.0, c = 2.0, k = 100.0 }
target = { type = "sine", amplitude_deg = 10, frequency_hz = 0.5 }
"""


def write(tmp_path, text: str) -> pathlib.Path:
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def test_demo_rig_loads():
    rig = load_rig(CONFIGS / "demo.toml")
    assert rig.joint_names == ("head_pan", "head_tilt", "jaw", "tail")
    assert rig.servo_ids == (1, 2, 3, 4)
    assert rig.bus.read is ReadMode.AUTO
    assert rig.safety.exit_policy is ExitPolicy.HOLD
    tail = rig.joints[3]
    assert tail.initial_rad == pytest.approx(math.radians(35))
    assert (tail.spring.m, tail.spring.c, tail.spring.k) == (1.0, 0.8, 25.0)
    assert rig.joints[2].direction == -1


def test_hardware_example_loads():
    rig = load_rig(CONFIGS / "hardware_example.toml")
    assert rig.bus.port.startswith("/dev/")


def test_minimal_rig_defaults_and_units(tmp_path):
    rig = load_rig(write(tmp_path, BASE))
    pan, _tilt = rig.joints
    assert pan.min_rad == pytest.approx(-math.pi / 3)
    assert pan.max_speed_rad_s == pytest.approx(math.radians(180))
    assert rig.loop.h_s == pytest.approx(0.002)
    f = 3.0
    assert float(pan.spring.k) == 1.0  # animator form: m = 1/(2πf)², c = ζ/(πf), k = 1
    assert float(pan.spring.m) == pytest.approx(1 / (2 * math.pi * f) ** 2)
    assert rig.name == "rig"


def test_port_override(tmp_path):
    rig = load_rig(write(tmp_path, BASE), port="/dev/ttyUSB3")
    assert rig.bus.port == "/dev/ttyUSB3"


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("rate_hz = 500", "rate_hz = -5", r"loop\.rate_hz: must be > 0"),
        ("rate_hz = 500", 'rate_hz = "fast"', r"loop\.rate_hz: expected float"),
        (
            "rate_hz = 500",
            'rate_hz = 500\nintegrator = "rk5"',
            r"loop\.integrator: must be one of euler, semi_implicit_euler, midpoint, rk4",
        ),
        ("rate_hz = 500", "rate_hz = 500\nsubsteps = 0", r"loop\.substeps: must be >= 1"),
        ("rate_hz = 500", "rate_hz = 500\nturbo = true", r"unknown key\(s\) turbo in loop"),
        ("baud = 1000000", 'baud = 1000000\nread = "quick"', r"bus\.read: must be one of auto"),
        ('port = "dxlsim://?ids=1-2"\n', "", r"missing bus\.port"),
        ('name = "pan"', 'name = "pan left"', r"joints\[0\]\.name: use letters"),
        ("servo_id = 2", "servo_id = 1", r"joints\[1\]\.servo_id: servo_id 1 is already used"),
        ('name = "tilt"', 'name = "pan"', r"joints\[1\]\.name: joint name 'pan' is already used"),
        ("servo_id = 1", "servo_id = 300", r"joints\[0\]\.servo_id: must be 0\.\.252"),
        ("max_deg = 60", "max_deg = -70", r"joints\[0\]\.max_deg: must be greater than min_deg"),
        ("max_deg = 60", "max_deg = 200", r"joints\[0\]\.max_deg: .* outside one servo turn"),
        (
            "min_deg = -60",
            "min_deg = -60\ndirection = 2",
            r"joints\[0\]\.direction: must be 1 or -1",
        ),
        (
            "spring = { frequency_hz = 3.0, damping_ratio = 0.7 }",
            "spring = { frequency_hz = 3.0, damping_ratio = 0.7, k = 5 }",
            r"joints\[0\]\.spring: give either physics terms",
        ),
        (
            "spring = { m = 1.0, c = 2.0, k = 100.0 }",
            "spring = { m = 0.0, c = 2.0, k = 100.0 }",
            r"joints\[1\]\.spring\.m: must be > 0",
        ),
        (
            "spring = { m = 1.0, c = 2.0, k = 100.0 }",
            "spring = { m = 1.0, c = 2.0, k = 100.0, q = 1 }",
            r"unknown key\(s\) q in joints\[1\]\.spring",
        ),
        ('target = { type = "hold", value_deg = 0 }', "", r"missing joints\[0\]\.target"),
        (
            "[loop]",
            '[safety]\nexit_policy = "panic"\n[loop]',
            r"safety\.exit_policy: must be one of hold, relax",
        ),
        ("[loop]", "[safety]\nwatchdog_ms = 5\n[loop]", r"safety\.watchdog_ms: must be 0 \(off\)"),
        (
            "[loop]",
            "[safety]\ncomm_failure_budget_ms = 1\n[loop]",
            r"safety\.comm_failure_budget_ms: must be at least one tick",
        ),
        ("[bus]", 'colour = "red"\n[bus]', r"unknown key\(s\) colour in the top level"),
    ],
)
def test_each_config_error_names_file_and_key(tmp_path, old, new, message):
    assert old in BASE
    path = write(tmp_path, BASE.replace(old, new, 1))
    with pytest.raises(RigError, match=message) as info:
        load_rig(path)
    assert str(info.value).startswith(str(path))


def test_unstable_spring_is_refused_with_the_guards_advice(tmp_path):
    stiff = BASE.replace(
        "spring = { m = 1.0, c = 2.0, k = 100.0 }", "spring = { m = 1.0, c = 0.0, k = 4000000.0 }"
    )
    with pytest.raises(RigError, match=r"joints\[1\]\.spring \(tilt\).*UNSTABLE") as info:
        load_rig(write(tmp_path, stiff))
    assert "Set loop.substeps = 2" in str(info.value)
    # ... and the advice works.
    fixed = stiff.replace("rate_hz = 500", "rate_hz = 500\nsubsteps = 2")
    assert load_rig(write(tmp_path, fixed)).loop.substeps == 2


def test_euler_on_an_undamped_spring_has_no_substep_fix(tmp_path):
    text = BASE.replace("rate_hz = 500", 'rate_hz = 500\nintegrator = "euler"').replace(
        "spring = { m = 1.0, c = 2.0, k = 100.0 }", "spring = { m = 1.0, c = 0.0, k = 100.0 }"
    )
    with pytest.raises(RigError, match="No number of substeps helps"):
        load_rig(write(tmp_path, text))


def test_unreadable_and_invalid_toml(tmp_path):
    with pytest.raises(RigError, match="cannot read rig file"):
        load_rig(tmp_path / "missing.toml")
    with pytest.raises(RigError, match="not valid TOML"):
        load_rig(write(tmp_path, "[bus\nport = 1"))
