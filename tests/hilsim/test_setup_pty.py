"""The factory-servo day on a pseudo-terminal, as a user types it: ``hilsim emulate`` serves
factory-state servos (57600 bit/s, Return Delay 500 µs); ``hilsim run`` refuses once with one
table; ``hilsim setup --yes`` changes the servos' baud (the pty's host side follows) and reads
back; ``hilsim run`` then runs the show. Asserts behaviour, not speed."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.emulate_pty import emulated_pty
from tests.hilsim.test_servo_setup import RIG

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a Linux pty")


def _emulate(model: str, baud: int):
    args = ("--ids", "1-3", "--model", model, "--baud", str(baud), "--rdt-us", "500")
    with emulated_pty(*args) as (_proc, path):
        yield path


@pytest.fixture
def factory_pty():
    yield from _emulate("XL430-W250", 57_600)


@pytest.fixture
def factory_sts_pty():
    yield from _emulate("STS3215", 115_200)


def _hilsim(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hilsim", *args], capture_output=True, text=True, timeout=300
    )


def _refused_then_setup_then_runs(rig, pty: str, tmp_path, found: str) -> None:
    """`hilsim run` refused once (every mismatch in one table, the setup command named),
    `hilsim setup --yes` finds the servos (``found``) and reads them back, then the show runs."""
    run = ["run", str(rig), "--duration", "1", "--no-plots", "--out"]
    first = _hilsim(*run, str(tmp_path / "a"))
    assert first.returncode == 2, first.stderr
    assert first.stderr.count("do not match") == 1
    for item in ("baud", "Return Delay Time"):
        assert first.stderr.count(f"  {item} ") == 3, first.stderr
    assert f"hilsim setup {rig} --port {pty} --yes" in first.stderr

    setup = _hilsim("setup", str(rig), "--port", pty, "--yes")
    assert setup.returncode == 0, setup.stderr + setup.stdout
    assert found in setup.stderr
    assert "read back at 1000000 bit/s" in setup.stdout

    second = _hilsim(*run, str(tmp_path / "b"))
    assert second.returncode == 0, second.stderr


def test_refused_once_then_setup_on_the_pty_then_the_show_runs(factory_pty, tmp_path):
    rig = tmp_path / "skull.toml"
    rig.write_text(RIG.replace("PORT", factory_pty).replace("rate_hz = 250", "rate_hz = 50"))
    found = "57600 bit/s: 1 (XL430-W250), 2 (XL430-W250), 3 (XL430-W250)"
    _refused_then_setup_then_runs(rig, factory_pty, tmp_path, found)


def test_feetech_refused_once_then_setup_on_the_pty_then_the_show_runs(factory_sts_pty, tmp_path):
    """The same day with three STS3215 at 115200 bit/s: found by Feetech's broadcast Ping."""
    from tests.hilsim.test_p1_setup import RIG as P1RIG

    rig = tmp_path / "arm.toml"
    text = P1RIG.replace("PORT", factory_sts_pty).replace("MODEL", "STS3215")
    rig.write_text(text.replace("RATE", "50"))
    found = "115200 bit/s: 1 (STS3215), 2 (STS3215), 3 (STS3215)"
    _refused_then_setup_then_runs(rig, factory_sts_pty, tmp_path, found)
