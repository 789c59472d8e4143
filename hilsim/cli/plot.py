"""``hilsim plot RUN_DIR [--out DIR]``: PNG figures of one run directory.

Writes ``joints.png`` (target, spring, commanded and present position per joint, degrees),
``lateness.png`` (tick lateness histogram and time series, µs) and ``timing.png`` (per-stage wall
time, µs) into ``RUN_DIR/plots/`` or ``--out``, and prints each path written. Warnings about the
run (a truncated last line, ticks caught up without a row, rows lost, no summary; each naming
the file it is about) go to stderr. Exit codes: 0 written, 1 the run has no ticks (in the
``--start``/``--end`` window), 2 RUN_DIR is not a run directory (or its CSV header is not
telemetry), or an option is unusable: ``--dpi`` outside :data:`DPI_RANGE`, ``--start`` not
before ``--end``, ``--out`` not a directory that can be written. Every problem is one line on
stderr.
"""

from __future__ import annotations

import argparse
import sys

from hilsim.exit_codes import ExitCode

HELP = "plot a run directory: joint positions (deg), tick lateness and per-stage timing (PNG)"
#: --dpi bounds: a legible thumbnail .. print resolution (a 16-joint figure at 300 dpi is already
#: ~40 megapixels; far more exhausts memory)
DPI_RANGE = (30, 300)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", metavar="RUN_DIR", help="a run directory (hilsim run's output)")
    parser.add_argument("--out", metavar="DIR", help="output directory (default RUN_DIR/plots)")
    parser.add_argument("--start", type=float, metavar="S", help="window start, s since run start")
    parser.add_argument("--end", type=float, metavar="S", help="window end, s since run start")
    parser.add_argument(
        "--dpi",
        type=int,
        default=110,
        help=f"PNG resolution, {DPI_RANGE[0]}..{DPI_RANGE[1]} (default 110)",
    )


def _option_problem(args: argparse.Namespace) -> str | None:
    """What is wrong with --dpi, --start/--end or --out, in one line; None if nothing."""
    import math
    from pathlib import Path

    dpi = getattr(args, "dpi", 110)
    if not DPI_RANGE[0] <= dpi <= DPI_RANGE[1]:
        return f"--dpi must be {DPI_RANGE[0]}..{DPI_RANGE[1]}, got {dpi}"
    start, end = getattr(args, "start", None), getattr(args, "end", None)
    for flag, value in (("--start", start), ("--end", end)):
        if value is not None and not math.isfinite(value):
            return f"{flag} must be a finite time in s, got {value}"
    if start is not None and end is not None and not start < end:
        return f"--start ({start:g} s) must be before --end ({end:g} s)"
    out = getattr(args, "out", None)
    if out is not None:
        path = Path(out)
        if path.exists() and not path.is_dir():
            return f"--out {out}: exists and is not a directory"
        parent = next((p for p in (path, *path.parents) if p.exists()), None)
        if parent is not None and not parent.is_dir():
            return f"--out {out}: {parent} is not a directory"
    return None


def run(args: argparse.Namespace) -> int:
    from hilsim.telemetry.plots import PLOT_MAX_ROWS
    from hilsim.telemetry.reader import NotARunError, RunFormatError, read_run

    problem = _option_problem(args)
    if problem:
        print(f"hilsim plot: {problem}", file=sys.stderr)
        return int(ExitCode.USAGE)
    try:
        loaded = read_run(args.run_dir, max_rows=PLOT_MAX_ROWS)  # bounded memory, any length
    except (NotARunError, RunFormatError, NotADirectoryError) as exc:
        print(f"hilsim plot: {exc}", file=sys.stderr)
        return int(ExitCode.USAGE)
    except (OSError, UnicodeDecodeError) as exc:
        print(f"hilsim plot: {args.run_dir}: cannot read the run: {exc}", file=sys.stderr)
        return int(ExitCode.USAGE)
    for warning in loaded.warnings:
        print(f"hilsim plot: warning: {warning}", file=sys.stderr)
    if loaded.n_ticks == 0:
        print(f"hilsim plot: {args.run_dir} has no ticks to plot", file=sys.stderr)
        return int(ExitCode.NOTHING_FOUND)
    start, end = getattr(args, "start", None), getattr(args, "end", None)
    t = loaded.t_sched
    inside = (t >= (start if start is not None else -float("inf"))) & (
        t <= (end if end is not None else float("inf"))
    )
    if not inside.any():
        print(
            f"hilsim plot: no ticks between {start if start is not None else 'the start'} and "
            f"{end if end is not None else 'the end'} s; the run covers "
            f"{float(t.min()):g}..{float(t.max()):g} s",
            file=sys.stderr,
        )
        return int(ExitCode.NOTHING_FOUND)
    from hilsim.telemetry.plots import plot_run

    out = getattr(args, "out", None)
    try:
        paths = plot_run(loaded, out, start=start, end=end, dpi=getattr(args, "dpi", 110))
    except OSError as exc:
        where = out if out is not None else f"{args.run_dir}/plots"
        print(f"hilsim plot: cannot write to {where}: {exc.strerror or exc}", file=sys.stderr)
        return int(ExitCode.USAGE)
    for path in paths:
        print(path)
    return int(ExitCode.OK)
