"""``hilsim plot`` and :mod:`hilsim.telemetry.plots` on synthetic runs."""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hilsim.cli import main as hilsim_main
from hilsim.cli import plot as plot_cli
from hilsim.telemetry import TelemetryWriter
from hilsim.telemetry.format import TELEMETRY_CSV
from hilsim.telemetry.reader import read_run
from tests.hilsim.test_telemetry import write_synthetic_run
from tests.hilsim.tick_rows import tick_record

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
NAMES = ("joints.png", "lateness.png", "timing.png")


def _args(run_dir: Path, **kw: object) -> argparse.Namespace:
    defaults = {"out": None, "start": None, "end": None, "dpi": 50}
    return argparse.Namespace(run_dir=str(run_dir), **{**defaults, **kw})


@pytest.fixture(scope="module")
def synthetic_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run_dir = tmp_path_factory.mktemp("synthetic")
    write_synthetic_run(run_dir, seconds=4.0)
    return run_dir


def _assert_pngs(paths: list[Path]) -> None:
    assert [p.name for p in paths] == list(NAMES)
    for p in paths:
        assert p.read_bytes()[:8] == PNG_MAGIC and p.stat().st_size > 2_000


def test_plot_writes_pngs_into_run_dir(
    synthetic_run: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert plot_cli.run(_args(synthetic_run)) == 0
    out = capsys.readouterr()
    printed = [Path(line) for line in out.out.splitlines()]
    assert printed == [synthetic_run / "plots" / n for n in NAMES]
    _assert_pngs(printed)
    assert out.err == ""  # a clean run has nothing to warn about


def test_plot_out_dir_and_window(
    synthetic_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out_dir = tmp_path / "figs"
    assert hilsim_main(["plot", str(synthetic_run), "--out", str(out_dir), "--start", "1",
                          "--end", "2.5", "--dpi", "50"]) == 0  # fmt: skip
    printed = [Path(line) for line in capsys.readouterr().out.splitlines()]
    assert printed == [out_dir / n for n in NAMES]
    _assert_pngs(printed)


def test_not_a_run_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert plot_cli.run(_args(tmp_path)) == 2
    err = capsys.readouterr().err
    assert "not a run directory" in err and str(tmp_path) in err
    assert plot_cli.run(_args(tmp_path / "missing")) == 2
    (tmp_path / TELEMETRY_CSV).write_text("time,value\n0,1\n")
    assert plot_cli.run(_args(tmp_path)) == 2
    assert "not a telemetry header" in capsys.readouterr().err


def test_run_without_ticks_exits_1(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    TelemetryWriter(tmp_path, ["a"]).close()
    assert plot_cli.run(_args(tmp_path)) == 1
    assert "no ticks" in capsys.readouterr().err


def test_damaged_virtual_time_run_still_plots(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Virtual clock (lateness all 0), stage times never measured (NaN), a crash mid-line."""
    with TelemetryWriter(tmp_path, ["pan", "tilt"]) as w:
        for k in range(300):
            x = np.array([math.sin(k / 50), math.cos(k / 50)])
            status = np.array([1 if 100 <= k < 120 else 0, 0])
            present = np.where(status == 0, x, np.nan)
            w.record(tick_record(k, k * 0.01, k * 0.01, x, x, x * 0, x, present, status,
                     math.nan, math.nan, math.nan, math.nan, False, 0))  # fmt: skip
    with open(tmp_path / TELEMETRY_CSV, "a") as f:
        f.write("300,3.0,3.0,0.000,0.1")
    assert plot_cli.run(_args(tmp_path)) == 0
    out = capsys.readouterr()
    assert "incomplete" in out.err
    _assert_pngs([Path(line) for line in out.out.splitlines()])


def test_plot_run_accepts_a_loaded_run(synthetic_run: Path, tmp_path: Path) -> None:
    from hilsim.telemetry.plots import plot_run

    _assert_pngs(plot_run(read_run(synthetic_run), tmp_path, dpi=50))


def test_registered_as_hilsim_plot(synthetic_run: Path, tmp_path: Path) -> None:
    from hilsim import cli

    assert "plot" in cli.SUBCOMMANDS  # not registered is a failure, not a skip
    assert cli.main(["plot", str(synthetic_run), "--out", str(tmp_path), "--dpi", "50"]) == 0
    _assert_pngs([tmp_path / n for n in NAMES])


def test_importing_does_not_import_matplotlib() -> None:
    code = (
        "import sys, hilsim, hilsim.telemetry, hilsim.telemetry.plots, hilsim.cli.plot\n"
        "assert 'matplotlib' not in sys.modules, 'matplotlib imported'\n"
    )
    root = Path(__file__).resolve().parents[2]
    subprocess.run([sys.executable, "-c", code], check=True, cwd=root)


# ------------------------------------------------------------ limits, safety spans, virtual time

RIG_TEXT = """\
name = "two"
[safety]
soft_start_s = 0.5
[[joints]]
name = "arm"
min_deg = -40
max_deg = 40
[[joints]]
name = "still"
min_deg = -10.5
max_deg = 10
"""


def _write_run(run_dir: Path, *, config_text: str | None, summary: dict, noise: float = 0.0):
    """100 Hz, 3 s: arm's spring ramps 0 → 60° and the command is clamped at 40° (from t = 2 s);
    still sits at 0 (± noise)."""
    rate = 100
    with TelemetryWriter(run_dir, ["arm", "still"], config_text=config_text) as w:
        for k in range(3 * rate + 1):
            t = k / rate
            x = np.radians([20.0 * t, 0.0]) + noise * math.sin(k)
            cmd = np.minimum(x, np.radians([40.0, 90.0]))
            w.record(tick_record(k, t, t, x, x, x * 0, cmd, cmd, np.zeros(2, dtype=np.int8),
                     1.0, 1.0, 1.0, 1.0, False, 0))  # fmt: skip
        w.close(summary)
    return read_run(run_dir)


def _limit_lines(ax) -> list[float]:
    return sorted(
        float(line.get_ydata()[0]) for line in ax.get_lines() if line.get_linestyle() == ":"
    )


def _shaded(ax) -> list[tuple[float, float]]:
    """(start, end) in s of every shaded span in a joint row."""
    spans = []
    for coll in ax.collections:
        for path in coll.get_paths():
            xs = path.vertices[:, 0]
            spans.append((float(xs.min()), float(xs.max())))
    return sorted(spans)


def test_joint_limits_come_from_the_rig_copy(tmp_path: Path) -> None:
    from hilsim.telemetry.plots import joint_limits_deg, soft_start_s

    run = _write_run(tmp_path / "a", config_text=RIG_TEXT, summary={})
    assert joint_limits_deg(run) == {"arm": (-40.0, 40.0), "still": (-10.5, 10.0)}
    assert soft_start_s(run) == 0.5
    bad = RIG_TEXT.replace("max_deg = 10", "max_deg = -20").replace(
        "min_deg = -40", "min_deg = true"
    )
    run = _write_run(tmp_path / "b", config_text=bad, summary={})
    assert joint_limits_deg(run) == {}
    for text in (None, "not [toml", '[rig]\nname = "x"\n'):
        run = _write_run(tmp_path / f"c{len(str(text))}", config_text=text, summary={})
        assert joint_limits_deg(run) == {} and soft_start_s(run) is None


def test_joint_plot_draws_the_limits_and_shades_where_safety_acted(tmp_path: Path) -> None:
    from hilsim.telemetry.plots import joints_figure

    summary = {"safety_limits": {"position": {"arm": 100, "still": 0}, "speed": {"arm": 0}}}
    run = _write_run(tmp_path, config_text=RIG_TEXT, summary=summary)
    fig = joints_figure(run)
    arm, still = fig.axes[:2]
    assert _limit_lines(arm) == [-40.0, 40.0] and _limit_lines(still) == [-10.5, 10.0]
    # the command is clamped from t = 2.01 s (20°/s · t > 40°) to the end, 3 s + one tick
    (span,) = _shaded(arm)
    assert span == pytest.approx((2.01, 3.01))
    assert _shaded(still) == []
    assert arm.get_ylim()[0] < -40.0 and arm.get_ylim()[1] > 60.0  # limits and data in view
    notes = [t.get_text() for t in arm.texts]
    assert any("safety limited 1.00 s" in n and "position 100" in n for n in notes), notes
    assert any("never limited" in t.get_text() for t in still.texts)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "joint limits (rig.toml)" in labels and "safety filter limited the command" in labels


def test_joint_plot_title_counts_the_ticks_caught_up_without_a_row(tmp_path: Path) -> None:
    from hilsim.telemetry.plots import joints_figure

    summary = {"loop": {"skipped_ticks": 62}}
    run = _write_run(tmp_path / "a", config_text=RIG_TEXT, summary=summary)
    title = joints_figure(run)._suptitle.get_text()
    assert "(301 ticks + 62 caught up without a row, 3 s)" in title, title
    title = joints_figure(run, start=0.5, end=1.0)._suptitle.get_text()  # a window: its rows
    assert "caught up" not in title and "ticks" in title, title
    for i, bad in enumerate((0, True, -5, "62", 6.2, None)):  # none of them a count to add
        summary = {"loop": {"skipped_ticks": bad}}
        run = _write_run(tmp_path / f"b{i}", config_text=RIG_TEXT, summary=summary)
        assert "(301 ticks, 3 s)" in joints_figure(run)._suptitle.get_text(), bad


def test_timing_plot_titles_count_the_ticks_caught_up_as_the_joints_plot_does(
    tmp_path: Path, monkeypatch
) -> None:
    from hilsim.telemetry import plot_common, timing_plots

    titles = []
    monkeypatch.setattr(
        plot_common, "save", lambda fig, path, dpi: titles.append(fig._suptitle.get_text())
    )
    run = _write_run(tmp_path / "a", config_text=RIG_TEXT, summary={"loop": {"skipped_ticks": 62}})
    timing_plots.plot_lateness(run, tmp_path / "l.png")
    timing_plots.plot_lateness(run, tmp_path / "w.png", start=0.5, end=1.0)
    run = _write_run(tmp_path / "b", config_text=RIG_TEXT, summary={"loop": {"skipped_ticks": -5}})
    timing_plots.plot_lateness(run, tmp_path / "b.png")
    assert "(301 ticks + 62 caught up without a row, 0 overruns)" in titles[0], titles
    assert "caught up" not in titles[1] and "ticks" in titles[1], titles  # a window: its rows
    assert "(301 ticks, 0 overruns)" in titles[2], titles
    run = _write_run(tmp_path / "c", config_text=RIG_TEXT, summary={"loop": {"skipped_ticks": 7}})
    timing_plots.plot_timing(run, tmp_path / "t.png")
    assert "(301 ticks + 7 caught up without a row)" in titles[3], titles
    # a virtual-time run skips ticks too (a stall in the show's own code): its lateness note
    virtual = {"clock": plot_common.VIRTUAL_CLOCK, "loop": {"skipped_ticks": 9}}
    run = _write_run(tmp_path / "d", config_text=RIG_TEXT, summary=virtual)
    timing_plots.plot_lateness(run, tmp_path / "v.png")
    assert "(301 ticks + 9 caught up without a row)" in titles[4], titles


def test_a_quiet_window_keeps_a_readable_y_axis(tmp_path: Path) -> None:
    from hilsim.telemetry.plots import MIN_SPAN_DEG, joints_figure

    # no rig copy: no limits to show, so at least MIN_SPAN_DEG; tiny noise must not fill the axis
    run = _write_run(tmp_path / "a", config_text=None, summary={}, noise=1e-72)
    fig = joints_figure(run, start=0.5, end=1.0)
    lo, hi = fig.axes[1].get_ylim()
    assert hi - lo >= MIN_SPAN_DEG and lo < 0.0 < hi
    assert _limit_lines(fig.axes[1]) == []
    run = _write_run(tmp_path / "b", config_text=RIG_TEXT, summary={}, noise=1e-72)
    lo, hi = joints_figure(run, start=0.5, end=1.0).axes[1].get_ylim()
    assert lo < -10.5 and hi > 10.0  # with the rig: the joint's whole range


def test_virtual_time_runs_say_lateness_and_timing_are_not_measured(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import hilsim.telemetry.plot_common as common
    import hilsim.telemetry.plots as plots

    figures = {}
    save = common.save

    def keep(fig, path, dpi):
        figures[Path(path).name] = fig
        return save(fig, path, dpi)

    monkeypatch.setattr(common, "save", keep)
    run = _write_run(tmp_path, config_text=RIG_TEXT, summary={"clock": "virtual time"})
    _assert_pngs(plots.plot_run(run, tmp_path / "out", dpi=50))
    lateness = " ".join(t.get_text() for ax in figures["lateness.png"].axes for t in ax.texts)
    assert "Virtual-time run" in lateness and "not measured" in lateness
    timing = figures["timing.png"]
    assert "virtual-time run" in timing._suptitle.get_text()
    labels = [line.get_label() for line in timing.axes[0].get_lines()]
    assert not any("tick period" in label for label in labels)
    # the same run on the real clock keeps both figures as they were
    figures.clear()
    run = _write_run(tmp_path / "real", config_text=RIG_TEXT, summary={"clock": "real time"})
    plots.plot_run(run, tmp_path / "out2", dpi=50)
    assert any("tick period" in ln.get_label() for ln in figures["timing.png"].axes[0].get_lines())
