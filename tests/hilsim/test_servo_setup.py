"""``hilsim setup`` and the start-up check's one refusal, from factory-state servos.

Factory state as a buyer has it: 57600 bit/s, Return Delay Time 500 µs (IDs already made
unique). The rig asks 1 Mbit/s and Return Delay 0: the run refuses once naming every problem;
``hilsim setup --yes`` fixes them and reads them back; the run then runs, exit 0.
"""

from __future__ import annotations

import itertools
import os
from pathlib import Path

import pytest

import hilsim
from drivers.clock import VirtualClock
from drivers.dxlsim import DxlBus, VirtualServo, register_bus, unregister_bus
from drivers.dxlsim.protocol import Instruction, StreamParser
from hilsim.cli import main
from hilsim.exit_codes import ExitCode

RIG = """
name = "skull"
[bus]
port = "PORT"
baud = 1000000
return_delay_us = 0
[loop]
rate_hz = 250
[safety]
soft_start_s = 0.1
[[joints]]
name = "jaw"
servo_id = 1
model = "XL430-W250"
min_deg = 0
max_deg = 25
spring = { frequency_hz = 5.0, damping_ratio = 0.9 }
target = { type = "hold", value_deg = 5 }
[[joints]]
name = "pan"
servo_id = 2
model = "XL430-W250"
min_deg = -60
max_deg = 60
spring = { frequency_hz = 5.0, damping_ratio = 0.9 }
target = { type = "hold", value_deg = 0 }
[[joints]]
name = "tilt"
servo_id = 3
model = "XL430-W250"
min_deg = -30
max_deg = 30
spring = { frequency_hz = 5.0, damping_ratio = 0.9 }
target = { type = "hold", value_deg = 0 }
"""

_names = itertools.count()


@pytest.fixture
def factory(tmp_path):
    """A named emulated bus of three factory-state XL430-W250s (IDs 1-3) and a rig file
    (text changes via ``edit``) on it; yields ``make(edit=None, ids=(1, 2, 3))``."""
    names = []

    def make(edit=None, ids=(1, 2, 3), **servo_kw):
        servos = [
            VirtualServo("XL430-W250", i, baud=57_600, return_delay_us=500, t=0.0, **servo_kw)
            for i in ids
        ]
        bus = DxlBus(servos, baud=1_000_000, clock=VirtualClock(), latency_timer_ms=1.0, trace=True)
        name = f"setup{os.getpid()}-{next(_names)}"
        register_bus(name, bus)
        names.append(name)
        text = RIG.replace("PORT", f"dxlsim://{name}")
        if edit is not None:
            text = edit(text)
        path = tmp_path / f"{name}.toml"
        path.write_text(text)
        return bus, path

    yield make
    for n in names:
        unregister_bus(n)


def _writes(bus: DxlBus) -> list[int]:
    return [
        f.packet.instruction
        for rec in bus.trace or ()
        if rec.direction == "tx"
        for f in StreamParser().feed(rec.data)
        if f.packet.instruction in (Instruction.WRITE, Instruction.SYNC_WRITE)
    ]


def _refusal(path: Path, tmp_path: Path) -> str:
    with pytest.raises(hilsim.ShowRefusedError) as info, hilsim.Show(path, out=tmp_path / "r"):
        pytest.fail("a show started on factory servos")
    return str(info.value)


def test_factory_servos_refused_once_then_setup_then_the_show_runs(factory, tmp_path, capsys):
    bus, path = factory()
    text = _refusal(path, tmp_path)
    table = text.splitlines()
    # one table naming every problem: each servo's baud and Return Delay Time, the capacity
    for sid, joint in ((1, "jaw"), (2, "pan"), (3, "tilt")):
        rows = [line for line in table if line.startswith(f"{sid} ")]
        assert any(joint in r and "baud" in r and "57600 bit/s" in r for r in rows), text
        assert any("Return Delay Time" in r and "500 us" in r for r in rows), text
        assert all(f"hilsim setup {path} --port dxlsim://" in r for r in rows), text
    assert any(line.startswith("bus") and "bus capacity" in line for line in table), text
    assert "after setup" in text
    assert not _writes(bus), "the check wrote to a servo"

    assert main(["setup", str(path)]) == ExitCode.OK  # a dry run writes nothing
    out = capsys.readouterr()
    assert "Return Delay Time" in out.out and "nothing written" in out.err
    assert "57600 bit/s: 1 (XL430-W250), 2 (XL430-W250), 3 (XL430-W250)" in out.err
    assert not _writes(bus)

    assert main(["setup", str(path), "--yes"]) == ExitCode.OK
    out = capsys.readouterr()
    assert "read back at 1000000 bit/s" in out.out and "done: 3 servo(s)" in out.err
    assert all(s.baud == 1_000_000 and s.return_delay_s == 0 for s in bus.servos)

    with hilsim.Show(path, out=tmp_path / "run", duration=0.5) as show:
        result = show.run()
    assert result.exit_code == ExitCode.OK


def test_model_row_names_the_rig_key_and_the_joint(factory, tmp_path):
    _bus, path = factory(
        lambda t: t.replace('model = "XL430-W250"\nmin_deg = -60', "min_deg = -60")
    )
    text = _refusal(path, tmp_path)
    row = next(line for line in text.splitlines() if " model " in line)
    assert row.startswith("2 ") and "pan" in row
    assert 'joints[1].model = "XL430-W250"' in row


def test_a_silent_servo_names_its_joint_and_who_answered(factory, tmp_path):
    edit = lambda t: t.replace("servo_id = 3", "servo_id = 4")  # noqa: E731
    _bus, path = factory(edit)
    main(["setup", str(path), "--yes"])  # 1 and 2 set up; 3 is not the rig's, 4 is nowhere
    text = _refusal(path, tmp_path)
    row = next(line for line in text.splitlines() if line.startswith("4 "))
    assert "tilt" in row and "answers Ping" in row
    assert "IDs answering at 1000000: 1, 2" in row and "no answer at any other baud" in row


def test_setup_renames_an_id(factory, tmp_path, capsys):
    bus, path = factory(ids=(1, 2, 7))
    assert main(["setup", str(path), "--yes", "--id", "7:3"]) == ExitCode.OK
    assert sorted(s.id for s in bus.servos) == [1, 2, 3]
    assert "ID" in capsys.readouterr().out


def test_setup_says_which_servo_is_nowhere(factory, tmp_path, capsys):
    _bus, path = factory(ids=(1, 2))
    assert main(["setup", str(path)]) == ExitCode.USAGE
    assert "not found at any baud: servo(s) 3 (tilt)" in capsys.readouterr().err


def test_capacity_the_setup_cannot_cure_names_the_rate(factory, tmp_path):
    _bus, path = factory(lambda t: t.replace("baud = 1000000", "baud = 57600"))
    text = _refusal(path, tmp_path)
    row = next(line for line in text.splitlines() if line.startswith("bus"))
    assert "loop.rate_hz = " in row and "even after setup" in text


def test_bad_id_flag_is_one_line(factory, capsys):
    _bus, path = factory()
    assert main(["setup", str(path), "--id", "7-3"]) == ExitCode.USAGE
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "OLD:NEW" in err


def test_plan_widens_limits_and_keeps_shutdown_bits():
    from drivers.dynamixel.configure import X_SERIES, Found, Settings, Target, plan

    found = Found(1, 57_600, 1060, "XL430-W250", 46)
    now = {
        "return_delay": 0,
        "mode": 3,
        "min_position": 1000,
        "max_position": 3000,
        "shutdown": 0x01,
        "status_return": 2,
    }
    target = Target(1, 57_600, position_ticks=(900, 2500), shutdown_bits=0x34)
    changes = {c.key: c for c in plan(X_SERIES, found, Settings(now), target)}
    assert set(changes) == {"min_position", "shutdown"}
    assert changes["min_position"].wanted == 900  # widened, never narrowed
    assert changes["shutdown"].wanted == 0x35  # the servo's own bits kept


def test_a_speed_beyond_the_models_no_load_speed_is_a_warning_naming_both(tmp_path, caplog):
    from hilsim.rig import load_rig

    path = tmp_path / "rig.toml"
    text = RIG.replace("PORT", "dxlsim://?ids=1-3").replace("baud = 1000000\n", "")
    path.write_text(text.replace("servo_id = 1\n", "servo_id = 1\nmax_speed_deg_s = 400\n"))
    with caplog.at_level("WARNING", logger="hilsim.rig"):
        load_rig(path)
    (msg,) = [r.getMessage() for r in caplog.records]
    assert "joints[0].max_speed_deg_s (jaw) = 400 °/s" in msg
    assert "XL430-W250's no-load speed, 342 °/s (57 rpm)" in msg


def test_the_warning_reaches_the_command_line(tmp_path, capsys):
    path = tmp_path / "rig.toml"
    text = RIG.replace("PORT", "dxlsim://?ids=1-3&model=XL430-W250&rdt_us=0&latency_ms=1")
    path.write_text(text.replace("servo_id = 2\n", "servo_id = 2\nmax_speed_deg_s = 500\n"))
    assert main(["tracks", str(path), "--at", "0"]) == ExitCode.OK
    err = capsys.readouterr().err
    assert "hilsim tracks: " in err and "(pan) = 500 °/s is beyond the XL430-W250's" in err


def test_scan_says_each_baud_as_it_goes(capsys):
    port = "dxlsim://?ids=1-3&baud=57600&latency_ms=1&clock=virtual"
    assert main(["scan", "--port", port, "--ids", "0-9", "--baud", "57600", "--baud", "1M"]) == 0
    err = capsys.readouterr().err
    assert "57600 bit/s: IDs 1, 2, 3 (" in err
    assert "1000000 bit/s: no answer to a broadcast Ping; pinging 10 IDs one by one" in err
    assert "1000000 bit/s: none (" in err


def test_factory_servos_one_at_a_time_each_get_their_rig_id(factory, capsys):
    bus, path = factory(ids=(1,))  # the second servo of the figure, fresh from the box
    assert main(["setup", str(path), "--id", "1:2", "--yes"]) == ExitCode.OK
    assert [s.id for s in bus.servos] == [2]
    assert "not found at any baud: servo(s) 3 (tilt)" in capsys.readouterr().err


@pytest.mark.parametrize("level", [0, 1])
def test_setup_fixes_mode_limits_shutdown_and_a_quiet_status_level(factory, tmp_path, level):
    kw = dict(operating_mode=1, min_position_limit=1800, max_position_limit=2300, shutdown=0)
    bus, path = factory(status_return_level=level, **kw)
    assert main(["setup", str(path), "--yes"]) == ExitCode.OK
    for s in bus.servos:
        regs = s._regs
        assert s.status_return_level == 2 and s.baud == 1_000_000
        assert regs[11] == 3 and regs[63] & 0x34 == 0x34
    pan = bus.servo(2)._regs
    assert (pan[52], pan[48]) == (2048 - 683, 2048 + 683)  # widened to +-60 deg, no more
    # wide enough already: kept, when it could be read (level 0 answers Ping only: the
    # limits are then the joint's range)
    assert bus.servo(1)._regs[52] == (2048 if level == 0 else 1800)
    with hilsim.Show(path, out=tmp_path / "run", duration=0.2) as show:
        assert show.run().exit_code == ExitCode.OK


def test_the_refusal_names_mode_and_shutdown_with_the_setup_command(factory, tmp_path):
    _bus, path = factory(operating_mode=1, shutdown=0)
    rows = _refusal(path, tmp_path).splitlines()
    for item in ("Operating Mode", "Shutdown (torque cut on)", "Return Delay Time", "baud"):
        hits = [r for r in rows if f"  {item}  " in r]
        assert len(hits) == 3 and all("hilsim setup" in r and "--yes" in r for r in hits), rows
