"""``hilsim setup`` and the one refusal on Feetech STS and Dynamixel Protocol 1.0 (AX) buses.

Factory-state emulated servos at a rate the rig does not ask and Return Delay 500 µs: ``hilsim
run`` refuses once with one table (every servo's baud and Return Delay, each row naming its
joint and the ``hilsim setup`` command); ``hilsim setup --yes`` fixes them (Feetech: Lock
opened for the EEPROM writes and closed after; the values kept over a power cycle) and reads
them back; the run then runs, exit 0.
"""

from __future__ import annotations

import itertools
import os

import pytest

from drivers.dxlsim import register_bus, unregister_bus
from drivers.dxlsim.url import DxlsimUrl
from hilsim.cli import main
from hilsim.exit_codes import ExitCode

RIG = """
name = "arm"
[bus]
port = "PORT"
baud = 1000000
return_delay_us = 0
[loop]
rate_hz = RATE
[safety]
soft_start_s = 0.1
[[joints]]
name = "base"
servo_id = 1
model = "MODEL"
min_deg = -60
max_deg = 60
spring = { frequency_hz = 5.0, damping_ratio = 0.9 }
target = { type = "hold", value_deg = 0 }
[[joints]]
name = "elbow"
servo_id = 2
model = "MODEL"
min_deg = -40
max_deg = 40
spring = { frequency_hz = 5.0, damping_ratio = 0.9 }
target = { type = "hold", value_deg = 5 }
[[joints]]
name = "gripper"
servo_id = 3
model = "MODEL"
min_deg = 0
max_deg = 30
spring = { frequency_hz = 5.0, damping_ratio = 0.9 }
target = { type = "hold", value_deg = 10 }
"""

_names = itertools.count()


@pytest.fixture
def factory(tmp_path):
    """``make(model, baud, rate_hz=250, ids="1-3")``: a named emulated bus of factory-state
    servos (Return Delay 500 µs) at ``baud``, and a rig on it asking 1 Mbit/s and Return
    Delay 0; returns (rig path, the bus)."""
    names = []

    def make(model: str, baud: int, rate_hz: int = 250, ids: str = "1-3"):
        url = DxlsimUrl.parse(
            f"dxlsim://?ids={ids}&model={model}&baud={baud}&rdt_us=500&clock=virtual"
        )
        bus = url.build_bus(host_baud=1_000_000)
        name = f"p1setup{os.getpid()}-{next(_names)}"
        register_bus(name, bus)
        names.append(name)
        text = RIG.replace("PORT", f"dxlsim://{name}").replace("MODEL", model)
        path = tmp_path / f"{name}.toml"
        path.write_text(text.replace("RATE", str(rate_hz)))
        return path, bus

    yield make
    for n in names:
        unregister_bus(n)


def _run(path, out) -> int:
    return main(
        ["run", str(path), "--virtual-time", "--no-plots", "--duration", "1", "--out", str(out)]
    )


@pytest.mark.parametrize(("model", "baud"), [("STS3215", 115_200), ("AX-12A", 57_600)])
def test_factory_servos_refused_once_then_setup_then_the_show_runs(
    factory, tmp_path, capsys, model, baud
):
    path, bus = factory(model, baud)
    assert _run(path, tmp_path / "a") == ExitCode.USAGE
    err = capsys.readouterr().err
    assert err.count("do not match") == 1, err
    table = [ln for ln in err.splitlines() if ln[:1].isdigit()]
    for sid, joint in ((1, "base"), (2, "elbow"), (3, "gripper")):
        rows = [ln.split() for ln in table if ln.split()[0] == str(sid)]
        items = {" ".join(r[2:5]) for r in rows}
        assert all(r[1] == joint for r in rows), rows
        assert any(i.startswith("baud") for i in items), items
        assert any(i.startswith("Return Delay Time") for i in items), items
    assert f"{baud} bit/s (answers there, not at 1000000)" in err
    assert f"hilsim setup {path} --port dxlsim://" in err

    assert main(["setup", str(path)]) == ExitCode.OK  # a dry run writes nothing
    assert all(s.baud == baud for s in bus.servos)
    out = capsys.readouterr()
    assert "Return Delay Time  500 us (250)  0 us (0)" in out.out
    assert "run again with --yes" in out.err

    assert main(["setup", str(path), "--yes"]) == ExitCode.OK
    out = capsys.readouterr()
    assert f"{baud} bit/s: 1 ({model}), 2 ({model}), 3 ({model})" in out.err
    assert "read back at 1000000 bit/s" in out.out
    assert "done: 3 servo(s) read back" in out.err
    assert all(s.baud == 1_000_000 and s.raw("Return Delay Time") == 0 for s in bus.servos)

    assert _run(path, tmp_path / "b") == ExitCode.OK, capsys.readouterr().err


def test_feetech_setup_unlocks_for_eeprom_and_relocks_kept_over_power_off(factory, capsys):
    path, bus = factory("STS3215", 1_000_000)
    assert main(["setup", str(path), "--yes"]) == ExitCode.OK
    for s in bus.servos:
        assert s.raw("Lock") == 1  # relocked
        s.brownout(s._now)  # power off and on: EEPROM from flash
        assert s.raw("Return Delay Time") == 0
    assert "Return Delay Time" in capsys.readouterr().out


def test_setup_renames_a_feetech_servo(factory, capsys):
    path, bus = factory("STS3215", 1_000_000, ids="1,2,7")
    assert main(["setup", str(path), "--id", "7:3", "--yes"]) == ExitCode.OK
    assert sorted(s.id for s in bus.servos) == [1, 2, 3]
    rows = [ln.split() for ln in capsys.readouterr().out.splitlines()]
    assert ["7", "(gripper)", "@", "1000000", "ID", "7", "3"] in rows


def test_the_p1_capacity_check_is_a_row_of_the_one_table(factory, tmp_path, capsys):
    path, _ = factory("STS3215", 115_200, rate_hz=1000)
    assert _run(path, tmp_path / "a") == ExitCode.USAGE
    err = capsys.readouterr().err
    assert err.count("do not match") == 1
    cap = [ln for ln in err.splitlines() if ln.startswith("bus ")]
    assert len(cap) == 1 and "bus capacity" in cap[0] and "hilsim setup" in cap[0], err
    assert "the bus cannot carry 1000 Hz as the servos are now" in err


def test_a_capacity_setup_cannot_cure_names_the_rate_key(factory, tmp_path, capsys):
    path, _ = factory("STS3215", 1_000_000, rate_hz=2000)
    assert _run(path, tmp_path / "a") == ExitCode.USAGE
    err = capsys.readouterr().err
    cap = [ln for ln in err.splitlines() if ln.startswith("bus ")]
    assert len(cap) == 1 and "loop.rate_hz = " in cap[0], err
    assert "even after setup" in err


def test_a_silent_p1_servo_names_its_joint_and_who_answered(factory, tmp_path, capsys):
    path, _ = factory("STS3215", 1_000_000, ids="1,2")
    assert _run(path, tmp_path / "a") == ExitCode.USAGE
    err = capsys.readouterr().err
    row = next(ln for ln in err.splitlines() if ln.startswith("3 "))
    assert "gripper" in row and "answers Ping" in row
    assert "rig IDs answering at 1000000: 1, 2; no answer at any other baud" in row


def test_scan_of_an_emulated_sts_url_without_protocol_says_feetech(capsys):
    assert main(["scan", "--port", "dxlsim://?ids=1-3&model=STS3215"]) == ExitCode.USAGE
    err = capsys.readouterr().err
    assert "emulates STS3215 servos" in err and "try --protocol feetech" in err
    assert len(err.strip().splitlines()) == 1


def test_scan_without_protocol_finds_feetech_servos_by_their_own_ping(factory, capsys):
    path, _ = factory("STS3215", 1_000_000)
    url = path.read_text().split('port = "')[1].split('"')[0]  # a named bus, as hardware is
    assert main(["scan", "--port", url, "--ids", "0-3", "--baud", "1M"]) == ExitCode.NOTHING_FOUND
    err = capsys.readouterr().err
    assert (
        "Feetech servos answer their own Ping (IDs 1, 2, 3 at 1000000 bit/s): try --protocol "
        "feetech" in err
    )


@pytest.mark.parametrize("model", ["STS3215", "AX-12A"])
def test_setup_fixes_a_quiet_status_level_and_wheel_mode(factory, tmp_path, capsys, model):
    """Servos answering Ping only (Dynamixel Status Return Level 0; Feetech Response Status
    Level 0: no reply to writes) in wheel mode (angle limits 0..0): the refusal says what to
    run, setup writes them, the run runs."""
    path, bus = factory(model, 57_600)
    for s in bus.servos:
        s.set_value("Status Return Level" if s.dxl else "Response Status Level", 0)
        s.set_value("CW Angle Limit" if s.dxl else "Min Position Limit", 0)
        s.set_value("CCW Angle Limit" if s.dxl else "Max Position Limit", 0)
    assert _run(path, tmp_path / "a") == ExitCode.USAGE
    err = capsys.readouterr().err
    assert err.count("do not match") == 1 and f"hilsim setup {path}" in err
    assert main(["setup", str(path), "--yes"]) == ExitCode.OK, capsys.readouterr().err
    assert "is a model unread" not in capsys.readouterr().err
    assert _run(path, tmp_path / "b") == ExitCode.OK, capsys.readouterr().err


def test_setup_of_a_bus_mixing_ax_and_mx_servos(factory, tmp_path, capsys):
    """AX and MX servos share a Protocol 1.0 bus (their limits in their own ticks)."""
    path, _ = factory("AX-12A", 57_600)
    text = path.read_text().replace('model = "AX-12A"', 'model = "MX-64"', 1)
    path.write_text(text)
    url = DxlsimUrl.parse("dxlsim://?ids=1-3&model=1:MX-64,AX-12A&baud=57600&rdt_us=500")
    mixed = url.replace(clock="virtual").build_bus(host_baud=1_000_000)
    register_bus(str(path.stem), mixed)  # the same name: the rig now opens the mixed bus
    assert main(["setup", str(path), "--yes"]) == ExitCode.OK, capsys.readouterr().err
    out = capsys.readouterr()
    assert "57600 bit/s: 1 (MX-64), 2 (AX-12A), 3 (AX-12A)" in out.err
    assert "done: 3 servo(s) read back" in out.err
    mx, ax = mixed.servos[0], mixed.servos[1]
    assert mx.raw("CCW Angle Limit") == 4095 and ax.raw("CCW Angle Limit") == 1023
    assert all(s.baud == 1_000_000 and s.raw("Return Delay Time") == 0 for s in mixed.servos)
    assert _run(path, tmp_path / "b") == ExitCode.OK, capsys.readouterr().err
