"""``hilsim plot RUN_DIR [--out DIR]``: PNG figures of one run directory.

Writes ``joints.png`` (target, spring, commanded and present position per joint, degrees),
``lateness.png`` (tick lateness histogram and time series, µs) and ``timing.png`` (per-stage wall
time, µs) into ``RUN_DIR/plots/`` or ``--out``, and prints each path written. Warnings about the
run (a truncated last line, dropped rows, no summary) go to stderr. Exit codes: 0 written,
1 the run has no ticks, 2 RUN_DIR is not a run directory (or its CSV header is not telemetry).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

HELP = "plot a run directory: joint positions (deg), tick lateness and per-stage timing (PNG)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", metavar="RUN_DIR", help="a run directory (has telemetry.csv)")
    parser.add_argument("--out", metavar="DIR", help="output directory (default RUN_DIR/plots)")
    parser.add_argument("--start", type=float, metavar="S", help="window start, s since run start")
    parser.add_argument("--end", type=float, metavar="S", help="window end, s since run start")
    parser.add_argument("--dpi", type=int, default=110, help="PNG resolution (default 110)")


def run(args: argparse.Namespace) -> int:
    from hilsim.runs import NotARunError, RunFormatError, read_run

    try:
        loaded = read_run(args.run_dir)
    except (NotARunError, RunFormatError, NotADirectoryError) as exc:
        print(f"hilsim plot: {exc}", file=sys.stderr)
        return 2
    for warning in loaded.warnings:
        print(f"hilsim plot: warning: {warning}", file=sys.stderr)
    if loaded.n_ticks == 0:
        print(f"hilsim plot: {args.run_dir} has no ticks to plot", file=sys.stderr)
        return 1
    from hilsim.plots import plot_run

    paths = plot_run(
        loaded,
        getattr(args, "out", None),
        start=getattr(args, "start", None),
        end=getattr(args, "end", None),
        dpi=getattr(args, "dpi", 110),
    )
    for path in paths:
        print(path)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``hilsim plot`` on its own (``python -m hilsim.plot_cli RUN_DIR``)."""
    parser = argparse.ArgumentParser(prog="hilsim plot", description=HELP)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
