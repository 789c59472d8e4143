"""tools/bench_scale.py --alongside: cyclictest's output read, and the loop's overrun episodes
matched in time with its late wake-ups. No cyclictest runs here: its output is given."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

REPO = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("bench_scale", REPO / "tools" / "bench_scale.py")
assert _spec is not None and _spec.loader is not None
bench_scale = importlib.util.module_from_spec(_spec)
sys.modules["bench_scale"] = bench_scale
_spec.loader.exec_module(bench_scale)

#: what cyclictest 2.x prints with -q -S --spike on SIGINT (two CPUs)
OUTPUT = """WARN: not setting cpu_dma_latency from cyclictest
T: 0 (16711) P:80 I:1000 C:  59987 Min:     10 Act:   22 Avg:   48 Max:    5304
T: 1 (16712) P:80 I:1000 C:  59990 Min:      9 Act:   22 Avg:   23 Max:    2057

T: 0 Spike:     845: TS:  100001000000
T: 1 Spike:     300: TS:  100002000500
T: 1 Spike:    1374: TS:  100005000000
T: 0 Spike:     400: TS:  100090000000
spikes = 4
"""


class Finished:
    returncode = 0

    def poll(self) -> int:
        return 0

    def communicate(self, timeout: float | None = None) -> tuple[str, str]:
        return OUTPUT, ""


def test_cyclictests_threads_and_late_wake_ups_are_read_with_their_times():
    got = bench_scale.stop_alongside(Finished())
    assert got["threads"] == {0: (59987, 5304), 1: (59990, 2057)}
    assert got["spikes"][0] == (0, 845, 100001.0)  # CPU, µs late, CLOCK_MONOTONIC s
    assert [s[:2] for s in got["spikes"]] == [(0, 845), (1, 300), (1, 1374), (0, 400)]
    assert bench_scale.stop_alongside("cyclictest not run: no such file") == {
        "error": "cyclictest not run: no such file"
    }


def test_episodes_are_matched_with_late_wake_ups_in_the_shows_span(monkeypatch):
    # 1 kHz from t0 = 100000 s: overrun episodes begin at 1.000 s, 2.000 s and 4.000 s of show
    ticks = 10_000
    over = np.zeros(ticks, dtype=bool)
    over[[1000, 1001, 2000, 4000, 4001, 4002]] = True
    run = SimpleNamespace(overrun=over, t_sched=np.arange(ticks) * 1e-3)
    import hilsim.rig
    import hilsim.telemetry.reader

    monkeypatch.setattr(hilsim.telemetry.reader, "read_run", lambda d: run)
    pinned = [None]
    monkeypatch.setattr(
        hilsim.rig,
        "load_rig",
        lambda rig: SimpleNamespace(loop=SimpleNamespace(cpu=pinned[0], rate_hz=1000.0)),
    )
    summary = {"loop": {"clock_t0": 100000.0, "sched": "SCHED_FIFO:50"}, "duration_s": 10.0}
    beside = bench_scale.stop_alongside(Finished())
    a = bench_scale.coincide(Path("run"), summary, beside, Path("rig.toml"))
    # the wake-up at 90 s is after the show: not counted; 1.000 s (CPU 0) and 2.0005 s (CPU 1)
    # meet an episode; 5.000 s (CPU 1) meets none; the episode at 4 s has none
    assert a["episodes"] == 3 and a["episodes_at_host_wakeup"] == 2 and a["episodes_without"] == 1
    assert a["late_wakeups"] == {0: 1, 1: 2} and a["late_wakeups_1ms"] == 1
    assert a["max_us"] == 1374 and a["cpu_matched"] == "any"
    pinned[0] = 1  # the loop pinned to CPU 1: only that CPU's wake-ups explain its episodes
    a = bench_scale.coincide(Path("run"), summary, beside, Path("rig.toml"))
    assert a["episodes_at_host_wakeup"] == 1 and a["cpu_matched"] == 1
    line = bench_scale.alongside_line(a, 250)
    assert "3 overrun episodes of the loop" in line and "woke 250 us or more late 3 times" in line
    assert "(CPU 0 1, CPU 1 2; 1 of 1 ms or more, max 1374 us)" in line
    assert "1 episodes began within [-1, +3] ticks of such a wake-up on CPU 1, 2 did not" in line
    assert line.endswith("the loop ran SCHED_FIFO:50")
    assert "SCHED_OTHER" in bench_scale.alongside_line({**a, "loop_sched": "SCHED_OTHER"}, 250)
