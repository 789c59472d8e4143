"""Several buses in one rig: the `[buses.<name>]` form, the split into per-bus rigs, each bad form
refused in one line; the group's exit code and its side-by-side rows (no process started here;
the processes: test_multibus_run.py)."""

from __future__ import annotations

import json
import pathlib
import re
import signal

import pytest

from hilsim.cli import main
from hilsim.rig import RigError, load_rig, load_rigs
from hilsim.show.group import (
    BusOutcome,
    bus_outcome,
    bus_row,
    child_argv,
    first_stop,
    format_rows,
    group_code,
    parse_stopping,
    stopping_line,
    worst_code,
)

CONFIGS = pathlib.Path(__file__).resolve().parents[2] / "configs"

JOINT = """
[[joints]]
name = "{name}"
{bus}servo_id = {sid}
min_deg = -60
max_deg = 60
spring = {{ frequency_hz = 3.0, damping_ratio = 0.7 }}
target = {{ type = "sine", amplitude_deg = 10, frequency_hz = 0.5 }}
"""

TWO = (
    """
name = "fig"
[buses.arm]
port = "dxlsim://?ids=1-2&rdt_us=0"
baud = 1000000
[buses.leg]
port = "dxlsim://?ids=1-3&rdt_us=0"
baud = 2000000
read = "plain"
[loop]
rate_hz = 250
"""
    + JOINT.format(name="a1", bus='bus = "arm"\n', sid=1)
    + JOINT.format(name="l1", bus='bus = "leg"\n', sid=1)
    + JOINT.format(name="a2", bus='bus = "arm"\n', sid=2)
    + JOINT.format(name="l3", bus='bus = "leg"\n', sid=3)
)


def write(tmp_path, text: str) -> pathlib.Path:
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def refused(tmp_path, text: str, **kw) -> str:
    with pytest.raises(RigError) as info:
        load_rigs(write(tmp_path, text), **kw)
    message = str(info.value)
    assert "\n" not in message
    return message


# ------------------------------------------------------------------------------ the forms
def test_two_buses_split_into_one_rig_each_with_its_joints_in_file_order(tmp_path):
    arm, leg = load_rigs(write(tmp_path, TWO))
    assert (arm.bus_name, leg.bus_name) == ("arm", "leg")
    assert arm.joint_names == ("a1", "a2") and arm.servo_ids == (1, 2)
    assert leg.joint_names == ("l1", "l3") and leg.servo_ids == (1, 3)  # ID 1 on each bus
    assert (arm.bus.baud, leg.bus.baud, leg.bus.read.value) == (1_000_000, 2_000_000, "plain")
    assert arm.buses == (("arm", arm.bus),) and leg.buses == (("leg", leg.bus),)
    assert arm.loop == leg.loop and arm.safety == leg.safety and arm.name == leg.name == "fig"
    assert {j.bus for j in arm.joints} == {"arm"}


def test_load_rig_picks_one_bus_and_a_several_bus_rig_needs_one(tmp_path):
    path = write(tmp_path, TWO)
    assert load_rig(path, bus="leg").joint_names == ("l1", "l3")
    with pytest.raises(RigError, match=r"on 2 buses \(arm, leg\); give --bus NAME"):
        load_rig(path)
    with pytest.raises(RigError, match=r"no bus named 'hip'; this rig's: arm, leg"):
        load_rig(path, bus="hip")


def test_the_one_bus_form_is_unchanged():
    (rig,) = load_rigs(CONFIGS / "demo.toml")
    assert rig.bus_name is None and rig.buses == ()
    assert all(j.bus is None for j in rig.joints)
    again = load_rig(CONFIGS / "demo.toml")
    assert (again.bus, again.joint_names, again.buses) == (rig.bus, rig.joint_names, ())
    with pytest.raises(RigError, match=r"has one \[bus\] and no \[buses.<name>\] tables"):
        load_rig(CONFIGS / "demo.toml", bus="arm")


def test_one_named_bus_needs_no_bus_key_on_its_joints(tmp_path):
    text = TWO.split("[buses.leg]")[0] + "[loop]\nrate_hz = 250\n"
    text += JOINT.format(name="a1", bus="", sid=1)
    (rig,) = load_rigs(write(tmp_path, text))
    assert rig.bus_name == "arm" and rig.joints[0].bus == "arm"


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (('bus = "leg"\nservo_id = 3', 'bus = "hip"\nservo_id = 3'),
         r"joints\[3\]\.bus: no bus named 'hip'; this rig's: arm, leg"),
        (('bus = "leg"\nservo_id = 3', 'bus = "leg"\nservo_id = 1'),
         r"joints\[3\]\.servo_id: servo_id 1 is already used by joints\[1\] on bus 'leg'"),
        (("ids=1-3&rdt_us=0", "ids=1-2&rdt_us=0"),
         r"buses\.leg\.port: 'dxlsim://\?ids=1-2&rdt_us=0' is already the port of buses\.arm: "
         r"one port is one bus"),
        (('bus = "leg"\nservo_id = 3', "servo_id = 3"),
         r"joints\[3\]\.bus: missing: this rig has 2 buses \(arm, leg\); name the one servo 3"),
        (("[buses.leg]", "[buses.the_leg]"), r"joints\[1\]\.bus: no bus named 'leg'"),
        (("[buses.leg]", "[buses.'le g']"), r"buses\.le g: a bus name names its run directory"),
        (('read = "plain"', 'read = "plain"\nspeed = 3'),
         r"unknown key\(s\) speed in buses\.leg; allowed: port, baud, read, latency_timer_ms"),
        (("baud = 2000000", "baud = 2000001"), r"buses\.leg\.baud: 2000001 bit/s is not a servo"),
        (('name = "fig"', 'name = "fig"\n[bus]\nport = "/dev/ttyUSB0"'),
         r"buses: give one \[bus\] table or \[buses.<name>\] tables, not both"),
        (('name = "fig"', 'name = "fig"\n[buses.hip]\nport = "dxlsim://?ids=7"'),
         r"buses\.hip: no joint is on this bus \(a joint says bus = \"hip\"\)"),
        (("rate_hz = 250", "rate_hz = 250\ncpu = 1"),
         r"loop\.cpu: would pin every bus's process to one CPU; leave it out"),
    ],
    ids=["unknown-bus", "id-twice-on-a-bus", "two-buses-one-port", "no-bus-key", "renamed",
         "bad-name", "unknown-key", "bad-baud", "bus-and-buses", "empty-bus", "one-cpu"],
)  # fmt: skip
def test_each_bad_form_is_one_line_naming_the_key(tmp_path, change, expected):
    old, new = change
    assert old in TWO
    message = refused(tmp_path, TWO.replace(old, new, 1))
    assert str(tmp_path / "rig.toml") in message
    assert re.search(expected, message), message


def test_two_buses_on_one_device_under_two_names_are_one_port(tmp_path):
    dev = tmp_path / "ttyUSB0"
    dev.write_text("")
    link = tmp_path / "by-id"
    link.symlink_to(dev)
    text = TWO.replace("dxlsim://?ids=1-2&rdt_us=0", str(dev)).replace(
        "dxlsim://?ids=1-3&rdt_us=0", str(link)
    )
    assert "is already the port of buses.arm" in refused(tmp_path, text)


def test_a_joint_may_not_name_a_bus_in_the_one_bus_form(tmp_path):
    text = (CONFIGS / "demo.toml").read_text().replace("servo_id = 1", 'bus = "x"\nservo_id = 1')
    text = text.replace('"demo_animation.csv"', f'"{CONFIGS / "demo_animation.csv"}"')
    message = refused(tmp_path, text)
    assert "joints[0].bus: this rig has one [bus]; name buses with [buses.<name>]" in message


def test_port_override_is_for_the_one_bus_form(tmp_path):
    message = refused(tmp_path, TWO, port="/dev/ttyUSB0")
    assert "--port replaces the port of a rig's one [bus]" in message


def test_the_cli_refuses_bad_bus_choices_in_one_line_exit_2(tmp_path, capsys):
    path = write(tmp_path, TWO)
    for argv in (["--port", "/dev/ttyUSB0"], ["--bus", "hip"]):
        code = main(["run", str(path), "--virtual-time", "--no-plots", *argv])
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1, err
    assert not (tmp_path / "runs").exists()


# ------------------------------------------------------------------------------ the parent
def test_the_worst_bus_decides_the_exit_code():
    assert worst_code([0, 0]) == 0
    assert worst_code([0, 2]) == 2  # refused: nothing moved
    assert worst_code([143, 0, 2]) == 143
    assert worst_code([143, 4]) == 4  # a servo not confirmed safe outranks a signal
    assert worst_code([4, 3, 143]) == 3  # a fault outranks the rest of the show's endings
    assert worst_code([3, 1]) == 1  # a crash outside the show: a bug
    assert worst_code([0, 77]) == 77  # unknown: the worst
    assert worst_code([]) == 0


def test_a_childs_stop_line_reads_back():
    line = stopping_line(3, "bus: adapter gone\n  servo 3: no reply", 1234.5678)
    assert "\n" not in line
    stop = parse_stopping(line + "\n")
    assert (stop.code, stop.at, stop.reason) == (
        3,
        1234.5678,
        "bus: adapter gone servo 3: no reply",
    )
    assert parse_stopping("ready") is None and parse_stopping("stopping x y z") is None


def test_the_first_own_stop_before_the_parents_signal_stopped_the_show():
    assert first_stop({"a": 10.2, "b": 10.1}) == "b"  # by instant, not by name or end order
    assert first_stop({"a": 10.2, "b": 10.1}, before=10.15) == "b"
    assert first_stop({"a": 10.2}, before=10.15) is None  # after the user's signal: its doing
    assert first_stop({}) is None


def test_a_bus_stopped_for_another_counts_by_the_stoppers_code():
    def out(name, code, confirmed=True):
        return BusOutcome(name, code, "", {"exit_policy_confirmed": confirmed})

    fault = [out("a", 143), out("b", 3)]
    assert group_code(fault, "b", {"a"}) == 3
    # b's adapter went in its start-up, after a had moved: nobody signalled the figure
    assert group_code([out("a", 143), out("b", 2, None)], "b", {"a"}) == 3
    # a was stopped before its torque went on: nothing moved anywhere
    assert group_code([out("a", 143, None), out("b", 2, None)], "b", {"a"}) == 2
    # a child signalled alone stopped the others: the signal is the figure's ending
    assert group_code([out("a", 143), out("b", 143)], "b", {"a"}) == 143
    # a bus stopped for another that could not confirm its exit policy still says so
    assert group_code([out("a", 4, False), out("b", 3)], "b", {"a"}) == 3
    assert group_code([out("a", 4, False), out("b", 143)], "b", {"a"}) == 4
    # the user's signal: every bus's own code
    assert group_code([out("a", 143), out("b", 2, None)], None, set()) == 143


def _summary(tmp_path, name: str, **summary) -> pathlib.Path:
    run = tmp_path / name
    run.mkdir()
    if summary:
        (run / "summary.json").write_text(json.dumps(summary))
    return run


def test_a_child_killed_by_a_signal_is_judged_by_what_it_left(tmp_path):
    done = _summary(tmp_path, "a", exit_code=0, exit_reason="end of show")
    empty = _summary(tmp_path, "b")
    after = bus_outcome("a", -signal.SIGKILL, True, done)
    # its record stands, with the reason it gives
    assert (after.exit_code, after.note) == (0, "end of show (killed by SIGKILL after its show)")
    before = bus_outcome("b", -signal.SIGTERM, False, empty)
    assert before.exit_code == 143 and "before its start: nothing moved" in before.note
    during = bus_outcome("b", -signal.SIGKILL, True, empty)
    assert during.exit_code == 3 and "exit policy was not applied" in during.note
    normal = bus_outcome("a", 0, True, done)
    assert (normal.exit_code, normal.note, normal.summary["exit_reason"]) == (0, "", "end of show")


def test_rows_side_by_side_come_from_each_bus_summary(tmp_path):
    run = _summary(
        tmp_path,
        "arm",
        exit_code=143,
        exit_reason="stopped by SIGTERM",
        ticks=500,
        overruns=2,
        lateness_us={"p50": 1.25, "p99": 40.0, "max": 900.0},
        stale_reads={"a1": 3, "a2": 0},
        error_reads={"a1": 1},
        alert_reads={},
        servo_ids={"a1": 1, "a2": 2},
        clock="real time",
        loop={"clock_t0": 100.000012, "host_stalls": {"count": 1}},
    )
    row = bus_row(bus_outcome("arm", 143, True, run), start_at=100.0)
    assert row["reason"] == "stopped by SIGTERM" and row["joints"] == 2
    assert (row["comm_errors"], row["overruns"], row["host_stalls"]) == (4, 2, 1)
    assert row["tick0_after_start_us"] == pytest.approx(12.0, abs=1e-3)
    missing = bus_row(bus_outcome("leg", 2, False, _summary(tmp_path, "leg")), start_at=None)
    assert missing["reason"] == "no summary written" and missing["tick0_after_start_us"] is None
    head, arm, leg = format_rows([row, missing])
    assert head.split()[:2] == ["bus", "exit"]
    assert arm.split() == ["arm", "143", "1.2/40.0/900", "2/500", "4", "1", "+12", "us"]
    assert leg.split() == ["leg", "2", "-/-/-", "-/-", "-", "-", "-"]


def test_each_child_runs_hilsim_run_on_its_bus_into_its_own_directory(tmp_path):
    argv = child_argv("rig.toml", "arm", tmp_path, ["--virtual-time"])
    assert argv[1:] == [
        "-m", "hilsim", "run", "rig.toml", "--bus", "arm", "--out", str(tmp_path / "arm"),
        "--shared-start", "--virtual-time",
    ]  # fmt: skip
