"""What ``hilsim run`` prints about a show: the live status line, the statistics after it, and
the one-line verdict on a show that completed but was not healthy."""

from __future__ import annotations

import sys
import time

#: a show that completes with more than this share of overrunning ticks, or of failed reads,
#: ends with a verdict line saying so (the exit code stays 0: the show did go on)
VERDICT_OVERRUN_SHARE = 0.05
VERDICT_COMM_SHARE = 0.01


def status_printer(rate_hz: float):
    if not sys.stderr.isatty():
        return None
    start = time.perf_counter()

    def show(st: dict) -> None:
        wall = time.perf_counter() - start
        rate = st["tick"] / wall if wall > 0 else 0.0
        total = st.get("duration")
        of = f"/{total:.1f}" if total is not None else ""
        sys.stderr.write(
            f"\r t {st['t']:.1f}{of} s  {rate:.0f}/{rate_hz:g} Hz  "
            f"late p99 {st.get('lateness_p99_us', float('nan')):.0f} us  "
            f"comm err {st['comm_errors']}  overruns {st['overruns']}  "
            f"stalls {st.get('host_stalls', 0)} "
            + (f" | {st['cue']}" if st.get("cue") else "")
            + "\033[K"
        )
        sys.stderr.flush()

    return show


def print_stats(summary: dict) -> None:
    from hilsim.telemetry.stats import comm_errors

    lat = summary.get("lateness_us") or {}
    loop = summary.get("loop") or {}

    def us(key: str) -> str:
        value = lat.get(key)
        return "n/a" if value is None else f"{value:.0f} us"

    stalls = loop.get("host_stalls") or {}
    print(
        f"  lateness p50 {us('p50')}, p99 {us('p99')}, max {us('max')}; "
        f"overruns {summary.get('overruns', 0)}; "
        f"comm errors {comm_errors(summary)}; "
        f"host stalls {stalls.get('count', 0)} (max {stalls.get('max_ms', 0):.0f} ms)"
        + (f"; watchdog recoveries {loop['recoveries']}" if loop.get("recoveries") else ""),
        file=sys.stderr,
    )


def verdict(summary: dict, ticks_run: int) -> str | None:
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
