"""Past runs for the panel: the run directories beside the current one, with their summary.

:func:`list_runs` reads each ``<root>/<name>/summary.json`` (a run without one is listed as
unfinished); :func:`run_file` resolves a plot a page may show, refusing any path that leaves
the run directory or is not a PNG or SVG plot.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["list_runs", "run_file"]

MAX_RUNS = 200  # the newest first; older ones are not listed
PLOT_SUFFIXES = (".png", ".svg")

#: a completed show's one-line verdict from its summary (the CLI's), or None when healthy
Verdict = Callable[[dict[str, Any], int], str | None]


def list_runs(root: Path, verdict: Verdict | None = None) -> list[dict[str, Any]]:
    """The run directories under ``root``, newest first: name, when, exit code, reason,
    verdict, ticks, plots (file names)."""
    try:
        dirs = [d for d in root.iterdir() if d.is_dir() and _is_run(d)]
    except OSError:
        return []
    dirs.sort(key=lambda d: d.stat().st_mtime, reverse=True)
    out = []
    for d in dirs[:MAX_RUNS]:
        row: dict[str, Any] = {"name": d.name, "mtime": d.stat().st_mtime}
        try:
            summary = json.loads((d / "summary.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            summary = None
        if not isinstance(summary, dict):
            row["state"] = "no summary (running, or it ended without one)"
        else:
            code = summary.get("exit_code")
            row["exit_code"] = code
            row["reason"] = summary.get("exit_reason") or ""
            row["ticks"] = summary.get("ticks")
            row["exit_policy"] = summary.get("exit_policy")
            if code == 0 and verdict is not None:
                try:
                    row["verdict"] = verdict(summary, int(summary.get("ticks") or 0))
                except (TypeError, ValueError, KeyError):
                    row["verdict"] = None
        plots = sorted(p.name for p in _files(d) if p.suffix in PLOT_SUFFIXES)
        row["plots"] = plots
        out.append(row)
    return out


def _is_run(d: Path) -> bool:
    """A run directory: it has a summary, or the events of a show under way."""
    return (d / "summary.json").is_file() or (d / "events.jsonl").is_file()


def _files(d: Path) -> list[Path]:
    try:
        return [p for p in d.iterdir() if p.is_file()]
    except OSError:
        return []


def run_file(root: Path, name: str, file: str) -> Path | None:
    """``root/name/file`` when it is a plot inside that run directory, else None."""
    if os.sep in name or os.sep in file or name.startswith(".") or file.startswith("."):
        return None
    path = root / name / file
    try:
        resolved = path.resolve(strict=True)
    except OSError:
        return None
    if resolved.parent != (root / name).resolve() or resolved.suffix not in PLOT_SUFFIXES:
        return None
    return resolved if resolved.is_file() else None
