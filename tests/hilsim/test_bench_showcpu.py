"""``hilsim bench``'s CPU per second of show (hilsim.bench.showcpu): its lines, its JSON, when
it runs and how a run's figures are taken. The real measurement needs ptys and seconds of real
time: here the child processes and /proc are stood in for."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import pytest

from hilsim.bench import cpu, showcpu
from hilsim.bench.report import BenchReport
from hilsim.bench.showcpu import ShowCpu, ShowCpuResult


def result() -> ShowCpuResult:
    return ShowCpuResult(
        [
            ShowCpu("demo", "pty", 250.0, 5.0, 0.05, 0.04, 0.03, 250.0, 2.1, 40.0, 0),
            ShowCpu("scale16", "in-process", 1000.0, 5.0, 0.7, 0.6, 0.5, 500.0, 1.5, 9000.0, 0),
        ],
        load=[0.4, 0.5, 0.6],
        notes=[],
    )


def test_each_rig_says_its_cpu_a_second_its_share_of_a_core_and_the_emulator_apart():
    text = result().text()
    head, demo, scale, tail = text.splitlines()
    assert "CPU per second of show on the real clock (emulated: host overhead only" in head
    assert "telemetry writer, heartbeat" in head and "the emulator's CPU apart" in head
    assert demo == (
        "  demo         50 ms of CPU a second = 5.0% of one core (loop thread 4.0%); 200 µs a "
        "tick, 2.1 wake-ups a tick; 250 of its 250 ticks a second kept; lateness p99 40 µs; "
        "emulator process 3.0%"
    )
    # a rig the pty cannot carry at its rate says how many ticks it kept: its CPU is theirs
    assert "scale16" in scale and "500 of its 1000 ticks a second kept" in scale
    assert "1400 µs a tick" in scale and scale.endswith("emulator's work taken out 50.0%")
    assert tail == "  (5 s of each show measured; load 0.40 0.50 0.60)"


def test_its_json_has_every_figure_and_says_where_the_emulator_ran():
    data = json.loads(json.dumps(result().as_dict()))
    demo = data["shows"][0]
    assert demo["rig"] == "demo" and demo["cpu_per_s"] == 0.05
    assert demo["us_per_tick"] == 200.0 and demo["emulator_per_s"] == 0.03
    assert "another process" in data["emulator"]["pty"]
    assert "taken out" in data["emulator"]["in-process"]
    assert data["shows"][1]["where"] == "in-process"
    assert math.isnan(ShowCpu("x", "pty", 250.0, 1.0, 0.1, 0.1, 0.0, 0.0, 0.0, 0.0, 1).us_per_tick)


def test_it_runs_for_the_built_in_emulator_on_the_real_clock_quick_or_not(monkeypatch):
    seen = []
    monkeypatch.setattr(showcpu, "measure", lambda quick, progress: seen.append(quick) or "ran")

    def args(**kw):
        return argparse.Namespace(**{"config": None, "port": None, "clock": "real", **kw})

    for a in (args(clock="virtual"), args(port="/dev/ttyUSB0"), args(config="rig.toml")):
        assert showcpu.for_bench(a, None, print) is None  # a rig or a port: itself
    assert showcpu.for_bench(args(quick=True), None, print) == "ran"
    assert showcpu.for_bench(args(quick=False), None, print) == "ran"
    assert seen == [True, False]


def test_a_rig_that_cannot_be_measured_is_a_note_not_a_crash(monkeypatch):
    def fails(rig, label, *, window_s, settle_s, where):
        raise RuntimeError("hilsim emulate printed '', not a pty path")

    monkeypatch.setattr(showcpu, "show_once", fails)
    r = showcpu.measure(quick=True)
    assert r.shows == [] and len(r.notes) == 2
    assert r.notes[0] == "demo: not measured: hilsim emulate printed '', not a pty path"
    report = BenchReport(command="x", quick=True, subject="t")
    monkeypatch.setattr(showcpu, "measure", lambda **kw: (_ for _ in ()).throw(OSError("no pty")))
    a = argparse.Namespace(config=None, port=None, clock="real", quick=True)
    assert showcpu.for_bench(a, report, print) is None
    assert report.notes == ["CPU per second of show not measured: no pty"]


def test_an_in_process_emulators_work_is_timed_in_the_child_and_taken_out(tmp_path, monkeypatch):
    """The child's prelude times WireBus.write and read on the thread that runs them and
    writes (ns, calls) at exit; show_once takes that out of the process's and loop's CPU."""
    import subprocess
    import sys

    books = tmp_path / "emu.json"
    code = showcpu.CHILD.replace(
        "from hilsim.cli import main\nsys.exit(main(sys.argv[1:]))",
        "from drivers.dxlsim.wire import WireBus\n"
        "print(WireBus.write.__name__, WireBus.read.__name__)",
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(books)], capture_output=True, text=True, check=True
    )
    assert out.stdout.split() == ["timed", "timed"]
    ns, calls = json.loads(books.read_text())
    assert ns == 0 and calls == 0  # nothing ran on the bus

    # the figures: 10 s of show at 1 kHz, 2 s of emulator work in all -> 0.2 s a second out
    fake_cpu = iter([1.0, 0.8, 1.9, 1.5])  # process, loop thread; at the window's ends

    class Proc:
        pid, stderr = 4242, iter(["hilsim run: scale16: ... -> run\n"])

        def poll(self):
            return 0

        def wait(self, timeout=None):
            return 0

    def popen(cmd, **kw):
        assert cmd[1] == "-c" and cmd[2] == showcpu.CHILD  # the in-process child
        run = Path(cmd[cmd.index("--out") + 1])
        run.mkdir()
        summary = {"ticks": 10_000, "duration_s": 10.0, "lateness_us": {"p99": 12.0}}
        (run / "summary.json").write_text(json.dumps(summary))
        Path(cmd[3]).write_text(json.dumps([2_000_000_000, 20_000]))
        p = Proc()
        p.stderr = _Stderr(p.stderr)
        return p

    class _Stderr:
        def __init__(self, lines):
            self._lines = list(lines)

        def __iter__(self):
            return iter(self._lines)

        def read(self):
            return ""

        def close(self):
            pass

    monkeypatch.setattr(showcpu, "_bus", lambda rig: ("1-16", 4_000_000, "XM430-W350", 1000.0))
    monkeypatch.setattr(cpu.subprocess, "Popen", popen)
    monkeypatch.setattr(cpu, "_cpu_s", lambda pid, tid=None: next(fake_cpu))  # (it samples)
    monkeypatch.setattr(cpu, "_wakeups", lambda pid: 0)
    monkeypatch.setattr(cpu.time, "sleep", lambda s: None)
    clock = iter([0.0, 1.0])
    monkeypatch.setattr(cpu.time, "perf_counter", lambda: next(clock))
    s = showcpu.show_once(
        Path("scale16.toml"), "scale16", window_s=1.0, settle_s=0.0, where="in-process"
    )
    assert s.where == "in-process" and s.ticks_per_s == 1000.0
    assert s.emulator_per_s == pytest.approx(0.2)
    assert s.cpu_per_s == pytest.approx(0.9 - 0.2) and s.loop_per_s == pytest.approx(0.7 - 0.2)
