"""Scheduler statistics, the scheduler on a virtual clock, and the cyclictest parser/runner."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from drivers.clock import VirtualClock
from hilsim.bench import cyclictest
from hilsim.bench import sched as sched_mod
from hilsim.bench.sched import (
    SCHED_FIFO,
    SCHED_OTHER,
    lateness_stats,
    measure_scheduler,
    percentile,
    realtime,
    run_scheduler,
)

# Captured from `cyclictest -m -i 1000 -l 300 -q -h 60` (rt-tests 2.40, SCHED_OTHER, loaded host).
HIST_SAMPLE = """\
# /dev/cpu_dma_latency set to 0us
# Histogram
000000 000000
000021 000000
000022 000001
000057 000029
000058 000095
000059 000073
000060 000000
# Total: 000000198
# Min Latencies: 00022
# Avg Latencies: 00069
# Max Latencies: 01025
# Histogram Overflows: 00102
# Histogram Overflow at cycle number:
# Thread 0: 00000 00004 00006 00008 00010 00031 # 00042 others
"""
# Captured from `cyclictest -m -i 1000 -l 300 -q` (no histogram: one summary line).
SUMMARY_SAMPLE = """\
# /dev/cpu_dma_latency set to 0us
T: 0 (16814) P: 0 I:1000 C:    300 Min:     12 Act:   62 Avg:   65 Max:    1607
"""
FIFO_SAMPLE = """\
# /dev/cpu_dma_latency set to 0us
# Histogram
000005 000010
000006 000980
000007 000009
000150 000001
# Total: 000001000
# Min Latencies: 00005
# Avg Latencies: 00006
# Max Latencies: 00150
# Histogram Overflows: 00000
# Histogram Overflow at cycle number:
# Thread 0:
"""


# ----------------------------------------------------------------------------- statistics
def test_lateness_stats_from_synthetic_lateness():
    late = np.arange(1000) * 1e-6  # 0, 1, ..., 999 µs
    s = lateness_stats(late, period_s=1e-3)
    # inverted CDF: the smallest sample with at least q % of samples at or below it
    assert s.p50_us == pytest.approx(499.0)
    assert s.p99_us == pytest.approx(989.0)
    assert s.p999_us == pytest.approx(998.0)
    assert s.max_us == pytest.approx(999.0)
    assert s.mean_us == pytest.approx(499.5)
    assert s.overruns == 0
    s = lateness_stats(late, period_s=500e-6)
    assert s.overruns == 499  # 501..999 µs started after the next deadline


def test_overruns_and_a_tail():
    late = np.full(10_000, 2e-6)
    late[:20] = 3e-3  # 0.2 % of the ticks missed a whole 1 ms period
    s = lateness_stats(late, 1e-3)
    assert s.overruns == 20
    assert s.p50_us == pytest.approx(2.0) and s.p99_us == pytest.approx(2.0)
    assert s.p999_us == pytest.approx(3000.0) and s.max_us == pytest.approx(3000.0)


def test_percentile_rule_matches_histogram_reading():
    rng = np.random.default_rng(1)
    values = rng.integers(0, 50, size=777)
    hist = {int(v): int(c) for v, c in zip(*np.unique(values, return_counts=True), strict=True)}
    out = cyclictest.CyclictestOutput(histogram=hist, count=len(values), max_us=49.0)
    for q in (50, 90, 99, 99.9):
        assert out.percentile(q) == percentile(values.astype(float), q)


def test_scheduler_on_a_virtual_clock_is_never_late():
    clock = VirtualClock()
    late, wall, _cpu = run_scheduler(clock, 1000.0, 500)
    assert late.shape == (500,) and np.all(late == 0.0)
    assert wall == pytest.approx(0.5)
    run = measure_scheduler(VirtualClock(), 250.0, 100, sched="other")
    assert run.stats.ticks == 100 and run.stats.max_us == 0.0 and run.stats.overruns == 0
    assert run.sched == SCHED_OTHER and run.spin_us is None


def test_realtime_restores_the_scheduling_class(monkeypatch):
    """The suite refuses SCHED_FIFO (tests/conftest.py), so the switch back after it never ran
    here: a kernel that grants it is faked (and memory is not locked for real)."""
    policy, asked = [os.SCHED_OTHER], []

    def setscheduler(pid, new, param):
        asked.append((new, param.sched_priority))
        policy[0] = new

    monkeypatch.setattr(os, "sched_setscheduler", setscheduler)
    monkeypatch.setattr(os, "sched_getscheduler", lambda pid: policy[0])
    monkeypatch.setattr(os, "sched_getparam", lambda pid: os.sched_param(0))
    monkeypatch.setattr(sched_mod, "_libc", lambda: None)
    with realtime("other") as (cls, locked):
        assert (cls, locked) == (SCHED_OTHER, False) and not asked
    with realtime("auto", 10) as (cls, locked):
        assert (cls, locked) == (SCHED_FIFO, False) and policy == [os.SCHED_FIFO]
    assert policy == [os.SCHED_OTHER] and asked == [(os.SCHED_FIFO, 10), (os.SCHED_OTHER, 0)]

    def refuse(*_args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with realtime("auto", 10) as (cls, locked):  # refused: SCHED_OTHER, nothing to undo
        assert (cls, locked) == (SCHED_OTHER, False)
    with pytest.raises(ValueError, match="sched must be auto, fifo or other"), realtime("rr"):
        pass


# ----------------------------------------------------------------------------- cyclictest
def test_parse_histogram_output_with_overflows():
    out = cyclictest.parse_output(HIST_SAMPLE)
    assert out.histogram == {22: 1, 57: 29, 58: 95, 59: 73}
    assert out.count == 300 and out.overflows == 102
    assert (out.min_us, out.avg_us, out.max_us) == (22.0, 69.0, 1025.0)
    assert out.percentile(50) == 59.0  # 1 + 29 + 95 = 125 < 150 <= 198
    assert out.percentile(99) == 1025.0  # in the overflows: the reported maximum


def test_parse_fifo_histogram():
    out = cyclictest.parse_output(FIFO_SAMPLE)
    assert out.count == 1000 and out.overflows == 0
    assert out.percentile(50) == 6.0
    assert out.percentile(99) == 6.0  # 990 of 1000 at or below 6 µs
    assert out.percentile(99.9) == 7.0
    assert out.percentile(100) == 150.0


def test_parse_summary_line():
    out = cyclictest.parse_output(SUMMARY_SAMPLE)
    assert out.histogram == {} and out.count == 300
    assert (out.min_us, out.avg_us, out.max_us) == (12.0, 65.0, 1607.0)
    assert out.percentile(99) is None


def test_command_lines():
    base = ["ct", "-m", "-i", "1000", "-l", "500", "-q", "-h", "10000"]
    kw = dict(priority=80, hist_max_us=10_000)
    assert cyclictest.command("ct", 1000, 500, fifo=False, **kw) == base
    assert cyclictest.command("ct", 1000, 500, fifo=True, **kw) == [*base, "-p", "80"]


@pytest.fixture
def fake_cyclictest(tmp_path):
    """A stand-in cyclictest: refuses -p (no RT permission), prints FIFO_SAMPLE otherwise."""
    path = tmp_path / "cyclictest"
    sample = tmp_path / "sample.txt"
    sample.write_text(FIFO_SAMPLE)
    path.write_text(
        "#!/bin/sh\n"
        'case "$*" in --help) echo "cyclictest V 2.40"; exit 0;; esac\n'
        'case "$*" in *"-p "*) echo "Unable to change scheduling policy!" >&2; exit 1;; esac\n'
        f'cat "{sample}"\n'
    )
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return str(path)


def test_run_falls_back_to_sched_other_and_says_why(fake_cyclictest):
    run = cyclictest.run(1000, 1000, fifo=True, priority=80, path=fake_cyclictest)
    assert run.version == "2.40"
    assert run.sched == SCHED_OTHER and run.priority == 0
    assert "Unable to change scheduling policy" in run.error
    assert run.p99_us == 6.0
    d = run.as_dict()
    assert d["lateness_us"]["p99"] == 6.0 and d["sched"] == SCHED_OTHER


def test_run_without_cyclictest(monkeypatch):
    monkeypatch.setattr(cyclictest.shutil, "which", lambda _name: None)
    assert cyclictest.run(1000, 10, fifo=False, priority=80) is None
