"""A gap in a run's ticks, told from the rows themselves: ticks the loop caught up on without a
row (after an overrun) or rows lost (dropped while recording), with no summary.json to ask (the
run was killed), whatever the rows' format; older rows without ``skipped_ticks`` still read."""

from __future__ import annotations

import gzip
import threading
from pathlib import Path

import numpy as np
import pytest

import hilsim.show.loop as loop_mod
from hilsim.cli import main
from hilsim.exit_codes import ExitCode
from hilsim.telemetry import TelemetryWriter, plot_common
from hilsim.telemetry.format import SUMMARY_JSON, TELEMETRY_CSV_GZ, csv_columns
from hilsim.telemetry.reader import read_run
from tests.hilsim.tick_rows import tick_record

RIG = """
name = "gaps"
[bus]
port = "dxlsim://?ids=1-2&model=XM430-W350&rdt_us=0&latency_ms=1"
baud = 1000000
[loop]
rate_hz = 250
[safety]
soft_start_s = 0.2
watchdog_ms = 100
[telemetry]
format = "{fmt}"
[[joints]]
name = "pan"
servo_id = 1
min_deg = -50
max_deg = 50
spring = {{ frequency_hz = 3.0, damping_ratio = 0.7 }}
target = {{ type = "keyframes", keys = [[0, 0], [0.5, 30], [1.0, -30]] }}
[[joints]]
name = "jaw"
servo_id = 2
min_deg = -5
max_deg = 30
spring = {{ frequency_hz = 5.0, damping_ratio = 0.9 }}
target = {{ type = "sine", amplitude_deg = 15, frequency_hz = 1.0, offset_deg = 12 }}
"""


def _titles(monkeypatch) -> list[str]:
    """The titles of the figures ``hilsim plot`` draws (in this process; none is written)."""
    from hilsim.telemetry import plots

    titles: list[str] = []
    monkeypatch.setattr(plots, "can_fork", lambda: False)
    monkeypatch.setattr(
        plot_common, "save", lambda fig, path, dpi: titles.append(fig._suptitle.get_text()) or path
    )
    return titles


@pytest.mark.parametrize("fmt", ["parquet", "csv.gz"])
def test_a_killed_run_says_its_caught_up_ticks_from_its_rows(
    tmp_path: Path, monkeypatch, capsys, fmt: str
) -> None:
    """A host stall of 200 ms at tick 100 (the virtual clock jumps): the loop catches up ~50
    ticks without a row. With summary.json gone (SIGKILL), ``hilsim plot`` names the rows' file
    and says those ticks were caught up, not dropped; every title counts them."""
    tick = loop_mod.HilLoop._tick

    def stalled(self, k, *args):
        tick(self, k, *args)
        if k == 100:
            self.clock.advance(0.2)

    monkeypatch.setattr(loop_mod.HilLoop, "_tick", stalled)
    rig, out = tmp_path / "rig.toml", tmp_path / "run"
    rig.write_text(RIG.format(fmt=fmt))
    args = ["run", str(rig), "--virtual-time", "--no-plots", "--out", str(out), "--duration", "1"]
    assert main(args) == ExitCode.OK
    skipped = read_run(out).summary["loop"]["skipped_ticks"]
    assert 40 <= skipped <= 60
    (out / SUMMARY_JSON).unlink()  # as after a SIGKILL
    capsys.readouterr()

    titles = _titles(monkeypatch)
    assert main(["plot", str(out), "--dpi", "30"]) == ExitCode.OK
    err = capsys.readouterr().err
    rows = "telemetry.parquet" if fmt == "parquet" else TELEMETRY_CSV_GZ
    assert f"{rows}: {skipped} tick(s) caught up by the loop without a row" in err, err
    assert "telemetry.csv:" not in err and "missing" not in err and "lost" not in err, err
    assert len(titles) == 3 and all(f"+ {skipped} caught up without a row" in t for t in titles)


def _gated(w: TelemetryWriter) -> threading.Event:
    """Hold the writer thread before it takes any row from the ring until the event is set."""
    gate, take = threading.Event(), w._sink.take

    def held(ring, n):
        assert gate.wait(10.0), "the test never opened the gate"
        return take(ring, n)

    w._sink.take = held
    return gate


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_a_dropped_row_is_told_from_the_ticks_caught_up_beside_it(
    tmp_path: Path, monkeypatch, fmt: str
) -> None:
    """Ticks 0-3 fill a 4-row ring the writer does not drain; tick 3 overruns and the loop
    catches up ticks 4-9 without a row; tick 10's row is dropped (the ring is full). Later tick
    50 overruns and 51-60 are caught up. Rows 3 -> 11: 6 caught up and 1 lost, not 7 of one."""
    w = TelemetryWriter(tmp_path, ("a", "b"), format=fmt, queue_size=4, overflow="drop")
    gate = _gated(w)
    vals, skipped, kept = np.zeros(2), 0, []
    for k in range(100):
        if 4 <= k <= 9 or 51 <= k <= 60:
            skipped += 1  # caught up: no row
            continue
        rec = tick_record(k, k * 4e-3, k * 4e-3, vals, vals, vals, vals, vals,
                          np.zeros(2, dtype=np.int8), 1.0, 1.0, 1.0, 1.0, False, 0)  # fmt: skip
        rec.skipped_ticks = skipped
        kept.append(w.record(rec))
        rec.overrun = k in (3, 50)
        w.amend(rec)
        if k == 10:
            assert kept[-1] is False  # the ring was full: dropped
            w.overflow = "block"  # no more drops; let the writer drain
            gate.set()
    gate.set()
    w.close({"exit_code": 0})
    assert w.rows_dropped == 1 and sum(kept) == 100 - 16 - 1
    rows = "telemetry.parquet" if fmt == "parquet" else "telemetry.csv"
    caught = f"{rows}: 16 tick(s) caught up by the loop without a row"
    lost = f"{rows}: 1 tick(s) missing: the loop ran them but their rows were lost"
    for summary in (True, False):  # the rows tell it, with the summary or without
        if not summary:
            (tmp_path / SUMMARY_JSON).unlink()
        run = read_run(tmp_path)
        assert run.tick[3:5].tolist() == [3, 11] and run.caught_up == 16
        said = [m for m in run.warnings if m.startswith(rows)]
        assert len(said) == 2 and said[0].startswith(caught) and said[1].startswith(lost), said
    titles = _titles(monkeypatch)
    from hilsim.telemetry.plots import plot_run

    plot_run(run, tmp_path / "plots", dpi=30)
    assert all("(83 ticks + 16 caught up without a row" in t for t in titles), titles


def _v1_run(path: Path, overrun_at: int, summary: str | None) -> None:
    """Rows of layout 1 (no skipped_ticks) in csv.gz: ticks 0-29 without 11-14 (after an
    overrun at ``overrun_at``) and 20 (after an on-time tick)."""
    path.mkdir()
    lines = [",".join(csv_columns(["a"], 1))]
    for k in (*range(11), *range(15, 20), *range(21, 30)):
        t = k * 4e-3
        over = int(k == overrun_at)
        lines.append(f"{k},{t},{t},0,0,0,0,0,0,0,1,1,1,1,{over},0,0")
    with gzip.open(path / TELEMETRY_CSV_GZ, "wt") as f:
        f.write("\n".join(lines) + "\n")
    if summary is not None:
        (path / SUMMARY_JSON).write_text(summary)


def test_rows_without_skipped_ticks_still_read_and_say_what_is_unknown(tmp_path: Path) -> None:
    _v1_run(tmp_path / "a", 10, None)
    run = read_run(tmp_path / "a")
    assert run.rows_version == 1 and run.caught_up is None and run.n_ticks == 25
    said = [m for m in run.warnings if m.startswith(TELEMETRY_CSV_GZ)]
    assert said == [
        f"{TELEMETRY_CSV_GZ}: 4 tick(s) without a row after overruns: caught up by the loop or "
        "rows lost (these rows do not count the ticks caught up, and no summary says it)",
        f"{TELEMETRY_CSV_GZ}: 1 tick(s) missing: the loop ran them but their rows were lost "
        "(dropped while recording, or unreadable)",
    ]
    _v1_run(tmp_path / "b", 10, '{"loop": {"skipped_ticks": 4}}')  # the summary tells
    said = [m for m in read_run(tmp_path / "b").warnings if m.startswith(TELEMETRY_CSV_GZ)]
    assert len(said) == 2 and "4 tick(s) caught up" in said[0] and "1 tick(s) missing" in said[1]
    _v1_run(tmp_path / "c", -1, None)  # no overrun: no catch-up, every gap is rows lost
    said = [m for m in read_run(tmp_path / "c").warnings if m.startswith(TELEMETRY_CSV_GZ)]
    assert len(said) == 1 and "5 tick(s) missing" in said[0], said


def test_every_warning_about_the_rows_names_the_file_read(tmp_path: Path) -> None:
    lines = [",".join(csv_columns(["a"]))]
    for k in (0, 1, 5, 3):  # a gap after an on-time tick (rows lost), then back in time
        lines.append(f"{k},{k * 4e-3},{k * 4e-3},0,0,0,0,0,0,0,1,1,1,1,0,0,0,0")
    lines.insert(2, "garbage,,")
    with gzip.open(tmp_path / TELEMETRY_CSV_GZ, "wt") as f:
        f.write("\n".join(lines) + "\n")
    run = read_run(tmp_path)
    about_rows = [m for m in run.warnings if "summary" not in m and "events" not in m]
    assert len(about_rows) == 3, run.warnings  # unparsable, not increasing, rows lost
    assert all(m.startswith(f"{TELEMETRY_CSV_GZ}: ") for m in about_rows), about_rows
