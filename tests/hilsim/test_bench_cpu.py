"""``hilsim bench``'s CPU-over-a-pty section (hilsim.bench.cpu): its line, its JSON and when
it runs. The measurement itself needs a real pty and seconds of real time: not tested here
(``python -m hilsim.bench.cpu``)."""

from __future__ import annotations

import argparse
import json

import pytest

from hilsim.bench.cpu import CpuResult, CycleCpu, DemoCpu, WaitCpu, add_to_bench, for_bench


def cycles(port: str, cpu: float, wall: float) -> CycleCpu:
    return CycleCpu(port, 500, 7, cpu, wall, cpu, wall, 0)


def result() -> CpuResult:
    demo = DemoCpu(6.0, 250.0, 180.0, [180.0, 190.0], [0, 0], [0, 0], 150.0, 30.0, 2.1, 0.1, 35.0)
    waits = [
        WaitCpu(200.0, 50_000, 750, 250.0, 140.0, 0.1, 40.0, 900.0),
        WaitCpu(50.0, 1, 750, 250.0, 45.0, 0.1, 42.0, 800.0),
    ]
    return CpuResult(
        cycles("bare SDK (busy-poll)", 1450.0, 1460.0),
        cycles("hilsim", 150.0, 1480.0),
        demo,
        waits,
        load=[0.5, 0.6, 0.7],
    )


def test_the_line_says_both_ports_cpu_and_wall():
    text = result().text()
    assert text.splitlines()[0] == (
        "CPU per cycle over a pty (emulated: host overhead only: hilsim emulate): bare SDK "
        "(busy-poll) 1450 µs, hilsim 150 µs; "
        "wall per cycle 1460 vs 1480 µs (+1.4%)"
    )
    assert "load 0.50 0.60 0.70" in text
    assert (
        "The demo over a pty (emulated: host overhead only): 180 µs of CPU per tick at 250 Hz "
        "(4.5 % of a core"
    ) in text
    assert (
        "  loop thread 150 µs, other threads (telemetry) 30 µs; 2.1 wake-ups per tick; "
        "lateness p50 0.1 µs, p99 35 µs"
    ) in text.splitlines()
    assert (
        "The clock at 250 Hz, spin window 200 µs, timer slack 50 µs: 140 µs of CPU per wait, "
        "lateness p50 0.1 µs, p99 40 µs, max 900 µs (750 ticks)"
    ) in text.splitlines()
    assert "spin window 50 µs, timer slack 0.001 µs: 45 µs of CPU per wait" in text


def test_an_old_style_demo_result_prints_without_its_split():
    r = result()
    r.demo = DemoCpu(6.0, 250.0, 180.0, [180.0], [0], [0])  # no split measured
    assert "loop thread" not in r.text()


def test_it_joins_the_bench_json_under_cpu(tmp_path, capsys):
    path = tmp_path / "bench.json"
    path.write_text(json.dumps({"bus": []}))
    add_to_bench(result(), path)
    data = json.loads(path.read_text())
    assert data["bus"] == [] and data["cpu"]["hilsim"]["cpu_us"] == 150.0
    assert data["cpu"]["demo"]["cpu_us_per_tick"] == 180.0
    assert data["cpu"]["demo"]["loop_us_per_tick"] == 150.0
    assert [w["spin_us"] for w in data["cpu"]["waits"]] == [200.0, 50.0]
    assert "CPU per cycle over a pty" in capsys.readouterr().out


def test_it_runs_only_for_the_built_in_emulator_on_the_real_clock():
    def args(**kw):
        return argparse.Namespace(**{"config": None, "port": None, "clock": "real", **kw})

    for a in (args(clock="virtual"), args(port="/dev/ttyUSB0"), args(config="rig.toml")):
        assert for_bench(a, None, print) is None  # returns before measuring anything


def test_quick_leaves_it_to_the_full_run_and_says_so():
    from hilsim.bench.report import BenchReport

    report = BenchReport(command="x", quick=True, subject="t")
    a = argparse.Namespace(config=None, port=None, clock="real", quick=True)
    assert for_bench(a, report, print) is None
    assert report.notes == ["CPU per cycle over a pty: measured by the full run, not --quick"]


def test_the_clock_measurement_waits_for_every_deadline_with_the_slack_asked_for(monkeypatch):
    """measure_waits on a simulated clock (nothing sleeps): one wait per deadline, the
    lateness each returned, and the timer slack in force while it waited."""
    import drivers.clock as clock_mod
    from hilsim.bench import cpu

    t = [0.0]

    def perf_counter() -> float:
        t[0] += 1e-6
        return t[0]

    def sleep(dt: float) -> None:
        t[0] += dt + 30e-6  # the OS wakes the sleeper 30 µs late

    monkeypatch.setattr(clock_mod.time, "perf_counter", perf_counter)
    monkeypatch.setattr(clock_mod.time, "sleep", sleep)
    slack: list[int] = []
    monkeypatch.setattr(clock_mod, "timer_slack_ns", lambda: slack[-1] if slack else 50_000)
    monkeypatch.setattr(clock_mod, "set_timer_slack_ns", lambda ns: slack.append(ns) or True)
    w = cpu.measure_waits(50.0, 1, rate_hz=250.0, seconds=0.2)
    assert w.ticks == 50 and w.slack_ns == 1 and w.spin_us == 50.0
    assert slack == [1, 50_000]  # set for the waits, then restored
    # woke 20 µs before each deadline (50 - 30), spun the rest: on time to a microsecond
    assert 0.0 <= w.lateness_p50_us <= 1.0 and w.lateness_max_us <= 1.0


def test_the_first_read_drains_a_late_reply_and_asks_again(monkeypatch):
    """A loaded host: the previous port gave up on a reply that arrives as the next port
    opens. The first read asks again after draining, rather than drop the whole section."""
    from drivers.dynamixel.bench_session import BenchError
    from hilsim.bench import cpu

    monkeypatch.setattr(cpu, "DRAIN_S", 0.0)

    class Bus:
        def __init__(self, fails: int) -> None:
            self.fails = fails

        def read_positions(self, ids):
            if self.fails:
                self.fails -= 1
                raise BenchError("Incorrect status packet!")
            return {i: 2048 for i in ids}

    class Port:
        cleared = 0

        def clearPort(self):
            self.cleared += 1

    port = Port()
    assert cpu.first_read(Bus(2), port) == {1: 2048, 2: 2048, 3: 2048, 4: 2048}
    assert port.cleared == 2
    with pytest.raises(BenchError, match="Incorrect status packet"):  # the bench's to report
        cpu.first_read(Bus(3), Port())
