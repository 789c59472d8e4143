"""The end of a show: its outcome decided once, then the end of its record says it.

After :meth:`HilLoop.run <hilsim.show.loop.HilLoop.run>` (the exit policy applied), the telemetry's
rows are finished first: a full disk or an I/O error found there is part of the outcome (with
``telemetry.on_failure = "stop"`` a show that ended well exits 3, and the fault is recorded).
Only then is ``summary.json`` written, from that outcome, so it never says other than the exit
code. If summary.json itself cannot be written there is none to contradict; the exit code says
so (3 with ``on_failure = "stop"``).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hilsim.exit_codes import ExitCode
from hilsim.telemetry import TelemetryWriter, WriterFailedError

if TYPE_CHECKING:
    from drivers.dynamixel.bus import DynamixelBus
    from hilsim.show.loop import RunResult
    from hilsim.show.parts import Parts


@dataclass
class ShowResult:
    """How a show ended: the exit code and reason (the outcome, decided once: summary.json
    says the same), and the summary (written, unless ``summary_error``)."""

    exit_code: int
    reason: str
    ticks: int
    wall_s: float
    exit_policy: str
    summary: dict[str, Any] = field(default_factory=dict)
    #: why the telemetry is not all on the disk (the writer's error), else None
    telemetry_error: BaseException | None = None
    telemetry_traceback: str | None = None
    #: the run directory (its telemetry, events, summary.json)
    run_dir: Path | None = None
    #: the writer's traceback in the run directory (telemetry_error.txt), if written
    traceback_path: Path | None = None
    #: why summary.json could not be written, else None
    summary_error: BaseException | None = None


def end_show(
    parts: Parts,
    bus: DynamixelBus,
    telemetry: TelemetryWriter,
    result: RunResult,
    wall: float,
    *,
    endless: bool = False,
) -> ShowResult:
    """The outcome of a show that ran (``result``, ``wall`` seconds), and its record's end.
    ``endless``: the show had no end of its own (``telemetry.on_failure = "auto"``)."""
    rig = parts.rig
    show = ShowResult(result.exit_code, result.reason, result.ticks, wall, result.exit_policy)
    live = None if parts.director is None else parts.director.close(telemetry.run_dir)
    show.telemetry_error = error = telemetry.finish()
    show.telemetry_traceback = telemetry.error_traceback
    stop_on_failure = not rig.telemetry.on_failure.continues(endless=endless)
    if error is not None and stop_on_failure and show.exit_code == ExitCode.OK:
        show.exit_code = int(ExitCode.FAULT)
        show.reason = f"telemetry: the writer failed at the end of the show ({error})"
        telemetry.event("fault", show.reason, tick=max(result.ticks - 1, 0))
    outcome = {
        "exit_code": show.exit_code,
        "exit_reason": show.reason,
        "exit_policy": result.exit_policy,
        "exit_policy_confirmed": result.exit_policy_confirmed,
        "wall_s": wall,
        "clock": "virtual time" if bus.clock.virtual else "real time",
        "port": rig.bus.port,
        "read_mode": bus.read_mode.value,
        "reads_per_tick": getattr(bus, "per_tick", bus.n),  # (a bus reading in rotation: fewer)
        "read_hz_per_servo": rig.loop.rate_hz * getattr(bus, "per_tick", bus.n) / bus.n,
        "loop": result.loop,
    }
    if live is not None:  # the inputs stopped, the take written, their counts
        outcome["live"] = live
    try:
        show.summary = telemetry.write_summary(outcome)
    except WriterFailedError as exc:  # no summary.json: nothing there says otherwise
        show.summary_error = exc.__cause__ or exc
        if stop_on_failure and show.exit_code == ExitCode.OK:
            show.exit_code = int(ExitCode.FAULT)
            show.reason = f"telemetry: summary.json not written ({show.summary_error})"
        show.summary = telemetry.stats.summary(**outcome)  # what it would have said
    show.traceback_path = telemetry.end.traceback_path
    return show


def crashed(exc: BaseException) -> dict[str, Any]:
    """The summary's outcome of a show that raised ``exc``, with the exit code the process
    will have (Ctrl-C outside the handlers: 130; a bug: 1, its traceback printed)."""
    if isinstance(exc, KeyboardInterrupt):
        code = int(ExitCode.SIGINT)
    elif isinstance(exc, SystemExit):
        code = exc.code if isinstance(exc.code, int) else int(exc.code is not None)
    else:
        code = int(ExitCode.INTERNAL)
    return {"exit_code": code, "exit_reason": f"crashed: {exc!r}"}


def close_quietly(telemetry: TelemetryWriter, summary: dict[str, Any]) -> None:
    """Close the telemetry with ``summary`` while something else is being raised."""
    with contextlib.suppress(Exception):
        telemetry.close(summary, timeout_s=2.0)
