"""``hilsim bench``'s CPU-over-a-pty section (hilsim.bench.cpu): its line, its JSON and when
it runs. The measurement itself needs a real pty and seconds of real time: not tested here
(``python -m hilsim.bench.cpu``)."""

from __future__ import annotations

import argparse
import json

from hilsim.bench.cpu import CpuResult, CycleCpu, DemoCpu, add_to_bench, for_bench


def cycles(port: str, cpu: float, wall: float) -> CycleCpu:
    return CycleCpu(port, 500, 7, cpu, wall, cpu, wall, 0)


def result() -> CpuResult:
    demo = DemoCpu(6.0, 250.0, 180.0, [180.0, 190.0], [0, 0], [0, 0])
    return CpuResult(
        cycles("bare SDK (busy-poll)", 1450.0, 1460.0),
        cycles("hilsim", 150.0, 1480.0),
        demo,
        load=[0.5, 0.6, 0.7],
    )


def test_the_line_says_both_ports_cpu_and_wall():
    text = result().text()
    assert text.splitlines()[0] == (
        "CPU per cycle over a pty: bare SDK (busy-poll) 1450 µs, hilsim 150 µs; "
        "wall per cycle 1460 vs 1480 µs (+1.4%)"
    )
    assert "load 0.50 0.60 0.70" in text
    assert "The demo over a pty: 180 µs of CPU per tick at 250 Hz (4.5 % of a core" in text


def test_it_joins_the_bench_json_under_cpu(tmp_path, capsys):
    path = tmp_path / "bench.json"
    path.write_text(json.dumps({"bus": []}))
    add_to_bench(result(), path)
    data = json.loads(path.read_text())
    assert data["bus"] == [] and data["cpu"]["hilsim"]["cpu_us"] == 150.0
    assert data["cpu"]["demo"]["cpu_us_per_tick"] == 180.0
    assert "CPU per cycle over a pty" in capsys.readouterr().out


def test_it_runs_only_for_the_built_in_emulator_on_the_real_clock():
    def args(**kw):
        return argparse.Namespace(**{"config": None, "port": None, "clock": "real", **kw})

    for a in (args(clock="virtual"), args(port="/dev/ttyUSB0"), args(config="rig.toml")):
        assert for_bench(a, None, print) is None  # returns before measuring anything
