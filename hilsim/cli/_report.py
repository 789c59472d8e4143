"""What ``hilsim run`` prints about a show: the live status line, the statistics after it, and
the one-line verdict on a show that completed but was not healthy."""

from __future__ import annotations

import collections
import contextlib
import math
import sys
import threading
import time
from collections.abc import Callable
from typing import TextIO

from hilsim._types import JsonDict
from hilsim.show.monitors import STALL_EVENT_S

#: a show that completes with more than this share of overrunning ticks, or of failed reads,
#: ends with a verdict line saying so (the exit code stays 0: the show did go on)
VERDICT_OVERRUN_SHARE = 0.05
VERDICT_COMM_SHARE = 0.01


#: when stderr is not a terminal (a log file, systemd's journal), a status line this often
LOG_STATUS_S = 10.0


class StatusLine:
    """The live status line of a show on the real clock: on a terminal rewritten in place
    (the loop offers it about twice a second); elsewhere one line every
    :data:`LOG_STATUS_S`, so an operator reading a log sees the show go on. Its own thread
    writes: a terminal paused with Ctrl-S or a pipe nobody reads never holds up the loop
    (only the newest lines wait). :meth:`close` ends it before the end-of-show lines."""

    def __init__(
        self,
        rate_hz: float,
        stream: TextIO | None = None,
        *,
        tty: bool | None = None,
        clock: Callable[[], float] | None = None,
    ) -> None:
        self.stream = sys.stderr if stream is None else stream
        self.tty = self.stream.isatty() if tty is None else tty
        self.rate_hz, self._clock = rate_hz, clock or time.perf_counter
        self._start, self._logged = self._clock(), -math.inf
        self._cv = threading.Condition()
        # what waits to be written: on a terminal the newest line only; in a log the lines
        # of the last ten minutes (older ones are dropped only if the log never takes them)
        self._waiting: collections.deque[str] = collections.deque(maxlen=1 if self.tty else 60)
        self._closed = self._wrote = self._abandoned = False
        self._thread = threading.Thread(target=self._write, name="hilsim-status", daemon=True)
        self._thread.start()

    def __call__(self, st: JsonDict) -> None:
        wall = self._clock() - self._start
        if not self.tty and wall - self._logged < LOG_STATUS_S:
            return
        self._logged = wall
        rate = st["tick"] / wall if wall > 0 else 0.0
        total = st.get("duration")
        of = f"/{total:.1f}" if total is not None else ""
        line = (
            f"t {st['t']:.1f}{of} s  {rate:.0f}/{self.rate_hz:g} Hz  "
            f"late p99 {st.get('lateness_p99_us', float('nan')):.0f} us  "
            f"comm err {st['comm_errors']}  overruns {st['overruns']}  "
            f"stalls {st.get('host_stalls', 0)}" + (f" | {st['cue']}" if st.get("cue") else "")
        )
        with self._cv:
            self._waiting.append(
                f"\r {line} \033[K" if self.tty else f"hilsim run: status: {line}\n"
            )
            self._cv.notify()

    def _write(self) -> None:
        while True:
            with self._cv:
                while not self._waiting and not self._closed:
                    self._cv.wait()
                if not self._waiting or self._abandoned:
                    return
                line = self._waiting.popleft()
            try:
                self.stream.write(line)
                self.stream.flush()
                self._wrote = True
            except (OSError, ValueError):  # a closed or broken stream: nothing more to say
                return

    def close(self, timeout_s: float = 1.0) -> None:
        """Write the lines offered, end the terminal's line; wait at most ``timeout_s``, then
        drop what still waits (a blocked stream: the line being written is ended after it)."""
        with self._cv:
            self._closed = True
            self._cv.notify()
        self._thread.join(timeout_s)
        alive = self._thread.is_alive()
        if alive:
            with self._cv:
                self._abandoned = True
        if self.tty and (self._wrote or alive):
            with contextlib.suppress(OSError, ValueError):
                self.stream.write("\n")  # (after the line being written: the stream's lock)


def print_stats(summary: JsonDict) -> None:
    from hilsim.telemetry.stats import comm_errors

    lat = summary.get("lateness_us") or {}
    loop = summary.get("loop") or {}

    def us(key: str) -> str:
        value = lat.get(key)
        return "n/a" if value is None else f"{value:.0f} us"

    stalls = loop.get("host_stalls") or {}
    n_stalls, max_ms = stalls.get("count", 0), stalls.get("max_ms", 0)
    event_ms = STALL_EVENT_S * 1e3
    # a stall shorter than the event threshold is counted here but has no events.jsonl line
    quiet = f", each under {event_ms:g} ms: no event" if n_stalls and max_ms < event_ms else ""
    print(
        f"  lateness p50 {us('p50')}, p99 {us('p99')}, max {us('max')}; "
        f"overruns {summary.get('overruns', 0)}; "
        f"comm errors {comm_errors(summary)}; "
        f"host stalls {n_stalls} (max {max_ms:.0f} ms{quiet})"
        + (f"; watchdog recoveries {loop['recoveries']}" if loop.get("recoveries") else ""),
        file=sys.stderr,
    )
    if stalls.get("held_last_goal"):  # no Bus Watchdog on the bus: said, not a fault
        print(
            f"  the servos held their last goal through {stalls['held_last_goal']} host "
            f"stall(s) of safety.watchdog_ms or longer (max {stalls.get('held_max_ms', 0):.0f} "
            "ms; no Bus Watchdog on them): the host's, not a servo fault",
            file=sys.stderr,
        )


def verdict(summary: JsonDict, ticks_run: int) -> str | None:
    """One line when a completed show was not healthy (overruns, failed reads, lost rows)."""
    from hilsim.telemetry.stats import comm_errors

    ticks = max(int(summary.get("ticks") or ticks_run or 0), 1)
    problems = []
    overruns = int(summary.get("overruns") or 0)
    if overruns > VERDICT_OVERRUN_SHARE * ticks:
        on_bus = min(int(summary.get("overruns_failed_read") or 0), overruns)
        # with failed reads, the ticks after one catch up: the host is not the one to name;
        # in virtual time the host takes no time at all
        virtual = summary.get("clock") == "virtual time"
        why = (
            f"{on_bus} on a tick whose read failed"
            if on_bus
            else "other bus traffic, such as health reads?"
            if virtual
            else "the host is too busy?"
        )
        problems.append(f"{overruns / ticks:.0%} of ticks overran ({why})")
    comm = comm_errors(summary)
    if comm > VERDICT_COMM_SHARE * ticks * max(len(summary.get("stale_reads") or {}), 1):
        problems.append(f"{comm} failed reads (check wiring, power and Return Delay Time)")
    tel = summary.get("telemetry") or {}
    if tel.get("rows_dropped"):
        problems.append(
            f"{tel['rows_dropped']} telemetry rows dropped "
            "(the writer fell behind: a stalled disk or no CPU for it)"
        )
    if tel.get("error"):
        problems.append(f"telemetry failed ({tel['error']}): the run is not fully recorded")
    if not problems:
        return None
    return "the show completed, but " + "; ".join(problems)
