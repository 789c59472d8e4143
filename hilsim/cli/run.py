"""``hilsim run CONFIG``: drive a rig's joints as springs following its animation.

Exit codes (:mod:`hilsim.exit_codes`): 0 the show completed, exit policy confirmed;
2 the rig file, a command-line value or the servos on the bus do not fit (nothing moved);
3 a fault stopped the show (the servo, bus, host or telemetry cause printed); 4 the exit
policy could not be confirmed on some servo; 5 stopped by a stop command of a show (``--show``,
``--live``: OSC ``/hilsim/stop``, Bottango ``STOP``); 129/130/131/143 stopped by
SIGHUP/SIGINT/SIGQUIT/SIGTERM (exit policy applied); 1 an unexpected error outside the show.

A rig with several ``[buses.<name>]`` runs one child process per bus (``hilsim.show.group``:
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
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

from hilsim.cli._args import add_port
from hilsim.cli.panel import add_panel_options
from hilsim.exit_codes import ExitCode, for_signal

# The show's modules are imported inside the functions: `run` starts the plotting process
# (plots.prestart) first, so it imports matplotlib while this one imports the rest.

if TYPE_CHECKING:
    from hilsim.rig import Rig
    from hilsim.show import Show, ShowResult
    from hilsim.show.feed import PanelFeed
    from hilsim.show.group import GroupResult
    from hilsim.show.run_dir import RunDir
    from hilsim.targets import TargetSet

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
    p.add_argument(
        "--runs-dir",
        metavar="DIR",
        help="make each run's directory <name>-<time> in DIR (instead of the rig's "
        "telemetry.out_dir, which is relative to the working directory)",
    )
    p.add_argument(
        "--status-file",
        metavar="PATH",
        help="write the heartbeat (status.json, docs/service.md) here instead of in the run "
        "directory, e.g. /run/hilsim/status.json (several buses: status-<bus>.json each)",
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
    p.add_argument(
        "--panel",
        action="store_true",
        help="serve the browser control panel (live plots, cues, live joints, STOP) and print "
        "its URL first; docs/panel.md",
    )
    add_panel_options(p, "--panel-bind")
    # a child of hilsim.show.group: "ready" on stdout once the servos are checked, then the
    # shared instant of tick 0 from stdin; "stopping ..." on stdout when its loop stops;
    # stdin closing stops it
    p.add_argument("--shared-start", action="store_true", help=argparse.SUPPRESS)


def _say(message: str) -> None:
    print(f"hilsim run: {message}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    if args.virtual_time and not args.no_plots:  # matplotlib loads on another CPU meanwhile
        from hilsim.telemetry.plots import prestart

        prestart()
    from hilsim.rig import RigError, load_rigs, select_bus
    from hilsim.show.api import Show, endless_in_virtual_time
    from hilsim.show.parts import build_parts
    from hilsim.show.run_dir import RunDirError, make_run_dir
    from hilsim.show.session import port_for

    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        _say(f"--duration must be a finite number of seconds > 0, got {args.duration!r}")
        return EXIT_USAGE
    try:
        rigs = load_rigs(args.config, port=args.port)
        if (
            len(rigs) > 1
            and args.bus is None
            and (args.show is not None or args.live or args.panel)
        ):
            _say(
                "--show/--live/--panel drive one bus for now: this rig has several buses; give "
                "--bus NAME (one process, one show)"
            )
            return EXIT_USAGE
        if len(rigs) > 1 and args.bus is None:
            for each in rigs:  # every bus's targets and port, before any child starts
                port_for(each, args.virtual_time)
                build_parts(each)
            return _run_group(args, rigs)
        show = Show(
            select_bus(rigs, args.bus),
            duration=args.duration,
            virtual_time=args.virtual_time,
            show=args.show,
            live=args.live,
            controls=args.panel,
            runs_dir=args.runs_dir,
            on_note=_say,
            status_file=args.status_file or True,
        )
    except (RigError, ValueError) as exc:
        _say(str(exc))
        return EXIT_USAGE
    rig, parts = show.rig, show.parts
    if args.virtual_time and not args.no_plots and rig.telemetry.format not in ("none", "off"):
        from hilsim.telemetry.plots import prepare

        prepare(len(rig.joints), virtual=True)  # its figures made while the show runs
    if parts.director is not None:
        for note in parts.director.spec.notes:
            _say(f"note: {note}")
    if problem := endless_in_virtual_time(parts, args.duration):
        if args.virtual_time:  # it would rehearse as fast as it can, filling the disk
            _say(problem)
            return EXIT_USAGE
        _say(
            "the show runs until stopped: Ctrl-C, or a stop command (exit policy applied)"
            if parts.director is not None
            else "the animation never ends (generators only); running until Ctrl-C. "
            "Give --duration to stop by itself."
        )
    for note in parts.targets.notes:  # what the animation files say (Bottango's playback
        _say(f"note: {note}")  # settings, frames a Blender export left out)
    # a show's targets change with its cues and inputs: what is checked at load is the rig's
    checked = parts.targets if parts.director is None else parts.director.base
    for line in _track_warnings(rig, checked, args.duration):
        _say(f"warning: {line}")
    try:
        made = make_run_dir(args.out, args.runs_dir or rig.telemetry.out_dir, rig.name)
    except RunDirError as exc:
        _say(str(exc))
        return EXIT_USAGE
    shown = [False]
    try:
        return _run_show(args, show, made, shown)
    except KeyboardInterrupt:  # outside the signal handlers: before the show, or after it
        if shown[0]:
            _say("interrupted after the show (its record is written)")
        else:
            _say("interrupted before the show started: nothing moved")
            made.remove_if_empty()
        return int(ExitCode.SIGINT)


def _run_group(args: argparse.Namespace, rigs: tuple[Rig, ...]) -> int:
    """Several buses: one child process each (:mod:`hilsim.show.group`), a table at the end."""
    from hilsim.show.group import run_group
    from hilsim.show.run_dir import RunDirError, make_run_dir

    rig = rigs[0]
    if args.shared_start:  # a child runs one bus, never a group
        _say("--shared-start needs --bus")
        return EXIT_USAGE
    try:
        made = make_run_dir(args.out, args.runs_dir or rig.telemetry.out_dir, rig.name)
    except RunDirError as exc:
        _say(str(exc))
        return EXIT_USAGE
    run_dir = made.path
    removed = _prune_group_runs(args, rig, run_dir)
    names = [str(r.bus_name) for r in rigs]  # several buses: each is named ([buses.<name>])
    _say(
        f"{rig.name}: {len(rigs)} buses ({', '.join(names)}), one process each, "
        f"{'virtual' if args.virtual_time else 'real'} time -> {run_dir}"
    )
    extra = [] if args.duration is None else ["--duration", repr(args.duration)]
    extra += ["--virtual-time"] * args.virtual_time + ["--no-plots"] * args.no_plots
    lock = threading.Lock()

    def echo(line: str) -> None:
        with lock, contextlib.suppress(OSError, ValueError):  # a hung-up terminal: drop it,
            print(line, file=sys.stderr, flush=True)  # keep reading the child's pipe

    status = None if args.status_file is None else Path(args.status_file).expanduser()
    result = run_group(
        args.config, names, run_dir, extra, echo=echo, status_file=status, runs_removed=removed
    )
    with contextlib.suppress(OSError):  # stderr gone (a hung-up terminal): buses.json says it
        _report_group(args, result, run_dir)
    if not any(run_dir.iterdir()):
        made.remove_if_empty()
    return result.exit_code


def _prune_group_runs(args: argparse.Namespace, rig: Rig, run_dir: Path) -> list[dict[str, object]]:
    """The runs root's caps, applied once for the figure (its buses' runs are inside its
    directory): each run removed said; a failure is a warning, never a stop."""
    from hilsim.show.run_dir import RunDirError, cap_removal_line, prune_under_caps

    tel = rig.telemetry
    root = args.runs_dir or tel.out_dir
    try:
        removed = prune_under_caps(root, run_dir, tel.runs_max_mb, tel.runs_max_age_days)
    except (OSError, RunDirError) as exc:
        _say(f"warning: old runs under {root} not removed: {exc}")
        return []
    for rec in removed:
        _say(cap_removal_line(rec, tel.runs_max_mb, tel.runs_max_age_days))
    return removed


def _report_group(args: argparse.Namespace, result: GroupResult, run_dir: Path) -> None:
    from hilsim.show.group import format_rows

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
    _say(f"exit code {result.exit_code} (the worst bus's)")


def _await_start(show: Show) -> float | None:
    """A child of a group: say ready, wait for the shared instant of tick 0. None: the start
    was called off (a signal, or the parent closed the pipe: another bus cannot start)."""
    print("ready", flush=True)
    while not show.stopping:
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
    from hilsim.show.group import stopping_line

    with contextlib.suppress(OSError, ValueError):  # (the parent gone: its stdin tells us)
        print(stopping_line(code, reason, time.monotonic()), flush=True)


def _run_show(args: argparse.Namespace, show: Show, made: RunDir, shown: list[bool]) -> int:
    """Open and check the bus, run the show, print how it went. ``shown[0]``: the show began."""
    from hilsim.cli._report import StatusLine
    from hilsim.show.session import ShowRefusedError
    from hilsim.show.stop import STOP_SIGNALS

    rig, run_dir = show.rig, made.path
    show.out = run_dir
    previous = {s: signal.signal(s, lambda signum, _f: show.stop(signum)) for s in STOP_SIGNALS}
    panel = None
    if args.panel:  # its URL first, before the start-up check
        panel = _start_panel(args, show, run_dir)
        if panel is None:
            made.remove_if_empty()
            return EXIT_USAGE
    try:
        try:
            show.open()
        except ShowRefusedError as exc:
            _say(str(exc))
            made.remove_if_empty()
            return EXIT_USAGE
        if panel is not None:
            panel.feed.write_info()  # `hilsim panel` finds the show now
        with show:
            start_at = None
            if args.shared_start and not show.stopping:
                start_at = _await_start(show)
                if start_at is None and not show.stopping:
                    _say("another bus of the figure could not start: nothing moved")
                    made.remove_if_empty()
                    return EXIT_USAGE
            if (signum := show.stop_signal) is not None:
                _say(f"stopped by signal {signum} during the start-up check: nothing moved")
                made.remove_if_empty()
                return for_signal(signum)
            virtual = show.bus.clock.virtual
            _say(
                f"{rig.name}: {len(rig.joints)} joints on {rig.bus.port} at "
                f"{rig.loop.rate_hz:g} Hz ({'virtual' if virtual else 'real'} time) -> {run_dir}"
            )
            if args.shared_start:
                _watch_parent()
            status = None if virtual else StatusLine(rig.loop.rate_hz)
            try:
                shown[0] = True
                result = show.run(
                    on_status=status,
                    start_at=start_at,
                    on_stop=_tell_parent if args.shared_start else None,
                )
            except ShowRefusedError as exc:  # the telemetry could not be opened
                shown[0] = False
                _say(str(exc))
                made.remove_if_empty()
                return EXIT_USAGE
            finally:
                if status is not None:
                    status.close()
        if panel is not None:
            panel.feed.close()  # the page has been told how the show ended
    finally:
        if not args.shared_start:  # a group's child keeps them: the parent's stop is late
            for s, handler in previous.items():
                signal.signal(s, handler)
        if panel is not None:
            panel.close()
    try:
        return _report(args, rig, result, run_dir, virtual)
    except OSError:  # stderr gone (a hung-up terminal: SIGHUP): the record says it all
        return result.exit_code


class _Panel:
    """The show's feed and the panel's process (``hilsim panel --child``)."""

    def __init__(self, feed: PanelFeed, proc: subprocess.Popen[bytes]) -> None:
        self.feed, self.proc = feed, proc

    def close(self) -> None:
        self.feed.close()
        with contextlib.suppress(OSError):
            assert self.proc.stdin is not None
            self.proc.stdin.close()  # the panel closes when its pipe does
        try:
            self.proc.wait(5.0)
        except subprocess.TimeoutExpired:
            self.proc.terminate()
            self.proc.wait()


def _start_panel(args: argparse.Namespace, show: Show, run_dir: Path) -> _Panel | None:
    """The feed on its socket, the panel's process; its URL printed. None: it cannot listen
    (the panel said why, one line); nothing has moved."""
    import importlib.util
    import secrets

    from hilsim.cli.panel import EXTRA_HINT, TOKEN_ENV, check_options
    from hilsim.show.feed import PanelFeed

    try:
        check_options(args.panel_bind, args.panel_allow)
    except ValueError as exc:
        _say(str(exc))
        return None
    if importlib.util.find_spec("websockets") is None:
        _say(EXTRA_HINT)
        return None
    feed = PanelFeed(show, run_dir=run_dir)
    sock = feed.start(write_info=False)
    cmd = [sys.executable, "-m", "hilsim", "panel", str(run_dir), "--feed", str(sock), "--child"]
    cmd += ["--bind", args.panel_bind or "127.0.0.1:8080", "--allow", args.panel_allow]
    proc = subprocess.Popen(  # its own session: a Ctrl-C stops the show, the page sees it end
        cmd,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        env=dict(os.environ, **{TOKEN_ENV: secrets.token_urlsafe(18)}),
        start_new_session=True,
    )
    assert proc.stdout is not None
    line = b""
    if select.select([proc.stdout], [], [], 15.0)[0]:
        line = proc.stdout.readline()
    if not line.startswith(b"panel: http"):
        feed.close()
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(5.0)
        if proc.poll() is None:
            proc.kill()
            _say("the panel did not start within 15 s")
        return None
    print(line.decode().strip(), file=sys.stderr, flush=True)
    return _Panel(feed, proc)


def _report(
    args: argparse.Namespace, rig: Rig, show: ShowResult, run_dir: Path, virtual: bool
) -> int:
    """What the show did, on stderr; the plots; returns its exit code."""
    from hilsim.cli._report import print_stats, verdict

    _say_telemetry_failed(show, run_dir)
    summary = show.summary
    show_s = show.ticks / rig.loop.rate_hz
    x = show_s / show.wall_s if virtual and show.wall_s > 0 else None
    pace = "" if x is None else f": {x:.0f}× real time" if x >= 10 else f": {x:.2g}× real time"
    when = f"{show.ticks} ticks ({show_s:.2f} s of show in {show.wall_s:.2f} s{pace})"
    if show.reason.startswith(("end of show", "stopped by", "interrupted")):
        _say(f"{show.reason} after {when}; {show.exit_policy}")
    else:  # a fault's sentences end with what to do: the tick count must not follow them
        _say(f"stopped after {when}: {show.reason}; {show.exit_policy}")
    print_stats(summary)
    tel = summary.get("telemetry") or {}
    how = (
        ""
        if tel.get("format") in (None, "csv")
        else f" ({tel['format']}: {tel.get('format_reason')})"
    )
    if tel.get("format") == "off":
        how, run_dir_said = "", "off (telemetry.format = 'off': nothing kept)"
        if show.run_dir is not None:  # a take the show recorded is never thrown away
            run_dir_said = f"{show.run_dir} (telemetry.format = 'off': only the recorded take)"
    elif tel.get("format") == "none":
        how, run_dir_said = " (summary only: telemetry.format = 'none')", str(run_dir)
    else:
        run_dir_said = str(run_dir)
    print(f"  telemetry: {run_dir_said}{how}", file=sys.stderr)
    if show.exit_code == ExitCode.OK and (line := verdict(summary, show.ticks)):
        _say(f"verdict: {line}")
    rows = tel.get("format") not in ("none", "off")
    if rows and not args.no_plots and show.summary_error is None:  # the run reads back
        try:
            from hilsim.telemetry.plots import plot_run

            for path in plot_run(run_dir):
                print(f"  plot: {path}", file=sys.stderr)
        except Exception as exc:  # plots are a convenience: never change the show's verdict
            _say(f"plots not drawn: {type(exc).__name__}: {exc}")
    _say(f"exit code {show.exit_code}")
    return show.exit_code


def _say_telemetry_failed(show: ShowResult, run_dir: Path) -> None:
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


def _track_warnings(rig: Rig, targets: TargetSet, duration_s: float | None) -> list[str]:
    """Targets beyond a joint's limits or speed, found at load (joint, time, value)."""
    from hilsim.targets.check import check_tracks

    warnings = check_tracks(targets, rig.joints, rig.loop.period_s, duration_s=duration_s)
    return [str(w) for w in warnings]
