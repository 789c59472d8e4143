"""Bus rate, latency and diagnosis measured through the SDK on the emulator in virtual time:
known wire time in, known figures out (nothing sleeps; nothing depends on host speed)."""

from __future__ import annotations

import itertools

import pytest

from drivers.dynamixel.bench_session import BenchError
from drivers.protocol2.wire_time import cycle_rate_hz, read_reply_bytes, sync_write_bytes
from hilsim.bench.busrate import measure_bus_rate, run_cycles
from hilsim.bench.diagnose import diagnose, gather_facts, sysfs_latency
from hilsim.bench.latency import measure_latency
from hilsim.bench.ports import emulator_url, open_bus, prepare_url

CASES = [
    # (servos, baud, rdt_us, turnaround_us, latency_ms)
    *[
        (n, b, 0.0, 20.0, 0.0)
        for n, b in itertools.product((1, 4, 16), (57_600, 1_000_000, 4_000_000))
    ],
    (4, 1_000_000, 500.0, 20.0, 0.0),
    (3, 2_000_000, 100.0, 50.0, 0.0),
    (4, 1_000_000, 0.0, 20.0, 1.0),
    (8, 57_600, 500.0, 20.0, 16.0),
]


def _bus(ids, baud, **kw):
    return open_bus(emulator_url(ids, baud, clock="virtual", **kw), baud)


@pytest.mark.parametrize("fast", [False, True], ids=["plain", "fast"])
@pytest.mark.parametrize(("n", "baud", "rdt_us", "turnaround_us", "latency_ms"), CASES)
def test_measured_cycle_rate_equals_the_model(n, baud, rdt_us, turnaround_us, latency_ms, fast):
    ids = list(range(1, n + 1))
    with _bus(ids, baud, rdt_us=rdt_us, turnaround_us=turnaround_us, latency_ms=latency_ms) as bb:
        row = measure_bus_rate(bb, ids, fast, cycles=12)
    model = cycle_rate_hz(
        n,
        baud,
        fast,
        return_delay_s=rdt_us * 1e-6,
        turnaround_s=turnaround_us * 1e-6,
        latency_s=latency_ms * 1e-3,
    )
    assert row.timing.failures == 0 and row.timing.cycles == 12
    assert row.model_hz == pytest.approx(model, rel=1e-12)
    assert row.achieved_hz == pytest.approx(model, rel=1e-6)
    assert row.ratio == pytest.approx(1.0, rel=1e-6)
    assert row.return_delay_us == rdt_us and row.clock == "virtual"


@pytest.mark.parametrize(("n", "baud", "latency_ms"), [(4, 1_000_000, 1.0), (16, 4_000_000, 0.0)])
def test_the_tick_blocks_cycle_rate_equals_the_model_with_its_bytes(n, baud, latency_ms):
    # the X series' tick reads 7 B a servo (position, torque, watchdog, marker), not 4
    ids = list(range(1, n + 1))
    with _bus(ids, baud, latency_ms=latency_ms) as bb:
        row = measure_bus_rate(bb, ids, True, cycles=12, block=True)
    model = cycle_rate_hz(n, baud, True, latency_s=latency_ms * 1e-3, read_data_bytes=7)
    assert row.read_bytes == 7 and row.as_dict()["read_bytes"] == 7
    assert row.model_hz == pytest.approx(model, rel=1e-12)
    assert row.achieved_hz == pytest.approx(model, rel=1e-6)
    assert row.model_hz < cycle_rate_hz(n, baud, True, latency_s=latency_ms * 1e-3)


def test_timed_run_on_the_virtual_clock():
    ids = [1, 2, 3, 4]
    with _bus(ids, 1_000_000) as bb:
        timing = run_cycles(bb, ids, True, duration_s=0.05)
    period = 1.0 / cycle_rate_hz(4, 1_000_000, True)
    assert timing.cycles == pytest.approx(0.05 / period, abs=1)
    assert timing.rate_hz == pytest.approx(1.0 / period, rel=1e-6)


def test_bus_row_json_shape():
    with _bus([1, 2], 1_000_000) as bb:
        d = measure_bus_rate(bb, [1, 2], True, cycles=3).as_dict()
    for key in ("ids", "baud", "read", "achieved_hz", "model_hz", "return_delay_us"):
        assert key in d
    assert d["ids"] == [1, 2] and d["read"] == "fast" and d["cpu_percent"] is None


def test_prepare_url_and_errors():
    assert "clock=real" in prepare_url("dxlsim://?ids=1-2")
    assert "clock=virtual" in prepare_url("dxlsim://?ids=1-2&clock=virtual")
    assert "trace=1" in prepare_url("dxlsim://?ids=1", trace=True)
    assert prepare_url("/dev/ttyUSB0", trace=True) == "/dev/ttyUSB0"
    assert prepare_url("dxlsim://named") == "dxlsim://named"
    with pytest.raises(BenchError, match="does not support"):
        open_bus("dxlsim://?ids=1&clock=virtual", 12345)
    with _bus([1], 1_000_000) as bb, pytest.raises(BenchError, match="Sync Read"):
        bb.read_positions([1, 7])  # nobody answers as ID 7


# ------------------------------------------------------------------------------ latency
@pytest.mark.parametrize("fast", [False, True], ids=["plain", "fast"])
@pytest.mark.parametrize(("baud", "latency_ms"), [(1_000_000, 0.0), (4_000_000, 1.0)])
def test_latency_in_virtual_time_is_the_wire_time(fast, baud, latency_ms):
    ids = [1, 2, 3, 4]
    url = emulator_url(ids, baud, clock="virtual", latency_ms=latency_ms)
    with open_bus(url, baud, trace=True, stamped=True) as bb:
        lat = measure_latency(bb, ids, rate_hz=250.0, duration_s=0.3, fast=fast)
    n, bt, turn = len(ids), 10.0 / baud, 20e-6
    assert lat.method.startswith("emulator") and lat.failures == 0 and lat.overruns == 0
    # tick start -> last Sync Write byte: exactly its wire time (nothing else takes time)
    assert lat.command_to_wire_s == pytest.approx(sync_write_bytes(n) * bt, abs=1e-9)
    # reply's first byte -> host has it: the reply's wire time (+ turnarounds, + adapter)
    age = read_reply_bytes(n, fast) * bt + (0 if fast else (n - 1) * turn) + latency_ms * 1e-3
    assert lat.feedback_age_s == pytest.approx(age, abs=1e-9)
    # the step: the servo model lags by ~8 ms; the figures are ordered and plausible
    start, reach = lat.motion_start_s, lat.motion_63_s
    assert start is not None and reach is not None
    assert lat.command_to_wire_s[0] < start <= reach
    assert 2e-3 < reach < 40e-3
    d = lat.as_dict()
    assert d["command_to_motion_ms"]["reach_63"] == pytest.approx(reach * 1e3)
    assert d["ticks"] == len(lat.t_tick) >= 30


def test_latency_estimate_from_write_times_matches_the_trace():
    """The hardware method (host clock at writePort + wire model) on the emulator."""
    ids = [1, 2, 3]
    url = emulator_url(ids, 1_000_000, clock="virtual")
    with open_bus(url, 1_000_000, trace=True, stamped=True) as bb:
        exact = measure_latency(bb, ids, rate_hz=500.0, duration_s=0.1, fast=True, move=False)
    with open_bus(url, 1_000_000, stamped=True) as bb:  # no trace: the estimate
        est = measure_latency(bb, ids, rate_hz=500.0, duration_s=0.1, fast=True, move=False)
    assert est.method.startswith("host clock")
    assert est.command_to_wire_s == pytest.approx(exact.command_to_wire_s, abs=1e-9)
    assert est.feedback_age_s == pytest.approx(exact.feedback_age_s, abs=1e-9)
    assert est.step_tick is None and est.motion_start_s is None
    assert len(set(est.positions)) == 1  # nothing moved


# ------------------------------------------------------------------------------ diagnosis
def test_slow_bus_gets_all_four_findings_with_their_rates():
    ids = [1, 2, 3, 4]
    url = emulator_url(ids, 57_600, rdt_us=500, latency_ms=16, firmware=44, clock="virtual")
    with open_bus(url, 57_600) as bb:
        d = diagnose(gather_facts(bb, ids))
    by_check = {f.check: f for f in d.findings}
    assert set(by_check) == {"latency_timer", "return_delay", "baud_rate", "fast_sync_read"}
    f = d.facts
    assert f.latency_timer_ms == pytest.approx(16.0, abs=1e-6)
    assert f.latency_source.startswith("inferred")
    assert not f.fast_read and [s.firmware for s in f.servos] == [44] * 4

    def rate(baud=57_600, fast=False, rdt=500e-6, latency=16e-3):
        return cycle_rate_hz(4, baud, fast, return_delay_s=rdt, latency_s=latency)

    assert d.current_hz == pytest.approx(rate(), rel=1e-6)
    assert by_check["latency_timer"].predicted_hz == pytest.approx(rate(latency=1e-3), rel=1e-6)
    assert by_check["return_delay"].predicted_hz == pytest.approx(rate(rdt=0.0), rel=1e-6)
    assert by_check["baud_rate"].predicted_hz == pytest.approx(rate(baud=1_000_000), rel=1e-6)
    assert by_check["baud_rate"].alternatives["4000000"] == pytest.approx(rate(baud=4_000_000))
    assert by_check["fast_sync_read"].predicted_hz == pytest.approx(rate(fast=True), rel=1e-6)
    everything = cycle_rate_hz(4, 1_000_000, True, return_delay_s=0.0, latency_s=1e-3)
    assert d.all_fixed_hz == pytest.approx(everything, rel=1e-6)
    for x in d.findings:
        assert x.predicted_hz > x.current_hz and x.fix
    assert "latency_ms=1" in by_check["latency_timer"].fix  # the emulator's own knob too
    assert d.as_dict()["findings"][0]["check"] == "latency_timer"


def test_healthy_bus_has_no_findings():
    ids = [1, 2, 3, 4]
    with _bus(ids, 1_000_000) as bb:
        d = diagnose(gather_facts(bb, ids))
    assert d.findings == () and d.facts.fast_read
    assert d.facts.latency_timer_ms == 0.0
    assert d.current_hz == pytest.approx(cycle_rate_hz(4, 1_000_000, True), rel=1e-9)


def test_x330_needs_firmware_46():
    url = "dxlsim://?ids=1-2&model=XL330-M288&firmware=45&rdt_us=0&clock=virtual"
    with open_bus(url, 1_000_000) as bb:
        d = diagnose(gather_facts(bb, [1, 2]))
    assert [f.check for f in d.findings] == ["fast_sync_read"]
    assert d.facts.servos[0].model == "XL330-M288" and d.facts.servos[0].fast_min_firmware == 46


def test_missing_servo_is_reported():
    with _bus([1, 2], 1_000_000) as bb:
        d = diagnose(gather_facts(bb, [1, 2, 9]))
    assert [f.check for f in d.findings] == ["no_answer"]
    assert "9" in d.findings[0].problem and d.findings[0].predicted_hz is None


def test_sysfs_latency_timer(tmp_path, monkeypatch):
    (tmp_path / "ttyUSB3").mkdir()
    (tmp_path / "ttyUSB3" / "latency_timer").write_text("16\n")
    monkeypatch.setattr(
        "hilsim.bench.diagnose.SYSFS_LATENCY", str(tmp_path / "{name}" / "latency_timer")
    )
    assert sysfs_latency("/dev/ttyUSB3") == (str(tmp_path / "ttyUSB3" / "latency_timer"), 16.0)
    assert sysfs_latency("/dev/ttyUSB4") == (None, None)
    assert sysfs_latency(None) == (None, None)
