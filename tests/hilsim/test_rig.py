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


# -- bounds: every bad value is one line naming the file, the key, the value and what is allowed
PAN_SPRING = "spring = { frequency_hz = 3.0, damping_ratio = 0.7 }"
TILT_SPRING = "spring = { m = 1.0, c = 2.0, k = 100.0 }"
BAUDS = "9600, 57600, 115200, 1000000, 2000000, 3000000, 4000000, 4500000"


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        # model and baud against the driver's tables
        (
            'name = "pan"',
            'name = "pan"\nmodel = "XM999-W999"',
            r"joints\[0\]\.model: unknown servo model 'XM999-W999'; known: XH430-W350, "
            r"XH430-W210, XM430-W350, .*XC330-M288, STS3215, .*AX-12W \(a -T or -R suffix is fine\)",
        ),
        (
            'name = "pan"',
            'name = "pan"\nmodel = "XM430W350"',
            r"joints\[0\]\.model: unknown servo model 'XM430W350'",
        ),
        (
            "baud = 1000000",
            "baud = 123",
            rf"bus\.baud: 123 bit/s is not a servo baud rate; allowed: {BAUDS}$",
        ),
        (
            "baud = 1000000",
            "baud = 1000000000000000",
            r"bus\.baud: 1000000000000000 bit/s is not a servo",
        ),
        (
            "baud = 1000000",
            'baud = "1M"',
            rf"bus\.baud: expected int, got '1M' \(one of {BAUDS} bit/s\)",
        ),
        (
            'name = "tilt"',
            'name = "tilt"\nmodel = "XL330-M288"',
            None,  # an X330 on a 4.5 Mbps bus: the bus's baud is set in the test
        ),
        # loop
        (
            "rate_hz = 500",
            "rate_hz = 500\nsubsteps = 10000000",
            r"loop\.substeps: must be <= 100 \(at 500 Hz: at most 50,000 integrator steps a second",
        ),
        (
            "rate_hz = 500",
            "rate_hz = 250\nsubsteps = 201",
            r"loop\.substeps: must be <= 200 \(at 250 Hz",
        ),
        (
            "rate_hz = 500",
            "rate_hz = 500\ncpu = -1",
            r"loop\.cpu: must be >= 0 \(a CPU number, as in taskset -c\), got -1",
        ),
        (
            "rate_hz = 500",
            "rate_hz = 500\nrealtime_priority = 100",
            r"loop\.realtime_priority: must be <= 99, got 100",
        ),
        (
            "baud = 1000000",
            "baud = 1000000\nlatency_timer_ms = 1e9",
            r"bus\.latency_timer_ms: must be <= 255 \(a USB adapter's latency timer",
        ),
        # safety
        (
            "[loop]",
            "[safety]\nexit_retries = 1000000000\n[loop]",
            r"safety\.exit_retries: must be <= 10 \(each retry waits on a bus that may be dead\), got 1000000000",
        ),
        (
            "[loop]",
            "[safety]\nexit_retries = 0\n[loop]",
            r"safety\.exit_retries: must be >= 1, got 0",
        ),
        (
            "[loop]",
            "[safety]\nsoft_start_s = 1e300\n[loop]",
            r"safety\.soft_start_s: must be <= 60 \(a minute.*got 1e\+300",
        ),
        (
            "[loop]",
            "[safety]\nwatchdog_ms = 30\n[loop]",
            r"safety\.watchdog_ms: must be a multiple of 20 ms \(the servo counts in 20 ms units\): the nearest are 20 and 40, got 30$",
        ),
        (
            "[loop]",
            "[safety]\nwatchdog_ms = 2539\n[loop]",
            r"safety\.watchdog_ms: .*the nearest are 2520 and 2540, got 2539$",
        ),
        (
            "[loop]",
            "[safety]\nwatchdog_ms = 5000\n[loop]",
            r"safety\.watchdog_ms: must be 0 \(off\) or 20\.\.2540",
        ),
        (
            "[loop]",
            "[safety]\ncomm_failure_budget_ms = 1e6\n[loop]",
            r"safety\.comm_failure_budget_ms: must be <= 10000 \(a servo silent for longer is gone",
        ),
        # joint motion limits
        (
            "max_deg = 60",
            "max_deg = 60\nmax_accel_deg_s2 = 1e-300",
            r"joints\[0\]\.max_accel_deg_s2: must be >= 1 \(slower, a joint takes minutes to cross its range\), got 1e-300",
        ),
        (
            "max_deg = 60",
            "max_deg = 60\nmax_speed_deg_s = 0.5",
            r"joints\[0\]\.max_speed_deg_s: must be >= 1 \(slower",
        ),
        # tracking monitor
        (
            "max_deg = 60",
            "max_deg = 60\ntracking_tolerance_deg = 0",
            r"joints\[0\]\.tracking_tolerance_deg: must be > 0, got 0\.0",
        ),
        (
            "max_deg = 60",
            "max_deg = 60\ntracking_tolerance_deg = 400",
            r"joints\[0\]\.tracking_tolerance_deg: must be <= 360 \(one turn\)",
        ),
        (
            "max_deg = 60",
            "max_deg = 60\ntracking_time_ms = -5",
            r"joints\[0\]\.tracking_time_ms: must be > 0, got -5\.0",
        ),
        (
            "max_deg = 60",
            "max_deg = 60\ntracking_time_ms = nan",
            r"joints\[0\]\.tracking_time_ms: must be a finite number, got nan",
        ),
        (
            "max_deg = 60",
            "max_deg = 60\ntracking_time_ms = 1e9",
            r"joints\[0\]\.tracking_time_ms: must be <= 60000",
        ),
        # telemetry
        (
            "[loop]",
            '[telemetry]\non_failure = "explode"\n[loop]',
            r"telemetry\.on_failure: must be one of stop, continue, auto; got 'explode'",
        ),
        # springs that cannot be integrated to finite numbers
        (
            PAN_SPRING,
            "spring = { frequency_hz = 3.0, damping_ratio = 0.7, response = 1e308 }",
            r"joints\[0\]\.spring\.response: must be <= 100 \(the joint would react",
        ),
        (
            PAN_SPRING,
            "spring = { frequency_hz = 1e300, damping_ratio = 0.7 }",
            r"joints\[0\]\.spring\.frequency_hz: must be <= 1e\+06 \(slower never moves in a show; faster is beyond any loop\)",
        ),
        (
            PAN_SPRING,
            "spring = { frequency_hz = 1e-9, damping_ratio = 0.7 }",
            r"joints\[0\]\.spring\.frequency_hz: must be >= 0\.01",
        ),
        (
            PAN_SPRING,
            "spring = { frequency_hz = 3.0, damping_ratio = 1e308 }",
            r"joints\[0\]\.spring\.damping_ratio: must be <= 1000",
        ),
        (
            TILT_SPRING,
            "spring = { m = 1.0, c = 0.8, k = 1e300 }",
            r"joints\[1\]\.spring\.k: the natural frequency √\(k/m\)/2π = 1\.59e\+149 Hz \(k = 1e\+300, m = 1\) must lie within 0\.01\.\.1e\+06 Hz",
        ),
        (
            TILT_SPRING,
            "spring = { m = 1e-300, c = 0.0, k = 1e300 }",
            r"joints\[1\]\.spring\.k: the natural frequency .* = 1\.59e\+299 Hz \(k = 1e\+300, m = 1e-300\)",
        ),
        (
            TILT_SPRING,
            "spring = { m = 1e300, c = 0.0, k = 1.0 }",
            r"joints\[1\]\.spring\.k: the natural frequency .* = 1\.59e-151 Hz",
        ),
        (
            TILT_SPRING,
            "spring = { m = 1.0, c = 1e300, k = 100.0 }",
            r"joints\[1\]\.spring\.c: the damping ratio c/\(2√\(k·m\)\) = 5e\+298 must be <= 1000",
        ),
        (
            TILT_SPRING,
            "spring = { m = 1.0, c = 2.0, k = 100.0, b = 1e300 }",
            r"joints\[1\]\.spring\.b: \|b\| must be <= 100·\(c \+ 2√\(k·m\)\) = 2\.2e\+03 for this spring",
        ),
        # names that would escape the run directory
        (
            "[bus]",
            'name = "../../escape/x"\n[bus]',
            r"name: it names the run directory, so use letters, digits, _ - \+ \. and inner spaces .*got '\.\./\.\./escape/x'$",
        ),
        ("[bus]", 'name = ".."\n[bus]', r"name: it names the run directory"),
        ("[bus]", 'name = "a\\\\b"\n[bus]', r"name: it names the run directory"),
        ("[bus]", 'name = ""\n[bus]', r"name: it names the run directory"),
        ("[bus]", 'name = "-rf"\n[bus]', r"name: it names the run directory"),
    ],
)
def test_each_bound_names_file_key_value_and_what_is_allowed(tmp_path, old, new, message):
    if message is None:  # an X330 on a 4.5 Mbps bus
        text = BASE.replace("baud = 1000000", "baud = 4500000").replace(old, new)
        message = (
            r"joints\[1\]\.model: XL330-M288 \(X330 series\) runs at most 4000000 bit/s, "
            r"but bus\.baud = 4500000"
        )
    else:
        assert old in BASE
        text = BASE.replace(old, new, 1)
    path = write(tmp_path, text)
    with pytest.raises(RigError, match=message) as info:
        load_rig(path)
    assert str(info.value).startswith(f"{path}: ")
    assert "\n" not in str(info.value)  # one line


@pytest.mark.parametrize(
    ("old", "new"),
    [
        ('name = "pan"', 'name = "pan"\nmodel = "xm430-w350-t"'),  # case and -T suffix
        ("rate_hz = 500", "rate_hz = 500\nsubsteps = 100"),  # the cap itself
        ("[loop]", "[safety]\nwatchdog_ms = 2540\nexit_retries = 10\nsoft_start_s = 60\n[loop]"),
        ("[loop]", "[safety]\nwatchdog_ms = 0\n[loop]"),  # off
        ("[bus]", 'name = "my rig-2.0"\n[bus]'),
        ("baud = 1000000", "baud = 57600"),
        ("max_deg = 60", "max_deg = 60\nmax_speed_deg_s = 1\nmax_accel_deg_s2 = 1"),
        (PAN_SPRING, "spring = { frequency_hz = 3.0, damping_ratio = 0.7, response = -100 }"),
    ],
)
def test_values_at_the_bounds_are_accepted(tmp_path, old, new):
    assert old in BASE
    load_rig(write(tmp_path, BASE.replace(old, new, 1)))


def test_a_spring_needing_more_substeps_than_allowed_says_so(tmp_path):
    # 1e5 Hz at 500 Hz: rk4 needs ~445 substeps, over the cap of 100 (50,000 steps/s)
    text = BASE.replace(PAN_SPRING, "spring = { frequency_hz = 1e5, damping_ratio = 0.7 }")
    with pytest.raises(RigError) as info:
        load_rig(write(tmp_path, text))
    message = str(info.value)
    assert "joints[0].spring (pan) at 500 Hz x 1 substep(s)" in message
    assert "but at most 100 are allowed at 500 Hz: soften the spring" in message


def test_k_1e300_is_refused_promptly_not_hung(tmp_path):
    # it once hung in check_stability; the frequency bound refuses it before the guard runs
    text = BASE.replace(TILT_SPRING, "spring = { m = 1.0, c = 0.8, k = 1e300 }")
    with pytest.raises(RigError, match=r"joints\[1\]\.spring\.k"):
        load_rig(write(tmp_path, text))


def test_default_name_from_an_unusable_file_name_says_how_to_fix_it(tmp_path):
    path = tmp_path / "my,rig.toml"
    path.write_text(BASE)
    with pytest.raises(RigError, match=r"name: .*got 'my,rig' \(the file name; set name = "):
        load_rig(path)


def test_binary_rig_file_is_one_line_naming_the_file(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_bytes(b"[bus]\nport = 1\n\x80\x81\xfe garbage")
    with pytest.raises(RigError) as info:
        load_rig(path)
    assert str(info.value) == (
        f"{path}: not a text file: byte 0x80 on line 3 is not UTF-8 (a rig file is TOML text)"
    )


def test_binary_csv_names_the_csv_file_and_line(tmp_path):
    from hilsim.show.parts import build_targets

    (tmp_path / "anim.csv").write_bytes(b"time_s,pan\n0,0\n1,\xff\xfe\n")
    text = BASE.replace(
        'target = { type = "hold", value_deg = 0 }', 'target = { type = "csv", file = "anim.csv" }'
    )
    rig = load_rig(write(tmp_path, text))
    with pytest.raises(RigError) as info:
        build_targets(rig)
    message = str(info.value)
    assert message.startswith(f"{rig.path}: joints[0].target (pan): ")
    assert f"{tmp_path / 'anim.csv'}:3: not a text file: byte 0xff is not UTF-8" in message
    assert "\n" not in message


def test_csv_with_nul_bytes_is_refused(tmp_path):
    from hilsim.targets.csv_file import CsvAnimation, CsvFormatError

    path = tmp_path / "anim.csv"
    path.write_bytes(b"time_s,pan\n0,0\x00\n")
    with pytest.raises(CsvFormatError, match=r"anim\.csv:2: not a text file: it contains NUL"):
        CsvAnimation.load(path)


def test_tracking_and_telemetry_failure_keys(tmp_path):
    from hilsim.rig import TelemetryFailurePolicy

    rig = load_rig(write(tmp_path, BASE))
    pan = rig.joints[0]
    assert pan.tracking_tolerance_rad == pytest.approx(math.radians(10.0))
    assert pan.tracking_time_s == pytest.approx(0.25)
    assert rig.telemetry.on_failure is TelemetryFailurePolicy.AUTO  # stop unless endless
    text = BASE.replace(
        "max_deg = 60", "max_deg = 60\ntracking_tolerance_deg = 4.5\ntracking_time_ms = 120"
    ).replace("[loop]", '[telemetry]\non_failure = "continue"\n[loop]')
    rig = load_rig(write(tmp_path, text))
    assert rig.joints[0].tracking_tolerance_rad == pytest.approx(math.radians(4.5))
    assert rig.joints[0].tracking_time_s == pytest.approx(0.12)
    assert rig.joints[1].tracking_time_s == pytest.approx(0.25)  # the default, per joint
    assert rig.telemetry.on_failure is TelemetryFailurePolicy.CONTINUE


def test_loading_a_rig_does_not_import_the_sdk():
    import subprocess
    import sys

    code = "import hilsim, hilsim.rig, sys; assert 'dynamixel_sdk' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_read_mode_is_the_drivers():
    from drivers.dynamixel.startup import ReadMode as BusReadMode

    assert ReadMode is BusReadMode


def test_defaults_are_the_dataclass_defaults(tmp_path):
    from hilsim.rig import JointConfig, LoopConfig, SafetyConfig, TelemetryConfig

    rig = load_rig(write(tmp_path, BASE))
    assert rig.loop == LoopConfig(rate_hz=500.0)
    assert rig.safety == SafetyConfig()
    assert rig.telemetry == TelemetryConfig()
    assert rig.bus.baud == 1_000_000 and rig.bus.latency_timer_ms is None
    pan = rig.joints[0]
    for name in ("model", "home_rad", "direction", "max_speed_rad_s", "max_accel_rad_s2"):
        assert getattr(pan, name) == JointConfig.__dataclass_fields__[name].default, name
    assert pan.max_speed_rad_s == pytest.approx(math.radians(180.0))
    assert pan.max_accel_rad_s2 == pytest.approx(math.radians(3000.0))
    assert pan.initial_rad is None


def test_the_joint_table_lists_every_key_when_refusing_one(tmp_path):
    text = BASE.replace('name = "pan"', 'name = "pan"\nhome = 3')
    with pytest.raises(RigError) as info:
        load_rig(write(tmp_path, text))
    message = str(info.value)
    assert "unknown key(s) home in joints[0]; allowed: name, servo_id, model, home_deg," in message
    assert message.endswith("initial_deg, tracking_tolerance_deg, tracking_time_ms")
