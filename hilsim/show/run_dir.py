"""The run directory: one run's record (telemetry, events, summary.json, plots).

It is made before anything touches the bus, so a path that cannot be written is refused
while nothing has moved. A directory made for a run that never started is removed again.
Under caps on the runs root (``telemetry.runs_max_mb``, ``runs_max_age_days``) the oldest runs
there are removed as a show starts (:func:`prune_runs`).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "RunDir",
    "RunDirError",
    "cap_removal_line",
    "make_run_dir",
    "prune_runs",
    "prune_under_caps",
]


class RunDirError(ValueError):
    """The run directory cannot be used; the message is one line naming the path."""


@dataclass(frozen=True)
class RunDir:
    """A run directory and whether this call made it."""

    path: Path
    #: made here (not an existing empty directory): removed again if the run never starts
    created: bool

    def remove_if_empty(self) -> None:
        """Remove the directory if this call made it and nothing was written into it."""
        if self.created:
            with contextlib.suppress(OSError):
                self.path.rmdir()


def make_run_dir(
    out: str | os.PathLike[str] | None, out_dir: str | os.PathLike[str], name: str,
    *, what: str = "--out",
) -> RunDir:  # fmt: skip
    """Create the run directory.

    ``out``: a new directory, or an existing empty one (``what`` names it in messages).
    Default: ``<out_dir>/<name>-<time>``, with ``-2``, ``-3`` ... added if that exists (two
    runs started in the same second). ``~`` is the user's home. Raises :class:`RunDirError`.
    """
    if out is not None:
        path = _home(Path(out))
        if path.exists() and not path.is_dir():
            raise RunDirError(f"{what} {out}: exists and is not a directory")
        if path.is_dir() and any(path.iterdir()):
            raise RunDirError(
                f"{what} {out}: the directory is not empty (a run directory holds one run)"
            )
        existed = path.is_dir()
        _mkdir(path, exist_ok=True)
        return RunDir(path, created=not existed)
    stem = _home(Path(out_dir)) / f"{name}-{time.strftime('%Y%m%d-%H%M%S')}"
    for n in range(1, 1000):
        path = stem if n == 1 else stem.with_name(f"{stem.name}-{n}")
        try:
            _mkdir(path, exist_ok=False)
        except FileExistsError:
            continue
        return RunDir(path, created=True)
    raise RunDirError(f"{stem}: too many runs with this name in one second")


def _home(path: Path) -> Path:
    """``~`` as the user's home; ``~user`` of no such user refused in one line."""
    try:
        return path.expanduser()
    except RuntimeError:
        raise RunDirError(f"{path}: no such user's home directory") from None


def _mkdir(path: Path, *, exist_ok: bool) -> None:
    try:
        path.mkdir(parents=True, exist_ok=exist_ok)
    except FileExistsError:
        if not exist_ok:
            raise
        raise RunDirError(
            f"{path}: cannot create the run directory (a file is in the way)"
        ) from None
    except OSError as exc:
        raise RunDirError(
            f"{path}: cannot create the run directory: {exc.strerror or exc}"
        ) from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise RunDirError(f"{path}: the run directory is not writable")


#: what makes a directory under the runs root a run's record (and so removable by the caps)
RUN_MARKERS = ("events.jsonl", "summary.json", "buses.json")


def _size_and_last_write(path: Path) -> tuple[int, float]:
    size, last = 0, path.stat().st_mtime
    for root, _dirs, files in os.walk(path):
        for name in files:
            with contextlib.suppress(OSError):
                st = os.stat(os.path.join(root, name), follow_symlinks=False)
                size += st.st_size
                last = max(last, st.st_mtime)
    return size, last


def prune_runs(
    root: Path, current: Path, max_bytes: int | None, max_age_s: float | None
) -> list[dict[str, object]]:
    """Remove old run directories under ``root`` (not ``current``): those last written more than
    ``max_age_s`` ago, then the oldest until the rest take ``max_bytes`` at most. Only
    directories holding a run's record (:data:`RUN_MARKERS`) are touched, never a symbolic
    link. Returns one record per run removed (its name, bytes, last write, why), oldest first;
    an OSError is the caller's to say."""
    if max_bytes is None and max_age_s is None:
        return []
    here = current.resolve()
    runs = []
    for d in root.iterdir():
        if d.is_symlink() or not d.is_dir() or d.resolve() == here:
            continue
        if any((d / m).exists() for m in RUN_MARKERS):
            size, last = _size_and_last_write(d)
            runs.append((last, d.name, d, size))
    runs.sort()
    now, removed = time.time(), []
    held = sum(r[3] for r in runs)
    for last, name, d, size in runs:
        old = max_age_s is not None and now - last > max_age_s
        big = max_bytes is not None and held > max_bytes
        if not (old or big):
            continue
        shutil.rmtree(d)
        held -= size
        removed.append(
            {
                "run": name,
                "bytes": size,
                "last_write": time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(last)),
                "why": "age" if old else "size",
            }
        )
    return removed


def prune_under_caps(
    root: str | os.PathLike[str], run_dir: Path, max_mb: float | None, max_age_days: float | None
) -> list[dict[str, object]]:
    """The runs root's caps (``telemetry.runs_max_mb``, ``runs_max_age_days``) applied as a
    run starts: nothing unless ``run_dir`` was made under ``root`` (a run put elsewhere leaves
    the root alone). Returns :func:`prune_runs`' records; an OSError is the caller's to say."""
    path = _home(Path(root))
    if run_dir.resolve().parent != path.resolve():
        return []
    max_bytes = None if max_mb is None else int(max_mb * 1e6)
    max_age = None if max_age_days is None else max_age_days * 86400.0
    return prune_runs(path, run_dir, max_bytes, max_age)


def cap_removal_line(rec: dict[str, object], max_mb: float | None, max_age: float | None) -> str:
    """One removal of :func:`prune_runs`, said: the cap that removed it, the run, its size."""
    cap = (
        f"telemetry.runs_max_mb = {max_mb:g}"
        if rec["why"] == "size"
        else f"telemetry.runs_max_age_days = {max_age:g}"
    )
    mb, last = float(rec["bytes"]) / 1e6, rec["last_write"]  # type: ignore[arg-type]
    return f"{cap}: removed the old run {rec['run']} ({mb:.1f} MB, last written {last})"
