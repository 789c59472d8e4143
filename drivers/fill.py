"""Python numbers in and out of numpy arrays on the tick's path, without numpy's per-call
machinery.

``arr[:] = values`` from a list runs numpy's general conversion (find the list's dtype and
shape, build a temporary array, cast, copy), and even ``arr.tolist()`` parses its
arguments: microseconds for four values, and enough code to push the rest of the tick out
of the instruction cache, which on a busy host costs the tick more than the work itself.
:class:`Packed` reads an array through a memoryview (``tolist``: the same Python numbers)
and writes it with a :mod:`struct` packer on that memoryview (``put(*values)``: the same
doubles or bytes as ``arr[:] = values``), each one C call. Arrays it cannot view that way
(strided, read-only, another dtype or size) take numpy's own ``tolist`` and assignment.

Who is handed a different array each call keeps one :class:`Packed` and makes a new one
when ``view.arr is not arr`` (:meth:`Packed.of`).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from functools import partial

import numpy as np

#: the struct code of each dtype :class:`Packed` views
_CODES = {"float64": "d", "uint8": "B", "int8": "b"}


def packer(arr: np.ndarray) -> Callable[..., None] | None:
    """``put(*values)`` writing ``arr.size`` values into ``arr`` (1-D, C-contiguous, writable,
    native float64, uint8 or int8), or None for any other array."""
    if not (
        isinstance(arr, np.ndarray)
        and arr.ndim == 1
        and arr.flags.c_contiguous
        and arr.flags.writeable
        and arr.dtype.isnative
    ):
        return None
    code = _CODES.get(arr.dtype.name)
    if code is None:
        return None
    return partial(struct.Struct(f"{arr.size}{code}").pack_into, memoryview(arr), 0)


class Packed:
    """``arr`` read (:attr:`tolist`) and written (:attr:`put`) as described above; with
    ``n``, an array of another size takes numpy's ways (and its errors)."""

    __slots__ = ("arr", "n", "put", "tolist")

    def __init__(self, arr: np.ndarray | None = None, n: int | None = None) -> None:
        self.arr, self.n = arr, n
        pack = None if arr is None or (n is not None and arr.size != n) else packer(arr)
        if pack is None:
            self.tolist: Callable[[], list] = getattr(arr, "tolist", list)
            self.put: Callable[..., None] = self._assign
        else:
            self.tolist = memoryview(arr).tolist
            self.put = pack

    def _assign(self, *values: float) -> None:
        self.arr[:] = values  # type: ignore[index]

    def of(self, arr: np.ndarray, n: int | None = None) -> Packed:
        """This view if it is of ``arr``, else a new one (the caller keeps it)."""
        return self if self.arr is arr else Packed(arr, n)

    def __reduce__(self) -> tuple:
        return (Packed, (self.arr, self.n))  # a copy views its copied array (not a memoryview)
