"""``hilsim compare``: the integrator study of the design paper, its figures and report.

The study itself is :mod:`hilsim.studies.compare`; this module is only its command-line face.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from hilsim.exit_codes import ExitCode
from hilsim.studies.compare import HELP, run_study, summary

__all__ = ["HELP", "add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("out/compare"),
        help="output directory (default: %(default)s)",
    )
    parser.add_argument(
        "--json",
        type=Path,
        default=None,
        help="where to write the numbers (default: OUT/compare.json)",
    )
    parser.add_argument(
        "--quick", action="store_true", help="shorter long run (100 s) and one step size fewer"
    )


def run(args: argparse.Namespace) -> int:
    import json

    from hilsim.studies.compare_plots import write_figures
    from hilsim.studies.compare_report import write_report

    started = time.perf_counter()
    results = run_study(quick=args.quick)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    json_path: Path = args.json if args.json is not None else out / "compare.json"
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(results, allow_nan=False) + "\n", encoding="utf-8")
    figures = write_figures(results, out)
    report = write_report(results, figures, out, json_path)
    print(summary(results))
    print(
        f"\nwrote {report}, {json_path} and {len(figures)} figures to {out}/ "
        f"in {time.perf_counter() - started:.1f} s"
    )
    return int(ExitCode.OK)
