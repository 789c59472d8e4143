"""Telemetry formats (issue 12, item 5): csv, csv.gz and Parquet through the writer and read_run,
the auto choice, a crash's leftovers, a full disk, and the rig key.

No test sleeps or times anything: the writer is drained with flush() and close().
"""

from __future__ import annotations

import errno
import gzip
import json
import math
import shutil
import threading
from pathlib import Path

import numpy as np
import pytest

from hilsim.rig import RigError, load_rig
from hilsim.telemetry import TelemetryWriter, WriterFailedError
from hilsim.telemetry.format import (
    SUMMARY_JSON,
    TELEMETRY_CSV,
    TELEMETRY_CSV_GZ,
    TELEMETRY_PARQUET,
    TelemetryFormat,
    choose_format,
    csv_row_bytes,
    parquet_columns,
)
from hilsim.telemetry.reader import RunFormatError, read_run
from tests.hilsim.test_rig import BASE, write
from tests.hilsim.test_telemetry import write_synthetic_run
from tests.hilsim.tick_rows import tick_record

pq = pytest.importorskip("pyarrow.parquet")  # the dev extra installs it (the parquet extra)

JOINTS = ("pan", "tilt", "jaw")
WAIT_S = 10.0
#: the Parquet columns' precision: half a unit of their integers
ANGLE_TOL, TIME_TOL, MICROS_TOL = 0.5e-6, 0.5e-9, 0.5e-3


def _rows(n: int, seed: int = 3) -> list[dict]:
    """Rows with awkward values: signs, tiny and large magnitudes, NaN, +-inf, every status."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        vals = rng.normal(0.0, 1.0, 3) * np.array([1e-9, 1.0, 30.0])
        present = vals + 4
        if i % 7 == 3:
            present[1] = math.nan
        target = vals.copy()
        if i == 5:
            target[0], target[2] = math.inf, -math.inf  # a non-finite target reaches the file
        out.append(
            {
                "tick": i,
                "t_sched": i / 300.0,
                "t_actual": i / 300.0 + rng.exponential(20e-6),
                "target": target,
                "sim_x": vals + 1,
                "sim_v": (vals + 2) * 3,
                "cmd": vals + 3,
                "present": present,
                "status": np.array([i % 4, 0, 1], dtype=np.int8),
                "stages": rng.normal(100.0, 30.0, 4),
                "overrun": i % 11 == 0,
                "comm": i // 5,
                "stall": 0.0 if i % 13 else 1234.5678,
                "skipped": i // 97,
            }
        )
    return out


def _write(run: Path, rows: list[dict], fmt: str, **kw) -> TelemetryWriter:
    w = TelemetryWriter(run, JOINTS, format=fmt, overflow="block", **kw)
    _record_all(w, rows)
    return w


def _record_all(w: TelemetryWriter, rows: list[dict]) -> None:
    for r in rows:
        rec = tick_record(r["tick"], r["t_sched"], r["t_actual"], r["target"], r["sim_x"],
                          r["sim_v"], r["cmd"], r["present"], r["status"], *r["stages"][:3],
                          math.nan, r["overrun"], r["comm"])  # fmt: skip
        rec.host_stall_us, rec.skipped_ticks = r["stall"], r["skipped"]
        w.record(rec)
        rec.t_telemetry_us = r["stages"][3]
        w.amend(rec)


def _expected(rows: list[dict]) -> dict[str, np.ndarray]:
    cols = {
        "tick": [r["tick"] for r in rows],
        "t_sched": [r["t_sched"] for r in rows],
        "t_actual": [r["t_actual"] for r in rows],
        "lateness_us": [(r["t_actual"] - r["t_sched"]) * 1e6 for r in rows],
        "overrun": [float(r["overrun"]) for r in rows],
        "comm_errors": [r["comm"] for r in rows],
        "host_stall_us": [r["stall"] for r in rows],
        "skipped_ticks": [r["skipped"] for r in rows],
    }
    for s, name in enumerate(("sim", "safety", "bus", "telemetry")):
        cols[f"t_{name}_us"] = [r["stages"][s] for r in rows]
    for f in ("target", "sim_x", "sim_v", "cmd", "present", "status"):
        for j, joint in enumerate(JOINTS):
            cols[f"{f}_{joint}"] = [r[f][j] for r in rows]
    return {k: np.asarray(v, dtype=np.float64) for k, v in cols.items()}


def _tolerance(column: str) -> float:
    if column in ("t_sched", "t_actual"):
        return TIME_TOL
    if column.endswith("_us"):
        return MICROS_TOL
    if column.startswith(("tick", "status", "overrun", "comm", "skipped")):
        return 0.0
    return ANGLE_TOL


def _exact_csv_text(x: np.ndarray) -> np.ndarray:
    return np.array([float(f"{v:.3f}") for v in x])  # the CSV's µs columns: %.3f


@pytest.mark.parametrize("fmt", ["csv", "csv.gz", "parquet"])
def test_round_trip_of_each_format(tmp_path: Path, fmt: str) -> None:
    rows = _rows(700)
    summary = _write(tmp_path / "run", rows, fmt).close({})
    run = read_run(tmp_path / "run")
    assert summary["telemetry"]["format"] == fmt and summary["telemetry"]["rows_written"] == 700
    assert run.joint_names == JOINTS and run.n_ticks == 700 and run.warnings == []
    want = _expected(rows)
    assert set(run.columns) == set(want)
    for name, expect in want.items():
        got = run.columns[name]
        np.testing.assert_array_equal(np.isnan(got), np.isnan(expect), err_msg=name)
        np.testing.assert_array_equal(np.isinf(got), np.isinf(expect), err_msg=name)
        ok = np.isfinite(expect)
        if fmt == "parquet":
            err = np.abs(got[ok] - expect[ok]).max()
            assert err <= _tolerance(name) * (1 + 1e-9), (name, err)
        elif name.endswith("_us"):  # written with %.3f, as always
            np.testing.assert_array_equal(got[ok], _exact_csv_text(expect[ok]), err_msg=name)
        else:  # %.17g: every bit
            np.testing.assert_array_equal(got[ok], expect[ok], err_msg=name)
    assert np.array_equal(np.sign(run.joint("target")[5]), [1.0, np.sign(rows[5]["target"][1]), -1])


def test_csv_gz_holds_exactly_the_csv_text(tmp_path: Path) -> None:
    rows = _rows(300)
    _write(tmp_path / "a", rows, "csv").close({})
    _write(tmp_path / "b", rows, "csv.gz").close({})
    text = gzip.decompress((tmp_path / "b" / TELEMETRY_CSV_GZ).read_bytes())
    assert text == (tmp_path / "a" / TELEMETRY_CSV).read_bytes()


def test_parquet_reads_without_hilsim(tmp_path: Path) -> None:
    """The part directory is a Parquet dataset any pyarrow-based tool reads; the columns say their
    unit; a temporary part left by a crash is ignored."""
    rows = _rows(50)
    _write(tmp_path / "run", rows, "parquet").close({})
    parts = tmp_path / "run" / TELEMETRY_PARQUET
    (parts / ".part-00099.tmp").write_bytes(b"PAR1 half a part")
    table = pq.read_table(parts)
    assert table.column_names == [c.name for c in parquet_columns(JOINTS)]
    assert "cmd_jaw_urad" in table.column_names and "t_actual_ns" in table.column_names
    assert table.column("tick").to_pylist() == list(range(50))
    cmd = np.array(table.column("cmd_tilt_urad").to_pylist())
    np.testing.assert_allclose(cmd * 1e-6, [r["cmd"][1] for r in rows], atol=ANGLE_TOL)
    assert table.column("present_tilt_urad").null_count == sum(1 for i in range(50) if i % 7 == 3)


def test_a_parquet_part_per_fsync_point_and_a_crash_keeps_the_closed_parts(tmp_path: Path) -> None:
    rows = _rows(900)
    w = _write(tmp_path / "run", rows[:400], "parquet", fsync_interval_s=3600.0)
    assert w.flush(WAIT_S)  # an fsync point: part 0
    _record_all(w, rows[400:900])
    crashed = tmp_path / "crashed"
    shutil.copytree(tmp_path / "run", crashed)  # the disk as a crash would leave it
    (crashed / TELEMETRY_PARQUET / ".part-00001.tmp").write_bytes(b"PAR1\x00\x01")  # half-written
    w.close({})
    run = read_run(crashed)
    assert run.n_ticks == 400 and run.tick[-1] == 399  # all fsync-ed rows, no more
    assert any("no summary.json" in m for m in run.warnings)
    assert read_run(tmp_path / "run").n_ticks == 900
    assert sorted(p.name for p in (tmp_path / "run" / TELEMETRY_PARQUET).iterdir()) == [
        "part-00000.parquet",
        "part-00001.parquet",
    ]


def test_a_damaged_parquet_part_is_skipped_and_said(tmp_path: Path) -> None:
    rows = _rows(200)
    w = _write(tmp_path / "run", rows[:100], "parquet")
    assert w.flush(WAIT_S)
    _record_all(w, rows[100:])
    w.close({})
    part = tmp_path / "run" / TELEMETRY_PARQUET / "part-00000.parquet"
    part.write_bytes(part.read_bytes()[:-100])  # the footer gone
    run = read_run(tmp_path / "run")
    assert run.n_ticks == 100 and run.tick[0] == 100
    assert any("part-00000.parquet: unreadable, skipped" in m for m in run.warnings)
    assert any("100 tick(s) missing" in m for m in run.warnings) is False  # a gap at the start


def test_a_cut_gzip_stream_reads_back_to_its_last_flush(tmp_path: Path) -> None:
    rows = _rows(600)
    w = _write(tmp_path / "run", rows[:250], "csv.gz", flush_interval_s=3600.0)
    assert w.flush(WAIT_S)  # a sync flush: everything so far decodes
    gz = tmp_path / "run" / TELEMETRY_CSV_GZ
    at_flush = gz.stat().st_size
    _record_all(w, rows[250:])
    w.close({})
    whole = gz.read_bytes()
    want = _expected(rows)["sim_x_tilt"]
    for cut in (at_flush, at_flush + 1, at_flush + 700, len(whole) - 9, len(whole) - 1):
        gz.write_bytes(whole[:cut])
        run = read_run(tmp_path / "run")
        assert 250 <= run.n_ticks <= 600, cut
        assert np.array_equal(run.tick, np.arange(run.n_ticks))  # the rows there are whole
        np.testing.assert_array_equal(run.columns["sim_x_tilt"], want[: run.n_ticks])
        assert any("cut off" in m for m in run.warnings), (cut, run.warnings)
    gz.write_bytes(whole[:at_flush])
    assert read_run(tmp_path / "run").n_ticks == 250
    gz.write_bytes(whole[:at_flush] + b"\xff" * 64)  # garbage after the flush point
    run = read_run(tmp_path / "run")
    assert run.n_ticks == 250 and any("damaged" in m for m in run.warnings)


class _FullDisk:
    """A file whose writes fail with ENOSPC once ``armed`` is set."""

    def __init__(self, inner, armed: threading.Event) -> None:
        self._inner, self._armed = inner, armed

    def write(self, data):
        if self._armed.is_set():
            raise OSError(errno.ENOSPC, "No space left on device")
        return self._inner.write(data)

    def __getattr__(self, name: str):
        return getattr(self._inner, name)


class _FullDiskWriter(TelemetryWriter):
    def __init__(self, *args, **kw) -> None:
        self.armed = threading.Event()
        super().__init__(*args, **kw)

    def _open(self, path: Path, mode: str):
        inner = super()._open(path, mode)
        return inner if path.name == "events.jsonl" else _FullDisk(inner, self.armed)


@pytest.mark.parametrize("fmt", ["csv.gz", "parquet"])
def test_a_full_disk_fails_the_writer_as_before(tmp_path: Path, fmt: str) -> None:
    w = _FullDiskWriter(tmp_path, JOINTS, format=fmt)
    _record_all(w, _rows(50))
    w.armed.set()
    with pytest.raises(WriterFailedError):
        w.flush(WAIT_S)  # an fsync point: the rows must reach the disk, and cannot
    assert w.failed and isinstance(w.error, OSError)
    with pytest.raises(WriterFailedError, match="No space left"):
        w.close({"exit_code": 3})
    summary = json.loads((tmp_path / SUMMARY_JSON).read_text())
    assert summary["telemetry"]["rows_lost"] >= 1 and summary["telemetry"]["format"] == fmt
    if fmt == "parquet":
        assert list((tmp_path / TELEMETRY_PARQUET).iterdir()) == []  # no half part left


def test_the_auto_choice() -> None:
    csv, gz, parquet = TelemetryFormat.CSV, TelemetryFormat.CSV_GZ, TelemetryFormat.PARQUET
    # the demo (4 joints, 250 Hz) stays exact CSV; scale16 (16 joints, 1 kHz) does not
    assert choose_format("auto", 250, 4, have_parquet=True)[0] is csv
    assert 600 * 250 * csv_row_bytes(4) < 100e6 < 600 * 1000 * csv_row_bytes(16)
    fmt, why = choose_format("auto", 1000, 16, have_parquet=True)
    assert fmt is parquet and "1052 MB per 10 min" in why
    fmt, why = choose_format("auto", 1000, 16, have_parquet=False)
    assert fmt is gz and "pip install 'hilsim[parquet]'" in why
    assert choose_format("auto", None, 16, have_parquet=True)[0] is csv
    # the threshold is the 10-minute size, at the byte
    assert choose_format("auto", 100e6 / 600 / csv_row_bytes(8), 8, have_parquet=True)[0] is csv
    assert choose_format("auto", 100e6 / 600 / csv_row_bytes(8) * 1.001, 8)[0] is not csv
    # an explicit choice is kept; parquet without pyarrow says how to get it
    assert choose_format("csv", 1000, 16, have_parquet=True)[0] is csv
    assert choose_format("csv.gz", 10, 1, have_parquet=True)[0] is gz
    with pytest.raises(ValueError, match=r"pip install 'hilsim\[parquet\]'"):
        choose_format("parquet", 10, 1, have_parquet=False)


def test_measured_csv_rows_stay_under_the_estimate(tmp_path: Path) -> None:
    """The auto threshold's row estimate is an upper bound on a real-looking run's rows."""
    write_synthetic_run(tmp_path, seconds=2.0)
    data = (tmp_path / TELEMETRY_CSV).read_bytes().splitlines()[1:]
    assert max(map(len, data)) + 1 <= csv_row_bytes(4)


def test_the_writer_resolves_auto_and_says_why(tmp_path: Path) -> None:
    names = [f"j{i}" for i in range(16)]
    w = TelemetryWriter(tmp_path / "big", names, format="auto", rate_hz=1000)
    assert w.format is TelemetryFormat.PARQUET
    assert json.loads(json.dumps(w.close({})))["telemetry"]["format_reason"].startswith("auto:")
    w = TelemetryWriter(tmp_path / "small", names[:4], format="auto", rate_hz=250)
    assert w.format is TelemetryFormat.CSV
    w.close({})
    assert (tmp_path / "small" / TELEMETRY_CSV).is_file()


def test_one_run_per_directory_whatever_the_format(tmp_path: Path) -> None:
    TelemetryWriter(tmp_path, JOINTS, format="parquet").close({})
    with pytest.raises(FileExistsError):
        TelemetryWriter(tmp_path, JOINTS, format="csv")


def test_parquet_without_its_columns_is_not_a_run(tmp_path: Path) -> None:
    import pyarrow as pa

    (tmp_path / TELEMETRY_PARQUET).mkdir()
    pq.write_table(pa.table({"x": [1, 2]}), tmp_path / TELEMETRY_PARQUET / "part-00000.parquet")
    with pytest.raises(RunFormatError, match="not telemetry columns"):
        read_run(tmp_path)


def test_the_rig_key(tmp_path: Path) -> None:
    assert load_rig(write(tmp_path, BASE)).telemetry.format is TelemetryFormat.AUTO
    text = BASE.replace("[loop]", '[telemetry]\nformat = "csv.gz"\n[loop]')
    assert load_rig(write(tmp_path, text)).telemetry.format is TelemetryFormat.CSV_GZ
    for bad in ('"xml"', '"CSV"', "1"):
        text = BASE.replace("[loop]", f"[telemetry]\nformat = {bad}\n[loop]")
        with pytest.raises(RigError, match=r"telemetry\.format: ") as info:
            load_rig(write(tmp_path, text))
        assert "\n" not in str(info.value)
    with pytest.raises(
        RigError, match=r"must be one of auto, csv, csv\.gz, parquet, none, off; got 'xml'"
    ):
        load_rig(write(tmp_path, BASE.replace("[loop]", '[telemetry]\nformat = "xml"\n[loop]')))


def test_parquet_without_pyarrow_refuses_the_show_in_one_line(tmp_path, monkeypatch) -> None:
    from hilsim.show import session
    from hilsim.telemetry import format as tf

    text = BASE.replace("[loop]", '[telemetry]\nformat = "parquet"\n[loop]')
    rig = load_rig(write(tmp_path, text))
    monkeypatch.setattr(tf, "parquet_available", lambda: False)
    with pytest.raises(session.ShowRefusedError) as info:
        session.open_telemetry(rig, tmp_path / "run", False)
    assert "pip install 'hilsim[parquet]'" in str(info.value) and "\n" not in str(info.value)
    # auto on a big rig without pyarrow: csv.gz, and the summary says why
    text = BASE.replace("rate_hz = 500", "rate_hz = 2000")
    rig = load_rig(write(tmp_path, text))
    w = session.open_telemetry(rig, tmp_path / "run2", True)
    reason = w.close({})["telemetry"]["format_reason"]
    assert w.format is TelemetryFormat.CSV_GZ and "pyarrow is not installed" in reason


def test_parquet_encodes_in_steps_the_same_batch(tmp_path: Path) -> None:
    # the writer encodes a step (~0.1 ms) at a time in the loop's free time: the same
    # integers as the whole block at once, NaN and overflow included, over several slices
    import pyarrow as pa

    from hilsim.telemetry.format import csv_columns
    from hilsim.telemetry.sinks import INT_INF, ParquetSink

    names = ["a", "b"]
    sink = ParquetSink(tmp_path / "p", names, lambda p, m: open(p, m))  # noqa: SIM115
    rng = np.random.default_rng(3)
    rows = rng.uniform(-4.0, 4.0, (300, len(csv_columns(names))))
    rows[5, 7], rows[70, 8], rows[199, 3] = math.nan, 1e300, -1e300  # slices 1, 2 and 4
    sink.put(rows[:150])
    sink.put(rows[150:])
    steps = 0
    while sink.busy():
        sink.work()
        steps += 1
    assert steps > 5  # several slices of rows and of columns
    (stepped,) = sink._batches
    # the whole block at once (the encoding before it was stepped)
    scaled = rows * sink._scale
    whole = np.rint(np.where(np.isnan(scaled) | (np.abs(scaled) > 2.0**62), 0.0, scaled))
    whole = whole.astype(np.int64)
    whole[70, 8], whole[199, 3] = INT_INF, -INT_INF
    for k in range(rows.shape[1]):
        column = stepped.column(k)
        expect = pa.array(whole[:, k], mask=np.isnan(scaled[:, k])).cast(column.type)
        assert column.equals(expect), k
    assert stepped.column(7)[5].as_py() is None


def test_a_failed_encoding_step_loses_its_rows_only_and_says_so(tmp_path: Path) -> None:
    # an exception inside a step (memory, say) kills the writer; the failure path then
    # flushes what it can: the batches encoded before are written, the failed one's rows are
    # not counted as written (the writer reports them lost), and no dead step is run again
    pq = pytest.importorskip("pyarrow.parquet")
    from hilsim.telemetry.format import csv_columns
    from hilsim.telemetry.sinks import ParquetSink

    names = ["a"]
    sink = ParquetSink(tmp_path / "p", names, lambda p, m: open(p, m))  # noqa: SIM115
    width = len(csv_columns(names))
    sink.put(np.zeros((300, width)))
    while sink.busy():
        sink.work()  # 300 rows encoded
    sink.put(np.ones((300, width)))
    real = sink._batch_steps

    def failing(rows):
        yield from real(rows[:10])
        raise MemoryError("encoding")

    sink._batch_steps = failing
    with pytest.raises(MemoryError):
        while sink.busy():
            sink.work()
    assert not sink.busy()
    assert sink.flush(True) == 300  # the 300 encoded before; not the 300 that failed
    assert sink.parts == 1 and pq.read_table(tmp_path / "p").num_rows == 300


def test_a_failed_encoding_at_a_flush_loses_its_rows_only_and_says_so(tmp_path: Path) -> None:
    pq = pytest.importorskip("pyarrow.parquet")
    from hilsim.telemetry.format import csv_columns
    from hilsim.telemetry.sinks import ParquetSink

    sink = ParquetSink(tmp_path / "p", ["a"], lambda p, m: open(p, m))  # noqa: SIM115
    width = len(csv_columns(["a"]))
    sink.put(np.zeros((300, width)))
    while sink.busy():
        sink.work()  # 300 rows encoded
    sink.put(np.ones((100, width)))  # fewer than a step takes: encoded at the flush
    real = sink._batch_steps

    def failing(rows):
        raise MemoryError("encoding")
        yield  # (a generator, as the real one)

    sink._batch_steps = failing
    with pytest.raises(MemoryError):
        sink.flush(True)
    sink._batch_steps = real
    assert sink.flush(True) == 300  # the 300 encoded before; not the 100 that failed
    assert pq.read_table(tmp_path / "p").num_rows == 300
