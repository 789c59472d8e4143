"""Unattended operation (docs/service.md): SIGHUP and SIGQUIT end a show as SIGTERM does, the
heartbeat file, and the systemd unit ``hilsim service print`` writes."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import pty
import select
import shlex
import shutil
import signal
import subprocess
import sys
import termios
import time
from pathlib import Path

import pytest

import hilsim
from drivers.servo_bus import CONDITION_FIELDS, ConditionRecord, ServoCondition
from hilsim.cli import main
from hilsim.rig import load_rigs
from hilsim.show import heartbeat as hb
from hilsim.telemetry.reader import read_run

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "configs" / "demo.toml"


def _status(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _wait_running(proc: subprocess.Popen, status: Path) -> dict:
    """status.json saying the show runs, past its first ticks (waiting, not timing)."""
    deadline = time.monotonic() + 120.0
    while time.monotonic() < deadline:
        st = _status(status)
        if st is not None and st["state"] == "running" and st["tick"] > 0:
            return st
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    raise AssertionError(f"no running status in {status}: {_status(status)}")


def _hilsim_run(out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "hilsim", "run", str(DEMO), "--virtual-time", "--duration",
         "3600", "--no-plots", "--out", str(out), *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
    )  # fmt: skip


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGHUP, 129), (signal.SIGQUIT, 131)])
def test_sighup_and_sigquit_mid_show_apply_the_exit_policy(tmp_path, signum, code):
    out = tmp_path / "run"
    proc = _hilsim_run(out)
    try:
        running = _wait_running(proc, out / "status.json")
        assert running["servos"][0]["read"] == "ok" and running["pid"] == proc.pid
        proc.send_signal(signum)
        assert proc.wait(timeout=60) == code, proc.communicate()
    finally:
        if proc.poll() is None:
            proc.kill()
    err = proc.communicate()[1]
    assert f"exit code {code}" in err
    run = read_run(out)
    assert run.summary["exit_code"] == code
    assert run.summary["exit_policy_confirmed"] is True  # mid-show: the hold was read back
    assert run.n_ticks >= running["tick"]
    assert [e["kind"] for e in run.events].count("signal") == 1
    policy = [e for e in run.events if e["kind"] == "exit_policy"]
    assert "4 servo(s) confirmed" in policy[0]["message"]
    ended = _status(out / "status.json")
    assert ended is not None and ended["state"] == "ended"
    assert ended["exit_code"] == code and ended["exit_policy_confirmed"] is True
    assert signal.Signals(signum).name in ended["exit_reason"]


@pytest.mark.skipif(not hasattr(termios, "TIOCSCTTY"), reason="needs a controlling terminal")
@pytest.mark.parametrize(("rig", "beat"), [("demo", "."), ("two_buses", "left")])
def test_a_terminal_that_goes_away_stops_the_show_through_the_exit_policy(tmp_path, rig, beat):
    """An SSH session dropped: ``hilsim run`` on a terminal (its controlling one) that then
    closes gets SIGHUP from the kernel, and its stderr fails after it. Exit 129, as the
    summary says, not a traceback's 1. Several buses: the parent sends it on to each."""
    out = tmp_path / "run"
    master, slave = pty.openpty()

    def own_terminal() -> None:
        os.setsid()
        fcntl.ioctl(0, termios.TIOCSCTTY, 0)

    proc = subprocess.Popen(
        [sys.executable, "-m", "hilsim", "run", str(REPO / "configs" / f"{rig}.toml"),
         "--duration", "600", "--no-plots", "--out", str(out)],
        stdin=slave, stdout=slave, stderr=slave, preexec_fn=own_terminal, cwd=REPO,
    )  # fmt: skip
    os.close(slave)
    try:
        seen = b""
        deadline = time.monotonic() + 120.0
        while (st := _status(out / beat / "status.json")) is None or st["state"] != "running":
            assert time.monotonic() < deadline and proc.poll() is None, seen
            if select.select([master], [], [], 0.05)[0]:  # (a terminal nobody reads fills up)
                with contextlib.suppress(OSError):
                    seen += os.read(master, 65536)
        os.close(master)  # the terminal goes away
        assert proc.wait(timeout=120) == 129
    finally:
        if proc.poll() is None:
            proc.kill()
    runs = [out] if beat == "." else [out / "left", out / "right"]
    for run_dir in runs:
        run = read_run(run_dir)
        assert run.summary["exit_code"] == 129
        assert run.summary["exit_policy_confirmed"] in (True, None)  # None: before torque-on
        assert _status(run_dir / "status.json")["state"] == "ended"
    if beat == ".":  # it was running: the hold was confirmed
        assert read_run(out).summary["exit_policy_confirmed"] is True


def test_the_status_file_can_live_elsewhere(tmp_path):
    out, status = tmp_path / "run", tmp_path / "run-hilsim" / "status.json"
    proc = _hilsim_run(out, "--status-file", str(status))
    try:
        _wait_running(proc, status)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 143
    finally:
        if proc.poll() is None:
            proc.kill()
    proc.communicate()
    assert not (out / "status.json").exists()
    assert _status(status)["state"] == "ended"


def test_each_bus_of_a_figure_writes_its_heartbeat_beside_the_status_file(tmp_path):
    out, status = tmp_path / "run", tmp_path / "rt" / "status.json"
    done = subprocess.run(
        [sys.executable, "-m", "hilsim", "run", str(REPO / "configs" / "two_buses.toml"),
         "--virtual-time", "--duration", "0.5", "--no-plots", "--out", str(out),
         "--status-file", str(status)],
        capture_output=True, text=True, cwd=REPO, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    for bus in ("left", "right"):
        st = _status(tmp_path / "rt" / f"status-{bus}.json")
        assert st["state"] == "ended" and st["exit_code"] == 0 and st["bus"] == bus
        assert st["run_dir"] == str(out / bus)
    assert not status.exists()


def test_a_library_show_writes_the_heartbeat_and_how_it_ended(tmp_path):
    out = tmp_path / "run"
    with hilsim.Show(DEMO, virtual_time=True, duration=1.0, out=out, status_file=True) as show:
        result = show.run()
    st = _status(out / "status.json")
    assert st is not None and result.exit_code == 0
    assert st["state"] == "ended" and st["exit_code"] == 0 and st["exit_reason"] == "end of show"
    assert st["tick"] == result.ticks and st["summary_written"] is True
    assert st["rig"] == "demo" and st["run_dir"] == str(out) and st["clock"] == "virtual time"
    assert [s["joint"] for s in st["servos"]] == ["head_pan", "head_tilt", "jaw", "tail"]
    assert not list(out.glob(".status.json*"))  # no temporary file left behind


def test_without_the_option_a_library_show_writes_no_heartbeat(tmp_path):
    out = tmp_path / "run"
    with hilsim.Show(DEMO, virtual_time=True, duration=0.2, out=out) as show:
        show.run()
    assert not (out / "status.json").exists()


def test_a_refused_show_says_so_in_a_status_file_elsewhere(tmp_path):
    status = tmp_path / "status.json"
    show = hilsim.Show(
        DEMO, port="dxlsim://?ids=1-2&rdt_us=0&latency_ms=1", virtual_time=True,
        out=tmp_path / "run", status_file=status,
    )  # fmt: skip
    with pytest.raises(hilsim.ShowRefusedError):
        show.open()
    st = _status(status)
    assert st is not None and st["state"] == "refused" and st["exit_code"] == 2
    assert "answers Ping" in st["exit_reason"] and st["run_dir"] is None
    assert not (tmp_path / "run").exists()  # nothing left of a run that never started


def test_a_status_file_that_cannot_be_written_is_one_line_and_the_show_goes_on(tmp_path):
    (tmp_path / "file").write_text("in the way")
    notes: list[str] = []
    with hilsim.Show(
        DEMO, virtual_time=True, duration=1.0, out=tmp_path / "run",
        status_file=tmp_path / "file" / "status.json", status_every_s=1e-6, on_note=notes.append,
    ) as show:  # fmt: skip
        result = show.run()
    assert result.exit_code == 0 and result.summary["exit_policy_confirmed"] is True
    failed = [n for n in notes if "status file" in n]
    assert len(failed) == 1 and "not written" in failed[0] and "the show goes on" in failed[0]


def _beat(tmp_path: Path, said: list[str]) -> hb.Heartbeat:
    return hb.Heartbeat(
        tmp_path / "status.json", fixed={"rig": "r"}, joints=[("a", 1), ("b", 2)],
        every_s=1e-9, say=said.append,
    )  # fmt: skip


def _wait_for(beat: hb.Heartbeat, writes: int, failures: int = 0) -> None:
    deadline = time.monotonic() + 10.0
    while (beat.writes < writes or beat.failures < failures) and time.monotonic() < deadline:
        time.sleep(0.01)


def test_a_full_disk_is_said_once_and_again_when_it_writes(tmp_path, monkeypatch):
    said: list[str] = []
    beat = _beat(tmp_path, said)
    real_replace, full = os.replace, [True]

    def replace(src, dst):
        if full[0]:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_replace(src, dst)

    monkeypatch.setattr(hb.os, "replace", replace)
    beat.start()
    _wait_for(beat, 0, 1)
    st = {"tick": 10, "t": 0.04, "read": [0, 1], "present_rad": [0.0, float("nan")], "limp": [1]}
    for k in range(3):
        beat.offer({**st, "tick": 10 + k})
        _wait_for(beat, 0, 2 + k)
    assert beat.failures >= 2 and not (tmp_path / "status.json").exists()
    assert len(said) == 1 and "No space left on device" in said[0]
    assert not list(tmp_path.glob(".status.json*"))  # the temporary file is removed
    full[0] = False
    beat.offer({**st, "tick": 20})
    _wait_for(beat, 1)
    beat.end({"exit_code": 0, "exit_reason": "end of show"})
    assert said[1:] == [f"status file {tmp_path / 'status.json'} written again"]
    st = _status(tmp_path / "status.json")
    assert st["state"] == "ended" and st["tick"] == 20 and st["rig"] == "r"
    never_read = {k: None for f in CONDITION_FIELDS for k in (f, f + "_age_s")}
    assert st["servos"] == [
        {"id": 1, "joint": "a", "read": "ok", "present_deg": 0.0, "limp": False, **never_read},
        {"id": 2, "joint": "b", "read": "stale", "present_deg": None, "limp": True, **never_read},
    ]


def test_status_json_carries_each_servos_temperature_voltage_and_load(tmp_path):
    said: list[str] = []
    beat = _beat(tmp_path, said)
    beat.start()
    record = ConditionRecord(2)
    record.update(0, ServoCondition(41.0, 11.9, float("nan"), 0.25), t=1.0)
    record.update(1, ServoCondition(38.0, 12.1, -12.5), t=1.5)
    st = {"tick": 10, "t": 0.04, "read": [0, 0], "present_rad": [0.0, 0.0], "limp": []}
    beat.offer({**st, "condition": record.views(2.0)})
    _wait_for(beat, 1)
    beat.end({"exit_code": 0, "exit_reason": "end of show"})
    a, b = _status(tmp_path / "status.json")["servos"]
    assert (a["temperature_c"], a["voltage_v"], a["load_pct"], a["current_a"]) == (
        41.0, 11.9, None, 0.25
    )  # fmt: skip
    assert a["temperature_c_age_s"] == 1.0 and a["load_pct_age_s"] is None
    assert (b["temperature_c"], b["voltage_v"], b["load_pct"], b["current_a"]) == (
        38.0, 12.1, -12.5, None
    )  # fmt: skip
    assert b["voltage_v_age_s"] == 0.5


def test_the_loop_never_waits_for_the_status_disk(tmp_path, monkeypatch):
    """A write stuck on the disk: offers return at once, only the newest is kept."""
    import threading

    said: list[str] = []
    beat = _beat(tmp_path, said)
    stuck, release = threading.Event(), threading.Event()
    real_replace = os.replace

    def replace(src, dst):
        stuck.set()
        release.wait(120.0)
        real_replace(src, dst)

    monkeypatch.setattr(hb.os, "replace", replace)
    beat.start()
    assert stuck.wait(10.0)
    done = threading.Event()

    def offers() -> None:
        for k in range(1000):
            beat.offer({"tick": k, "t": k * 0.004})
        done.set()

    threading.Thread(target=offers, daemon=True).start()
    assert done.wait(60.0)  # every offer handed over while the write is still stuck
    assert not release.is_set() and beat.writes == 0
    release.set()
    beat.end({"exit_code": 0, "exit_reason": "end of show"})
    st = _status(tmp_path / "status.json")
    assert st["state"] == "ended" and st["tick"] == 999
    assert beat.writes <= 3  # starting, (perhaps the newest offer), ended


# ------------------------------------------------------------------ the systemd unit
SYSTEMD_ANALYZE = shutil.which("systemd-analyze")
needs_systemd_analyze = pytest.mark.skipif(
    SYSTEMD_ANALYZE is None, reason="systemd-analyze not installed (Debian: apt install systemd)"
)


def _unit(capsys, *argv: str) -> str:
    assert main(["service", "print", *argv]) == 0, capsys.readouterr().err
    return capsys.readouterr().out


def _keys(unit: str) -> dict[str, str]:
    return dict(
        line.split("=", 1) for line in unit.splitlines() if "=" in line and line[0] not in "#;"
    )


def _verify(tmp_path: Path, unit: str, name: str = "hilsim-demo") -> None:
    path = tmp_path / f"{name}.service"
    path.write_text(unit)
    done = subprocess.run(
        [SYSTEMD_ANALYZE, "verify", str(path)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert f"{name}.service" not in done.stderr, done.stderr  # (an unknown key: rc 0, a line)


@needs_systemd_analyze
@pytest.mark.parametrize(
    "rig", ["demo.toml", "hardware_example.toml", "two_buses.toml"], ids=lambda r: r[:-5]
)
def test_the_generated_unit_passes_systemd_analyze_verify(tmp_path, capsys, monkeypatch, rig):
    monkeypatch.chdir(tmp_path)
    show = ["--show", str(REPO / "configs" / "shows" / "demo_show.toml")] * (rig == "demo.toml")
    unit = _unit(capsys, str(REPO / "configs" / rig), *show, "--runs-dir", "/srv/fig ure/r%s")
    _verify(tmp_path, unit, "hilsim-" + load_rigs(REPO / "configs" / rig)[0].name)
    keys = _keys(unit)
    assert keys["SuccessExitStatus"].split() == ["5", "129", "130", "131", "143"]
    assert set(keys["RestartPreventExitStatus"].split()) == {
        "2",
        "4",
        "5",
        "129",
        "130",
        "131",
        "143",
    }
    assert keys["Restart"] == "on-failure" and keys["WorkingDirectory"] == str(tmp_path)
    assert keys["StandardError"] == "journal"
    # systemd kills hilsim alone: a guardian or a bus's process must outlive a crash of it
    # (KillMode=mixed would SIGKILL them the moment it died, before the exit policy)
    assert keys["KillMode"] == "process" and keys["TimeoutStopSec"] == "30"
    exec_start = shlex.split(keys["ExecStart"].replace("%%", "%"))
    assert Path(exec_start[0]).is_absolute() and Path(exec_start[0]).exists()
    assert exec_start[exec_start.index("--runs-dir") + 1] == "/srv/fig ure/r%s"
    if rig == "hardware_example.toml":  # it asks for SCHED_FIFO: the unit grants it
        assert keys["AmbientCapabilities"] == "CAP_SYS_NICE" and keys["LimitRTPRIO"] == "50"
        assert keys["SupplementaryGroups"] == "dialout"
    if rig == "two_buses.toml":  # each bus writes its own: status-<bus>.json
        assert "status-<bus>.json" in unit


def test_the_units_command_runs_a_show_and_its_heartbeat(tmp_path, capsys, monkeypatch):
    """ExecStart as systemd would run it (the runtime directory moved into tmp_path), on the
    virtual clock for a moment: a show, its run in --runs-dir, status.json ended."""
    monkeypatch.chdir(tmp_path)
    unit = _unit(capsys, str(DEMO), "--runs-dir", str(tmp_path / "runs"))
    keys = _keys(unit)
    status = tmp_path / "rt" / "status.json"
    argv = shlex.split(keys["ExecStart"].replace("%%", "%"))
    argv[argv.index("--status-file") + 1] = str(status)
    done = subprocess.run(
        [*argv, "--virtual-time", "--duration", "0.5"], capture_output=True, text=True,
        cwd=keys["WorkingDirectory"], timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    (run,) = (tmp_path / "runs").iterdir()
    assert read_run(run).summary["exit_code"] == 0
    assert _status(status)["state"] == "ended" and _status(status)["run_dir"] == str(run)


@pytest.mark.parametrize("bad", ["rig", "show", "show-of-two-buses"])
def test_service_print_refuses_a_bad_rig_or_show_in_one_line(tmp_path, capsys, bad):
    (tmp_path / "show.toml").write_text("[cues.scare]\nnot_a_key = 1\n")
    argv = {
        "rig": [str(tmp_path / "nope.toml")],
        "show": [str(DEMO), "--show", str(tmp_path / "show.toml")],
        "show-of-two-buses": [str(REPO / "configs" / "two_buses.toml"), "--show",
                              str(REPO / "configs" / "shows" / "demo_show.toml")],
    }[bad]  # fmt: skip
    assert main(["service", "print", *argv]) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1, err
    assert {"rig": "nope.toml", "show": "show.toml", "show-of-two-buses": "one bus"}[bad] in err


def test_the_loops_figures_become_fields_on_the_writers_thread(tmp_path, monkeypatch):
    """The loop's side is a hand-over: turning its figures into fields (a loop over the
    servos) happens on the heartbeat's thread, never in the tick's."""
    import threading

    beat = _beat(tmp_path, [])
    threads: list[str] = []
    figures = beat._figures

    def spy(st):
        threads.append(threading.current_thread().name)
        return figures(st)

    monkeypatch.setattr(beat, "_figures", spy)
    beat.start()
    beat.offer({"tick": 5, "t": 0.02, "read": [0, 0], "present_rad": [0.0, 0.0]})
    beat.end({"exit_code": 0, "exit_reason": "end of show"})
    assert threads == ["hilsim-heartbeat"]
    assert _status(tmp_path / "status.json")["tick"] == 5
