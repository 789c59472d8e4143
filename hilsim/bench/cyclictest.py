"""cyclictest (rt-tests) beside our scheduler: run it, parse what version 2.x prints.

The bench runs ``cyclictest -m -i INTERVAL -l LOOPS -q -h HIST_MAX [-p PRIO]`` right after our
own scheduler measurement, not beside it (on two cores the two loops would delay each other).
``-p`` makes its thread SCHED_FIFO, as ours; ``-m`` locks memory, as our run does. It measures
the wake-up latency of a thread sleeping in ``clock_nanosleep`` to an absolute deadline; ours
is the lateness of a thread that sleeps, then spins.

With ``-q -h N`` version 2.x prints a histogram and totals::

    # Histogram
    000001 000012           <- bucket (µs, floor of the latency), count
    ...
    # Total: 000002000
    # Max Latencies: 00149
    # Histogram Overflows: 00000

Without ``-h`` it prints one ``T: 0 ( 7809) P: 0 I:1000 C: 2000 Min: 31 ... Max: 3802`` line per
thread instead. Percentiles come from the histogram by our own rule (inverted CDF); samples
past its end count as the reported maximum.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from dataclasses import dataclass, field

from hilsim._types import JsonDict
from hilsim.bench.sched import SCHED_FIFO, SCHED_OTHER

INSTALL_HINT = "sudo apt-get install rt-tests"
#: Histogram range (µs); later samples are overflows (counted at the reported maximum).
DEFAULT_HIST_MAX_US = 10_000

_HIST_LINE = re.compile(r"^(\d{6,})\s+(\d+)\s*$")
_SUMMARY_KEYS = {
    "Total": "total",
    "Min Latencies": "min",
    "Avg Latencies": "avg",
    "Max Latencies": "max",
    "Histogram Overflows": "overflows",
}
_SUMMARY_LINE = re.compile(
    r"^T:\s*\d+\s*\(\s*\d+\)\s*P:\s*(?P<prio>\d+)\s*I:\s*(?P<interval>\d+)\s*C:\s*(?P<count>\d+)"
    r"\s*Min:\s*(?P<min>\d+)\s*Act:\s*(?P<act>\d+)\s*Avg:\s*(?P<avg>\d+)\s*Max:\s*(?P<max>\d+)"
)


@dataclass(frozen=True)
class CyclictestOutput:
    """What one single-threaded run printed. Latencies in µs; ``histogram`` maps a bucket
    (µs) to its count and is empty when ``-h`` was not given."""

    histogram: dict[int, int] = field(default_factory=dict)
    count: int = 0
    overflows: int = 0
    min_us: float | None = None
    avg_us: float | None = None
    max_us: float | None = None

    def percentile(self, q: float) -> float | None:
        """Latency (µs) at percentile ``q`` from the histogram, or None without one."""
        total = sum(self.histogram.values()) + self.overflows
        if total == 0:
            return None
        need = q / 100.0 * total - 1e-9  # same rank rule as sched.percentile
        seen = 0
        for bucket in sorted(self.histogram):
            seen += self.histogram[bucket]
            if seen >= need:
                return float(bucket)
        return self.max_us


def parse_output(text: str) -> CyclictestOutput:
    """Parse cyclictest's stdout (``-q``, with or without ``-h``) for one thread."""
    hist: dict[int, int] = {}
    summary: dict[str, float] = {}
    line_summary = None
    for raw in text.splitlines():
        line = raw.strip()
        if m := _HIST_LINE.match(line):
            count = int(m.group(2))
            if count:
                hist[int(m.group(1))] = count
            continue
        if line.startswith("#") and ":" in line:
            key, _, value = line[1:].partition(":")
            name = _SUMMARY_KEYS.get(key.strip())
            nums = value.split()
            if name and nums and nums[0].lstrip("-").replace(".", "", 1).isdigit():
                summary[name] = float(nums[0])
            continue
        if (m := _SUMMARY_LINE.match(line)) and line_summary is None:
            line_summary = m
    if line_summary is not None and not hist:
        return CyclictestOutput(
            count=int(line_summary["count"]),
            min_us=float(line_summary["min"]),
            avg_us=float(line_summary["avg"]),
            max_us=float(line_summary["max"]),
        )
    overflows = int(summary.get("overflows", 0))
    return CyclictestOutput(
        histogram=hist,
        count=int(summary.get("total", sum(hist.values()))) + overflows,
        overflows=overflows,
        min_us=summary.get("min"),
        avg_us=summary.get("avg"),
        max_us=summary.get("max"),
    )


@dataclass(frozen=True)
class CyclictestRun:
    """One cyclictest run, parsed; ``error`` says why there are no numbers."""

    command: list[str]
    version: str | None
    sched: str
    priority: int
    interval_us: int
    loops: int
    output: CyclictestOutput | None
    error: str | None = None

    @property
    def p99_us(self) -> float | None:
        return self.output.percentile(99) if self.output else None

    def as_dict(self) -> JsonDict:
        out = self.output
        return {
            "command": " ".join(self.command),
            "version": self.version,
            "sched": self.sched,
            "priority": self.priority,
            "interval_us": self.interval_us,
            "loops": self.loops,
            "error": self.error,
            "lateness_us": None
            if out is None
            else {
                "p50": out.percentile(50),
                "p99": out.percentile(99),
                "p999": out.percentile(99.9),
                "max": out.max_us,
                "avg": out.avg_us,
                "min": out.min_us,
            },
            "overflows": None if out is None else out.overflows,
        }


def find() -> str | None:
    """Path of cyclictest, or None when rt-tests is not installed."""
    return shutil.which("cyclictest")


def version(path: str) -> str | None:
    """``"2.40"`` from the ``cyclictest V 2.40`` banner, or None."""
    try:
        proc = subprocess.run([path, "--help"], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return None
    m = re.search(r"cyclictest V\s*([\w.]+)", proc.stdout + proc.stderr)
    return m.group(1) if m else None


def command(
    path: str, interval_us: int, loops: int, *, fifo: bool, priority: int, hist_max_us: int
) -> list[str]:
    """The cyclictest command line the bench runs."""
    cmd = [path, "-m", "-i", str(interval_us), "-l", str(loops), "-q", "-h", str(hist_max_us)]
    return [*cmd, "-p", str(priority)] if fifo else cmd


def run(
    interval_us: int,
    loops: int,
    *,
    fifo: bool,
    priority: int,
    hist_max_us: int = DEFAULT_HIST_MAX_US,
    path: str | None = None,
) -> CyclictestRun | None:
    """Run cyclictest; None when it is not installed. Falls back to SCHED_OTHER when
    SCHED_FIFO is refused, and says so in ``sched``."""
    path = path or find()
    if path is None:
        return None
    ver = version(path)
    timeout = loops * interval_us * 1e-6 * 3 + 20
    cmd: list[str] = []
    error = None
    for want_fifo in (True, False) if fifo else (False,):
        cmd = command(
            path, interval_us, loops, fifo=want_fifo, priority=priority, hist_max_us=hist_max_us
        )
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except (OSError, subprocess.TimeoutExpired) as exc:
            error = f"{type(exc).__name__}: {exc}"
            continue
        if proc.returncode == 0:
            return CyclictestRun(
                command=cmd,
                version=ver,
                sched=SCHED_FIFO if want_fifo else SCHED_OTHER,
                priority=priority if want_fifo else 0,
                interval_us=interval_us,
                loops=loops,
                output=parse_output(proc.stdout),
                error=error,
            )
        error = (proc.stderr.strip() or proc.stdout.strip())[-300:] or f"exit {proc.returncode}"
    return CyclictestRun(cmd, ver, SCHED_OTHER, 0, interval_us, loops, None, error)
