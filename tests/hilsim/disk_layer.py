"""A run directory's disk, faked at the file layer: full, small, or failing at one operation.

:class:`DiskLayer` sees every operation hilsim makes on a file in one directory (opened for
writing by ``open``/``Path.open``: ``write``, ``flush``, ``close``; ``os.fsync``,
``os.replace``, ``os.rename``, ``os.truncate``, ``os.ftruncate``, ``os.posix_fallocate``) and
asks :meth:`DiskLayer.check` first, which may raise the ``OSError`` a real disk would. Files
elsewhere are left alone. Two disks:

* :class:`SmallDisk`: ``capacity`` bytes for the whole directory (what its files hold, by
  their sizes); a write beyond it writes what fits and raises ENOSPC, as a full file system
  does; an allocation beyond it raises ENOSPC and allocates nothing. Files are written through
  at once, so their sizes are what is on the disk.
* :class:`FailsOnce`: once ``armed()`` is true, the first operation ``(op, file name)`` equal to
  ``at`` raises ``err``; every operation seen while armed is listed in ``points``.
"""

from __future__ import annotations

import builtins
import errno
import io
import os
from collections.abc import Callable
from pathlib import Path

_WRITING = set("wax+")


class DiskLayer:
    def __init__(self, monkeypatch, root: Path, *, write_through: bool = False) -> None:
        self.root = Path(root).resolve()
        self.write_through = write_through
        real_open = builtins.open

        def layer_open(file, mode="r", *a, **kw):
            f = real_open(file, mode, *a, **kw)
            if isinstance(file, str | os.PathLike) and set(mode) & _WRITING:
                name = self.name_of(file)
                if name is not None:
                    return _File(self, f, name)
            return f

        monkeypatch.setattr(builtins, "open", layer_open)
        monkeypatch.setattr(io, "open", layer_open)
        for op in ("fsync", "ftruncate", "posix_fallocate"):
            if hasattr(os, op):
                monkeypatch.setattr(os, op, self._fd_op(op, getattr(os, op)))
        for op in ("replace", "rename", "truncate"):
            monkeypatch.setattr(os, op, self._path_op(op, getattr(os, op)))

    def name_of(self, path) -> str | None:
        """The path's name inside the directory (its subdirectories too), else None."""
        try:
            p = Path(os.path.abspath(path))
            return str(p.relative_to(self.root)) if p.is_relative_to(self.root) else None
        except (TypeError, ValueError):
            return None

    def check(self, op: str, name: str, grow: int = 0) -> int:
        """Before ``op`` on ``name`` that would add ``grow`` bytes to the disk: the bytes that
        may be added (fewer: the disk is full); raise to fail the operation."""
        return grow

    def _fd_name(self, fd: int) -> str | None:
        try:
            return self.name_of(os.readlink(f"/proc/self/fd/{fd}"))
        except OSError:
            return None

    def _fd_op(self, op: str, real: Callable) -> Callable:
        def wrapped(fd, *args):
            name = self._fd_name(fd)
            if name is not None:
                grow = 0
                if op == "posix_fallocate":
                    offset, length = args
                    grow = max(0, offset + length - os.fstat(fd).st_size)
                if self.check(op, name, grow) < grow:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return real(fd, *args)

        return wrapped

    def _path_op(self, op: str, real: Callable) -> Callable:
        def wrapped(path, *args, **kw):
            name = self.name_of(path)
            if name is not None:
                self.check(op, name)
            return real(path, *args, **kw)

        return wrapped

    def used(self) -> int:
        return sum(p.stat().st_size for p in self.root.rglob("*") if p.is_file())


class _File:
    """A file of the directory: each operation passes the layer's check first."""

    def __init__(self, layer: DiskLayer, inner, name: str) -> None:
        self._layer, self._inner, self._name = layer, inner, name

    def write(self, data):
        inner, layer = self._inner, self._layer
        if not layer.write_through:
            layer.check("write", self._name)
            return inner.write(data)
        raw = data.encode() if isinstance(data, str) else bytes(data)
        inner.flush()
        grow = max(0, inner.tell() + len(raw) - os.fstat(inner.fileno()).st_size)
        allowed = layer.check("write", self._name, grow)
        if allowed < grow:  # what fits is written: the line in progress is torn
            part = raw[: len(raw) - (grow - allowed)]
            inner.write(part.decode(errors="ignore") if isinstance(data, str) else part)
            inner.flush()
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        n = inner.write(data)
        inner.flush()
        return n

    def flush(self) -> None:
        self._layer.check("flush", self._name)
        self._inner.flush()

    def close(self) -> None:
        try:
            if not self._inner.closed:
                self._layer.check("close", self._name)
        finally:
            self._inner.close()  # as a real close: the descriptor goes even if it fails

    def __getattr__(self, name: str):
        return getattr(self._inner, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class SmallDisk(DiskLayer):
    """``capacity`` bytes for the directory's files (module docstring)."""

    def __init__(self, monkeypatch, root: Path, capacity: int) -> None:
        super().__init__(monkeypatch, root, write_through=True)
        self.capacity = capacity
        self.full = False  # a write or allocation was refused

    def check(self, op: str, name: str, grow: int = 0) -> int:
        if grow <= 0:
            return grow
        free = max(0, self.capacity - self.used())
        if grow > free:
            self.full = True
        return min(grow, free)


class FailsOnce(DiskLayer):
    """One operation fails while ``armed()`` (module docstring)."""

    def __init__(
        self,
        monkeypatch,
        root: Path,
        armed: Callable[[], bool],
        at: tuple[str, str] | None = None,
        err: int = errno.ENOSPC,
    ) -> None:
        super().__init__(monkeypatch, root)
        self.armed, self.at, self.err = armed, at, err
        self.points: list[tuple[str, str]] = []
        self.fired = False

    def check(self, op: str, name: str, grow: int = 0) -> int:
        if self.armed():
            self.points.append((op, name))
            if not self.fired and (op, name) == self.at:
                self.fired = True
                raise OSError(self.err, os.strerror(self.err))
        return grow
