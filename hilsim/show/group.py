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
* **One stop.** SIGINT/SIGTERM to the parent is sent on to every child; each applies its exit
  policy. A child that ends with a code other than 0 while others still run (a fault, a
  signal of its own) stops the others with SIGTERM: a figure half-running is not a show.
  A child's stdin closing (the parent died) stops it too.
* **One verdict.** Each bus's lateness, overruns, comm errors and stalls side by side, and the
  exit code of the worst child (:func:`worst_code`).
"""

from __future__ import annotations

import contextlib
import json
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
    int(ExitCode.SIGINT),
    int(ExitCode.USAGE),
    int(ExitCode.OK),
)
_POLL_S = 0.02


def worst_code(codes: Sequence[int]) -> int:
    """The exit code of the group: the worst of its buses' (:data:`SEVERITY`); a code outside
    the table counts as the worst."""
    if not codes:
        return int(ExitCode.OK)
    rank = {code: i for i, code in enumerate(SEVERITY)}
    return min(codes, key=lambda c: rank.get(c, -1))


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
    if "exit_code" in summary:
        return BusOutcome(
            name, int(summary["exit_code"]), f"killed by {sig} after its show", summary
        )
    if not ready:
        code = for_signal(signum) if signum in (signal.SIGINT, signal.SIGTERM) else ExitCode.USAGE
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
    #: the bus whose end stopped the others, and why (None: no bus stopped the others)
    stopped_by: str | None = None


class _Child:
    """One bus's process: its pipes read by two threads (stderr echoed with the bus's name)."""

    def __init__(self, name: str, argv: list[str], echo: Callable[[str], None]) -> None:
        self.name, self.ready = name, threading.Event()
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


def run_group(
    config: str,
    buses: Sequence[str],
    run_dir: Path,
    extra: Sequence[str],
    *,
    echo: Callable[[str], None],
) -> GroupResult:
    """Start one child per bus, start their shows at one instant, stop them together; returns
    each bus's outcome (``RUN/buses.json`` holds them too)."""
    pending: list[int] = []
    previous = {
        s: signal.signal(s, lambda signum, _f: pending.append(signum))
        for s in (signal.SIGINT, signal.SIGTERM)
    }
    children: list[_Child] = []
    start_at: float | None = None
    stopped_by: str | None = None
    try:
        for name in buses:
            children.append(_Child(name, child_argv(config, name, run_dir, extra), echo))
        called_off = signalled = False
        while any(c.proc.poll() is None for c in children):
            while pending:  # every signal the parent gets, every running child gets
                signum, signalled = pending.pop(0), True
                for c in children:
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
            elif start_at is not None and stopped_by is None and not signalled:
                for c in children:
                    code = c.proc.poll()
                    if code is not None and code != 0:
                        stopped_by = c.name  # a figure half-running is not a show
                        for other in children:
                            other.signal(signal.SIGTERM)
                        break
            time.sleep(_POLL_S)
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
    result = GroupResult(worst_code([o.exit_code for o in outcomes]), outcomes, rows, start_at)
    result.stopped_by = stopped_by
    record = {
        "exit_code": result.exit_code,
        "start_at_monotonic_s": start_at,
        "stopped_by": stopped_by,
        "buses": rows,
    }
    with contextlib.suppress(OSError):
        (run_dir / GROUP_FILE).write_text(json.dumps(record, indent=2) + "\n")
    return result
