"""Bad input on the command line: one clear line (file, key, value, what is allowed), an exit code,
never a traceback or a hang. Rig-level messages in detail are in ``test_rig.py``."""

from __future__ import annotations

import pathlib

import pytest
import serial

from drivers.dxlsim.url import bus_from_url
from hilsim.cli import main
from hilsim.cli import main as hilsim_main
from hilsim.cli._args import parse_baud
from tests.hilsim.test_rig import BASE, PAN_SPRING, TILT_SPRING
from tests.hilsim.test_telemetry import write_synthetic_run


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err
    assert len(lines) == 1, err
    return lines[0]


# -- hilsim run: rig problems stop before the bus is opened, exit 2, one line
@pytest.mark.parametrize(
    ("old", "new", "says"),
    [
        ('name = "pan"', 'name = "pan"\nmodel = "XM999-W999"', "joints[0].model: unknown servo"),
        ("baud = 1000000", "baud = 123", "bus.baud: 123 bit/s is not a servo baud rate"),
        ("rate_hz = 500", "rate_hz = 500\nsubsteps = 10000000", "loop.substeps: must be <= 100"),
        ("[loop]", "[safety]\nexit_retries = 1000000000\n[loop]", "safety.exit_retries"),
        ("[loop]", "[safety]\nsoft_start_s = 1e300\n[loop]", "safety.soft_start_s"),
        ("[loop]", "[safety]\nwatchdog_ms = 30\n[loop]", "nearest are 20 and 40"),
        ("rate_hz = 500", "rate_hz = 500\ncpu = -1", "loop.cpu: must be >= 0"),
        ("max_deg = 60", "max_deg = 60\nmax_accel_deg_s2 = 1e-300", "max_accel_deg_s2"),
        (TILT_SPRING, "spring = { m = 1.0, c = 0.8, k = 1e300 }", "joints[1].spring.k"),
        (PAN_SPRING, PAN_SPRING.replace(" }", ", response = 1e308 }"), "spring.response"),
        ("[bus]", 'name = "../../escape/x"\n[bus]', "name: it names the run directory"),
        (
            PAN_SPRING,
            PAN_SPRING.replace("damping_ratio", "dampng_ratio"),
            "'dampng_ratio': a typo?",
        ),
    ],
)
def test_run_refuses_a_bad_rig_in_one_line(tmp_path, capsys, old, new, says):
    assert old in BASE
    rig = tmp_path / "rig.toml"
    rig.write_text(BASE.replace(old, new, 1))
    out = tmp_path / "out"
    code = main(["run", str(rig), "--virtual-time", "--no-plots", "--out", str(out)])
    line = _one_line(capsys.readouterr().err)
    assert code == 2
    assert str(rig) in line and says in line
    assert not out.exists()  # nothing was written
    assert not (tmp_path.parent / "escape").exists()


def test_a_rehearsal_that_would_never_end_is_refused(tmp_path, capsys):
    # generators only (hold, sine): in virtual time it would run flat out, filling the disk
    rig = tmp_path / "rig.toml"
    rig.write_text(BASE)
    out = tmp_path / "out"
    assert main(["run", str(rig), "--virtual-time", "--no-plots", "--out", str(out)]) == 2
    assert "give --duration with --virtual-time" in _one_line(capsys.readouterr().err)
    assert not out.exists()
    argv = ["run", str(rig), "--virtual-time", "--no-plots", "--out", str(out), "--duration", "0.1"]
    assert main(argv) == 0


def test_run_refuses_a_binary_rig_in_one_line(tmp_path, capsys):
    rig = tmp_path / "rig.toml"
    rig.write_bytes(bytes(range(256)))
    assert main(["run", str(rig), "--virtual-time", "--no-plots"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert (
        f"{rig}: not a text file: byte 0x80 on line 2 is not UTF-8" in line
    )  # byte 10 is the one newline before it


# -- hilsim scan --baud: the help's own notation, and one line for anything else
@pytest.mark.parametrize(
    ("text", "bps"),
    [("1M", 1_000_000), ("57.6k", 57_600), ("115.2K", 115_200), ("4.5M", 4_500_000),
     ("1000000", 1_000_000), ("9600", 9_600), ("2m", 2_000_000), ("3Mbps", 3_000_000)],
)  # fmt: skip
def test_scan_baud_notation(text, bps):
    assert parse_baud(text) == bps


def test_scan_accepts_1M_as_the_help_writes_it(capsys):
    assert (
        main(["scan", "--port", "dxlsim://?ids=1-2&clock=virtual", "--baud", "1M", "--ids", "1-3"])
        == 0
    )
    assert len(capsys.readouterr().out.splitlines()) == 2


@pytest.mark.parametrize(
    ("baud", "says"),
    [
        ("1.5M", "the servos do not run at that rate; allowed: 9.6k (9600), 57.6k (57600)"),
        ("123", "the servos do not run at that rate"),
        ("fast", "not a baud rate (write 1000000 or 1M); allowed:"),
        ("1e6", "not a baud rate"),
    ],
)
def test_scan_refuses_a_bad_baud_in_one_line(capsys, baud, says):
    assert main(["scan", "--port", "dxlsim://?ids=1", "--baud", baud]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"hilsim scan: --baud '{baud}': ") and says in line


def test_scan_with_a_bad_emulator_url_is_a_usage_error(capsys):
    assert main(["scan", "--port", "dxlsim://?ids=1&model=XM999", "--baud", "1M"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert err.splitlines()[-1].startswith("hilsim scan: 'dxlsim://?ids=1&model=XM999': model: ")


# -- dxlsim:// URLs: the ValueError that reaches the user is one line naming the key
@pytest.mark.parametrize(
    ("query", "says"),
    [
        ("idz=1", "unknown key(s) idz; allowed: ids, model, baud"),
        ("ids=abc", "ids: bad servo ID 'abc'"),
        ("ids=1-999", "ids: servo IDs must be 0..252, got 253, 254, 255, 256, 257 … (747 in all)"),
        ("model=XM999", "model: unknown servo model 'XM999'; known: XM430-W350"),
        ("faults=brownout:at=4", "faults: 'brownout:at=4': brownout is an event on one servo"),
        ("faults=dorp:id=1", "faults: unknown fault kind 'dorp' in 'dorp:id=1'; choose from:"),
        ("faults=drop:id=1,nbytes=0", "faults: 'drop:id=1,nbytes=0': drop: nbytes must be >= 1"),
        ("baud=1M", "baud: expected bit/s as an integer, e.g. 1000000, got '1M'"),
        ("baud=123", "baud: XM430-W350 does not support 123 bps"),
        ("rdt_us=501", "rdt_us: return_delay_us must be a multiple of 2 in 0..508, got 501"),
        ("rdt_us=nan", "rdt_us: expected µs, a multiple of 2 in 0..508, got 'nan'"),
        ("latency_ms=inf", "latency_ms: expected ms, a finite number >= 0"),
        ("turnaround_us=-5", "turnaround_us: expected µs, a finite number >= 0, got '-5'"),
        ("firmware=x", "firmware: expected an integer 0..255, got 'x'"),
        ("seed=1.5", "seed: expected an integer, got '1.5'"),
        ("clock=sundial", "clock: must be 'virtual' or 'real', got 'sundial'"),
    ],
)
def test_bad_dxlsim_url_is_one_line_naming_the_key(query, says):
    url = f"dxlsim://?{query}"
    with pytest.raises(ValueError) as info:
        bus_from_url(url)
    message = str(info.value)
    assert message.startswith(f"{url!r}: ") and says in message
    assert "\n" not in message and len(message) < 400
    # through pyserial (how the driver opens it), the same text
    with pytest.raises(serial.SerialException) as info2:
        serial.serial_for_url(url)
    assert str(info2.value) == message


# -- hilsim plot: options, one line each, exit 2
@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    path = tmp_path_factory.mktemp("run")
    write_synthetic_run(path, seconds=1.0)
    return path


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--dpi", "0"], "--dpi must be 30..300, got 0"),
        (["--dpi", "-5"], "--dpi must be 30..300, got -5"),
        (["--dpi", "100000"], "--dpi must be 30..300, got 100000"),
        (["--start", "5", "--end", "1"], "--start (5 s) must be before --end (1 s)"),
        (["--start", "2", "--end", "2"], "--start (2 s) must be before --end (2 s)"),
        (["--start", "nan"], "--start must be a finite time in s, got nan"),
        (["--end", "inf"], "--end must be a finite time in s, got inf"),
    ],
)
def test_plot_refuses_bad_options_in_one_line(run_dir, capsys, args, says):
    assert hilsim_main(["plot", str(run_dir), *args]) == 2
    assert _one_line(capsys.readouterr().err) == f"hilsim plot: {says}"
    assert not (run_dir / "plots").exists()


def test_plot_out_pointing_at_a_file(run_dir, tmp_path, capsys):
    target = tmp_path / "figure.png"
    target.write_bytes(b"x")
    assert hilsim_main(["plot", str(run_dir), "--out", str(target)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line == f"hilsim plot: --out {target}: exists and is not a directory"
    assert hilsim_main(["plot", str(run_dir), "--out", str(target / "sub")]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line == f"hilsim plot: --out {target / 'sub'}: {target} is not a directory"


def test_plot_window_without_ticks_says_what_the_run_covers(run_dir, capsys):
    assert hilsim_main(["plot", str(run_dir), "--start", "50", "--end", "60"]) == 1
    line = _one_line(capsys.readouterr().err)
    assert line.startswith("hilsim plot: no ticks between 50.0 and 60.0 s; the run covers 0..")


def test_a_home_relative_path_is_the_users_home(tmp_path, monkeypatch, capsys):
    """``~/anim.csv`` in a rig, ``out_dir = "~/runs"``: the user's home, as in a shell."""
    from hilsim.show.run_dir import make_run_dir
    from hilsim.targets.sources import rig_file

    monkeypatch.setenv("HOME", str(tmp_path))
    assert rig_file(pathlib.Path("/elsewhere"), "~/anim.csv") == tmp_path / "anim.csv"
    assert rig_file(tmp_path / "rigs", "anim.csv") == tmp_path / "rigs" / "anim.csv"
    run = make_run_dir(None, "~/runs", "demo").path
    assert run.parent == tmp_path / "runs" and run.is_dir()
    assert make_run_dir("~/out", "runs", "demo").path == tmp_path / "out"
    rig = tmp_path / "rig.toml"
    rig.write_text(BASE)
    argv = ["run", str(rig), "--virtual-time", "--duration", "0.1", "--no-plots"]
    assert main([*argv, "--out", "~nosuchuser4711/out"]) == 2  # (it was a traceback)
    assert "no such user's home" in _one_line(capsys.readouterr().err)


@pytest.mark.parametrize(
    ("port", "says"),
    [
        ("/dev/ttyUSB97", "is the USB adapter plugged in?"),
        ("dxlsim:/?ids=1-4", "begin with dxlsim://, e.g. dxlsim://?ids=1-4"),
    ],
)
def test_a_port_that_cannot_be_opened_says_what_to_try(tmp_path, capsys, port, says):
    rig = tmp_path / "rig.toml"
    rig.write_text(BASE)
    argv = ["run", str(rig), "--port", port, "--duration", "1", "--no-plots"]
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"cannot open {port}" in line and says in line


def test_a_port_one_may_not_open_names_the_group(tmp_path):
    from drivers.dynamixel.link import port_hint

    device = tmp_path / "ttyUSB0"
    device.touch()
    assert "dialout" in port_hint(str(device), "[Errno 13] Permission denied: '/dev/ttyUSB0'")
    assert port_hint(str(device), "[Errno 16] Device or resource busy") == ""
    assert port_hint("dxlsim://?ids=1", "anything") == ""
