"""Past runs for the panel: the run directories beside the current one, with their summary.

:func:`list_runs` reads each ``<root>/<name>/summary.json`` (a run without one is listed as
unfinished); :func:`run_file` resolves a plot a page may show, refusing any path that leaves
the run directory (or its ``plots/``) or is not a PNG or SVG plot.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["list_runs", "run_file"]

MAX_RUNS = 200  # the newest first; older ones are not listed
PLOT_SUFFIXES = (".png", ".svg")
PLOTS_DIR = "plots"

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
        row["plots"] = [
            str(p.relative_to(d))
            for where in (d, d / PLOTS_DIR)  # `hilsim run` and `hilsim plot` write plots/
            for p in sorted(_files(where))
            if p.suffix in PLOT_SUFFIXES
        ]
        out.append(row)
    return out


def _is_run(d: Path) -> bool:
    """A run directory: it has a summary, or the events of a show under way."""
    return (d / "summary.json").is_file() or (d / "events.jsonl").is_file()


def _files(d: Path) -> list[Path]:
    try:
        return [p for p in d.iterdir() if p.is_file() and not p.is_symlink()]
    except OSError:
        return []


def run_file(root: Path, name: str, file: str) -> Path | None:
    """``root/name/file`` when it is a plot in that run directory or its ``plots/``, else
    None (no other directory, no way out of it)."""
    parts = file.split("/")
    if len(parts) == 2 and parts[0] == PLOTS_DIR:
        sub, leaf = PLOTS_DIR, parts[1]
    elif len(parts) == 1:
        sub, leaf = "", parts[0]
    else:
        return None
    if "/" in name or name.startswith(".") or leaf.startswith(".") or not leaf or not name:
        return None
    try:
        run = (root / name).resolve(strict=True)
        where = (run / sub).resolve(strict=True) if sub else run
        resolved = (where / leaf).resolve(strict=True)
    except OSError:
        return None
    inside = run.parent == root.resolve() and (where == run or where.parent == run)
    if not inside or resolved.parent != where:  # no link or name leads out of the run
        return None
    if resolved.suffix not in PLOT_SUFFIXES or not resolved.is_file():
        return None
    return resolved
