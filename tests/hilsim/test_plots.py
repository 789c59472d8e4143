"""``hilsim plot`` and :mod:`hilsim.plots` on synthetic runs."""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hilsim import plot_cli
from hilsim.runs import read_run
from hilsim.telemetry import TelemetryWriter
from hilsim.telemetry_format import TELEMETRY_CSV
from tests.hilsim.test_telemetry import write_synthetic_run

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
    assert plot_cli.main([str(synthetic_run), "--out", str(out_dir), "--start", "1",
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
            w.record(k, k * 0.01, k * 0.01, x, x, x * 0, x, present, status,
                     math.nan, math.nan, math.nan, math.nan, False, 0)  # fmt: skip
    with open(tmp_path / TELEMETRY_CSV, "a") as f:
        f.write("300,3.0,3.0,0.000,0.1")
    assert plot_cli.run(_args(tmp_path)) == 0
    out = capsys.readouterr()
    assert "incomplete" in out.err
    _assert_pngs([Path(line) for line in out.out.splitlines()])


def test_plot_run_accepts_a_loaded_run(synthetic_run: Path, tmp_path: Path) -> None:
    from hilsim.plots import plot_run

    _assert_pngs(plot_run(read_run(synthetic_run), tmp_path, dpi=50))


def test_registered_as_hilsim_plot(synthetic_run: Path, tmp_path: Path) -> None:
    from hilsim import cli

    if "plot" not in cli.SUBCOMMANDS:
        pytest.skip("`plot` is not in hilsim.cli.SUBCOMMANDS yet")
    assert cli.main(["plot", str(synthetic_run), "--out", str(tmp_path), "--dpi", "50"]) == 0
    _assert_pngs([tmp_path / n for n in NAMES])


def test_importing_does_not_import_matplotlib() -> None:
    code = (
        "import sys, hilsim, hilsim.telemetry, hilsim.plots, hilsim.plot_cli\n"
        "assert 'matplotlib' not in sys.modules, 'matplotlib imported'\n"
    )
    root = Path(__file__).resolve().parents[2]
    subprocess.run([sys.executable, "-c", code], check=True, cwd=root)
