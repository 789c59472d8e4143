"""Bounded telemetry (issue 31, item 4): a size and age cap with rotated parts (oldest first, an
event each, counted in the summary), format "none" (summary only) and "off" (nothing kept), the
long-show failure default, and the bounded (decimated) read behind the plots.

No test sleeps or times anything: the writer is drained with close(), the shows run in virtual
time.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import hilsim
from hilsim.rig import TelemetryFailurePolicy, load_rig
from hilsim.show.api import _failure_note
from hilsim.telemetry import TelemetryWriter
from hilsim.telemetry.format import TELEMETRY_PARQUET, TELEMETRY_PARTS
from hilsim.telemetry.reader import NotARunError, read_run
from hilsim.telemetry.rotation import Part, PartBook
from tests.hilsim.test_rig import BASE, write
from tests.hilsim.tick_rows import tick_record

JOINTS = ("pan", "tilt")
RIG_PORT = 'port = "dxlsim://?ids=1-2&rdt_us=0&latency_ms=1"'


def _record(w: TelemetryWriter, n: int, *, late_us=None, bad=(), overruns=(), acted=()) -> None:
    """``n`` rows: a sine on both joints; ``late_us(i)`` the lateness; ``bad`` ticks read
    ERROR on pan; ``overruns`` ticks overran; ``acted`` ticks where pan's command differs."""
    for i in range(n):
        x = np.array([math.sin(i / 50.0), 0.5 * math.cos(i / 70.0)])
        cmd = x + (np.array([1e-3, 0.0]) if i in acted else 0.0)
        status = np.array([2 if i in bad else 0, 0], dtype=np.int8)
        lat = 0.0 if late_us is None else late_us(i)
        rec = tick_record(i, i / 250.0, i / 250.0 + lat * 1e-6, x, x, x * 0, cmd, x, status,
                          10.0 + i % 7, 2.0, 100.0 + i % 13, 3.0, i in overruns, 0)  # fmt: skip
        w.record(rec)


def _parts(run: Path, sub: str) -> list[Path]:
    return sorted((run / sub).glob("part-*"))


@pytest.mark.parametrize(
    ("fmt", "sub"),
    [("csv", TELEMETRY_PARTS), ("csv.gz", TELEMETRY_PARTS), ("parquet", TELEMETRY_PARQUET)],
)
def test_a_size_cap_removes_the_oldest_parts_first_each_said(tmp_path: Path, fmt, sub) -> None:
    if fmt == "parquet":
        pytest.importorskip("pyarrow")
    cap, n = 60_000, 6000
    run_dir = tmp_path / "run"
    w = TelemetryWriter(run_dir, JOINTS, format=fmt, overflow="block", max_bytes=cap)
    for k in range(12):
        for i in range(500):
            rec_i = k * 500 + i
            x = np.array([math.sin(rec_i / 50.0), 0.5])
            w.record(tick_record(rec_i, rec_i / 250.0, rec_i / 250.0, x, x, x * 0, x, x,
                                 np.zeros(2, np.int8), 1.0, 1.0, 1.0, 1.0, False, 0))  # fmt: skip
        w.flush()
        assert sum(p.stat().st_size for p in _parts(run_dir, sub)) <= cap  # never over it
    summary = w.close({"exit_code": 0})
    rot = summary["telemetry"]["rotation"]
    events = [e for e in read_run(run_dir).events if e["kind"] == "telemetry_rotated"]
    assert rot["parts_removed"] == len(events) > 0
    assert rot["rows_removed"] == sum(e["rows"] for e in events)
    assert [e["first_tick"] for e in events] == sorted(e["first_tick"] for e in events)
    assert events[0]["first_tick"] == 0  # the oldest went first
    assert all(e["why"] == "size" and "telemetry.max_mb = 0.06" in e["message"] for e in events)
    run = read_run(run_dir)
    ticks = run.tick
    assert ticks[-1] == n - 1 and ticks[0] == rot["first_tick_kept"] == events[-1]["last_tick"] + 1
    assert np.all(np.diff(ticks) == 1)  # what is left is whole and in order
    assert any("removed under the run's cap" in line for line in run.warnings)
    assert summary["telemetry"]["rows_written"] == n


def test_an_age_cap_removes_parts_older_than_it() -> None:
    book = PartBook(None, max_age_s=3600.0)
    now = time.time()
    for k, age in enumerate((7200.0, 4000.0, 10.0)):
        book.closed(Part(Path(f"/nonexistent/part-{k}"), 100, 10, 10 * k, 10 * k + 9, now - age))
    book.make_room(0)
    notes = book.take_notes()
    assert [n["part"] for n in notes] == ["part-0", "part-1"]
    assert all(n["why"] == "age" and "telemetry.max_age_h = 1" in n["message"] for n in notes)
    assert book.summary()["rows_removed"] == 20 and book.summary()["first_tick_kept"] == 20
    assert book.full(0, opened_at=0.0, now=451.0) and not book.full(0, opened_at=0.0, now=449.0)


def _rig(tmp_path: Path, telemetry: str) -> Path:
    text = BASE.replace('port = "dxlsim://?ids=1-2"', RIG_PORT).replace(
        "rate_hz = 500", "rate_hz = 250"
    )
    return write(tmp_path, text + f"\n[telemetry]\n{telemetry}\n")


def test_a_short_show_under_a_small_cap_stays_under_it(tmp_path: Path) -> None:
    rig = _rig(tmp_path, 'format = "csv"\nmax_mb = 0.1')
    with hilsim.Show(rig, virtual_time=True, duration=4.0, out=tmp_path / "run") as show:
        result = show.run()
    assert result.exit_code == 0
    parts = _parts(tmp_path / "run", TELEMETRY_PARTS)
    assert sum(p.stat().st_size for p in parts) <= 100_000
    assert result.summary["telemetry"]["rotation"]["parts_removed"] > 0
    run = read_run(tmp_path / "run")
    assert run.tick[-1] == result.ticks - 1


def test_summary_only_keeps_events_and_the_summary_not_the_rows(tmp_path: Path) -> None:
    rig = _rig(tmp_path, 'format = "none"')
    with hilsim.Show(rig, virtual_time=True, duration=0.5, out=tmp_path / "run") as show:
        result = show.run()
    assert result.exit_code == 0 and result.run_dir == tmp_path / "run"
    names = {p.name for p in (tmp_path / "run").iterdir()}
    assert {"events.jsonl", "summary.json", "rig.toml"} <= names
    assert not any(n.startswith("telemetry") for n in names)
    tel = result.summary["telemetry"]
    assert tel["format"] == "none" and tel["rows_written"] == 0
    assert result.summary["ticks"] == result.ticks  # the statistics still cover every tick
    with pytest.raises(NotARunError, match=r"telemetry\.format = 'none'"):
        read_run(tmp_path / "run")


def test_off_keeps_nothing(tmp_path: Path) -> None:
    rig = _rig(tmp_path, 'format = "off"')
    with hilsim.Show(rig, virtual_time=True, duration=0.5, out=tmp_path / "run") as show:
        result = show.run()
    assert result.exit_code == 0 and result.run_dir is None
    assert not (tmp_path / "run").exists()
    assert result.summary["telemetry"]["format"] == "off"


def test_the_failure_default_keeps_an_endless_show_going(tmp_path: Path) -> None:
    rig = load_rig(_rig(tmp_path, ""))
    assert rig.telemetry.on_failure is TelemetryFailurePolicy.AUTO
    policy = TelemetryFailurePolicy
    assert policy.AUTO.continues(endless=True) and not policy.AUTO.continues(endless=False)
    assert policy.CONTINUE.continues(endless=False) and not policy.STOP.continues(endless=True)
    endless = SimpleNamespace(targets=SimpleNamespace(duration=None))
    assert "goes on if the disk fills up" in (_failure_note(rig, endless, None) or "")
    assert _failure_note(rig, endless, 60.0) is None  # a show with an end: stop, as before
    stop = load_rig(_rig(tmp_path, 'on_failure = "stop"'))
    assert _failure_note(stop, endless, None) is None


def test_a_dead_writer_stops_a_show_with_an_end_not_an_endless_one(tmp_path: Path) -> None:
    from hilsim.show.loop import HilLoop
    from hilsim.telemetry.writer import WriterFailedError

    rig = load_rig(_rig(tmp_path, ""))
    dead = WriterFailedError("telemetry writer failed: No space left on device")
    endless = SimpleNamespace(rig=rig, duration_s=None, _recording=True)
    HilLoop._telemetry_failed(endless, dead)  # type: ignore[arg-type]
    assert endless._recording is False  # the record stops; the show goes on
    ends = SimpleNamespace(rig=rig, duration_s=60.0, _recording=True)
    with pytest.raises(WriterFailedError):
        HilLoop._telemetry_failed(ends, dead)  # type: ignore[arg-type]


def test_a_bounded_read_keeps_an_envelope_and_exact_counts(tmp_path: Path) -> None:
    n = 20_000
    bad, overruns, acted = {17, 9000}, {5, 12_345, 19_999}, set(range(3000, 3100))
    with TelemetryWriter(tmp_path, JOINTS, format="csv", overflow="block") as w:
        _record(w, n, late_us=lambda i: 5.0 + (i % 100), bad=bad, overruns=overruns, acted=acted)
    full = read_run(tmp_path)
    run = read_run(tmp_path, max_rows=2000)
    assert run.decimated and run.envelope is not None and run.envelope.rows == n
    assert run.n_ticks <= 2000  # bounded: two rows a bucket
    assert run.counts is not None
    assert run.counts["rows"].sum() == n
    assert run.counts["status2_pan"].sum() == len(bad)
    assert run.counts["overrun"].sum() == len(overruns)
    assert run.counts["acted_pan"].sum() == len(acted)
    for name in ("tick", "t_sched", "cmd_pan", "sim_x_tilt", "lateness_us", "t_bus_us"):
        assert np.nanmin(run.columns[name]) == np.nanmin(full.columns[name])
        assert np.nanmax(run.columns[name]) == np.nanmax(full.columns[name])
    for q in (50.0, 99.0, 99.9):
        exact = float(np.percentile(full.lateness_us, q))
        assert exact <= run.envelope.percentile("lateness_us", q) <= exact * 1.0235
    small = read_run(tmp_path, max_rows=n)  # under the bound: the rows as they are
    assert not small.decimated
    assert np.array_equal(small.columns["cmd_pan"], full.columns["cmd_pan"])


def test_plots_of_a_bounded_read_say_what_they_show(tmp_path: Path) -> None:
    from hilsim.telemetry.plots import plot_run

    with TelemetryWriter(tmp_path, JOINTS, format="csv", overflow="block") as w:
        _record(w, 6000, late_us=lambda i: 5.0 + (i % 100), bad={17}, overruns={5})
    run = read_run(tmp_path, max_rows=1000)
    paths = plot_run(run, tmp_path / "plots", parallel=False)
    assert [p.name for p in paths] == ["joints.png", "lateness.png", "timing.png"]
    assert all(p.stat().st_size > 10_000 for p in paths)


def _old_runs(root: Path) -> list[Path]:
    """Three old runs (300 kB each, last written 10, 5 and 1 days ago) and a folder that is
    not a run."""
    now = time.time()
    runs = []
    for name, days in (("demo-a", 10), ("demo-b", 5), ("demo-c", 1)):
        d = root / name
        d.mkdir(parents=True)
        (d / "events.jsonl").write_bytes(b"x" * 300_000)
        (d / "summary.json").write_text("{}")
        for f in (*d.iterdir(), d):
            os.utime(f, (now - days * 86400, now - days * 86400))
        runs.append(d)
    (root / "notes").mkdir()
    (root / "notes" / "todo.txt").write_bytes(b"y" * 900_000)
    os.utime(root / "notes" / "todo.txt", (now - 99 * 86400, now - 99 * 86400))
    return runs


@pytest.mark.parametrize(
    ("cap", "gone", "why"),
    [("runs_max_mb = 0.5", ["demo-a", "demo-b"], "size"),
     ("runs_max_age_days = 3", ["demo-a", "demo-b"], "age"),
     ("runs_max_mb = 1", [], "")],
)  # fmt: skip
def test_old_runs_under_the_runs_root_go_oldest_first_each_said(tmp_path, cap, gone, why) -> None:
    root = tmp_path / "runs"
    runs = _old_runs(root)
    rig = _rig(tmp_path, f'out_dir = "{root}"\n{cap}')
    with hilsim.Show(rig, virtual_time=True, duration=0.2) as show:
        result = show.run()
    assert result.exit_code == 0 and result.run_dir is not None
    assert result.run_dir.parent == root and result.run_dir.is_dir()  # this run stays
    assert [d.name for d in runs if not d.exists()] == gone
    assert (root / "notes" / "todo.txt").exists()  # not a run: never touched
    said = [e for e in read_run(result.run_dir).events if e["kind"] == "run_removed"]
    assert [e["run"] for e in said] == gone and all(e["why"] == why for e in said)
    removed = result.summary["telemetry"]["runs_removed"]
    assert removed["runs"] == len(gone) and removed["names"] == gone
    assert removed["bytes"] == sum(e["bytes"] for e in said)


def test_a_run_made_elsewhere_leaves_the_runs_root_alone(tmp_path) -> None:
    root = tmp_path / "runs"
    runs = _old_runs(root)
    rig = _rig(tmp_path, f'out_dir = "{root}"\nruns_max_age_days = 3')
    with hilsim.Show(rig, virtual_time=True, duration=0.2, out=tmp_path / "mine") as show:
        assert show.run().exit_code == 0
    assert all(d.exists() for d in runs)


def test_runs_dir_is_the_root_the_caps_prune_as_the_service_unit_runs_it(tmp_path, capsys) -> None:
    """`hilsim service print` runs `hilsim run --runs-dir DIR`: the caps prune DIR, not the
    rig's telemetry.out_dir (which a unit's working directory makes meaningless)."""
    from hilsim.cli import main

    root = tmp_path / "var-runs"
    runs = _old_runs(root)
    rig = _rig(tmp_path, 'out_dir = "elsewhere"\nruns_max_age_days = 3')
    code = main(
        ["run", str(rig), "--virtual-time", "--no-plots", "--duration", "0.2",
         "--runs-dir", str(root)]
    )  # fmt: skip
    assert code == 0, capsys.readouterr().err
    assert [d.name for d in runs if not d.exists()] == ["demo-a", "demo-b"]
    (mine,) = [d for d in root.iterdir() if d.name.startswith("rig-")]
    said = [e["run"] for e in read_run(mine).events if e["kind"] == "run_removed"]
    assert said == ["demo-a", "demo-b"]
    assert not (tmp_path / "elsewhere").exists()


def test_a_figure_of_several_buses_prunes_its_runs_root_once(tmp_path, capsys) -> None:
    from hilsim.cli import main
    from tests.hilsim.test_multibus_run import group_record, rig

    root = tmp_path / "runs"
    runs = _old_runs(root)
    path = rig(tmp_path)
    path.write_text(path.read_text() + f'\n[telemetry]\nout_dir = "{root}"\nruns_max_mb = 0.5\n')
    code = main(["run", str(path), "--virtual-time", "--no-plots", "--duration", "0.2"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert [d.name for d in runs if not d.exists()] == ["demo-a", "demo-b"]
    assert "telemetry.runs_max_mb = 0.5: removed the old run demo-a" in err
    (mine,) = [d for d in root.iterdir() if d.name.startswith("pair-")]
    assert [r["run"] for r in group_record(mine)["runs_removed"]] == ["demo-a", "demo-b"]


def test_off_keeps_a_recorded_take_and_the_summary_says_where(tmp_path: Path) -> None:
    """A show that records its live input keeps the take with format "off" (it was removed
    with the rest while the summary still named its files)."""
    import socket

    from tests.hilsim.test_live_run import PERIOD, RIG, osc

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    (tmp_path / "rig.toml").write_text(RIG + '\n[telemetry]\nformat = "off"\n')
    show_file = tmp_path / "show.toml"
    show_file.write_text(
        f"[inputs.osc]\nport = {port}\njoints = {{ jaw = [0, 20] }}\n[record]\ntolerance_deg = 0.5\n"
    )
    out = tmp_path / "run"
    with hilsim.Show(
        tmp_path / "rig.toml", show=show_file, virtual_time=True, duration=1.0, out=out
    ) as show:
        director = show.parts.director
        assert director is not None and director.osc is not None
        tick = director.tick

        def fed(k, t, present):
            tick(k, t, present)
            if k in (50, 100, 150):
                director.osc.feed(k * PERIOD, osc("/hilsim/joint/jaw", k / 200), ("127.0.0.1", 1))

        director.tick = fed
        result = show.run()
    assert result.exit_code == 0 and result.run_dir == out
    assert sorted(p.name for p in out.iterdir()) == ["take"]  # the take, nothing else
    take = result.summary["live"]["takes"]["live"]
    assert Path(take["raw_csv"]).is_file() and Path(take["take_toml"]).is_file()
    assert take["raw_samples"] == {"jaw": 3}
