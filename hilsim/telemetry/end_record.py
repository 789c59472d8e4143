"""The end of a run's record, kept writable when the disk fills up.

What a run writes last (the events logged after the writer stopped, such as the fault and the
exit policy; the writer's traceback, ``telemetry_error.txt``; ``summary.json``) must reach the
disk even when the rows filled it: a full disk is the fault it has to report. So at the start
the writer sets aside :func:`end_bytes` in ``summary.reserve`` (:class:`Reserve`:
``os.posix_fallocate``, else written zeros). At the end the events and the traceback each take
their share back just before they are written (the reserve shrinks by what they need), and
``summary.json`` is written *into* what is left of it, which is then renamed: the end never
competes with the rows, nor with another program filling the disk in between. On a
copy-on-write file system (btrfs, ZFS) rewriting allocated space needs new blocks; there only
the space given back is sure.

A reserve that cannot be made at the start (the disk is already that full) is not an error: the
show goes on, and :attr:`Reserve.error` says why (``hilsim run`` says it in one line). A run
killed before its end leaves ``summary.reserve`` behind: zeros, safe to delete.

:func:`disk_error` tells an OS error of the disk (full, quota, I/O error, read-only) from a bug:
``hilsim run`` says the first in one line and keeps its traceback in the run directory.
"""

from __future__ import annotations

import contextlib
import errno
import os
import queue
import threading
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from hilsim.telemetry.format import (
    EVENTS_JSONL,
    RESERVE_NAME,
    SUMMARY_JSON,
    TRACEBACK_TXT,
    to_json,
)
from hilsim.telemetry.sinks import fsync_dir

#: OS errors that mean the disk failed, not hilsim
DISK_ERRNOS: frozenset[int] = frozenset(
    {errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EROFS, errno.EFBIG}
)

_PAGE = 4096
#: summary.json of a run without joints and with its longest parts (a fault, the writer's
#: traceback, a live show's counts), and what each joint adds (its reads, limits, IDs);
#: about twice what the demo's summaries measure
_SUMMARY_BYTES, _SUMMARY_PER_JOINT = 12 * 1024, 512
#: the events logged after the writer stopped (the fault, the exit policy, a crash's
#: traceback), and the traceback file
_EVENTS_BYTES, _TRACEBACK_BYTES = 8 * 1024, 8 * 1024
#: events kept for the end of the record once the writer has stopped or died
END_EVENTS_MAX = 100


def disk_error(exc: BaseException | None) -> bool:
    """Whether ``exc`` is an OS error of the disk (:data:`DISK_ERRNOS`)."""
    return isinstance(exc, OSError) and exc.errno in DISK_ERRNOS


def end_bytes(n_joints: int) -> int:
    """Bytes the end of a run's record needs with ``n_joints`` joints, in whole pages."""
    need = _SUMMARY_BYTES + _SUMMARY_PER_JOINT * n_joints + _EVENTS_BYTES + _TRACEBACK_BYTES
    return -(-need // _PAGE) * _PAGE


class Reserve:
    """``size`` bytes allocated at ``path`` now, for the end of the record (module docstring).

    :attr:`size` is what is still set aside (0 when it could not be made: :attr:`error` says
    why). Single-threaded: the writer makes it and spends it on its own thread.
    """

    def __init__(self, path: Path, size: int) -> None:
        self.path = Path(path)
        self.wanted = int(size)
        self.size = 0
        self.error: OSError | None = None
        try:
            self._allocate(self.wanted)
        except OSError as exc:
            self.error = exc
            self.discard()

    def _allocate(self, size: int) -> None:
        fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            try:
                os.posix_fallocate(fd, 0, size)
            except (AttributeError, OSError) as exc:  # no fallocate here: zeros take the space
                if isinstance(exc, OSError) and exc.errno not in (
                    errno.EOPNOTSUPP,
                    errno.EINVAL,
                    errno.ENOSYS,
                ):
                    raise
                zeros = bytes(_PAGE)
                for _ in range(-(-size // _PAGE)):
                    os.write(fd, zeros)
        finally:
            os.close(fd)
        self.size = size

    def give_back(self, n: int) -> None:
        """Free enough of the reserve for ``n`` bytes written elsewhere, just before they are
        (whole pages, and one more for the file's own books)."""
        if self.size <= 0 or n <= 0:
            return
        size = max(0, self.size - (-(-n // _PAGE) + 1) * _PAGE)
        with contextlib.suppress(OSError):  # shrinking a file frees; it hardly ever fails
            os.truncate(self.path, size)
            self.size = size

    def discard(self) -> None:
        """Whatever is left of the reserve goes (the end is written, or was never wanted)."""
        self.size = 0
        with contextlib.suppress(OSError):
            self.path.unlink()

    def append(self, path: Path, text: str) -> None:
        """Append ``text`` to ``path``, on a line of its own (a torn last line stays alone),
        flushed and fsync-ed, with the space given back from the reserve."""
        data = text.encode("utf-8")
        with contextlib.suppress(OSError):
            if path.stat().st_size > 0:
                with open(path, "rb") as f:
                    f.seek(-1, os.SEEK_END)
                    if f.read(1) != b"\n":
                        data = b"\n" + data
        self.give_back(len(data))
        with open(path, "ab") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())

    def write_new(self, path: Path, text: str) -> None:
        """A new file ``path`` holding ``text``, fsync-ed, with the space given back."""
        data = text.encode("utf-8")
        self.give_back(len(data))
        try:
            with open(path, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
        except BaseException:
            with contextlib.suppress(OSError):  # leave no empty or half file
                path.unlink()
            raise

    def write_last(self, path: Path, text: str) -> None:
        """``path`` (summary.json) holding ``text``, whole or not at all: written into the
        reserve, which is then renamed ``path`` (without a reserve: a temporary file). Raises
        the OSError if it could not be written; then there is no ``path``."""
        data = text.encode("utf-8")
        tmp = self.path if self.size > 0 else path.with_name(path.name + ".tmp")
        try:
            with open(tmp, "r+b" if tmp == self.path else "wb") as f:
                f.write(data)
                f.truncate(len(data))
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):  # leave no half-file
                tmp.unlink()
            raise
        finally:
            self.size = 0
        fsync_dir(path.parent)


class EndRecord:
    """The end of one run's record (module docstring), written once on the writer's thread.

    The writer makes it at its start (the :attr:`reserve` with it), :meth:`keep`-s the events
    logged once it has stopped or died, and on its thread, its rows done, calls :meth:`write`,
    which waits for the outcome (:meth:`request`, from the caller's thread) and writes.
    """

    def __init__(self, run_dir: Path, n_joints: int) -> None:
        self.run_dir = Path(run_dir)
        self.reserve = Reserve(self.run_dir / RESERVE_NAME, end_bytes(n_joints))
        #: events for the end, oldest first
        self.events: list[dict[str, Any]] = []
        self.requested = False
        self._outcome: queue.SimpleQueue[dict[str, Any]] = queue.SimpleQueue()
        self.done = threading.Event()
        #: the summary written, or why summary.json could not be (then there is none)
        self.summary: dict[str, Any] | None = None
        self.error: BaseException | None = None
        #: telemetry_error.txt once written
        self.traceback_path: Path | None = None

    def keep(self, ev: dict[str, Any]) -> bool:
        """Keep an event for the end; False once the end is under way or ``END_EVENTS_MAX``
        are kept."""
        if self.requested or len(self.events) >= END_EVENTS_MAX:
            return False
        self.events.append(ev)
        return True

    def request(self, summary: Mapping[str, Any] | None) -> None:
        """The caller's part of the summary (the outcome); the first request wins."""
        if not self.requested:
            self.requested = True
            self._outcome.put(dict(summary) if summary is not None else {})

    def write(
        self,
        leftovers: Callable[[], list[dict[str, Any]]],
        summary_for: Callable[[dict[str, Any], int], dict[str, Any]],
        traceback_text: str | None,
    ) -> None:
        """Wait for :meth:`request`, then write: the events kept (``leftovers()`` closes the
        writer's files and adds the events it still held), ``traceback_text`` as
        telemetry_error.txt, then summary.json, ``summary_for(outcome, events lost)``. Never
        raises: :attr:`error` says why summary.json was not written."""
        outcome = self._outcome.get()
        reserve = self.reserve
        try:
            evs = self.events + leftovers()
            self.events = []
            lost = 0
            if evs:
                try:
                    reserve.append(
                        self.run_dir / EVENTS_JSONL, "".join(to_json(ev) + "\n" for ev in evs)
                    )
                except OSError:
                    lost = len(evs)
            if traceback_text is not None:
                path = self.run_dir / TRACEBACK_TXT
                with contextlib.suppress(OSError):
                    reserve.write_new(path, traceback_text)
                    self.traceback_path = path
            summary = summary_for(outcome, lost)
            reserve.write_last(self.run_dir / SUMMARY_JSON, to_json(summary, indent=2) + "\n")
            self.summary = summary
        except BaseException as exc:
            self.error = exc
        finally:
            reserve.discard()
            self.done.set()
