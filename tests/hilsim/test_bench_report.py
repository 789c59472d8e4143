"""The report (JSON shape, terminal text), the PNGs, and the CLI end to end in virtual time."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from hilsim.bench import cyclictest
from hilsim.bench.busrate import measure_bus_rate
from hilsim.bench.diagnose import diagnose, gather_facts
from hilsim.bench.latency import measure_latency
from hilsim.bench.ports import emulator_url, open_bus
from hilsim.bench.report import BenchReport, LoopResult
from hilsim.bench.sched import SCHED_FIFO, SchedulerRun, lateness_stats
from hilsim.cli import bench as bench_cli
from hilsim.cli import main as hilsim_main
from tests.hilsim.test_bench_sched import FIFO_SAMPLE

SLOW_URL = "dxlsim://?ids=1-4&baud=57600&rdt_us=500&latency_ms=16&firmware=44"


def _loop() -> LoopResult:
    rng = np.random.default_rng(0)
    late = rng.exponential(0.05e-6, size=2000)
    late[7] = 650e-6
    slept = rng.exponential(40e-6, size=2000)
    ours = SchedulerRun(
        1000.0, slept, lateness_stats(slept, 1e-3), 2.0, 0.06, SCHED_FIFO, 80, True, 0.0
    )
    spin = SchedulerRun(
        1000.0, late, lateness_stats(late, 1e-3), 2.0, 0.4, SCHED_FIFO, 80, True, 200.0
    )
    ct = cyclictest.CyclictestRun(
        ["cyclictest", "-m"],
        "2.40",
        SCHED_FIFO,
        80,
        1000,
        1000,
        cyclictest.parse_output(FIFO_SAMPLE),
    )
    return LoopResult(ours, ct, True, spin)


@pytest.fixture(scope="module")
def report() -> BenchReport:
    rep = BenchReport(command="hilsim bench --test", quick=True, subject="test", rig_rate_hz=500.0)
    rep.loops.append(_loop())
    for n, fast in ((1, False), (1, True), (4, False), (4, True)):
        ids = list(range(1, n + 1))
        with open_bus(emulator_url(ids, 1_000_000, clock="virtual"), 1_000_000) as bb:
            rep.bus.append(measure_bus_rate(bb, ids, fast, cycles=5))
    url = emulator_url([1, 2], 1_000_000, clock="virtual")
    with open_bus(url, 1_000_000, trace=True, stamped=True) as bb:
        rep.latency = measure_latency(bb, [1, 2], rate_hz=500.0, duration_s=0.1, fast=True)
    with open_bus(SLOW_URL + "&clock=virtual", 57_600) as bb:
        rep.diagnosis = diagnose(gather_facts(bb, [1, 2, 3, 4]))
    return rep


def test_json_shape(report, tmp_path):
    path = tmp_path / "bench.json"
    report.write_json(path)
    d = json.loads(path.read_text())
    loop = d["loop"]
    assert loop["rate_hz"] == 1000.0 and loop["sched"] == SCHED_FIFO
    assert set(loop["lateness_us"]) == {"p50", "p99", "p999", "max"}
    assert loop["cyclictest_p99_us"] == 6.0
    assert loop["p99_ratio"] == pytest.approx(loop["lateness_us"]["p99"] / 6.0)
    assert loop["cpu_percent"] == pytest.approx(3.0) and loop["spin_us"] == 0.0  # sleep only
    spin = loop["spin"]
    assert spin["spin_us"] == 200.0 and spin["cpu_percent"] == pytest.approx(20.0)
    assert set(spin["lateness_us"]) == {"p50", "p99", "p999", "max"}
    for row in d["bus"]:
        assert {"ids", "baud", "read", "achieved_hz", "model_hz", "return_delay_us"} <= set(row)
        assert row["read"] in ("fast", "plain")
    lat = d["latency"]
    assert {"command_to_wire_us", "command_to_motion_ms", "feedback_age_us"} <= set(lat)
    assert len(d["diagnosis"]["findings"]) == 4
    assert d["verdict"] and d["host"]["cpus"] >= 1
    json.dumps(d, allow_nan=False)  # no NaN anywhere


def test_terminal_text(report):
    text = report.text()
    for heading in ("Loop timing", "Bus rate", "Latency at 500 Hz", "Diagnosis of", "Verdict"):
        assert heading in text
    assert "ours / cyclictest p99" in text and "cyclictest" in text
    assert "with every fix" in text
    assert "The bus keeps up" in text  # 1 servo: ~1,900 cycles/s for a 500 Hz rig


def test_the_report_compares_sleep_with_sleep_first_and_ends_with_the_verdict(report):
    """Like with like: the loop's first row sleeps as cyclictest does (spin window 0); the
    spin window is a separate, labelled section with its CPU; one fixed order, verdict last."""
    text = report.text()
    lines = text.splitlines()
    first = next(i for i, x in enumerate(lines) if x.startswith("Loop timing"))
    assert "spin window 0" in lines[first] and "cyclictest" in lines[first]
    assert lines[first + 2].split()[:3] == ["ours,", "sleep", "only"]
    assert lines[first + 3].split()[0] == "cyclictest"
    assert "sleep vs sleep: ours / cyclictest p99 =" in lines[first + 4]
    spin = next(i for i, x in enumerate(lines) if x.startswith("Spin window"))
    assert spin > first + 4 and "200 µs" in lines[spin] and "not comparable" in lines[spin]
    assert "% of a core" in lines[spin + 3]
    order = ["Loop timing", "Spin window", "Bus rate", "Latency", "Diagnosis", "Verdict"]
    at = [next(i for i, x in enumerate(lines) if x.startswith(h)) for h in order]
    assert at == sorted(at)
    verdict = lines.index("Verdict")
    assert all(x.startswith("  ") for x in lines[verdict + 1 :])  # nothing after the verdict


def test_emulated_figures_say_so_in_the_text_and_the_plots(report, tmp_path, monkeypatch):
    from hilsim.bench import plots
    from hilsim.bench.report import EMULATED

    report.emulated = True
    try:
        text = report.text()
    finally:
        report.emulated = False
    for heading in ("Bus rate", "Latency at", "Diagnosis of"):
        line = next(x for x in text.splitlines() if x.startswith(heading))
        assert EMULATED in line, line
    titles = []
    real_save = plots._save

    def keep(fig, path, plt):
        titles.append(fig._suptitle.get_text() if fig._suptitle else fig.axes[0].get_title())
        return real_save(fig, path, plt)

    monkeypatch.setattr(plots, "_save", keep)
    plots.plot_bus_rate(report.bus, tmp_path / "bus_rate.png")
    plots.plot_step(report.latency, tmp_path / "step.png", emulated=True)
    assert all(t.startswith(f"{EMULATED}\n") for t in titles) and len(titles) == 2


def test_the_loop_is_measured_sleeping_first_then_cyclictest_then_the_spin_window(monkeypatch):
    from hilsim.bench import runner
    from hilsim.bench.runner import BenchPlan

    done = []

    def scheduler(clock, rate, ticks, **_kw):
        done.append(("ours", clock.spin_s))
        late = np.zeros(ticks)
        stats = lateness_stats(late, 1 / rate)
        return SchedulerRun(rate, late, stats, 1.0, 0.1, SCHED_FIFO, 80, True, clock.spin_s * 1e6)

    def ct_run(interval_us, ticks, **_kw):
        done.append(("cyclictest", interval_us))
        return _loop().cyclictest

    monkeypatch.setattr(runner, "measure_scheduler", scheduler)
    monkeypatch.setattr(cyclictest, "find", lambda: "/usr/bin/cyclictest")
    monkeypatch.setattr(cyclictest, "run", ct_run)
    report = BenchReport(command="x", quick=True, subject="t")
    runner._loops(BenchPlan(loop_duration_s=0.1, spin_us=100.0), report, lambda _s: None)
    assert done == [("ours", 0.0), ("cyclictest", 1000), ("ours", pytest.approx(100e-6))]
    (lr,) = report.loops
    assert lr.ours.spin_us == 0.0 and lr.spin is not None and lr.spin.spin_us == pytest.approx(100)


def test_the_quick_plan_is_short_and_says_how_long():
    parser = __import__("argparse").ArgumentParser()
    bench_cli.add_arguments(parser)
    quick = bench_cli.build_plan(parser.parse_args(["--quick"]))
    full = bench_cli.build_plan(parser.parse_args([]))
    assert len(quick.sweep) == 4 and len(full.sweep) == 8  # 4 and 16 servos with --quick
    assert quick.expected_s() <= 25 < full.expected_s()
    help_text = parser.format_help()
    assert f"~{bench_cli.QUICK_S} s" in " ".join(help_text.split())


def test_missing_cyclictest_says_how_to_install():
    lr = _loop()
    missing = LoopResult(lr.ours, None, False, lr.spin)
    rep = BenchReport(command="x", quick=True, subject="t", loops=[missing])
    assert cyclictest.INSTALL_HINT in rep.text()
    assert rep.as_dict()["loop"]["cyclictest_install"] == cyclictest.INSTALL_HINT
    assert rep.as_dict()["loop"]["cyclictest_p99_us"] is None


def test_plots_are_written(report, tmp_path):
    from hilsim.bench import plots

    files = [
        plots.plot_lateness(report.loops[0], tmp_path / "lateness.png"),
        plots.plot_bus_rate(report.bus, tmp_path / "bus_rate.png"),
        plots.plot_step(report.latency, tmp_path / "step.png"),
    ]
    for f in files:
        assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_end_to_end_on_the_virtual_clock(tmp_path, capsys):
    out = tmp_path / "out"
    args = [
        "--clock",
        "virtual",
        "--quick",
        "--servos",
        "1,2",
        "--bauds",
        "1000000",
        "--no-plots",
        "--out",
    ]
    code = hilsim_main(["bench", *args, str(out)])
    assert code == 0
    d = json.loads((out / "bench.json").read_text())
    assert d["loop"] is None  # no loop timing in virtual time
    rows = [(len(r["ids"]), r["read"], r["read_bytes"]) for r in d["bus"]]
    # Fast: the SDK's read of positions, then the tick block the X series' tick reads
    assert rows == [
        (1, "plain", 4),
        (1, "fast", 4),
        (1, "fast", 7),
        (2, "plain", 4),
        (2, "fast", 4),
        (2, "fast", 7),
    ]
    assert all(r["achieved_hz"] == pytest.approx(r["model_hz"], rel=1e-6) for r in d["bus"])
    text = capsys.readouterr().out
    assert "Bus rate" in text and "tick block 7 B" in text
    assert "Torque Enable, Bus Watchdog" in text  # what each read carries, said


def test_cli_diagnoses_a_slow_port(tmp_path, capsys):
    args = ["--clock", "virtual", "--quick", "--no-plots", "--port", SLOW_URL]
    code = hilsim_main(["bench", *args, "--json", str(tmp_path / "b.json"), "--out", str(tmp_path)])
    assert code == 0
    d = json.loads((tmp_path / "b.json").read_text())
    checks = {f["check"] for f in d["diagnosis"]["findings"]}
    assert checks == {"latency_timer", "return_delay", "baud_rate", "fast_sync_read"}
    assert [r["read"] for r in d["bus"]] == ["plain"]  # firmware 44: no Fast Sync Read
    assert "tops out" in capsys.readouterr().out


def test_cli_bad_baud_is_one_line_and_exit_code_2(tmp_path, capsys):
    args = [
        "--clock",
        "virtual",
        "--quick",
        "--no-plots",
        "--port",
        "dxlsim://?ids=1-2",
        "--baud",
        "123",
        "--out",
    ]
    code = hilsim_main(["bench", *args, str(tmp_path)])
    assert code == 2
    err = capsys.readouterr().err
    assert "--baud '123': the servos do not run at that rate" in err and len(err.splitlines()) == 1


def test_plan_from_a_rig_file(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text(
        """
[bus]
port = "dxlsim://?ids=1-2&rdt_us=0"
baud = 1000000

[loop]
rate_hz = 250

[[joints]]
name = "a"
servo_id = 1
min_deg = -60
max_deg = 60
spring = { frequency_hz = 3.0, damping_ratio = 0.7 }
target = { type = "sine", amplitude_deg = 30, frequency_hz = 0.25 }

[[joints]]
name = "b"
servo_id = 2
min_deg = -60
max_deg = 60
spring = { frequency_hz = 3.0, damping_ratio = 0.7 }
target = { type = "sine", amplitude_deg = 30, frequency_hz = 0.25 }
"""
    )
    parser = __import__("argparse").ArgumentParser()
    bench_cli.add_arguments(parser)
    plan = bench_cli.build_plan(parser.parse_args([str(rig), "--quick"]))
    assert plan.loop_rates_hz == (1000.0, 250.0) and plan.rig_rate_hz == 250.0
    assert plan.target.ids == (1, 2) and plan.target.baud == 1_000_000
    assert plan.sweep == () and plan.latency_rate_hz == 250.0
    assert plan.loop_duration_s == 1.5 and plan.bus_duration_s == 0.3
    assert plan.spin_us == 100.0  # the rig's spin window, as its shows run
    rig.write_text(rig.read_text().replace("[loop]\n", "[loop]\nspin_us = 250\n", 1))
    assert bench_cli.build_plan(parser.parse_args([str(rig)])).spin_us == 250.0
    assert bench_cli.build_plan(parser.parse_args([str(rig), "--spin-us", "40"])).spin_us == 40
    assert bench_cli.build_plan(parser.parse_args(["--quick"])).spin_us == 100.0  # no rig


def test_importing_the_cli_imports_neither_matplotlib_nor_the_sdk():
    code = (
        "import sys, hilsim.cli.bench, hilsim.cli; hilsim.cli.build_parser(); "
        "bad = {'matplotlib', 'dynamixel_sdk'} & set(sys.modules); assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_subcommand_is_registered_with_the_contract():
    from hilsim.cli import SUBCOMMANDS, build_parser

    assert SUBCOMMANDS["bench"] == "hilsim.cli.bench"
    assert isinstance(bench_cli.HELP, str) and bench_cli.HELP
    args = build_parser().parse_args(["bench", "--quick", "--port", "dxlsim://?ids=1"])
    assert args._run is bench_cli.run and args.quick and args.sched == "auto"
