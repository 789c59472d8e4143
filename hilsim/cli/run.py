"""``hilsim run CONFIG``: drive a rig's joints as springs following its animation.

Exit codes (:mod:`hilsim.exit_codes`): 0 the show completed, exit policy confirmed;
2 the rig file, a command-line value or the servos on the bus do not fit (nothing moved);
3 a fault stopped the show (the servo, bus, host or telemetry cause printed); 4 the exit
policy could not be confirmed on some servo; 5 stopped by a stop command of a show (``--show``,
``--live``: OSC ``/hilsim/stop``, Bottango ``STOP``); 130/143 stopped by SIGINT/SIGTERM (exit
policy applied); 1 an unexpected error outside the show.

A rig with several ``[buses.<name>]`` runs one child process per bus (``hilsim.show_group``:
one start instant, one stop, each bus's record in ``RUN/<bus>/``); the exit code is the worst
bus's. ``--bus NAME`` runs one of them alone.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import select
import signal
import sys
import threading
import time
from pathlib import Path

from hilsim.cli._args import add_port
from hilsim.cli._report import StatusLine, print_stats, verdict
from hilsim.exit_codes import ExitCode, for_signal

HELP = "run a rig: springs follow the animation, streamed to the servos (or the emulator)"

EXIT_USAGE = int(ExitCode.USAGE)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="rig file (TOML), e.g. configs/demo.toml")
    add_port(p, help="override bus.port: /dev/ttyUSB0, a pty, or dxlsim://... (the emulator)")
    p.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="stop after S seconds of show (default: the animation's length)",
    )
    p.add_argument(
        "--virtual-time",
        action="store_true",
        help="run on the emulator's virtual clock: same numbers, no waiting",
    )
    p.add_argument(
        "--out",
        metavar="DIR",
        help="run directory, new or empty (default <out_dir>/<name>-<time>)",
    )
    p.add_argument("--no-plots", action="store_true", help="do not draw plots after the run")
    p.add_argument(
        "--show",
        metavar="SHOW",
        help="a show file (TOML): clips, idle, cues and their triggers, live inputs "
        "(OSC, MIDI, timecode, Bottango, gamepad, keys), a take to record",
    )
    p.add_argument(
        "--live",
        action="store_true",
        help="drive the joints live over OSC on 127.0.0.1:9000 (/hilsim/joint/<name> 0..1, "
        "/hilsim/stop); the live input is recorded as a take in the run directory",
    )
    p.add_argument(
        "--bus",
        metavar="NAME",
        help="a rig with several [buses.<name>]: run this bus's joints alone (default: every "
        "bus, one process each, started together)",
    )
    # a child of hilsim.show_group: "ready" on stdout once the servos are checked, then the
    # shared instant of tick 0 from stdin; "stopping ..." on stdout when its loop stops;
    # stdin closing stops it
    p.add_argument("--shared-start", action="store_true", help=argparse.SUPPRESS)


#: run directories this process created (and may remove again if the run never starts)
_CREATED: set[Path] = set()
#: run directories whose show began (a Ctrl-C after it is not "before the show")
_SHOWN: set[Path] = set()


class UsageError(Exception):
    """A command-line or file-system problem, said in one line (exit 2)."""


def make_run_dir(out: str | None, out_dir: str, name: str) -> Path:
    """Create the run directory before anything touches the bus.

    ``--out``: a new directory, or an existing empty one. Default: ``<out_dir>/<name>-<time>``,
    with ``-2``, ``-3`` ... added if that exists (two runs started in the same second).
    Raises :class:`UsageError` naming the path and the problem.
    """
    if out is not None:
        path = _home(Path(out))
        if path.exists() and not path.is_dir():
            raise UsageError(f"--out {out}: exists and is not a directory")
        if path.is_dir() and any(path.iterdir()):
            raise UsageError(
                f"--out {out}: the directory is not empty (a run directory holds one run)"
            )
        existed = path.is_dir()
        _mkdir(path, exist_ok=True)
        if not existed:
            _CREATED.add(path)
        return path
    stem = _home(Path(out_dir)) / f"{name}-{time.strftime('%Y%m%d-%H%M%S')}"
    for n in range(1, 1000):
        path = stem if n == 1 else stem.with_name(f"{stem.name}-{n}")
        try:
            _mkdir(path, exist_ok=False)
        except FileExistsError:
            continue
        _CREATED.add(path)
        return path
    raise UsageError(f"{stem}: too many runs with this name in one second")


def _home(path: Path) -> Path:
    """``~`` as the user's home; ``~user`` of no such user refused in one line."""
    try:
        return path.expanduser()
    except RuntimeError:
        raise UsageError(f"{path}: no such user's home directory") from None


def _mkdir(path: Path, *, exist_ok: bool) -> None:
    try:
        path.mkdir(parents=True, exist_ok=exist_ok)
    except FileExistsError:
        if not exist_ok:
            raise
        raise UsageError(
            f"{path}: cannot create the run directory (a file is in the way)"
        ) from None
    except OSError as exc:
        raise UsageError(
            f"{path}: cannot create the run directory: {exc.strerror or exc}"
        ) from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise UsageError(f"{path}: the run directory is not writable")


def _say(message: str) -> None:
    print(f"hilsim run: {message}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    if args.virtual_time and not args.no_plots:  # matplotlib loads on another CPU meanwhile
        from hilsim.telemetry.plots import prestart

        prestart()
    from hilsim.rig import RigError, load_rigs, select_bus
    from hilsim.session import build_parts, port_for

    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        _say(f"--duration must be a finite number of seconds > 0, got {args.duration!r}")
        return EXIT_USAGE
    try:
        rigs = load_rigs(args.config, port=args.port)
        if len(rigs) > 1 and args.bus is None and (args.show is not None or args.live):
            _say(
                "--show/--live drive one bus for now: this rig has several buses; give "
                "--bus NAME (one process, one show)"
            )
            return EXIT_USAGE
        if len(rigs) > 1 and args.bus is None:
            for each in rigs:  # every bus's targets and port, before any child starts
                port_for(each, args.virtual_time)
                build_parts(each)
            return _run_group(args, rigs)
        rig = select_bus(rigs, args.bus)
        port = port_for(rig, args.virtual_time)
        parts = build_parts(rig)
        if args.show is not None or args.live:
            from hilsim.session import with_show

            parts = with_show(parts, args.show, args.live, virtual=args.virtual_time)
    except (RigError, ValueError) as exc:
        _say(str(exc))
        return EXIT_USAGE
    if parts.director is not None:
        for note in parts.director.spec.notes:
            _say(f"note: {note}")
        if parts.targets.duration is None and args.duration is None:
            if args.virtual_time:
                _say("a live show never ends by itself: give --duration with --virtual-time")
                return EXIT_USAGE
            _say("the show runs until stopped: Ctrl-C, or a stop command (exit policy applied)")
    elif args.duration is None and parts.targets.duration is None:
        if args.virtual_time:  # it would rehearse as fast as it can, filling the disk
            _say("the animation never ends (generators only): give --duration with --virtual-time")
            return EXIT_USAGE
        _say(
            "the animation never ends (generators only); running until Ctrl-C. "
            "Give --duration to stop by itself."
        )
    for note in parts.targets.notes:  # what the animation files say (Bottango's playback
        _say(f"note: {note}")  # settings, frames a Blender export left out)
    # a show's targets change with its cues and inputs: what is checked at load is the rig's
    checked = parts.targets if parts.director is None else parts.director.base
    for line in _track_warnings(rig, checked, args.duration):
        _say(f"warning: {line}")
    try:
        run_dir = make_run_dir(args.out, rig.telemetry.out_dir, rig.name)
    except UsageError as exc:
        _say(str(exc))
        return EXIT_USAGE
    try:
        return _open_and_run(args, parts, port, run_dir)
    except KeyboardInterrupt:  # outside the signal handlers: before the show, or after it
        if run_dir in _SHOWN:
            _say("interrupted after the show (its record is written)")
        else:
            _say("interrupted before the show started: nothing moved")
            _remove_if_empty(run_dir)
        return int(ExitCode.SIGINT)


def _run_group(args: argparse.Namespace, rigs) -> int:
    """Several buses: one child process each (:mod:`hilsim.show_group`), a table at the end."""
    from hilsim.show_group import format_rows, run_group

    rig = rigs[0]
    if args.shared_start:  # a child runs one bus, never a group
        _say("--shared-start needs --bus")
        return EXIT_USAGE
    try:
        run_dir = make_run_dir(args.out, rig.telemetry.out_dir, rig.name)
    except UsageError as exc:
        _say(str(exc))
        return EXIT_USAGE
    names = [r.bus_name for r in rigs]
    _say(
        f"{rig.name}: {len(rigs)} buses ({', '.join(names)}), one process each, "
        f"{'virtual' if args.virtual_time else 'real'} time -> {run_dir}"
    )
    extra = [] if args.duration is None else ["--duration", repr(args.duration)]
    extra += ["--virtual-time"] * args.virtual_time + ["--no-plots"] * args.no_plots
    lock = threading.Lock()

    def echo(line: str) -> None:
        with lock:
            print(line, file=sys.stderr, flush=True)

    result = run_group(args.config, names, run_dir, extra, echo=echo)
    if result.stopped_by is not None and result.stop is not None:
        stopped = result.stop["buses_stopped"]
        when = (
            "" if args.virtual_time else f", {result.stop['after_start_s']:.2f} s after the start"
        )
        _say(
            f"bus {result.stopped_by} stopped first (exit {result.stop['exit_code']}{when}), so "
            + (
                f"bus{'es' if len(stopped) > 1 else ''} {', '.join(stopped)} "
                f"{'were' if len(stopped) > 1 else 'was'} stopped too (one figure)"
                if stopped
                else "it ended the show (no other bus was still running)"
            )
        )
    for line in format_rows(result.rows):
        print(f"  {line}", file=sys.stderr)
    for row in result.rows:
        print(f"  {row['bus']}: {row['reason']}", file=sys.stderr)
    print(f"  telemetry: {run_dir}/<bus>/", file=sys.stderr)
    if not any(run_dir.iterdir()):
        _remove_if_empty(run_dir)
    _say(f"exit code {result.exit_code} (the worst bus's)")
    return result.exit_code


def _await_start(stop) -> float | None:
    """A child of a group: say ready, wait for the shared instant of tick 0. None: the start
    was called off (a signal, or the parent closed the pipe: another bus cannot start)."""
    print("ready", flush=True)
    while stop.signum is None:
        if select.select([sys.stdin], [], [], 0.05)[0]:
            line = sys.stdin.readline().strip()
            return float(line) if line else None
    return None


def _watch_parent() -> None:
    """A child of a group: its stdin closing (the parent stopped it, or died) stops the show
    through the same path as SIGTERM: the exit policy."""

    def watch() -> None:
        with contextlib.suppress(OSError, ValueError):
            while sys.stdin.readline():
                pass
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, daemon=True).start()


def _tell_parent(code: int, reason: str) -> None:
    """A child of a group: its loop has stopped (its exit policy, record and plots come next).
    The parent stops the other buses now, and knows which bus stopped first, and when."""
    from hilsim.show_group import stopping_line

    with contextlib.suppress(OSError, ValueError):  # (the parent gone: its stdin tells us)
        print(stopping_line(code, reason, time.monotonic()), flush=True)


def _open_and_run(args, parts, port: str, run_dir: Path) -> int:
    from hilsim.session import ShowRefusedError, open_bus

    try:
        bus = open_bus(parts.rig, port)
    except ShowRefusedError as exc:
        _say(str(exc))
        _remove_if_empty(run_dir)
        return EXIT_USAGE
    try:
        return _run_on_bus(args, parts, bus, run_dir)
    finally:
        bus.close()


def _run_on_bus(args, parts, bus, run_dir: Path) -> int:
    from hilsim.loop import StopFlag
    from hilsim.session import ShowRefusedError, check_bus, check_teach, open_telemetry, run_show

    rig = parts.rig
    virtual = bus.clock.virtual
    stop = StopFlag()
    previous = {
        s: signal.signal(s, lambda signum, _f: stop.request(signum))
        for s in (signal.SIGINT, signal.SIGTERM)
    }
    try:
        try:
            notes = check_bus(rig, bus, _say)
            start_at = None
            if args.shared_start and stop.signum is None:
                start_at = _await_start(stop)
                if start_at is None and stop.signum is None:
                    _say("another bus of the figure could not start: nothing moved")
                    _remove_if_empty(run_dir)
                    return EXIT_USAGE
            if stop.signum is not None:
                _say(f"stopped by signal {stop.signum} during the start-up check: nothing moved")
                _remove_if_empty(run_dir)
                return for_signal(stop.signum)
            if parts.director is not None:  # its ports, before anything moves
                check_teach(rig, bus, parts.director)
                _open_inputs(parts.director, bus.clock)
            telemetry = open_telemetry(rig, run_dir, virtual)
        except ShowRefusedError as exc:
            if parts.director is not None:
                parts.director.close_inputs()
            _say(str(exc))
            _remove_if_empty(run_dir)
            return EXIT_USAGE
        reserve = telemetry.end.reserve
        if reserve.error is not None:  # the show goes on; its end may not fit on the disk
            notes.append(
                f"warning: cannot set aside {reserve.wanted // 1024} KiB in {run_dir} for the "
                f"end of the record ({reserve.error.strerror or reserve.error}): if the disk "
                "fills up, the summary and the fault record may be lost"
            )
            _say(notes[-1])
        for note in notes:  # what the start-up found and changed, in the run's record too
            telemetry.event("startup", note)
        _say(
            f"{rig.name}: {len(rig.joints)} joints on {rig.bus.port} at "
            f"{rig.loop.rate_hz:g} Hz ({'virtual' if virtual else 'real'} time) -> {run_dir}"
        )
        if args.shared_start:
            _watch_parent()
        _SHOWN.add(run_dir)
        status = None if virtual else StatusLine(rig.loop.rate_hz)
        try:
            show = run_show(
                parts,
                bus,
                telemetry,
                duration_s=args.duration,
                stop=stop,
                on_status=status,
                start_at=start_at,
                on_stop=_tell_parent if args.shared_start else None,
            )
        finally:
            if status is not None:
                status.close()
    finally:
        if not args.shared_start:  # a group's child keeps them: the parent's stop is late
            for s, handler in previous.items():
                signal.signal(s, handler)
    _say_telemetry_failed(show, run_dir)
    summary = show.summary
    show_s = show.ticks / rig.loop.rate_hz
    x = show_s / show.wall_s if virtual and show.wall_s > 0 else None
    pace = "" if x is None else f": {x:.0f}× real time" if x >= 10 else f": {x:.2g}× real time"
    _say(
        f"{show.reason} after {show.ticks} ticks "
        f"({show_s:.2f} s of show in {show.wall_s:.2f} s{pace}); {show.exit_policy}"
    )
    print_stats(summary)
    tel = summary.get("telemetry") or {}
    how = (
        ""
        if tel.get("format") in (None, "csv")
        else f" ({tel['format']}: {tel.get('format_reason')})"
    )
    print(f"  telemetry: {run_dir}{how}", file=sys.stderr)
    if show.exit_code == ExitCode.OK and (line := verdict(summary, show.ticks)):
        _say(f"verdict: {line}")
    if not args.no_plots and show.summary_error is None:  # the run reads back
        try:
            from hilsim.telemetry.plots import plot_run

            for path in plot_run(run_dir):
                print(f"  plot: {path}", file=sys.stderr)
        except Exception as exc:  # plots are a convenience: never change the show's verdict
            _say(f"plots not drawn: {type(exc).__name__}: {exc}")
    _say(f"exit code {show.exit_code}")
    return show.exit_code


def _say_telemetry_failed(show, run_dir: Path) -> None:
    """What the disk did to the record, a line each; a traceback only for what is not a disk
    error (a bug), the disk's in telemetry_error.txt."""
    from hilsim.telemetry.end_record import disk_error

    error, tb = show.telemetry_error, show.telemetry_traceback
    if error is not None:
        where = "" if show.traceback_path is None else f" (traceback: {show.traceback_path})"
        _say(f"telemetry could not be written to {run_dir}: {error}{where}")
        if tb and not disk_error(error):
            print(tb.rstrip(), file=sys.stderr)
    if show.summary_error is not None:
        _say(f"{run_dir / 'summary.json'}: {show.summary_error}")


def _open_inputs(director, clock) -> None:
    """The show's inputs opened (sockets, ports, threads); a refusal is one line, exit 2."""
    from hilsim.session import ShowRefusedError

    try:
        director.open(clock, _say)
    except (OSError, ValueError, RuntimeError, ImportError) as exc:
        where = director.spec.path or "--live"
        raise ShowRefusedError(f"{where}: cannot open the show's inputs: {exc}") from None


def _track_warnings(rig, targets, duration_s: float | None) -> list[str]:
    """Targets beyond a joint's limits or speed, found at load (joint, time, value)."""
    from hilsim.track_check import check_tracks

    warnings = check_tracks(targets, rig.joints, rig.loop.period_s, duration_s=duration_s)
    return [str(w) for w in warnings]


def _remove_if_empty(path: Path) -> None:
    """A run directory this process made for a run that never started is removed again."""
    if path in _CREATED:
        with contextlib.suppress(OSError):
            path.rmdir()
