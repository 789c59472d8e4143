"""How :func:`plot_run` gets its speed without changing the figures: the joints figure drawn in a
forked child, a process prestarted before the show, the layout done by hand, log axes labelled
without mathtext. None of these tests times anything."""

from __future__ import annotations

import os
import pickle
import signal
import time
from pathlib import Path

import pytest

from hilsim.telemetry import plot_common as common
from hilsim.telemetry import plots
from hilsim.telemetry.plots import PNG_NAMES, PlotProcessError, plot_run
from hilsim.telemetry.reader import NotARunError, read_run
from tests.hilsim.test_plots import RIG_TEXT, _write_run
from tests.hilsim.test_telemetry import write_synthetic_run

needs_fork = pytest.mark.skipif(not hasattr(os, "fork"), reason="no os.fork")


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("run")
    write_synthetic_run(path, seconds=2.0)
    return path


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


@needs_fork
def test_the_forked_child_draws_the_same_bytes(run_dir: Path, tmp_path: Path) -> None:
    run = read_run(run_dir)
    serial = plot_run(run, tmp_path / "serial", dpi=50, parallel=False)
    forked = plot_run(run, tmp_path / "forked", dpi=50, parallel=True)
    assert [p.name for p in forked] == list(PNG_NAMES)
    for a, b in zip(serial, forked, strict=True):
        assert a.read_bytes() == b.read_bytes(), a.name


@needs_fork
def test_an_error_in_the_child_is_raised_as_itself_and_the_rest_is_drawn(
    run_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(*_a: object, **_k: object) -> Path:
        raise ValueError("no joints today")

    monkeypatch.setattr(plots, "plot_joints", broken)
    with pytest.raises(ValueError, match="no joints today"):
        plot_run(read_run(run_dir), tmp_path, dpi=50, parallel=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lateness.png", "timing.png"]


@needs_fork
def test_a_child_that_dies_or_raises_what_cannot_travel_is_a_plot_process_error(
    run_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = read_run(run_dir)

    def dies(*_a: object, **_k: object) -> Path:
        os.kill(os.getpid(), 9)
        raise AssertionError("unreachable")

    monkeypatch.setattr(plots, "plot_joints", dies)
    with pytest.raises(PlotProcessError, match="signal 9"):
        plot_run(run, tmp_path / "a", dpi=50, parallel=True)

    class Odd(Exception):
        def __init__(self, a: int, b: int) -> None:  # does not unpickle from its args
            super().__init__(f"odd {a} {b}")

    def odd(*_a: object, **_k: object) -> Path:
        raise Odd(1, 2)

    monkeypatch.setattr(plots, "plot_joints", odd)
    with pytest.raises(PlotProcessError, match="Odd: odd 1 2"):
        plot_run(run, tmp_path / "b", dpi=50, parallel=True)


@needs_fork
def test_ctrl_c_in_the_parent_leaves_no_child(
    run_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pid_file = tmp_path / "child.pid"

    def slow(*_a: object, **_k: object) -> Path:
        part = pid_file.with_suffix(".part")  # renamed whole: never read empty
        part.write_text(str(os.getpid()))
        part.replace(pid_file)
        time.sleep(30)
        raise AssertionError("not killed")

    def interrupted(*_a: object, **_k: object) -> Path:
        deadline = time.monotonic() + 10
        while not pid_file.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        raise KeyboardInterrupt

    monkeypatch.setattr(plots, "plot_joints", slow)
    monkeypatch.setattr(plots, "plot_lateness", interrupted)
    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        plot_run(read_run(run_dir), tmp_path / "out", dpi=50, parallel=True)
    assert time.monotonic() - start < 20
    assert _gone(int(pid_file.read_text()))  # killed and reaped


def test_no_fork_while_another_thread_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    import threading

    monkeypatch.setattr(threading, "active_count", lambda: 2)
    assert not plots.can_fork()


# ------------------------------------------------------------------------- the prestarted process


@pytest.fixture
def no_worker():
    yield
    worker, plots._prestarted = plots._prestarted, None
    if worker is not None:
        worker.close(kill=True)


@needs_fork
@pytest.mark.usefixtures("no_worker")
def test_a_prestarted_process_draws_the_next_run_directory(run_dir: Path, tmp_path: Path) -> None:
    plots.prestart()
    worker = plots._prestarted
    if worker is None:
        pytest.skip("one CPU: nothing is prestarted")
    plots.prestart()  # one is waiting already
    assert plots._prestarted is worker
    paths = plot_run(run_dir, tmp_path, dpi=50)
    assert plots._prestarted is None and worker.proc.returncode == 0
    assert paths == [tmp_path / n for n in PNG_NAMES]
    serial = plot_run(read_run(run_dir), tmp_path / "here", dpi=50, parallel=False)
    for a, b in zip(serial, paths, strict=True):
        assert a.read_bytes() == b.read_bytes(), a.name


@needs_fork
@pytest.mark.usefixtures("no_worker")
def test_a_prestarted_process_told_the_runs_shape_draws_the_same_bytes(
    run_dir: Path, tmp_path: Path
) -> None:
    plots.prestart()
    if plots._prestarted is None:
        pytest.skip("one CPU: nothing is prestarted")
    run = read_run(run_dir)
    plots.prepare(len(run.joint_names), virtual=False, dpi=50)  # figures made while it waits
    plots.prepare(7, virtual=True, dpi=50)  # a shape not drawn: no harm
    paths = plot_run(run_dir, tmp_path, dpi=50)
    serial = plot_run(run, tmp_path / "here", dpi=50, parallel=False)
    for a, b in zip(serial, paths, strict=True):
        assert a.read_bytes() == b.read_bytes(), a.name


def test_prepare_without_a_prestarted_process_does_nothing() -> None:
    assert plots._prestarted is None
    plots.prepare(4, virtual=True)


@pytest.mark.usefixtures("no_worker")
def test_a_prestarted_process_never_asked_to_draw_is_terminated_at_exit(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A show refused at start-up exits at once, not after matplotlib's import."""
    import atexit

    at_exit = []
    monkeypatch.setattr(atexit, "register", lambda f, *a: at_exit.append((f, a)))
    plots.prestart()
    worker = plots._prestarted
    if worker is None:
        pytest.skip("one CPU: nothing is prestarted")
    ((f, a),) = at_exit
    f(*a)  # what the interpreter's exit runs
    assert worker.proc.returncode in (-signal.SIGTERM, 143)  # not a clean exit after importing


@needs_fork
@pytest.mark.usefixtures("no_worker")
def test_the_prestarted_process_raises_errors_as_themselves(tmp_path: Path) -> None:
    plots.prestart()
    if plots._prestarted is None:
        pytest.skip("one CPU: nothing is prestarted")
    with pytest.raises(NotARunError):
        plot_run(tmp_path / "nothing here", tmp_path / "out")


@needs_fork
@pytest.mark.usefixtures("no_worker")
def test_a_prestarted_process_not_needed_is_closed(run_dir: Path, tmp_path: Path) -> None:
    plots.prestart()
    worker = plots._prestarted
    if worker is None:
        pytest.skip("one CPU: nothing is prestarted")
    plot_run(read_run(run_dir), tmp_path, dpi=50, parallel=False)  # a loaded run: drawn here
    assert plots._prestarted is None and worker.proc.returncode is not None


@needs_fork
@pytest.mark.usefixtures("no_worker")
def test_a_dead_prestarted_process_is_replaced_by_drawing_here(
    run_dir: Path, tmp_path: Path
) -> None:
    plots.prestart()
    worker = plots._prestarted
    if worker is None:
        pytest.skip("one CPU: nothing is prestarted")
    worker.proc.kill()
    worker.proc.wait()
    assert plot_run(run_dir, tmp_path, dpi=50) == [tmp_path / n for n in PNG_NAMES]


def test_outcomes_that_do_not_round_trip_travel_as_text() -> None:
    class Odd(Exception):
        def __init__(self, a: int, b: int) -> None:
            super().__init__(f"odd {a} {b}")

    kind, exc = pickle.loads(plots._pickled(("error", Odd(1, 2))))
    assert kind == "error" and isinstance(exc, PlotProcessError) and "Odd: odd 1 2" in str(exc)


# ---------------------------------------------------------------------------- what is drawn


@pytest.mark.parametrize(
    ("label", "plain"),
    [
        ("$\\mathdefault{10^{3}}$", "10³"),
        ("$\\mathdefault{10^{-2}}$", "10⁻²"),
        ("$\\mathdefault{2\\times10^{1}}$", "2×10¹"),
        ("$\\mathdefault{0.5}$", "0.5"),
        ("", ""),
        ("12", "12"),
    ],
)
def test_log_tick_labels_in_plain_text(label: str, plain: str) -> None:
    assert common._plain(label) == plain


def _figures(tmp_path: Path, run, monkeypatch: pytest.MonkeyPatch) -> dict:
    figures = {}
    save = common.save

    def keep(fig, path, dpi):
        figures[Path(path).name] = fig
        return save(fig, path, dpi)

    monkeypatch.setattr(common, "save", keep)
    plot_run(run, tmp_path, dpi=80, parallel=False)
    return figures


def _overlap(a, b, tol: float) -> bool:
    return min(a.x1, b.x1) - max(a.x0, b.x0) > tol and min(a.y1, b.y1) - max(a.y0, b.y0) > tol


@pytest.mark.parametrize("clock", ["real time", "virtual time"])
def test_the_layout_keeps_everything_inside_and_apart(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, clock: str
) -> None:
    """What constrained layout guaranteed: every axes with its labels, ticks, notes and legends
    inside the figure; no two axes' decorations, the title or the figure legend overlapping."""
    synthetic = tmp_path / "synthetic"
    write_synthetic_run(synthetic, seconds=2.0)
    runs = [read_run(synthetic), _write_run(tmp_path / "r", config_text=RIG_TEXT,
                                            summary={"clock": clock})]  # fmt: skip
    for k, run in enumerate(runs):
        for name, fig in _figures(tmp_path / f"out{k}", run, monkeypatch).items():
            renderer = fig.canvas.get_renderer()
            fig.draw(renderer)
            page = fig.bbox
            boxes = [ax.get_tightbbox(renderer) for ax in fig.axes if ax.get_visible()]
            boxes += [a.get_window_extent(renderer) for a in (*fig.legends, fig._suptitle) if a]
            for i, box in enumerate(boxes):
                where = f"{name} of {run.path.name}, box {i}"
                assert box.x0 >= page.x0 - 1 and box.x1 <= page.x1 + 1, where
                assert box.y0 >= page.y0 - 1 and box.y1 <= page.y1 + 1, where
                for j, other in enumerate(boxes[:i]):
                    assert not _overlap(box, other, 1.0), f"{where} overlaps box {j}"


def _children() -> list[int]:
    """Processes whose parent is this one (Linux /proc), zombies included."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == os.getpid():
                found.append(int(entry.name))
    return found


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="no /proc")
@pytest.mark.usefixtures("no_worker")
def test_a_virtual_time_show_draws_through_a_prestarted_process_and_leaves_none(
    tmp_path: Path,
) -> None:
    from hilsim.cli import main

    demo = Path(__file__).resolve().parents[2] / "configs" / "demo.toml"
    before = set(_children())
    out = tmp_path / "run"
    assert main(["run", str(demo), "--virtual-time", "--duration", "0.5", "--out", str(out)]) == 0
    assert sorted(p.name for p in (out / "plots").iterdir()) == sorted(PNG_NAMES)
    assert plots._prestarted is None
    assert set(_children()) <= before


def _serving_here() -> list[int]:
    """Prestarted plot processes (and their forked helpers) in this process group."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
            if b"_serve()" in cmdline and os.getpgid(int(entry.name)) == os.getpgrp():
                stat = (entry / "stat").read_text()
                if stat.rsplit(")", 1)[1].split()[0] != "Z":
                    found.append(int(entry.name))
        except (OSError, ProcessLookupError):
            continue
    return found


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="no /proc")
@pytest.mark.usefixtures("no_worker")
def test_ctrl_c_while_the_prestarted_process_draws_leaves_nothing_running(
    run_dir: Path, tmp_path: Path
) -> None:
    import signal

    plots.prestart()
    if plots._prestarted is None:
        pytest.skip("one CPU: nothing is prestarted")
    time.sleep(1.0)  # importing, or drawing: either way it must go

    def interrupt(_s: int, _f: object) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGALRM, interrupt)
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.2)
        with pytest.raises(KeyboardInterrupt):
            plot_run(run_dir, tmp_path, dpi=50)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    assert plots._prestarted is None
    deadline = time.monotonic() + 5.0
    while _serving_here() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _serving_here() == []


# ------------------------------------------------------------------ the PNG writer, figures ahead


def _pixels(path: Path):
    import numpy as np
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGBA"))


def test_save_writes_the_pixels_savefig_draws(run_dir: Path, tmp_path: Path) -> None:
    import numpy as np

    from hilsim.telemetry.joint_plots import joints_figure

    run = read_run(run_dir)
    ours = common.save(joints_figure(run, dpi=60), tmp_path / "ours.png", 60)
    theirs = tmp_path / "theirs.png"
    joints_figure(run, dpi=60).savefig(theirs, dpi=60)
    assert np.array_equal(_pixels(ours), _pixels(theirs))


@pytest.mark.parametrize("clock", ["real time", "virtual time"])
def test_figures_made_ahead_draw_the_same_pixels(
    run_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, clock: str
) -> None:
    """The synthetic run has log axes (lateness, the timing bars: minor ticks made ahead)."""
    import numpy as np

    from hilsim.telemetry import joint_plots, timing_plots

    if clock == "real time":
        run = read_run(run_dir)
    else:
        run = _write_run(tmp_path / "r", config_text=RIG_TEXT, summary={"clock": clock})
    assert common.is_virtual_time(run) == (clock == "virtual time")
    fresh = plot_run(run, tmp_path / "fresh", dpi=60, parallel=False)
    monkeypatch.setattr(common, "_AHEAD", {})
    joint_plots.make_ahead(len(run.joint_names), dpi=60)
    timing_plots.make_ahead(common.is_virtual_time(run), dpi=60)
    made = [fig for figs in common._AHEAD.values() for fig, _ in figs]
    assert len(made) == 3
    ahead = plot_run(run, tmp_path / "ahead", dpi=60, parallel=False)
    assert not any(common._AHEAD.values())  # each was used
    for a, b in zip(fresh, ahead, strict=True):
        assert np.array_equal(_pixels(a), _pixels(b)), a.name
    if clock == "real time":  # the minor ticks made ahead were drawn
        assert made[-1].axes[1].get_yscale() == "log"
