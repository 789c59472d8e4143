"""A show from Python: one figure's rig on its bus, from the start-up check to the exit policy.

::

    import hilsim

    with hilsim.Show("configs/demo.toml", virtual_time=True, duration=2.0) as show:
        result = show.run()          # blocks; show.stop() from another thread ends it safely
    print(result.exit_code, result.run_dir, result.summary["ticks"])

Building a :class:`Show` reads the rig and builds its parts (targets, springs, safety filter);
a bad rig raises :class:`~hilsim.rig.RigError` (one line naming the file and the key).
Entering it makes the run directory, opens the bus and runs the start-up check, which
cannot be skipped: a mismatch raises :class:`ShowRefusedError` before anything moves.
:meth:`Show.run` runs the show once; every way out of it applies the rig's exit policy.
Leaving the ``with`` block stops a show still running and closes the bus.

While it runs, other threads talk to it through :meth:`Show.stop`, :meth:`Show.cue`,
:meth:`Show.set_joint` and :meth:`Show.release`. With ``status_file``, a heartbeat file says
how it is doing, for a monitor (:mod:`hilsim.show.heartbeat`, ``docs/service.md``); the
browser panel's feed (:mod:`hilsim.show.feed`) reads :attr:`Show.loop`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import shutil
import threading
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Self

from hilsim._types import JsonDict
from hilsim.live.controls import Controls
from hilsim.rig import Rig, TelemetryFailurePolicy, load_rigs, select_bus
from hilsim.show.end import ShowResult, crashed
from hilsim.show.heartbeat import STATUS_FILE, Heartbeat
from hilsim.show.parts import Parts, build_parts, with_show
from hilsim.show.run_dir import (
    RunDir,
    RunDirError,
    cap_removal_line,
    make_run_dir,
    prune_under_caps,
)
from hilsim.show.session import (
    ShowRefusedError,
    check_bus,
    check_teach,
    open_bus,
    open_telemetry,
    port_for,
    run_show,
    start_guardian,
)
from hilsim.show.show_files import record_show_files
from hilsim.show.stop import StopFlag
from hilsim.telemetry.format import TelemetryFormat

if TYPE_CHECKING:
    from drivers.dynamixel.bus import DynamixelBus
    from drivers.p1bus.guardian import Guardian
    from hilsim.show.loop import HilLoop
    from hilsim.telemetry import TelemetryWriter

__all__ = ["Show", "ShowError", "ShowRefusedError", "ShowResult", "endless_in_virtual_time"]

log = logging.getLogger("hilsim.show")

PathLike = str | os.PathLike[str]


class ShowError(RuntimeError):
    """A :class:`Show` used out of order (run twice, run before entering, a cue without a
    show file)."""


def endless_in_virtual_time(parts: Parts, duration_s: float | None) -> str | None:
    """Why a virtual-time rehearsal would never end (it would run flat out and fill the
    disk), or None."""
    if duration_s is not None or parts.targets.duration is not None:
        return None
    if parts.director is not None:
        return "a live show never ends by itself: give --duration with --virtual-time"
    return "the animation never ends (generators only): give --duration with --virtual-time"


def _failure_note(rig: Rig, parts: Parts, duration_s: float | None) -> str | None:
    """What a full disk will do to an endless show under ``telemetry.on_failure = "auto"``."""
    endless = duration_s is None and parts.targets.duration is None
    if rig.telemetry.on_failure is not TelemetryFailurePolicy.AUTO or not endless:
        return None
    return (
        "telemetry.on_failure = auto: an endless show goes on if the disk fills up or fails "
        "(the record ends there: a warning and telemetry_error.txt); set it to 'stop' to stop"
    )


class Show:
    """One figure's show on one bus.

    Args:
        rig: a rig file (TOML) or a loaded :class:`~hilsim.rig.Rig`.
        port: overrides the rig's ``bus.port`` (``/dev/ttyUSB0``, a pty, ``dxlsim://...``).
        bus: which of a rig's ``[buses.<name>]`` (a rig with several needs it).
        duration: stop after this much show time (s); None: the animation's length.
        out: the run directory (new, or an existing empty one); None:
            ``<runs_dir>/<name>-<time>``.
        runs_dir: where runs are made and the runs root's caps prune old ones (default: the
            rig's ``telemetry.out_dir``); a run put elsewhere by ``out`` leaves it alone.
        virtual_time: run on the emulator's virtual clock (same numbers, no waiting).
        show: a show file (clips, cues, live inputs); ``live``: OSC on 127.0.0.1.
        controls: :meth:`set_joint` and :meth:`release` without a show file or ``live``
            (no input of its own; the show ends with the rig's animation), e.g. for the panel.
        on_note: called with each thing the start-up found or changed (a line of text);
            default: logged on the ``hilsim.show`` logger.
        status_file: a heartbeat (``docs/service.md``): True writes ``status.json`` in the
            run directory, a path writes there (e.g. ``/run/hilsim/status.json``); about
            every ``status_every_s`` seconds while the show runs, and how it ended.

    Raises RigError (the rig or show file) or ValueError (an option) at once.
    """

    def __init__(
        self,
        rig: PathLike | Rig,
        *,
        port: str | None = None,
        bus: str | None = None,
        duration: float | None = None,
        out: PathLike | None = None,
        runs_dir: PathLike | None = None,
        virtual_time: bool = False,
        show: PathLike | None = None,
        live: bool = False,
        controls: bool = False,
        on_note: Callable[[str], None] | None = None,
        status_file: PathLike | bool = False,
        status_every_s: float = 1.0,
    ) -> None:
        if not (math.isfinite(status_every_s) and status_every_s > 0):
            raise ValueError(f"status_every_s must be a finite number > 0, got {status_every_s!r}")
        if duration is not None and not (math.isfinite(duration) and duration > 0):
            raise ValueError(f"duration must be a finite number of seconds > 0, got {duration!r}")
        if isinstance(rig, Rig):
            if port is not None or bus is not None:
                raise ValueError("port and bus apply to a rig file; this rig is loaded already")
            self.rig = rig
        else:
            self.rig = select_bus(load_rigs(Path(rig), port=port), bus)
        self.port = port_for(self.rig, virtual_time)
        parts = build_parts(self.rig)
        if show is not None or live or controls:
            parts = with_show(
                parts, None if show is None else str(show), live, virtual=virtual_time
            )
        #: what the show runs: targets, joint map, safety filter, springs, director
        self.parts = parts
        self.show_path = None if show is None else Path(show)
        self.duration = duration
        self.virtual_time = virtual_time
        self.out = out
        self.runs_dir = runs_dir
        self.status_file, self.status_every_s = status_file, status_every_s
        self._note = on_note or (lambda line: log.info("%s", line))
        #: what the start-up check found and changed, in order
        self.notes: list[str] = []
        self._stop = StopFlag()
        self._lock = threading.Lock()
        self._bus: DynamixelBus | None = None
        self._run_dir: RunDir | None = None
        self._guardian: Guardian | None = None  # no Bus Watchdog: drivers.p1bus.guardian
        self._running = threading.Event()
        self._done = threading.Event()
        self._result: ShowResult | None = None
        self._loop: HilLoop | None = None
        self._closed = False

    # ------------------------------------------------------------------ entering, leaving
    def __enter__(self) -> Self:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def open(self) -> Self:
        """Make the run directory, open the bus, check the servos, open the show's inputs.

        Raises :class:`ShowRefusedError` (nothing moved; the directory made here is removed
        again). ``with Show(...)`` calls it."""
        with self._lock:
            if self._closed:
                raise ShowError("this show is closed; make a new Show")
            if self._bus is not None:
                return self
        try:
            return self._open()
        except ShowRefusedError as exc:  # a heartbeat elsewhere says so; in the run dir: none
            if not isinstance(self.status_file, bool):
                self._heartbeat(Path(os.fspath(self.status_file))).refused(str(exc))
            raise

    def _open(self) -> Self:
        rig = self.rig
        try:
            runs = self.runs_dir if self.runs_dir is not None else rig.telemetry.out_dir
            self._run_dir = make_run_dir(self.out, runs, rig.name, what="out")
        except RunDirError as exc:
            raise ShowRefusedError(str(exc)) from None
        try:
            bus = open_bus(rig, self.port)
        except ShowRefusedError:
            self._run_dir.remove_if_empty()
            raise
        try:
            self.notes += check_bus(rig, bus, self._say)
            self._guardian, note = start_guardian(rig, bus, self._run_dir.path)
            if note:
                self.notes.append(note)
                self._say(f"note: {note}")
            director = self.parts.director
            if director is not None:  # its ports, before anything moves
                check_teach(rig, bus, director)
                try:
                    director.open(bus.clock, self._say)
                except (OSError, ValueError, RuntimeError, ImportError) as exc:
                    where = director.spec.path or "--live"
                    raise ShowRefusedError(
                        f"{where}: cannot open the show's inputs: {exc}"
                    ) from None
        except BaseException:
            if self.parts.director is not None:
                self.parts.director.close_inputs()
            self._release_guardian()
            bus.close()
            self._run_dir.remove_if_empty()
            raise
        self._bus = bus
        return self

    def close(self) -> None:
        """Stop a show still running (through its exit policy), then close the bus. Safe to
        call twice."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        if self._running.is_set() and not self._done.is_set():
            self.stop()
            self._done.wait()
        director = self.parts.director
        if director is not None and self._result is None:
            director.close_inputs()
        self._release_guardian()
        if self._bus is not None:
            self._bus.close()
        if self._result is None and self._run_dir is not None:
            self._run_dir.remove_if_empty()

    # ------------------------------------------------------------------ running
    def run(
        self,
        *,
        on_status: Callable[[JsonDict], None] | None = None,
        start_at: float | None = None,
        on_stop: Callable[[int, str], None] | None = None,
    ) -> ShowResult:
        """Run the show to its end, a stop or a fault; returns how it ended (its exit code,
        reason, run directory and summary). Every way out applies the exit policy.

        ``on_status``: called about twice a second (real time) with the live figures.
        ``start_at``: tick 0 at this ``time.monotonic()`` instant (several buses, one figure).
        ``on_stop``: told the exit code and reason as the loop stops, before the exit policy.
        Runs once; raises :class:`ShowError` if the show is not open or ran already."""
        with self._lock:
            if self._bus is None or self._closed:
                raise ShowError("open the show first: with hilsim.Show(...) as show: show.run()")
            if self._running.is_set():
                raise ShowError("a Show runs once; make a new Show for the next run")
            self._running.set()
        try:
            problem = endless_in_virtual_time(self.parts, self.duration)
            if problem and self._bus.clock.virtual:
                raise ValueError(problem)
            assert self._run_dir is not None
            run_dir = self._run_dir.path
            pruned = self._prune_runs(run_dir)  # first: the space is this run's
            telemetry = open_telemetry(self.rig, run_dir, self._bus.clock.virtual)
            self._said_pruned(telemetry, pruned)
            reserve = telemetry.end.reserve
            if reserve.error is not None:  # the show goes on; its end may not fit on the disk
                why = reserve.error.strerror or reserve.error
                self.notes.append(
                    f"warning: cannot set aside {reserve.wanted // 1024} KiB in {run_dir} for "
                    f"the end of the record ({why}): if the disk fills up, the summary and the "
                    "fault record may be lost"
                )
                self._say(self.notes[-1])
            if self.rig.telemetry.format is not TelemetryFormat.OFF:
                self._record_show_files(run_dir)
            if (note := _failure_note(self.rig, self.parts, self.duration)) is not None:
                self.notes.append(note)
                self._say(note)
            for note in self.notes:  # what the start-up found and changed, in the record too
                telemetry.event("startup", note)
            beat = None
            if self.status_file is not False:
                where = self.status_file
                path = run_dir / STATUS_FILE if where is True else Path(os.fspath(where))
                beat = self._heartbeat(path)
                beat.start()
                on_status, on_stop = _also(beat.offer, on_status), _also(beat.stopping, on_stop)
            try:
                self._result = run_show(
                    self.parts,
                    self._bus,
                    telemetry,
                    duration_s=self.duration,
                    stop=self._stop,
                    on_status=on_status,
                    start_at=start_at,
                    on_stop=on_stop,
                    on_loop=self._attach_loop,
                )
            except BaseException as exc:
                if beat is not None:
                    beat.end(crashed(exc))
                raise
            self._result.run_dir = run_dir
            if beat is not None:
                beat.end(_outcome(self._result, self.rig.loop.period_s))
            if self.rig.telemetry.format is TelemetryFormat.OFF:  # nothing kept, as asked,
                self._result.run_dir = _keep_only_takes(run_dir)  # but the takes recorded
            return self._result
        finally:
            self._release_guardian()  # every way out of the loop applied the exit policy
            self._done.set()

    def _release_guardian(self) -> None:
        """The show ended by itself: its guardian (if any) exits without a word."""
        guardian, self._guardian = self._guardian, None
        if guardian is not None:
            guardian.release()

    def _prune_runs(self, run_dir: Path) -> list[dict[str, Any]]:
        """The caps on the runs root: its oldest runs removed (a run made elsewhere, by
        ``out``, leaves the root alone); a failure is a warning, never a stop."""
        tel = self.rig.telemetry
        root = self.runs_dir if self.runs_dir is not None else tel.out_dir
        try:
            return prune_under_caps(root, run_dir, tel.runs_max_mb, tel.runs_max_age_days)
        except (OSError, RunDirError) as exc:
            self.notes.append(f"warning: old runs under {root} not removed: {exc}")
            self._say(self.notes[-1])
            return []

    def _said_pruned(self, telemetry: TelemetryWriter, pruned: list[dict[str, Any]]) -> None:
        """Each run removed under the runs root's caps: an event; their count in the summary."""
        tel = self.rig.telemetry
        for rec in pruned:
            line = cap_removal_line(rec, tel.runs_max_mb, tel.runs_max_age_days)
            telemetry.event("run_removed", line, **rec)
        if tel.runs_max_mb is not None or tel.runs_max_age_days is not None:
            telemetry.runs_removed = {
                "runs": len(pruned),
                "bytes": sum(int(r["bytes"]) for r in pruned),
                "names": [r["run"] for r in pruned],
            }

    def _record_show_files(self, run_dir: Path) -> None:
        """The show file and the files it and the rig name, kept with the run (copied or
        hashed: ``show_files.json``); a failure is a warning, never a stop."""
        rig = self.rig
        manifest, problem = record_show_files(run_dir, rig.path, rig.text or None, self.show_path)
        if manifest is None:  # (the manifest is the record: no event, "start" stays first)
            self.notes.append(f"warning: {problem}")
            self._say(self.notes[-1])

    def stop(self, signum: int | None = None, *, what: str = "Show.stop()") -> None:
        """End the show through the rig's exit policy (exit code 5; with ``signum``, the
        signal's code: 130 for SIGINT, 143 for SIGTERM). Safe from any thread or a signal
        handler; a stop before :meth:`run` makes the run end at once, nothing moved.
        ``what``: who asked, for the summary's reason (``stopped by <what>``)."""
        if signum is None:
            self._stop.request_command(what)
        else:
            self._stop.request(signum)

    @property
    def stop_signal(self) -> int | None:
        """The signal that asked the show to stop (via :meth:`stop`), or None."""
        return self._stop.signum

    @property
    def stopping(self) -> bool:
        """A stop was asked (a signal, a stop command, :meth:`stop`)."""
        return self._stop.signum is not None or self._stop.command is not None

    # ------------------------------------------------------------------ live control
    def cue(self, name: str) -> None:
        """Fire the show file's cue ``name`` at the next tick (as OSC ``/hilsim/cue/<name>``
        would). Thread-safe. Raises ShowError without a show file, KeyError for an unknown
        cue."""
        self._controls().cue(name)

    def set_joint(self, joint: str, deg: float) -> None:
        """Drive ``joint`` live at ``deg`` degrees (its spring and the safety filter apply, as
        for every input) from the next tick on. Thread-safe. Raises ShowError without a show
        file or ``live=True``, KeyError for an unknown joint, ValueError for a value that is
        not finite."""
        self._controls().set_joint(joint, deg)

    def release(self, joint: str | None = None) -> None:
        """Hand ``joint`` (None: every joint) back from its live value to the show's cues,
        clips and idle (``docs/live.md``, who drives a joint) at the next tick: the joint
        goes there through its spring and the safety filter, never a jump. Whatever live
        input held it (``set_joint``, OSC, MIDI ...). Thread-safe. A ``live_release`` event
        says it (``release_ignored`` when no live input held it). Raises ShowError without a
        show file, ``live=True`` or ``controls=True``, KeyError for an unknown joint."""
        self._controls().release(joint)

    def _controls(self) -> Controls:
        director = self.parts.director
        if director is None:
            raise ShowError("cues and live joints need a show file or live=True")
        controls: Controls = director.api
        return controls

    # ------------------------------------------------------------------ facts
    @property
    def bus(self) -> DynamixelBus:
        """The open bus (after entering)."""
        if self._bus is None:
            raise ShowError("the show is not open")
        return self._bus

    @property
    def run_dir(self) -> Path | None:
        """The run directory, once the show is open."""
        return None if self._run_dir is None else self._run_dir.path

    @property
    def result(self) -> ShowResult | None:
        """How the run ended, once it has."""
        return self._result

    @property
    def loop(self) -> HilLoop | None:
        """The running loop, once :meth:`run` has built it (read-only use from other threads:
        :mod:`hilsim.show.feed` copies its arrays)."""
        return self._loop

    def _attach_loop(self, loop: HilLoop) -> None:
        self._loop = loop

    def _say(self, line: str) -> None:
        self._note(line)

    def _heartbeat(self, path: Path) -> Heartbeat:
        rig = self.rig
        fixed = {
            "rig": rig.name,
            "bus": rig.bus_name,
            "port": rig.bus.port,
            "run_dir": None if self.run_dir is None else str(self.run_dir),
            "clock": "virtual time" if self.virtual_time else "real time",
            "rate_target_hz": rig.loop.rate_hz,
        }
        director = self.parts.director
        if director is not None and director.spec.path:
            fixed["show_file"] = str(director.spec.path)
        joints = [(j.name, j.servo_id) for j in rig.joints]
        return Heartbeat(
            path.expanduser(),
            fixed=fixed,
            joints=joints,
            every_s=self.status_every_s,
            say=self._say,
        )


def _also(first: Callable[..., None], then: Callable[..., None] | None) -> Callable[..., None]:
    """``first``, then the caller's own hook (if any): the heartbeat beside the status line."""

    def both(*args: object) -> None:
        first(*args)
        if then is not None:
            then(*args)

    return both


def _outcome(result: ShowResult, period_s: float) -> JsonDict:
    """How the show ended, for the heartbeat's last write (as summary.json says it)."""
    return {
        "exit_code": result.exit_code,
        "exit_reason": result.reason,
        "exit_policy": result.exit_policy,
        "exit_policy_confirmed": result.summary.get("exit_policy_confirmed"),
        "tick": result.ticks,
        "show_time_s": max(result.ticks - 1, 0) * period_s,  # its last tick
        "summary_written": result.summary_error is None,
    }


def _keep_only_takes(run_dir: Path) -> Path | None:
    """``telemetry.format = "off"``: the run directory removed, but for the takes the show
    recorded (asked for by its ``[record]`` or a teach session: never lost silently). Returns
    the directory if a take is kept in it."""
    from hilsim.live.director import TAKE_DIRS  # (loaded with a show's director anyway)

    kept = False
    for entry in list(run_dir.iterdir()) if run_dir.is_dir() else []:
        if entry.name in TAKE_DIRS and entry.is_dir() and not entry.is_symlink():
            kept = True
        elif entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                entry.unlink()
    if not kept:
        shutil.rmtree(run_dir, ignore_errors=True)
    return run_dir if kept else None
