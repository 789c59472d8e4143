"""Several buses, one show, as processes: a run directory per bus, one start, a signal to the
parent reaching every bus, a fault or a refusal on one bus stopping the others. Behaviour only:
nothing here asserts a speed (the children's own start-up is waited for, not timed)."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from hilsim.cli import main
from hilsim.telemetry.reader import read_run

JOINT = """
[[joints]]
name = "{name}"
bus = "{bus}"
servo_id = {sid}
min_deg = -60
max_deg = 60
spring = {{ frequency_hz = 3.0, damping_ratio = 0.7 }}
target = {{ type = "sine", amplitude_deg = 20, frequency_hz = {f} }}
"""

RIG = (
    """
name = "pair"
[buses.a]
port = "dxlsim://?ids=1-2&rdt_us=0"
[buses.b]
port = "dxlsim://?ids=3-4&rdt_us=0{b_url}"
[loop]
rate_hz = 100
[safety]
soft_start_s = 0.1
"""
    + JOINT.format(name="a1", bus="a", sid=1, f=0.5)
    + JOINT.format(name="b3", bus="b", sid=3, f=0.3)
    + JOINT.format(name="a2", bus="a", sid=2, f=0.4)
    + JOINT.format(name="b4", bus="b", sid=4, f=0.2)
)


def rig(tmp_path: Path, b_url: str = "", **replace: str) -> Path:
    text = RIG.replace("{b_url}", b_url)
    for old, new in replace.items():
        text = text.replace(old, new)
    path = tmp_path / "pair.toml"
    path.write_text(text)
    return path


class Parent:
    """``hilsim run`` as a process, its stderr collected line by line."""

    def __init__(self, *argv: str) -> None:
        self.lines: list[str] = []
        self._cond = threading.Condition()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hilsim", "run", *argv],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stderr:
            with self._cond:
                self.lines.append(line.rstrip("\n"))
                self._cond.notify_all()

    def wait_for(self, *needles: str, timeout: float = 60.0) -> None:
        """Until a line holding each needle has appeared (or the process ended)."""

        def seen() -> bool:
            return all(any(n in ln for ln in self.lines) for n in needles)

        with self._cond:
            self._cond.wait_for(lambda: seen() or self.proc.poll() is not None, timeout)
        assert seen(), "\n".join(self.lines)

    def finish(self, timeout: float = 120.0) -> int:
        try:
            return self.proc.wait(timeout=timeout)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()

    @property
    def text(self) -> str:
        return "\n".join(self.lines)


def group_record(out: Path) -> dict:
    return json.loads((out / "buses.json").read_text())


def test_each_bus_gets_a_normal_run_directory_with_its_own_joints(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(
        ["run", str(rig(tmp_path)), "--virtual-time", "--no-plots", "--duration", "1",
         "--out", str(out)]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == 0, err
    a, b = read_run(out / "a"), read_run(out / "b")
    assert (a.joint_names, b.joint_names) == (("a1", "a2"), ("b3", "b4"))
    assert a.summary["servo_ids"] == {"a1": 1, "a2": 2}
    assert b.summary["servo_ids"] == {"b3": 3, "b4": 4}
    for run in (a, b):
        assert run.summary["exit_code"] == 0 and run.summary["exit_policy_confirmed"] is True
        assert run.n_ticks == 101
    record = group_record(out)
    assert record["exit_code"] == 0 and [r["bus"] for r in record["buses"]] == ["a", "b"]
    table = [ln for ln in err.splitlines() if ln.startswith("  a ") or ln.startswith("  b ")]
    assert len(table) == 2 and all("0/101" in ln for ln in table)  # overruns/ticks, side by side
    assert "exit code 0 (the worst bus's)" in err

    # virtual time: a bus run alone commands the same numbers as in the group
    alone = tmp_path / "alone"
    code = main(
        ["run", str(rig(tmp_path)), "--bus", "b", "--virtual-time", "--no-plots",
         "--duration", "1", "--out", str(alone)]
    )  # fmt: skip
    assert code == 0, capsys.readouterr().err
    np.testing.assert_array_equal(read_run(alone).joint("cmd"), b.joint("cmd"))


@pytest.mark.parametrize(
    ("signum", "code"),
    [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGHUP, 129), (signal.SIGQUIT, 131)],
)
def test_a_signal_to_the_parent_reaches_every_bus_on_the_real_clock(tmp_path, signum, code):
    out = tmp_path / "run"
    parent = Parent(str(rig(tmp_path)), "--duration", "600", "--no-plots", "--out", str(out))
    parent.wait_for("[a] hilsim run: pair: 2 joints", "[b] hilsim run: pair: 2 joints")
    parent.proc.send_signal(signum)
    assert parent.finish() == code, parent.text
    record = group_record(out)
    assert record["start_at_monotonic_s"] is not None  # one instant for both buses' tick 0
    for bus in ("a", "b"):
        run = read_run(out / bus)
        assert run.summary["exit_code"] == code, parent.text
        assert run.summary["clock"] == "real time"
        beat = json.loads((out / bus / "status.json").read_text())  # each bus's heartbeat
        assert beat["state"] == "ended" and beat["exit_code"] == code
        signals = [e for e in run.events if e["kind"] == "signal"]
        assert len(signals) == 1, parent.text
        if run.summary["exit_policy_confirmed"] is None:  # it landed before torque went on
            assert "nothing was energised" in signals[0]["message"]
        else:  # each bus applied its own exit policy and confirmed it on both servos
            assert run.summary["exit_policy_confirmed"] is True
            policy = [e for e in run.events if e["kind"] == "exit_policy"]
            assert "2 servo(s) confirmed" in policy[0]["message"]
    assert f"exit code {code} (the worst bus's)" in parent.text
    assert "stopped first" not in parent.text and record["stopped_by"] is None  # the user did
    assert record["stop"] is None


def _children_of(out: Path) -> list[int]:
    """PIDs of the bus processes writing under ``out`` (found by their command line)."""
    pids = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            try:
                argv = (proc / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if b"--shared-start" in argv and any(str(out).encode() in a for a in argv):
                pids.append(int(proc.name))
    return pids


@pytest.mark.skipif(not Path("/proc/self/cmdline").exists(), reason="needs /proc")
def test_the_buses_stop_by_themselves_when_the_parent_dies(tmp_path):
    out = tmp_path / "run"
    parent = Parent(str(rig(tmp_path)), "--duration", "600", "--no-plots", "--out", str(out))
    try:
        parent.wait_for("[a] hilsim run: pair: 2 joints", "[b] hilsim run: pair: 2 joints")
        children = _children_of(out)
        assert len(children) == 2
        parent.proc.kill()  # no forwarding, no table: only the closed pipe tells them
        parent.finish()
        deadline = time.monotonic() + 60.0  # waiting for the children, not timing them
        while any(Path(f"/proc/{pid}").exists() for pid in children):
            assert time.monotonic() < deadline, "a bus kept running without its parent"
            time.sleep(0.05)
    finally:
        for pid in _children_of(out):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
    for bus in ("a", "b"):
        summary = read_run(out / bus).summary
        assert summary["exit_code"] == 143  # the SIGTERM path: the exit policy was applied
        assert summary["exit_policy_confirmed"] in (True, None)  # None: before torque-on


def test_a_fault_on_one_bus_stops_the_others(tmp_path):
    out = tmp_path / "run"
    path = rig(tmp_path, b_url="&faults=unplug:at=0.5")
    parent = Parent(
        str(path), "--virtual-time", "--duration", "3600", "--no-plots", "--out", str(out)
    )
    assert parent.finish() == 3, parent.text
    a, b = read_run(out / "a").summary, read_run(out / "b").summary
    assert b["exit_code"] == 3 and "bus" in b["exit_reason"]
    assert a["exit_code"] == 143 and a["exit_policy_confirmed"] is True  # stopped, held
    record = group_record(out)
    assert record["stopped_by"] == "b" and record["stop"]["buses_stopped"] == ["a"]
    assert record["stop"]["reason"] == b["exit_reason"]  # why, from the bus that stopped it
    assert "bus b stopped first (exit 3)" in parent.text  # (virtual time: no wall seconds)
    assert "so bus a was stopped too (one figure)" in parent.text


def test_a_bus_that_cannot_start_keeps_every_bus_still(tmp_path):
    out = tmp_path / "run"
    # bus b's servos are XM430s; the rig says XL330: b refuses, so a never starts either
    path = rig(tmp_path, **{"servo_id = 4\n": 'servo_id = 4\nmodel = "XL330-M288"\n'})
    parent = Parent(str(path), "--virtual-time", "--duration", "5", "--no-plots", "--out", str(out))
    assert parent.finish() == 2, parent.text
    assert "another bus of the figure could not start: nothing moved" in parent.text
    assert not (out / "a").exists() and not (out / "b").exists()  # no run began
    assert [r["exit_code"] for r in group_record(out)["buses"]] == [2, 2]


def test_a_bus_that_ends_after_saying_ready_calls_the_start_off(tmp_path, monkeypatch):
    """A child that said "ready" and then died (a crash, a telemetry refusal) cannot play its
    part: the others are told to stand down instead of being sent the start instant."""
    import hilsim.show.group as group

    marker = tmp_path / "a-pid"
    dies = (
        f"import os; print('ready', flush=True); open({str(marker)!r}, 'w').write(str(os.getpid()))"
        "; raise SystemExit(1)"
    )
    # b says ready only once a is gone (reaped by the parent), then reports what it was sent
    waits = (
        "import os, sys\n"
        f"while not os.path.exists({str(marker)!r}) or not open({str(marker)!r}).read(): pass\n"
        f"pid = int(open({str(marker)!r}).read())\n"
        "while True:\n"
        "    try:\n"
        "        os.kill(pid, 0)\n"
        "    except ProcessLookupError:\n"
        "        break\n"
        "print('ready', flush=True)\n"
        "line = sys.stdin.readline().strip()\n"
        "raise SystemExit(9 if line else 2)\n"
    )

    def argv(config, bus, run_dir, extra):
        return [sys.executable, "-c", dies if bus == "a" else waits]

    monkeypatch.setattr(group, "child_argv", argv)
    result = group.run_group("x", ["a", "b"], tmp_path / "run", [], echo=lambda line: None)
    assert result.start_at is None  # never sent
    assert {o.name: o.exit_code for o in result.outcomes}["b"] == 2  # told: nothing moves


# ---------------------------------------------------------------- which bus stopped the show
# Stand-in children (the protocol of hilsim run --shared-start without a bus): each says ready,
# takes the start instant, and says "stopping CODE INSTANT REASON" when its show stops.
CHILD = """
import json, os, signal, sys, time
from pathlib import Path
run, tmp = Path(sys.argv[1]), Path(sys.argv[2])
signals = []
signal.signal(signal.SIGTERM, lambda s, f: signals.append(s))  # as hilsim run's child does
(tmp / (run.name + ".pid")).write_text(str(os.getpid()))
print("ready", flush=True)
time.sleep(max(0.0, float(sys.stdin.readline()) - time.monotonic()))  # tick 0

def stop(code, reason, energised=True):
    print(f"stopping {code} {time.monotonic()!r} {reason}", flush=True)
    run.mkdir(parents=True, exist_ok=True)
    summary = {"exit_code": code, "exit_reason": reason,
               "exit_policy_confirmed": True if energised else None}
    (run / "summary.json").write_text(json.dumps(summary))

def gone(bus):
    pid = tmp / (bus + ".pid")
    while not pid.exists() or not pid.read_text():
        time.sleep(0.01)
    try:
        os.kill(int(pid.read_text()), 0)
    except ProcessLookupError:
        return True
    return False

def until(check, cap_s=20.0):
    deadline = time.monotonic() + cap_s  # only on a parent that never stops the others
    while not check() and time.monotonic() < deadline:
        time.sleep(0.01)
    return check()
"""

# faults first; its exit policy, record and plots keep the process for a while: until the
# other bus is gone. In those last moments it no longer catches SIGTERM (as a Python process
# while it shuts down): a SIGTERM from the parent now would kill it.
FAULTS_FIRST = """
stop(3, "bus: adapter gone during Sync Read")
(tmp / "faulted").write_text("")
signal.signal(signal.SIGTERM, signal.SIG_DFL)
left_after = until(lambda: gone("b"))
(tmp / "a-left").write_text("after b" if left_after else "before b")
raise SystemExit(3)
"""
# faults too, later (a brown-out reaching it second), unless the parent's stop came first;
# its process ends at once
FAULTS_SECOND = """
until(lambda: signals or (tmp / "faulted").exists(), cap_s=60.0)
if signals:
    stop(143, "stopped by SIGTERM")
    raise SystemExit(143)
time.sleep(0.05)
stop(3, "servo 3: following error 40 deg")
raise SystemExit(3)
"""
# runs until the parent stops it
HEALTHY = """
until(lambda: signals, cap_s=60.0)
stop(143, "stopped by SIGTERM")
raise SystemExit(143)
"""
# cannot start after the start instant (its adapter gone at its first read): nothing energised
CANNOT_START = """
stop(2, "cannot start: adapter gone during Sync Read", energised=False)
raise SystemExit(2)
"""


def _group(monkeypatch, tmp_path, **scripts):
    import hilsim.show.group as group

    def argv(config, bus, run_dir, extra):
        return [sys.executable, "-c", CHILD + scripts[bus], str(run_dir / bus), str(tmp_path)]

    monkeypatch.setattr(group, "child_argv", argv)
    lines: list[str] = []
    (tmp_path / "run").mkdir()
    result = group.run_group("x", list(scripts), tmp_path / "run", [], echo=lines.append)
    return result, group_record(tmp_path / "run"), "\n".join(lines)


def test_the_bus_that_faulted_first_is_recorded_not_the_one_that_ended_first(tmp_path, monkeypatch):
    """Bus a faults first; bus b's process ends first (its own fault a moment later, or the
    parent's stop). The record names a, with a's own reason; a is never sent SIGTERM."""
    result, record, err = _group(monkeypatch, tmp_path, a=FAULTS_FIRST, b=FAULTS_SECOND)
    a = next(r for r in record["buses"] if r["bus"] == "a")
    assert (a["exit_code"], a["reason"]) == (3, "bus: adapter gone during Sync Read"), err
    assert result.stopped_by == "a" and record["stopped_by"] == "a"
    assert record["stop"]["exit_code"] == 3
    assert record["stop"]["reason"] == "bus: adapter gone during Sync Read"
    assert 0 < record["stop"]["after_start_s"] < 60
    assert record["exit_code"] == result.exit_code == 3


def test_a_fault_stops_the_other_buses_before_the_faulted_bus_has_finished(tmp_path, monkeypatch):
    """The others are stopped when the faulted bus's loop stops, not when its process ends
    (after its record and plots: seconds at 1 kHz, while the rest of the figure moved on)."""
    result, record, err = _group(monkeypatch, tmp_path, a=FAULTS_FIRST, b=HEALTHY)
    assert (tmp_path / "a-left").read_text() == "after b", err
    assert record["stopped_by"] == "a" and record["stop"]["buses_stopped"] == ["b"]
    assert [r["exit_code"] for r in record["buses"]] == [3, 143]
    assert result.exit_code == 3


def test_a_bus_that_cannot_start_after_the_others_moved_is_a_fault_not_a_signal(
    tmp_path, monkeypatch
):
    """Bus b's adapter goes in its start-up, after the start instant: b moved nothing (2), a
    had moved and was stopped for it (143). Nobody signalled the figure: the exit code is 3."""
    result, record, err = _group(monkeypatch, tmp_path, a=HEALTHY, b=CANNOT_START)
    assert [r["exit_code"] for r in record["buses"]] == [143, 2], err
    assert record["exit_code"] == result.exit_code == 3
    assert record["stopped_by"] == "b" and record["stop"]["buses_stopped"] == ["a"]
