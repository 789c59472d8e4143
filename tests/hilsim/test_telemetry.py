"""Telemetry writer, run statistics and run reader.

No test sleeps: threads are synchronised with Events (with generous timeouts that only matter when
something is broken), and nothing asserts wall-clock speed.
"""

from __future__ import annotations

import errno
import json
import math
import os
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.servo_bus import ReadStatus
from hilsim.telemetry import TelemetryWriter, WriterFailedError
from hilsim.telemetry import writer as tm
from hilsim.telemetry.end_record import end_bytes
from hilsim.telemetry.format import (
    EVENTS_JSONL,
    RESERVE_NAME,
    SUMMARY_JSON,
    TELEMETRY_CSV,
    TelemetryError,
    csv_columns,
)
from hilsim.telemetry.reader import NotARunError, RunFormatError, read_run
from hilsim.telemetry.stats import RunStats, comm_errors, summarize
from tests.hilsim.tick_rows import stats_record, tick_record

JOINTS = ("neck_pan", "neck_tilt", "jaw")
WAIT_S = 10.0  # upper bound on any wait for the writer thread; reached only on failure


def write_synthetic_run(
    run_dir: Path, *, rate_hz: float = 500.0, seconds: float = 8.0, seed: int = 1
) -> dict[str, np.ndarray]:
    """A plausible 4-joint run, written through TelemetryWriter; returns the arrays written.

    Targets: a sine, steps, a triangle and a hold; a damped spring follows; safety clips one
    joint; present lags the command by 3 ticks, quantised to servo ticks, with stale stretches
    and an alert; lateness is mostly tens of µs with rare ms spikes.
    """
    rng = np.random.default_rng(seed)
    names = ("neck_pan", "neck_tilt", "jaw", "brow")
    n, h = len(names), 1.0 / rate_hz
    ticks = int(seconds * rate_hz)
    t = np.arange(ticks) * h
    target = np.empty((ticks, n))
    target[:, 0] = np.radians(40.0) * np.sin(2 * np.pi * 0.4 * t)
    target[:, 1] = np.radians(np.where((t % 3.0) < 1.5, 25.0, -10.0))
    target[:, 2] = np.radians(30.0) * (2 * np.abs((t * 0.5) % 1.0 - 0.5))
    target[:, 3] = np.radians(5.0)
    x, v = np.zeros(n), np.zeros(n)
    k, c = (2 * np.pi * 2.0) ** 2, 2 * 0.5 * (2 * np.pi * 2.0)
    sim_x, sim_v = np.empty((ticks, n)), np.empty((ticks, n))
    for i in range(ticks):
        v += h * (k * (target[i] - x) - c * v)
        x += h * v
        sim_x[i], sim_v[i] = x, v
    cmd = sim_x.copy()
    cmd[:, 1] = np.clip(cmd[:, 1], np.radians(-5.0), np.radians(22.0))
    q = 2 * np.pi / 4096
    present = np.round(np.vstack([np.repeat(cmd[:1], 3, axis=0), cmd[:-3]]) / q) * q
    status = np.zeros((ticks, n), dtype=np.int8)
    status[rng.random((ticks, n)) < 0.004] = ReadStatus.STALE
    status[int(0.375 * ticks) : int(0.4125 * ticks), 2] = ReadStatus.STALE
    status[int(0.625 * ticks) : int(0.63125 * ticks), 3] = ReadStatus.ALERT
    status[int(0.75 * ticks), 0] = ReadStatus.ERROR
    present[status != ReadStatus.OK] = np.nan
    lateness = rng.exponential(15.0, ticks) + 3.0
    spikes = rng.random(ticks) < 0.002
    lateness[spikes] = rng.uniform(300.0, 2500.0, int(spikes.sum()))
    t_actual = t + lateness * 1e-6
    stage = np.column_stack(
        [
            rng.normal(18.0, 2.0, ticks),
            rng.normal(6.0, 1.0, ticks),
            rng.normal(1150.0, 40.0, ticks) + (status != 0).any(axis=1) * 600.0,
            rng.normal(4.0, 0.5, ticks),
        ]
    )
    overrun = lateness + stage.sum(axis=1) > h * 1e6
    comm = np.cumsum((status == ReadStatus.STALE).any(axis=1))
    with TelemetryWriter(
        run_dir, names, servo_ids=[1, 2, 3, 4], config_text="[rig]\nname = 'synthetic'\n"
    ) as w:
        w.event("start", "run started", 0, 0.0, rate_hz=rate_hz)
        for i in range(ticks):
            rec = tick_record(i, t[i], t_actual[i], target[i], sim_x[i], sim_v[i], cmd[i],
                              present[i], status[i], *stage[i][:3], math.nan, False,
                              int(comm[i]))  # fmt: skip
            w.record(rec)
            rec.t_telemetry_us, rec.overrun = stage[i][3], bool(overrun[i])
            w.amend(rec)
        w.event("stop", "finished", ticks - 1, t[-1])
        w.close({"exit_code": 0, "exit_reason": "finished"})
    return {
        "t": t,
        "target": target,
        "sim_x": sim_x,
        "cmd": cmd,
        "present": present,
        "status": status,
        "lateness": lateness,
    }


def _record_row(
    w: TelemetryWriter, i: int, vals: np.ndarray, status: np.ndarray | None = None
) -> bool:
    return w.record(_row(w, i, vals, status))


def _row(w: TelemetryWriter, i: int, vals: np.ndarray, status: np.ndarray | None = None):
    n = len(w.joint_names)
    st_ = np.zeros(n, dtype=np.int8) if status is None else status
    return tick_record(
        i,
        i * 1e-3,
        i * 1e-3 + 2e-6,
        vals,
        vals + 1,
        vals + 2,
        vals + 3,
        vals + 4,
        st_,
        1.5,
        2.25,
        3.125,
        4.0,
        False,
        0,
    )


# ----------------------------------------------------------------------------- round trip


def test_columns_are_grouped_by_quantity() -> None:
    cols = csv_columns(["a", "b"])
    assert cols == [
        "tick", "t_sched", "t_actual", "lateness_us",
        "target_a", "target_b", "sim_x_a", "sim_x_b", "sim_v_a", "sim_v_b",
        "cmd_a", "cmd_b", "present_a", "present_b", "status_a", "status_b",
        "t_sim_us", "t_safety_us", "t_bus_us", "t_telemetry_us", "overrun", "comm_errors",
        "host_stall_us", "skipped_ticks",
    ]  # fmt: skip
    # layout 1, still read, had no skipped_ticks
    assert csv_columns(["a", "b"], 1) == cols[:-1]


def test_round_trip_is_exact(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    n_rows, n = 1000, len(JOINTS)
    data = {f: rng.normal(0.0, 2.0, (n_rows, n)) for f in ("target", "sim_x", "sim_v", "cmd")}
    data["target"][0] = [math.pi, -0.0, 1e-300]
    data["sim_x"][1] = [np.nextafter(1.0, 2.0), 5e-324, -1.7976931348623157e308]
    present = rng.normal(0.0, 2.0, (n_rows, n))
    status = rng.integers(0, 4, (n_rows, n)).astype(np.int8)
    present[status != 0] = np.nan
    t_sched = np.arange(n_rows) / 997.0
    t_actual = t_sched + rng.uniform(0, 1e-3, n_rows)
    buf = np.empty(n)  # the loop reuses its buffers: record must copy
    w = TelemetryWriter(tmp_path / "run", JOINTS, config_text="[rig]\n")
    w.event("start", "go", 0, 0.0, seed=np.int64(3), gains=np.array([1.0, 2.0]))
    for i in range(n_rows):
        buf[:] = data["target"][i]
        assert w.record(
            tick_record(
                i,
                t_sched[i],
                t_actual[i],
                buf,
                data["sim_x"][i],
                data["sim_v"][i],
                data["cmd"][i].tolist(),
                present[i],
                status[i],
                10.0 + i,
                2.5,
                1234.5678,
                0.001,
                i % 7 == 0,
                i // 10,
            )
        )
        buf[:] = -1.0
    summary = w.close({"exit_code": 0, "exit_reason": "end of show"})
    run = read_run(tmp_path / "run")
    assert summary == run.summary

    assert run.warnings == [] and not run.truncated
    assert run.joint_names == JOINTS and run.n_ticks == n_rows
    np.testing.assert_array_equal(run.tick, np.arange(n_rows))
    np.testing.assert_array_equal(run.t_sched, t_sched)
    np.testing.assert_array_equal(run.t_actual, t_actual)
    for f in ("target", "sim_x", "sim_v", "cmd"):
        np.testing.assert_array_equal(run.joint(f), data[f])
    assert math.copysign(1.0, run.joint("target")[0, 1]) == -1.0  # -0.0 kept
    np.testing.assert_array_equal(run.joint("present"), present)  # NaN where not OK
    np.testing.assert_array_equal(run.joint("status"), status)
    assert run.joint("status").dtype == np.int8
    np.testing.assert_allclose(run.lateness_us, (t_actual - t_sched) * 1e6, atol=5e-4)
    np.testing.assert_allclose(run.stage_us("sim"), 10.0 + np.arange(n_rows))
    assert run.stage_us("bus")[5] == pytest.approx(1234.568)
    np.testing.assert_array_equal(run.overrun, np.arange(n_rows) % 7 == 0)
    np.testing.assert_array_equal(run.comm_errors, np.arange(n_rows) // 10)

    assert run.events[0]["kind"] == "start" and run.events[0]["seed"] == 3
    assert run.events[0]["gains"] == [1.0, 2.0] and run.events[0]["tick"] == 0
    assert isinstance(run.events[0]["wall"], float)
    assert run.summary is not None and run.summary["exit_code"] == 0
    assert run.summary["ticks"] == n_rows and run.summary["overruns"] == len(range(0, n_rows, 7))
    assert run.summary["stale_reads"]["jaw"] == int((status[:, 2] == ReadStatus.STALE).sum())
    assert run.summary["telemetry"]["rows_written"] == n_rows
    assert run.summary["telemetry"]["rows_dropped"] == 0
    assert run.config_text == "[rig]\n"


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    values=st.lists(st.floats(allow_nan=False, width=64), min_size=2, max_size=2),
    t=st.floats(min_value=0.0, max_value=1e6),
)
def test_any_double_round_trips(
    tmp_path_factory: pytest.TempPathFactory, values: list[float], t: float
) -> None:
    d = tmp_path_factory.mktemp("run")
    with TelemetryWriter(d, ["a", "b"]) as w:
        w.record(
            tick_record(
                0, t, t, values, values, values, values, values, [0, 0], 0, 0, 0, 0, False, 0
            )
        )
    run = read_run(d)
    assert run.t_sched.tolist() == [t]
    for f in ("target", "sim_x", "sim_v", "cmd", "present"):
        assert run.joint(f)[0].tolist() == values


def test_close_twice_and_after_close(tmp_path: Path) -> None:
    w = TelemetryWriter(tmp_path, JOINTS)
    _record_row(w, 0, np.zeros(3))
    w.close({"exit_code": 0, "exit_reason": "first"})
    w.close({"exit_code": 1, "exit_reason": "second"})  # no-op: the first summary stays
    assert json.loads((tmp_path / SUMMARY_JSON).read_text())["exit_reason"] == "first"
    with pytest.raises(TelemetryError, match="closed"):
        _record_row(w, 1, np.zeros(3))
    assert w.event("late", "after close", 1, 0.001) is False
    assert w.flush() is True


def test_close_from_two_threads(tmp_path: Path) -> None:
    w = TelemetryWriter(tmp_path, JOINTS)
    for i in range(100):
        _record_row(w, i, np.full(3, i * 0.5))
    threads = [threading.Thread(target=w.close, args=({"by": k},)) for k in range(2)]
    for th in threads:
        th.start()
    for th in threads:
        th.join(WAIT_S)
        assert not th.is_alive()
    w.close()
    assert read_run(tmp_path).n_ticks == 100


def test_context_manager_closes(tmp_path: Path) -> None:
    with TelemetryWriter(tmp_path, JOINTS) as w:
        _record_row(w, 0, np.ones(3))
    run = read_run(tmp_path)
    assert run.n_ticks == 1 and run.summary is not None


def test_rejects_reused_run_dir_and_bad_joint_names(tmp_path: Path) -> None:
    TelemetryWriter(tmp_path, JOINTS).close()
    with pytest.raises(FileExistsError):
        TelemetryWriter(tmp_path, JOINTS)
    for bad in ([], ["a", "a"], ["a,b"], ["x\n"], [""], [" a"]):
        with pytest.raises(ValueError):
            TelemetryWriter(tmp_path / "other", bad)


def test_block_overflow_is_lossless(tmp_path: Path) -> None:
    w = TelemetryWriter(tmp_path, JOINTS, queue_size=4, overflow="block")
    for i in range(500):
        assert _record_row(w, i, np.full(3, float(i)))
    w.close()
    run = read_run(tmp_path)
    assert run.warnings == []
    np.testing.assert_array_equal(run.tick, np.arange(500))
    np.testing.assert_array_equal(run.joint("target")[:, 0], np.arange(500.0))


def test_rows_go_in_larger_chunks_while_the_free_time_has_no_end(tmp_path: Path) -> None:
    """A virtual-time show never sets the writer's free time an end: no tick can be made
    late, so the writer takes the ring's rows many chunks at a time (fewer turns of its loop
    and of the interpreter lock); all rows written, in order."""
    from hilsim.telemetry import sinks, writer_thread

    asked: list[int] = []
    take = sinks.CsvSink.take

    def counted(self, ring, n):
        asked.append(n)
        return take(self, ring, n)

    sinks.CsvSink.take = counted  # type: ignore[method-assign]
    try:
        w = TelemetryWriter(tmp_path, JOINTS, queue_size=1024, overflow="block")
        w.slack.clear()  # rows pile up first
        for i in range(600):
            assert _record_row(w, i, np.full(3, float(i)))
        w.slack.set()
        w.close()
    finally:
        sinks.CsvSink.take = take  # type: ignore[method-assign]
    assert max(asked) == writer_thread._FREE_CHUNKS * w._chunk_rows
    np.testing.assert_array_equal(read_run(tmp_path).tick, np.arange(600))


# ----------------------------------------------------------------------------- disk trouble


class _GatedFile:
    """A file whose write() waits on ``gate`` (a stalled disk) or raises ``fail`` (a full one),
    once ``armed`` (so the header, written in the constructor, goes through)."""

    def __init__(self, inner, owner: _TroubledWriter) -> None:
        self._inner, self._owner = inner, owner

    def write(self, text: str) -> int:
        owner = self._owner
        if owner.armed:
            owner.entered.set()
            if owner.fail is not None:
                raise owner.fail
            if owner.gate is not None and not owner.gate.wait(WAIT_S):
                raise TimeoutError("test gate never opened")
        return self._inner.write(text)

    def __getattr__(self, name: str):
        return getattr(self._inner, name)


class _TroubledWriter(TelemetryWriter):
    """A writer whose CSV sink stalls on ``gate`` or raises ``fail`` after the header."""

    def __init__(
        self, *args, gate: threading.Event | None = None, fail: OSError | None = None, **kw
    ) -> None:
        self.gate, self.fail, self.armed = gate, fail, False
        self.entered = threading.Event()  # set when the writer thread reaches the sink
        super().__init__(*args, **kw)
        self.armed = True

    def _open(self, path: Path, mode: str):
        inner = super()._open(path, mode)
        return _GatedFile(inner, self) if path.name == TELEMETRY_CSV else inner


def test_stalled_disk_never_blocks_and_counts_drops(tmp_path: Path) -> None:
    gate = threading.Event()
    w = _TroubledWriter(tmp_path, JOINTS, queue_size=64, gate=gate)
    n_rows = 1000
    accepted: list[bool] = []

    def loop() -> None:
        for i in range(n_rows):
            accepted.append(_record_row(w, i, np.full(3, float(i))))
            if i == 10:
                w.event("fault", "stalled?", i, i * 1e-3)  # fsync request: must not block either

    th = threading.Thread(target=loop)
    th.start()
    th.join(WAIT_S)
    assert not th.is_alive(), "record() blocked on a stalled disk"
    n_ok = sum(accepted)
    assert w.rows_dropped == n_rows - n_ok > 0
    assert w.rows_recorded == n_ok
    assert n_ok >= 64  # at least the ring's worth went in

    gate.set()
    w.close({"exit_code": 0})
    run = read_run(tmp_path)
    assert run.summary["telemetry"]["rows_dropped"] == n_rows - n_ok
    assert run.summary["telemetry"]["rows_written"] == n_ok
    assert run.n_ticks == n_ok
    # the rows that made it are exact, and the gap is reported rather than hidden
    np.testing.assert_array_equal(run.joint("target")[:, 0], run.tick.astype(float))
    assert any("dropped while recording" in msg for msg in run.warnings)
    dropped = [e for e in run.events if e["kind"] == "telemetry_dropped"]
    assert sum(e["rows"] for e in dropped) == n_rows - n_ok
    assert any(e["kind"] == "fault" for e in run.events)


@pytest.mark.parametrize("surface", ["record", "flush", "close"])
def test_writer_death_surfaces(tmp_path: Path, surface: str) -> None:
    w = _TroubledWriter(tmp_path, JOINTS, fail=OSError(errno.ENOSPC, "No space left"))
    _record_row(w, 0, np.zeros(3))
    _record_row(w, 1, np.zeros(3))  # hands row 0 over
    w._inbox.put(tm._WAKE)  # have the writer drain now
    assert w.entered.wait(WAIT_S)
    assert w._rows_done.wait(WAIT_S)
    assert w.failed and isinstance(w.error, OSError)
    if surface == "record":
        with pytest.raises(WriterFailedError) as info:
            _record_row(w, 2, np.zeros(3))
        assert isinstance(info.value.__cause__, OSError)
    elif surface == "flush":
        with pytest.raises(WriterFailedError):
            w.flush()
    # never raises on the fault path; kept for the end of the record
    assert w.event("fault", "disk full", 1, 0.001) is True
    for _ in range(2):  # every close says so; neither deadlocks
        with pytest.raises(WriterFailedError, match="No space left"):
            w.close({"exit_code": 3})
    summary = json.loads((tmp_path / SUMMARY_JSON).read_text())
    assert summary["exit_code"] == 3 and summary["faults"][0]["message"] == "disk full"
    assert read_run(tmp_path).events[-1]["message"] == "disk full"
    assert "No space left" in summary["telemetry"]["error"]
    assert summary["telemetry"]["rows_lost"] >= 1


def test_close_times_out_on_stalled_disk(tmp_path: Path) -> None:
    gate = threading.Event()
    w = _TroubledWriter(tmp_path, JOINTS, gate=gate)
    _record_row(w, 0, np.zeros(3))
    _record_row(w, 1, np.zeros(3))
    w._inbox.put(tm._WAKE)
    assert w.entered.wait(WAIT_S)  # the writer is now stuck in write()
    with pytest.raises(WriterFailedError, match="did not finish"):
        w.close({}, timeout_s=0.0)
    gate.set()
    w.close()  # the retry completes
    assert read_run(tmp_path).n_ticks == 2


def test_fault_event_fsyncs_both_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    synced: list[int] = []
    both = threading.Event()
    real_fsync = os.fsync

    def counting_fsync(fd: int) -> None:
        synced.append(fd)
        real_fsync(fd)
        if len(synced) >= 2:
            both.set()

    monkeypatch.setattr(tm.os, "fsync", counting_fsync)
    w = TelemetryWriter(tmp_path, JOINTS, flush_interval_s=3600.0)
    for i in range(5):
        _record_row(w, i, np.zeros(3))
    w.event("warning", "not synced", 4, 0.004)
    assert synced == []  # warnings and periodic flushes do not fsync (nothing waits here)
    w.event("fault", "joint 2 out of range", 4, 0.004, joint="jaw")
    assert both.wait(WAIT_S)
    assert sorted(synced[:2]) == sorted([w._sink._file.fileno(), w._events.fileno()])
    # what was fsync-ed is on disk before close: the rows and the fault
    assert (tmp_path / TELEMETRY_CSV).read_text().count("\n") == 1 + 5
    events = [json.loads(x) for x in (tmp_path / EVENTS_JSONL).read_text().splitlines()]
    assert [e["kind"] for e in events] == ["warning", "fault"] and events[1]["joint"] == "jaw"
    n_before = len(synced)
    w.close({})
    assert len(synced) > n_before  # and again at close (files, summary)


def test_periodic_flush_reaches_the_file(tmp_path: Path) -> None:
    flushed = threading.Event()

    class _Watched(TelemetryWriter):
        def _flush_files(self, *, fsync: bool) -> None:
            super()._flush_files(fsync=fsync)
            if self.rows_written:
                flushed.set()

    w = _Watched(tmp_path, JOINTS, flush_interval_s=0.0)
    _record_row(w, 0, np.full(3, 0.25))
    _record_row(w, 1, np.full(3, 0.5))  # hands row 0 over; row 1 stays amendable
    assert flushed.wait(WAIT_S)
    run = read_run(tmp_path)  # while the writer is open, without flush() or close()
    assert run.n_ticks == 1 and run.joint("target")[0, 0] == 0.25
    assert any("no summary.json" in msg for msg in run.warnings)
    w.close()


def test_the_writer_drains_when_the_loops_free_time_is_always_short(tmp_path: Path) -> None:
    # a fast rig whose bus takes most of each tick: the loop sleeps every tick, but never
    # long enough for a chunk. The writer must not nap for ever (the ring would fill and
    # rows be lost): after a while without a long enough free time it formats anyway.
    # (Parquet, whose chunks are cheap: a CSV writer waits, and drops rows instead)
    pytest.importorskip("pyarrow")
    drained = threading.Event()

    class _Watched(TelemetryWriter):
        def _drain_rows(self) -> None:
            super()._drain_rows()
            if self._ring.tail:  # rows taken out of the ring while the show runs
                drained.set()

    w = _Watched(tmp_path, JOINTS, flush_interval_s=0.01, format="parquet")
    w.slack.until = -math.inf  # a free time that has always just ended
    w.slack.set()
    for i in range(3):
        _record_row(w, i, np.full(3, float(i)))
    assert drained.wait(WAIT_S), "the writer waited for a free time that never came"
    w.close()
    assert read_run(tmp_path).n_ticks == 3


def test_a_csv_writer_short_of_free_time_still_writes_events_and_flushes(tmp_path: Path) -> None:
    # A CSV sink waits for free time and drops rows rather than make the loop late; while
    # it waits, a fault must still reach the disk at once and flush() must still answer
    synced = threading.Event()

    class _Watched(TelemetryWriter):
        def _flush_files(self, *, fsync: bool) -> None:
            super()._flush_files(fsync=fsync)
            if fsync:
                synced.set()

    w = _Watched(tmp_path, JOINTS, flush_interval_s=0.01)
    w.slack.until = -math.inf  # a free time that has always just ended
    w.slack.set()
    for i in range(50):
        _record_row(w, i, np.full(3, float(i)))
    w.event("fault", "joint 2 out of range", 49, 0.049, joint="jaw")
    assert synced.wait(WAIT_S), "the fault waited behind the rows"
    assert "out of range" in (tmp_path / EVENTS_JSONL).read_text()
    assert read_run(tmp_path).n_ticks < 49  # the rows still wait for free time
    assert w.flush(timeout_s=WAIT_S)  # the loop waits in flush(): its rows are written
    assert read_run(tmp_path).n_ticks == 50  # the pending row handed over too
    assert w.slack.until == -math.inf and w.slack.is_set()  # flush() left the slack as it was
    w.close()
    assert read_run(tmp_path).n_ticks == 50 and w.rows_dropped == 0


# ----------------------------------------------------------------------------- reading damaged runs


def test_truncated_last_line_is_tolerated(tmp_path: Path) -> None:
    with TelemetryWriter(tmp_path, JOINTS) as w:
        for i in range(10):
            _record_row(w, i, np.full(3, i * 0.1))
    csv_path = tmp_path / TELEMETRY_CSV
    with open(csv_path, "a") as f:
        f.write("10,0.01,0.0100")  # the crash cut this row short
    with open(tmp_path / EVENTS_JSONL, "a") as f:
        f.write('{"tick": 10, "kind": "fau')
    run = read_run(tmp_path)
    assert run.truncated and run.n_ticks == 10
    assert any("incomplete" in m and TELEMETRY_CSV in m for m in run.warnings)
    assert any("incomplete" in m and EVENTS_JSONL in m for m in run.warnings)


def test_nul_tail_and_bad_middle_line(tmp_path: Path) -> None:
    with TelemetryWriter(tmp_path, JOINTS) as w:
        for i in range(6):
            _record_row(w, i, np.full(3, i * 0.1))
    csv_path = tmp_path / TELEMETRY_CSV
    lines = csv_path.read_text().splitlines(keepends=True)
    lines[3] = "garbage,,\n"  # tick 2
    csv_path.write_bytes("".join(lines).encode() + b"\x00" * 4096)  # zeroed tail after power loss
    (tmp_path / SUMMARY_JSON).write_text("{not json")
    run = read_run(tmp_path)
    assert run.tick.tolist() == [0, 1, 3, 4, 5] and not run.truncated
    assert any("unparsable" in m for m in run.warnings)
    assert any("missing" in m for m in run.warnings)
    assert run.summary is None and any("unreadable" in m for m in run.warnings)


def test_empty_fields_read_as_nan(tmp_path: Path) -> None:
    header = ",".join(csv_columns(["a"]))
    row = "0,0,0,0,1,2,3,4,,1,5,6,7,8,0,0,0,0"
    (tmp_path / TELEMETRY_CSV).write_text(header + "\n" + row + "\n")
    run = read_run(tmp_path)
    assert math.isnan(run.joint("present")[0, 0]) and run.joint("cmd")[0, 0] == 4.0


def test_not_a_run(tmp_path: Path) -> None:
    with pytest.raises(NotARunError):
        read_run(tmp_path)
    (tmp_path / TELEMETRY_CSV).write_text("a,b,c\n1,2,3\n")
    with pytest.raises(RunFormatError):
        read_run(tmp_path)


def test_header_only_run_has_no_ticks(tmp_path: Path) -> None:
    w = TelemetryWriter(tmp_path, JOINTS)
    w.close()
    run = read_run(tmp_path)
    assert run.n_ticks == 0 and run.joint("cmd").shape == (0, 3)


# ----------------------------------------------------------------------------- statistics


def test_overruns_on_a_failed_read_are_counted_apart_and_the_verdict_names_them() -> None:
    from hilsim.cli._report import verdict

    status = np.zeros((100, 2), dtype=np.int8)
    status[[10, 20, 30], 1] = ReadStatus.STALE  # three reads waited out their timeout
    status[40, 0] = ReadStatus.ALERT  # a reading, not a failed read
    overrun = np.zeros(100)
    overrun[[10, 20, 30, 40, 50, 60]] = 1

    def summary(overrun) -> dict:
        return summarize(
            joint_names=["a", "b"],
            t_actual=np.arange(100) * 4e-3,
            lateness_us=np.zeros(100),
            overrun=overrun,
            stage_us={},
            status=status,
        )

    s = summary(overrun)
    assert s["overruns"] == 6 and s["overruns_failed_read"] == 3
    assert "6% of ticks overran (3 on a tick whose read failed)" in verdict(s, 100)
    overrun[[11, 12]] = 1  # the ticks after one catching up: not counted as the bus's ...
    s = summary(overrun)
    assert s["overruns"] == 8 and s["overruns_failed_read"] == 3
    overrun[:] = 1  # ... nor a host late every tick around one failed read (review)
    assert summary(overrun)["overruns_failed_read"] == 3
    overrun[:] = 0
    overrun[[50, 60, 70, 80, 90, 95]] = 1
    assert "(other bus traffic" in verdict({**summary(overrun), "clock": "virtual time"}, 100)
    assert "(the host is too busy?)" in verdict(summary(overrun), 100)


def test_summarize_percentiles_on_known_data() -> None:
    rng = np.random.default_rng(0)
    lateness = rng.permutation(np.arange(1000.0))  # 0..999 µs in random order
    status = np.zeros((1000, 2), dtype=np.int8)
    status[:7, 0] = ReadStatus.STALE
    status[10:12, 1] = ReadStatus.ALERT
    s = summarize(
        joint_names=["a", "b"],
        t_actual=np.arange(1000) * 2e-3,
        lateness_us=lateness,
        overrun=lateness > 990,
        stage_us={"sim": np.full(1000, 20.0), "bus": np.r_[np.full(999, 100.0), np.nan]},
        status=status,
        servo_ids=[11, 12],
        exit_code=0,
        exit_reason="finished",
        seed=5,
    )
    lat = s["lateness_us"]
    # numpy's linear interpolation on 0..999: the q-th percentile is 9.99 q
    assert lat["p50"] == pytest.approx(499.5)
    assert lat["p99"] == pytest.approx(989.01)
    assert lat["p99.9"] == pytest.approx(998.001)
    assert lat["max"] == 999.0 and lat["mean"] == pytest.approx(499.5)
    assert s["ticks"] == 1000 and s["overruns"] == 9
    assert s["overruns_failed_read"] == 0  # the stale reads (ticks 0-6) did not overrun
    assert s["duration_s"] == pytest.approx(1.998) and s["rate_hz"] == pytest.approx(500.0)
    assert s["stale_reads"] == {"a": 7, "b": 0} and s["alert_reads"] == {"a": 0, "b": 2}
    assert s["servo_ids"] == {"a": 11, "b": 12} and s["schema_version"] == 1
    assert s["stale_reads"] == {"a": 7, "b": 0} and s["alert_reads"] == {"a": 0, "b": 2}
    assert comm_errors(s) == 9 and comm_errors(s, servo=12) == 2 and comm_errors(s, servo=3) == 0
    assert s["stage_us"]["bus"]["max"] == 100.0  # NaN (not measured) ignored
    assert s["seed"] == 5 and s["exit_reason"] == "finished"
    json.dumps(s)  # JSON-ready


def test_run_stats_accumulates_across_chunks() -> None:
    stats = RunStats(["a", "b"], servo_ids=[1, 2], chunk_ticks=7)
    for i in range(50):
        rec = stats_record(i * 2e-3, float(i), False, 1.0, 2.0, 3.0 + i, math.nan,
                           [i % 25 == 0, 0], i)  # fmt: skip
        stats.add(rec)
        rec.overrun, rec.t_telemetry_us = i % 10 == 0, 4.0
        stats.amend(rec)
    with pytest.raises(ValueError):
        stats.amend(stats_record(0.0, 0.0, True, 0, 0, 0, 0, [0, 0], 3))
    stats.set_safety_counts({"position": {"b": 1}, "speed": {"a": 2}}, ticks=50)
    stats.fault("limit", "b beyond limit", 33, 0.066)
    assert stats.ticks == 50
    s = stats.summary(exit_code=2, exit_reason="fault", rate_hz_target=500.0)
    assert s["ticks"] == 50 and s["lateness_us"]["max"] == pytest.approx(49.0)
    assert s["lateness_us"]["p50"] == pytest.approx(24.5)
    assert s["stage_us"]["bus"]["max"] == 52.0 and s["stage_us"]["sim"]["p99"] == 1.0
    assert s["stage_us"]["telemetry"]["max"] == 4.0
    assert s["overruns"] == 5 and s["stale_reads"] == {"a": 2, "b": 0}
    assert comm_errors(s, servo=1) == 2 and comm_errors(s, servo=2) == 0
    assert s["safety_limits"] == {"position": {"a": 0, "b": 1}, "speed": {"a": 2, "b": 0}}
    assert s["faults"] == [{"kind": "limit", "message": "b beyond limit", "tick": 33, "t": 0.066}]
    assert s["exit_code"] == 2 and s["rate_hz_target"] == 500.0
    assert s["rate_hz"] == pytest.approx(500.0)


def test_empty_summary() -> None:
    s = RunStats(["a"]).summary(exit_code=1, exit_reason="no ticks")
    assert s["ticks"] == 0 and s["lateness_us"]["p50"] is None and s["rate_hz"] is None
    json.dumps(s)


def test_amend_fills_in_the_last_row(tmp_path: Path) -> None:
    w = TelemetryWriter(tmp_path, JOINTS)
    for i in range(3):
        rec = _row(w, i, np.zeros(3))
        w.record(rec)
        rec.overrun, rec.t_telemetry_us = i == 1, 7.5 + i
        assert w.amend(rec)
    with pytest.raises(ValueError):
        w.amend(tick_record(0, 0, 0, *[np.zeros(3)] * 6, 0, 0, 0, 0, True, 0))  # not the last
    summary = w.close()
    run = read_run(tmp_path)
    np.testing.assert_array_equal(run.overrun, [False, True, False])
    np.testing.assert_array_equal(run.stage_us("telemetry"), [7.5, 8.5, 9.5])
    assert summary["overruns"] == 1 and summary["stage_us"]["telemetry"]["max"] == 9.5


def test_fault_events_are_listed_in_the_summary(tmp_path: Path) -> None:
    w = TelemetryWriter(tmp_path, JOINTS)
    _record_row(w, 0, np.zeros(3))
    w.event("warning", "just a warning", 0, 0.0)
    w.event("fault", "servo 2 silent for 120 ms", 0, 0.0, servo=2)
    summary = w.close({"exit_code": 3, "exit_reason": "fault"})
    assert summary["faults"] == [
        {"kind": "fault", "message": "servo 2 silent for 120 ms", "tick": 0, "t": 0.0, "servo": 2}
    ]


def test_close_in_a_signal_handler_mid_record(tmp_path: Path) -> None:
    """A handler that closes the writer while record() is half-way through a row: the rows
    before it are all written, the half-filled one is not."""
    w = TelemetryWriter(tmp_path, JOINTS)
    for i in range(5):
        _record_row(w, i, np.full(3, float(i)))

    class _Interrupting:
        def __array__(self, dtype=None, copy=None):
            w.close({"exit_code": 130, "exit_reason": "SIGINT"})  # "the signal arrives here"
            return np.zeros(3)

    w.record(tick_record(5, 5e-3, 5e-3, np.full(3, 5.0), np.zeros(3), np.zeros(3), _Interrupting(),
             np.zeros(3), np.zeros(3), 0.0, 0.0, 0.0, 0.0, False, 0))  # fmt: skip
    w.close()
    run = read_run(tmp_path)
    assert run.tick.tolist() == [0, 1, 2, 3, 4] and run.summary["exit_code"] == 130
    np.testing.assert_array_equal(run.joint("target")[:, 2], np.arange(5.0))


def test_synthetic_run_reads_back(tmp_path: Path) -> None:
    data = write_synthetic_run(tmp_path, seconds=1.0)
    run = read_run(tmp_path)
    assert run.warnings == []
    np.testing.assert_array_equal(run.joint("cmd"), data["cmd"])
    np.testing.assert_array_equal(run.joint("status"), data["status"])
    assert [e["kind"] for e in run.events] == ["start", "stop"]
    assert run.summary["ticks"] == run.n_ticks == 500
    assert run.summary["stale_reads"]["jaw"] == int((data["status"][:, 2] == 1).sum())
    assert comm_errors(run.summary, servo=3) == int((data["status"][:, 2] != 0).sum())
    np.testing.assert_allclose(run.lateness_us, data["lateness"], atol=1e-3)


def test_the_end_of_the_record_has_its_space_set_aside_until_it_is_written(tmp_path: Path) -> None:
    w = TelemetryWriter(tmp_path, JOINTS)
    reserve = tmp_path / RESERVE_NAME
    assert reserve.stat().st_size == w.end.reserve.size == end_bytes(len(JOINTS)) >= 16384
    _record_row(w, 0, np.zeros(3))
    summary = w.close({"exit_code": 0})
    assert not reserve.exists()  # summary.json was written into it
    assert read_run(tmp_path).summary == json.loads(json.dumps(summary))


def test_without_fallocate_the_reserve_is_zeros_and_without_room_it_is_said(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def unsupported(fd: int, offset: int, length: int) -> None:
        raise OSError(errno.EOPNOTSUPP, "Operation not supported")

    monkeypatch.setattr(os, "posix_fallocate", unsupported)
    w = TelemetryWriter(tmp_path / "a", JOINTS)
    assert (tmp_path / "a" / RESERVE_NAME).read_bytes() == bytes(w.end.reserve.size)
    assert w.end.reserve.error is None
    w.close({})

    def full(fd: int, offset: int, length: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "posix_fallocate", full)
    w = TelemetryWriter(tmp_path / "b", JOINTS)  # the run goes on; the reason is kept
    assert w.end.reserve.size == 0 and w.end.reserve.error.errno == errno.ENOSPC
    assert not (tmp_path / "b" / RESERVE_NAME).exists()
    _record_row(w, 0, np.zeros(3))
    assert w.close({"exit_code": 0})["exit_code"] == 0  # written the ordinary way
    assert read_run(tmp_path / "b").n_ticks == 1
