"""Several buses, one show: ``hilsim run RIG`` for a rig with ``[buses.<name>]`` tables.

One child process per bus runs the same ``hilsim run`` on that bus's joints only
(``hilsim run RIG --bus NAME --out RUN/NAME --shared-start``), so each bus has its own loop, its
own core when there is one, and a normal run directory ``RUN/<bus>/`` that ``hilsim plot``
reads. This module is the parent (``docs/buses.md``):

* **One start.** Each child checks its servos and says ``ready`` on its stdout (nothing has
  moved). When every child is ready the parent sends each one instant on CLOCK_MONOTONIC
  (``time.monotonic()``, system-wide on Linux, the clock every show's loop keeps time with):
  ``START_MARGIN_S`` ahead, time for every child's soft-start reads and torque-on. Each child's
  tick 0 waits for it, its start-up just before (:data:`hilsim.show.loop.SHARED_START_LEAD_S`;
  :func:`hilsim.show.session.run_show`'s ``start_at``). A child that refuses
  (exit 2) calls the start off: the others are told (their stdin closes) and nothing moves.
  With ``--virtual-time`` each child keeps its own virtual clock (show time is k·period, so
  each bus's numbers are deterministic) and the instant is only the signal to go.
* **One stop.** SIGINT, SIGTERM, SIGHUP or SIGQUIT to the parent is sent on to every child
  whose show still runs; each applies its exit policy. A child whose loop stops with a code
  other than 0 (a fault, a signal of its own) says so on its stdout the moment it stops
  (:func:`stopping_line`: the code, the instant on CLOCK_MONOTONIC, the reason), before its
  exit policy, record and plots; the parent then stops every bus whose show still runs with
  SIGTERM: a figure half-running is not a show. A child that ends without saying so (a crash,
  SIGKILL) stops them when it ends. A child's stdin closing (the parent died) stops it too.
* **One verdict.** Each bus's lateness, overruns, comm errors and stalls side by side, which
  bus stopped the show and why (the earliest of the buses' own stops, by their instants, not
  by the order the processes ended: :func:`first_stop`), and the exit code of the worst child
  (:func:`group_code`).
"""

from __future__ import annotations

import contextlib
import json
import math
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hilsim.exit_codes import ExitCode, for_signal
from hilsim.show.stop import STOP_SIGNALS
from hilsim.telemetry.stats import comm_errors

#: from "every bus is ready" to the shared tick 0: each child opens its telemetry, reads where
#: its servos are and turns torque on before it (a few transactions; on hardware behind a
#: 16 ms latency timer about a tenth of a second)
START_MARGIN_S = 0.5
#: the file in RUN/ with each bus's outcome (the buses' own records are RUN/<bus>/)
GROUP_FILE = "buses.json"
#: worst first: a crash outside a show, a fault, an unconfirmed exit policy, a signal, a
#: refusal (nothing moved), success
SEVERITY = (
    int(ExitCode.INTERNAL),
    int(ExitCode.FAULT),
    int(ExitCode.UNSAFE_EXIT),
    int(ExitCode.SIGTERM),
    int(ExitCode.SIGQUIT),
    int(ExitCode.SIGHUP),
    int(ExitCode.SIGINT),
    int(ExitCode.USAGE),
    int(ExitCode.OK),
)
_POLL_S = 0.02
#: the first word of a child's line on its stdout when its loop stops (:func:`stopping_line`)
STOPPING = "stopping"


def worst_code(codes: Sequence[int]) -> int:
    """The exit code of the group: the worst of its buses' (:data:`SEVERITY`); a code outside
    the table counts as the worst."""
    if not codes:
        return int(ExitCode.OK)
    rank = {code: i for i, code in enumerate(SEVERITY)}
    return min(codes, key=lambda c: rank.get(c, -1))


@dataclass(frozen=True)
class Stop:
    """A child's loop stopped: its exit code then, the instant (CLOCK_MONOTONIC) and why."""

    code: int
    at: float
    reason: str


def stopping_line(code: int, reason: str, at: float) -> str:
    """What a child prints on its stdout the moment its loop stops (one line)."""
    return f"{STOPPING} {int(code)} {at!r} {' '.join(reason.split())}"


def parse_stopping(line: str) -> Stop | None:
    """A :func:`stopping_line` read back; None for any other line."""
    word, _, rest = line.strip().partition(" ")
    if word != STOPPING:
        return None
    code, _, rest = rest.partition(" ")
    at, _, reason = rest.partition(" ")
    try:
        return Stop(int(code), float(at), reason)
    except ValueError:
        return None


def first_stop(ends: dict[str, float], before: float = math.inf) -> str | None:
    """The bus that stopped the show: of the buses whose show ended by itself with a code other
    than 0 (``ends``: bus -> its instant), the earliest before ``before`` (the first signal the
    parent sent: a stop after it may be the parent's doing). None: no bus stopped the show."""
    own = {name: at for name, at in ends.items() if at < before}
    return min(own, key=own.__getitem__) if own else None


def group_code(outcomes: Sequence[BusOutcome], stopper: str | None, stopped: set[str]) -> int:
    """The group's exit code: the worst bus's (:func:`worst_code`), where a bus the parent
    stopped because ``stopper`` had stopped counts by the stopper's code, not by the SIGTERM it
    was sent (nobody signalled the figure). A stopper that could not start (2) after a bus it
    stopped had energised its servos is a fault of the figure (3): something had moved."""
    codes, moved = [], False
    for o in outcomes:
        if o.name in stopped and o.exit_code == int(ExitCode.SIGTERM):
            moved |= o.summary.get("exit_policy_confirmed") is not None
            continue
        codes.append(o.exit_code)
    by_name = {o.name: o.exit_code for o in outcomes}
    if moved and stopper is not None and by_name.get(stopper) == int(ExitCode.USAGE):
        codes.append(int(ExitCode.FAULT))
    return worst_code(codes)


@dataclass
class BusOutcome:
    """How one bus's child ended: its exit code, a note when the parent knows more than the
    child could say, and its ``summary.json`` (empty when it wrote none)."""

    name: str
    exit_code: int
    note: str = ""
    summary: dict[str, Any] = field(default_factory=dict)


def bus_outcome(name: str, returncode: int, ready: bool, run_dir: Path) -> BusOutcome:
    """The outcome of a child from its return code and run directory. A child killed by a
    signal said nothing itself: after its summary was written, the summary's code stands;
    before it was ready nothing had moved; in between its exit policy was not applied."""
    summary: dict[str, Any] = {}
    with contextlib.suppress(OSError, ValueError):
        summary = json.loads((run_dir / "summary.json").read_text())
    if returncode >= 0:
        return BusOutcome(name, returncode, "", summary)
    signum = -returncode
    try:
        sig = signal.Signals(signum).name
    except ValueError:
        sig = f"signal {signum}"
    if "exit_code" in summary:  # its record stands, and says why its show ended
        why = summary.get("exit_reason")
        note = f"killed by {sig} after its show"
        note = f"{why} ({note})" if why else note
        return BusOutcome(name, int(summary["exit_code"]), note, summary)
    if not ready:
        code = for_signal(signum) if signum in STOP_SIGNALS else ExitCode.USAGE
        return BusOutcome(name, int(code), f"killed by {sig} before its start: nothing moved")
    return BusOutcome(
        name,
        int(ExitCode.FAULT),
        f"killed by {sig} during its show: its exit policy was not applied (the servos' Bus "
        "Watchdog stops them)",
    )


def bus_row(outcome: BusOutcome, start_at: float | None) -> dict[str, Any]:
    """One bus's line of the side-by-side table, from its summary."""
    s = outcome.summary
    lat = s.get("lateness_us") or {}
    loop = s.get("loop") or {}
    stalls = loop.get("host_stalls") or {}
    t0 = loop.get("clock_t0")
    real = s.get("clock") == "real time"
    return {
        "bus": outcome.name,
        "exit_code": outcome.exit_code,
        "reason": outcome.note or s.get("exit_reason", "no summary written"),
        "joints": len(s.get("servo_ids") or {}) or None,
        "ticks": s.get("ticks"),
        "lateness_us": {k: lat.get(k) for k in ("p50", "p99", "max")},
        "overruns": s.get("overruns"),
        "comm_errors": comm_errors(s) if s else None,
        "host_stalls": stalls.get("count"),
        "tick0_after_start_us": (t0 - start_at) * 1e6
        if real and start_at is not None and t0 is not None
        else None,
    }


def format_rows(rows: Sequence[dict[str, Any]]) -> list[str]:
    """The side-by-side table: one line per bus."""

    def num(x: Any, fmt: str = ".0f") -> str:
        return "-" if x is None else format(x, fmt)

    head = ("bus", "exit", "lateness p50/p99/max us", "overruns", "comm err", "stalls", "tick 0")
    lines = [head]
    for r in rows:
        lat = r["lateness_us"]
        t0 = r["tick0_after_start_us"]
        lines.append(
            (
                r["bus"],
                str(r["exit_code"]),
                "/".join(
                    num(lat[k], ".1f" if k != "max" else ".0f") for k in ("p50", "p99", "max")
                ),
                f"{num(r['overruns'])}/{num(r['ticks'])}",
                num(r["comm_errors"]),
                num(r["host_stalls"]),
                "-" if t0 is None else f"{t0:+.0f} us",
            )
        )
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    return [
        "  ".join(c.ljust(w) for c, w in zip(line, widths, strict=True)).rstrip() for line in lines
    ]


@dataclass
class GroupResult:
    exit_code: int
    outcomes: list[BusOutcome]
    rows: list[dict[str, Any]]
    start_at: float | None
    #: the bus whose own stop came first (None: no bus stopped the show; the user, or the end)
    stopped_by: str | None = None
    #: its exit code, reason, seconds after the start instant, and the buses stopped for it
    stop: dict[str, Any] | None = None


class _Child:
    """One bus's process: its pipes read by two threads (stderr echoed with the bus's name)."""

    def __init__(self, name: str, argv: list[str], echo: Callable[[str], None]) -> None:
        self.name, self.ready = name, threading.Event()
        #: what the child said when its loop stopped (None: not said, or not yet read)
        self.stop: Stop | None = None
        #: when the parent first saw the process gone (time.monotonic())
        self.exited_at: float | None = None
        self.proc = subprocess.Popen(
            argv,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            bufsize=1,
            process_group=0,  # a terminal's Ctrl-C reaches the parent, which sends it on once
        )
        self._threads = [
            threading.Thread(target=self._read_stdout, daemon=True),
            threading.Thread(target=self._read_stderr, args=(echo,), daemon=True),
        ]
        for t in self._threads:
            t.start()

    def _read_stdout(self) -> None:
        assert self.proc.stdout is not None  # a pipe (__init__): for the type checker
        for line in self.proc.stdout:
            if line.strip() == "ready":
                self.ready.set()
            elif self.stop is None and (stop := parse_stopping(line)) is not None:
                self.stop = stop

    def observe(self, now: float) -> None:
        if self.exited_at is None and self.proc.poll() is not None:
            self.exited_at = now

    def own_stop(self) -> float | None:
        """When this bus's show ended by itself with a code other than 0: the instant its
        loop stopped, or (it could not say: a crash, SIGKILL) when it was seen gone."""
        code = self.proc.returncode
        failed = code is not None and code != 0
        if self.stop is not None:
            return self.stop.at if self.stop.code != 0 or failed else None
        return self.exited_at if failed else None

    def _read_stderr(self, echo: Callable[[str], None]) -> None:
        assert self.proc.stderr is not None  # a pipe (__init__): for the type checker
        for line in self.proc.stderr:
            echo(f"[{self.name}] {line.rstrip()}")

    def send(self, text: str | None) -> None:
        """A line to the child's stdin; None closes it (stop)."""
        assert self.proc.stdin is not None  # a pipe (__init__): for the type checker
        with contextlib.suppress(OSError, ValueError):
            if text is None:
                self.proc.stdin.close()
            else:
                self.proc.stdin.write(text + "\n")
                self.proc.stdin.flush()

    def signal(self, signum: int) -> None:
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(signum)

    def join(self) -> None:
        self.proc.wait()
        for t in self._threads:
            t.join(timeout=5.0)
        self.send(None)


def bus_status_file(path: Path, bus: str) -> Path:
    """One bus's heartbeat when the figure's is ``path``: ``status-<bus>.json`` beside it."""
    return path.with_name(f"{path.stem}-{bus}{path.suffix}")


def child_argv(config: str, bus: str, run_dir: Path, extra: Sequence[str]) -> list[str]:
    """The command line of one bus's child: this Python's ``hilsim run`` on that bus."""
    return [
        sys.executable,
        "-m",
        "hilsim",
        "run",
        config,
        "--bus",
        bus,
        "--out",
        str(run_dir / bus),
        "--shared-start",
        *extra,
    ]


def run_group(  # noqa: C901, PLR0912 (the group's life: start, watch, stop, record)
    config: str,
    buses: Sequence[str],
    run_dir: Path,
    extra: Sequence[str],
    *,
    echo: Callable[[str], None],
    status_file: Path | None = None,
    runs_removed: Sequence[dict[str, object]] = (),
) -> GroupResult:
    """Start one child per bus, start their shows at one instant, stop them together; returns
    each bus's outcome (``RUN/buses.json`` holds them too). ``status_file``: each bus's
    heartbeat at :func:`bus_status_file` of it (None: in its run directory). ``runs_removed``:
    old runs the runs root's caps removed as the figure started, kept in the record."""
    pending: list[int] = []
    previous = {
        s: signal.signal(s, lambda signum, _f: pending.append(signum)) for s in STOP_SIGNALS
    }
    children: list[_Child] = []
    start_at: float | None = None
    #: the first signal the parent sent (its stop, or the user's sent on): a bus's stop after
    #: it may be that signal's doing, so only the stops before it can have stopped the show
    signalled_at = math.inf
    sent: list[_Child] = []  # the buses the parent stopped because another had stopped
    try:
        for name in buses:
            mine = [*extra]
            if status_file is not None:
                mine += ["--status-file", str(bus_status_file(status_file, name))]
            children.append(_Child(name, child_argv(config, name, run_dir, mine), echo))
        called_off = False
        while any(c.proc.poll() is None for c in children):
            now = time.monotonic()
            for c in children:
                c.observe(now)
            while pending:  # every signal the parent gets, every show still running gets
                signum, signalled_at = pending.pop(0), min(signalled_at, now)
                for c in children:
                    if c.stop is None:  # (one that has stopped is writing its record)
                        c.signal(signum)
            if start_at is None and not called_off:
                # a bus that ended before the start, ready or not, cannot play its part
                refused = [c for c in children if c.proc.poll() is not None]
                if refused:  # one bus cannot start: none does (nothing has moved)
                    called_off = True
                    for c in children:
                        c.send(None)
                elif all(c.ready.is_set() for c in children):
                    start_at = time.monotonic() + START_MARGIN_S
                    for c in children:
                        c.send(repr(start_at))
            elif (
                start_at is not None
                and signalled_at == math.inf
                and any(c.own_stop() is not None for c in children)
            ):
                signalled_at = time.monotonic()  # a figure half-running is not a show
                for c in children:
                    if c.stop is None and c.proc.poll() is None:
                        c.signal(signal.SIGTERM)
                        sent.append(c)
            time.sleep(_POLL_S)
        now = time.monotonic()
        for c in children:
            c.observe(now)
    finally:
        for c in children:  # (a crash of the parent: the children see their stdin close)
            c.send(None)
        for s, handler in previous.items():
            signal.signal(s, handler)
    for c in children:
        c.join()
    outcomes = [
        bus_outcome(c.name, c.proc.returncode, c.ready.is_set(), run_dir / c.name) for c in children
    ]
    rows = [bus_row(o, start_at) for o in outcomes]
    stopper, stop = None, None
    if start_at is not None:
        ends = {c.name: at for c in children if (at := c.own_stop()) is not None}
        stopper = first_stop(ends, signalled_at)
    # a bus sent SIGTERM whose own stop came before it was not stopped by the parent
    stopped = [c.name for c in sent if c.stop is None or c.stop.at >= signalled_at]
    if stopper is not None and start_at is not None:  # (a stopper needs the shared start)
        row = rows[[o.name for o in outcomes].index(stopper)]
        # on virtual clocks the instant is only the signal to go: counted from when it was sent
        went = start_at - START_MARGIN_S if "--virtual-time" in extra else start_at
        stop = {
            "exit_code": row["exit_code"],
            "reason": row["reason"],
            "after_start_s": ends[stopper] - went,
            "buses_stopped": stopped,
        }
    code = group_code(outcomes, stopper, set(stopped))
    result = GroupResult(code, outcomes, rows, start_at, stopper, stop)
    record = {
        "exit_code": result.exit_code,
        "start_at_monotonic_s": start_at,
        "stopped_by": stopper,
        "stop": stop,
        "buses": rows,
    }
    if runs_removed:
        record["runs_removed"] = list(runs_removed)
    with contextlib.suppress(OSError):
        (run_dir / GROUP_FILE).write_text(json.dumps(record, indent=2) + "\n")
    return result
