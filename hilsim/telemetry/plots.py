"""Figures of one run directory (PNG): joint positions, tick lateness, per-stage timing.

Matplotlib is imported inside the functions, through its object-oriented API (``Figure`` on an Agg
canvas: no pyplot, no global backend switch), so ``import hilsim.telemetry.plots`` stays cheap.

* :func:`plot_joints`  one row per joint: target, spring (sim_x), commanded and present position
  in degrees against time; reads that were not OK are drawn as a coloured rug along the bottom of
  the row (stale, error, alert) and leave a gap in the present trace. The joint's limits
  (``min_deg``/``max_deg`` from the run's copy of the rig, ``rig.toml``, joint frame) are dotted
  lines, and the spans where the safety filter acted are shaded: the command differs from the
  spring by more than rounding (:data:`ACTED_TOLERANCE_RAD`: a limit, the soft start, a walk back
  in) or the spring is beyond a limit. The y axis always shows the joint's whole range (without a
  readable rig.toml: at least :data:`MIN_SPAN_DEG`), so a quiet window is not blown up to noise.
  Beside each row: how long the filter acted, and the summary's clamp counts if it has them.
* :func:`plot_lateness` histogram of tick lateness (µs, log count) with p50/p99/p99.9/max marked,
  and lateness against time with overruns marked. A virtual-time run (``"clock": "virtual
  time"`` in summary.json) starts every tick on time by construction: the figure says so instead.
* :func:`plot_timing`  per-stage wall time (sim, safety, bus, telemetry; µs) stacked against time
  (means over time bins, with the worst tick of each bin and the tick period for reference), and
  per-stage p50/p99/max. In a virtual-time run these are the host's compute times (the bus stage
  includes the in-process emulator) and no deadline applies: labelled so, without the period line.

:func:`plot_run` writes all three into ``RUN_DIR/plots/`` (or another directory). Where it can, it
draws the joints figure in a forked child process while this one draws the other two (2 CPUs:
about half the time; see :func:`plot_run`). :func:`prestart`, called before a show, has a process
import matplotlib (half a second) while the show runs, and the next :func:`plot_run` of a run
directory hands the drawing to it; told the run's shape (:func:`prepare`), that process also
makes the figures and their axes' ticks while the show runs (a quarter of the drawing).
"""

from __future__ import annotations

import atexit
import contextlib
import os
import pickle
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hilsim.telemetry import joint_plots, timing_plots
from hilsim.telemetry.joint_plots import (
    ACTED_TOLERANCE_RAD,
    MIN_SPAN_DEG,
    joint_limits_deg,
    joints_figure,
    plot_joints,
    safety_acted,
    soft_start_s,
)
from hilsim.telemetry.plot_common import VIRTUAL_CLOCK, is_virtual_time
from hilsim.telemetry.reader import Run, read_run
from hilsim.telemetry.timing_plots import plot_lateness, plot_timing

__all__ = [
    "ACTED_TOLERANCE_RAD",
    "MIN_SPAN_DEG",
    "VIRTUAL_CLOCK",
    "PlotProcessError",
    "is_virtual_time",
    "joint_limits_deg",
    "joints_figure",
    "plot_joints",
    "plot_lateness",
    "plot_run",
    "plot_timing",
    "prepare",
    "prestart",
    "safety_acted",
    "soft_start_s",
]


#: the files :func:`plot_run` writes, in the order it returns them
PNG_NAMES = ("joints.png", "lateness.png", "timing.png")


class PlotProcessError(RuntimeError):
    """The child process drawing a figure died or said something unreadable (its own exceptions
    are raised again as themselves)."""


#: rows a plot reads as they are; a longer run is read as a min/max envelope (bounded memory:
#: hilsim.telemetry.envelope). 50k rows: 3.3 minutes at 250 Hz, 15 MB at 4 joints; matplotlib's
#: lines of that many points take more than the rows (docs/telemetry.md: the figures measured).
PLOT_MAX_ROWS = 50_000


def plot_run(
    run: Run | str | os.PathLike[str],
    out_dir: str | os.PathLike[str] | None = None,
    *,
    start: float | None = None,
    end: float | None = None,
    dpi: int = 110,
    parallel: bool | None = None,
) -> list[Path]:
    """Write ``joints.png``, ``lateness.png`` and ``timing.png``; return their paths.

    ``out_dir`` defaults to ``RUN_DIR/plots``; ``start``/``end`` (s since run start) limit the
    time window.

    ``parallel`` (default: when :func:`can_fork`) draws the joints figure in a child forked after
    matplotlib is imported and the run is read, while this process draws the other two. An
    exception in either is raised here as itself, after both are done (the other figures are
    written); on KeyboardInterrupt or SystemExit the child is killed and reaped before it goes on.

    After :func:`prestart`, the first call with a run directory (not a loaded :class:`Run`) has
    the prestarted process draw (the same way); if that process cannot answer, this one draws.
    """
    global _prestarted
    worker, _prestarted = _prestarted, None
    if worker is not None:
        if isinstance(run, str | os.PathLike) and parallel is not False:
            request = {"run": os.fspath(run), "out_dir": out_dir, "start": start, "end": end}
            outcome = worker.draw({**request, "dpi": dpi})
            if outcome is not None:
                paths: list[Path] = _unpack(outcome)  # the worker's draw(): the paths
                return paths
        worker.close(kill=True)  # not needed: it stops importing or making figures at once
    if not isinstance(run, Run):
        run = read_run(run, max_rows=PLOT_MAX_ROWS)  # bounded: a week plots in the same memory
    out = Path(out_dir) if out_dir is not None else run.path / "plots"
    joints_path, lateness_path, timing_path = (out / n for n in PNG_NAMES)
    if not (can_fork() if parallel is None else parallel):
        return [
            plot_joints(run, joints_path, start=start, end=end, dpi=dpi),
            plot_lateness(run, lateness_path, start=start, end=end, dpi=dpi),
            plot_timing(run, timing_path, start=start, end=end, dpi=dpi),
        ]
    # imported once, before the fork: both processes use them
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401
    from matplotlib.figure import Figure  # noqa: F401

    out.mkdir(parents=True, exist_ok=True)
    child = _fork(lambda: plot_joints(run, joints_path, start=start, end=end, dpi=dpi))
    try:
        try:
            mine = [
                plot_lateness(run, lateness_path, start=start, end=end, dpi=dpi),
                plot_timing(run, timing_path, start=start, end=end, dpi=dpi),
            ]
        except Exception:
            child.wait()  # let it finish its figure; this process's error is the one reported
            raise
        return [child.result(), *mine]
    except BaseException as exc:  # Ctrl-C, SystemExit: nothing is left running
        if not isinstance(exc, Exception):
            child.kill()
        raise


def can_fork() -> bool:
    """True when a figure can be drawn in a forked child: fork exists, this process may run on
    two CPUs or more, and no other thread runs (a fork copies only the calling thread, and a
    lock another thread holds would stay held in the child)."""
    if not hasattr(os, "fork") or threading.active_count() != 1:
        return False
    try:
        return len(os.sched_getaffinity(0)) >= 2
    except (AttributeError, OSError):
        return (os.cpu_count() or 1) >= 2


class _Child:
    """A forked child drawing one figure; its outcome comes back pickled through a pipe."""

    def __init__(self, pid: int, fd: int) -> None:
        self.pid, self.pipe = pid, os.fdopen(fd, "rb")
        self.status: int | None = None  # its wait status, once reaped
        self.data = b""

    def wait(self) -> None:
        if self.status is None:
            self.data = self.pipe.read()
            self.pipe.close()
            self.status = os.waitpid(self.pid, 0)[1]

    def kill(self) -> None:
        if self.status is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)
            self.pipe.close()
            self.status = os.waitpid(self.pid, 0)[1]

    def result(self) -> Path:
        self.wait()
        try:
            outcome = pickle.loads(self.data)
        except Exception:  # it died before it could say (killed, out of memory)
            raise PlotProcessError(
                f"the process drawing a figure ended without a result ({_how(self.status)})"
            ) from None
        path: Path = _unpack(outcome)  # the child's figure
        return path


def _unpack(outcome: tuple[str, Any]) -> Any:
    """A child's ("ok", value) or ("error", exception), as its value or raised."""
    kind, value = outcome
    if kind == "ok":
        return value
    raise value


def _pickled(outcome: tuple[str, object]) -> bytes:
    """``outcome`` pickled; an exception that does not round-trip, as its type and text."""
    try:
        data = pickle.dumps(outcome)
        pickle.loads(data)
    except Exception:
        err = outcome[1]
        data = pickle.dumps(("error", PlotProcessError(f"{type(err).__name__}: {err}")))
    return data


def _how(status: int | None) -> str:
    if status is not None and os.WIFSIGNALED(status):
        return f"signal {os.WTERMSIG(status)}"
    return f"exit status {os.waitstatus_to_exitcode(status)}" if status is not None else "?"


def _fork(draw: Callable[[], Path]) -> _Child:
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid:
        os.close(write_fd)
        return _Child(pid, read_fd)
    # the child: never returns into the caller's code, never runs its exit handlers
    code = 1
    try:
        os.close(read_fd)
        outcome: tuple[str, object]
        try:
            outcome = ("ok", draw())
            code = 0
        except BaseException as exc:  # the parent raises it again
            outcome = ("error", exc)
        with os.fdopen(write_fd, "wb") as pipe:
            pipe.write(_pickled(outcome))
    finally:
        os._exit(code)


# ------------------------------------------------------------------ a process started before a show

_prestarted: _Worker | None = None


def prestart() -> None:
    """Start a process that imports matplotlib now, on another CPU while the show runs, and
    waits for the next :func:`plot_run` of a run directory in this process to draw for it.

    Nothing happens with fewer than two CPUs (it would take the show's), or when one is already
    waiting. The process leaves by itself when this one ends (its stdin closes), is terminated
    at exit if it was never asked to draw (a refused show does not wait for matplotlib's
    import), ignores SIGINT (the show's Ctrl-C stops the show, which still gets its plots) and
    stops on SIGTERM.
    """
    global _prestarted
    if _prestarted is not None and _prestarted.proc.poll() is None:
        return
    if _cpus() >= 2:
        with contextlib.suppress(OSError):
            _prestarted = _Worker()


def prepare(n_joints: int, *, virtual: bool, dpi: int = 110) -> None:
    """Tell the prestarted process (if one waits) what the next :func:`plot_run` draws: a run
    of ``n_joints`` joints, in virtual time or not, at ``dpi``. It makes those figures while
    the show runs (:func:`hilsim.telemetry.plot_common.make_ahead`); a run of another shape
    is drawn as ever."""
    if _prestarted is not None:
        _prestarted.tell(("ahead", {"n_joints": n_joints, "virtual": virtual, "dpi": dpi}))


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


class _Worker:
    """The prestarted process: one request in on its stdin, one outcome back on its stdout."""

    def __init__(self) -> None:
        root = str(Path(__file__).resolve().parents[2])  # where this hilsim is imported from
        path = os.environ.get("PYTHONPATH")
        env = {**os.environ, "PYTHONPATH": root + (os.pathsep + path if path else "")}
        code = "from hilsim.telemetry.plots import _serve; _serve()"
        self.proc = subprocess.Popen(
            [sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env
        )
        atexit.register(self.close, True)  # never asked to draw: it need not finish importing

    def tell(self, message: tuple[str, dict[str, Any]]) -> None:
        """A message before the request (:func:`prepare`); a worker that cannot take it is
        found out by :meth:`draw`."""
        assert self.proc.stdin is not None
        with contextlib.suppress(OSError):
            self.proc.stdin.write(pickle.dumps(message))
            self.proc.stdin.flush()

    def draw(self, request: dict[str, Any]) -> tuple[str, Any] | None:
        """The worker's outcome for ``request``; None when it could not answer (it had died)."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        try:
            self.proc.stdin.write(pickle.dumps(request))
            self.proc.stdin.close()
            data = self.proc.stdout.read()
        except BaseException as exc:
            self.close(kill=True)  # on Ctrl-C too: it stops drawing, its helper with it
            if isinstance(exc, Exception):
                return None
            raise
        self.close()
        try:
            outcome: tuple[str, Any] = pickle.loads(data)
            return outcome
        except Exception:  # it died before it could say
            return None

    def close(self, kill: bool = False) -> None:
        """End the process: its stdin closed (an idle worker leaves), with ``kill`` terminated
        too (SIGTERM: it may be importing matplotlib or drawing), then reaped."""
        with contextlib.suppress(OSError):
            if self.proc.stdin is not None:
                self.proc.stdin.close()  # EOF: an idle worker leaves
        if kill and self.proc.poll() is None:
            self.proc.terminate()
        try:
            self.proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        atexit.unregister(self.close)


def _serve() -> None:
    """The prestarted process: import matplotlib, make the figures :func:`prepare` announces,
    then draw what the one request asks; leave without the interpreter's clean-up (a tenth of
    a second with matplotlib loaded) that the caller would wait for."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, lambda _s, _f: sys.exit(143))  # plot_run reaps its child
    failure: BaseException | None = None
    try:
        _warm_up()
    except Exception as exc:  # said when the plots are asked for
        failure = exc
    request = _next_request(failure is None)
    if request is None:  # the show ended without plots
        os._exit(0)
    outcome: tuple[str, object]
    try:
        if failure is not None:
            raise failure
        outcome = ("ok", plot_run(request.pop("run"), **request))
    except Exception as exc:
        outcome = ("error", exc)
    sys.stdout.buffer.write(_pickled(outcome))
    sys.stdout.buffer.flush()
    sys.stderr.flush()
    os._exit(0)


def _next_request(make: bool) -> dict[str, Any] | None:
    """The request on stdin, after the figures of any :func:`prepare` message are made (when
    ``make``); None at the end of stdin (or what does not unpickle: the caller died)."""
    while True:
        try:
            message = pickle.load(sys.stdin.buffer)
        except Exception:
            return None
        if not (isinstance(message, tuple) and message[0] == "ahead"):
            request: dict[str, Any] = message
            return request
        if make:
            shape = message[1]
            with contextlib.suppress(Exception):  # made ahead or not, the figures are drawn
                timing_plots.make_ahead(shape["virtual"], shape["dpi"])
                joint_plots.make_ahead(shape["n_joints"], shape["dpi"])


def _warm_up() -> None:
    """Import what drawing needs and measure a text once (loads the font)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure()
    FigureCanvasAgg(fig)
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]  # (as in plot_common)
    fig.text(0, 0, "0").get_window_extent(renderer)
