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
from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    from numpy.typing import NDArray

#: the struct code of each dtype :class:`Packed` views
_CODES = {"float64": "d", "uint8": "B", "int8": "b"}


class Put(Protocol):
    """``put(*values)``: one value per element, in order."""

    def __call__(self, *values: float) -> None: ...


def packer(arr: NDArray[np.generic]) -> Put | None:
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
    return partial(struct.Struct(f"{arr.size}{code}").pack_into, arr.data, 0)  # arr.data: a view


class Packed:
    """``arr`` read (:attr:`tolist`) and written (:attr:`put`) as described above; with
    ``n``, an array of another size takes numpy's ways (and its errors)."""

    __slots__ = ("arr", "n", "put", "tolist")

    def __init__(self, arr: NDArray[np.generic] | None = None, n: int | None = None) -> None:
        self.arr, self.n = arr, n
        pack = None if arr is None or (n is not None and arr.size != n) else packer(arr)
        if pack is None or arr is None:  # (a packer implies an array)
            self.tolist: Callable[[], list[float]] = getattr(arr, "tolist", list)
            self.put: Put = self._assign
        else:
            # typeshed types memoryview.tolist() as list[int] whatever the format ("d": floats)
            self.tolist = arr.data.tolist  # type: ignore[assignment]
            self.put = pack

    def _assign(self, *values: float) -> None:
        arr = self.arr
        if arr is None:
            raise TypeError("Packed(): no array to write into")
        arr[:] = values

    def of(self, arr: NDArray[np.generic], n: int | None = None) -> Packed:
        """This view if it is of ``arr``, else a new one (the caller keeps it)."""
        return self if self.arr is arr else Packed(arr, n)

    def __reduce__(self) -> tuple[type[Packed], tuple[NDArray[np.generic] | None, int | None]]:
        return (Packed, (self.arr, self.n))  # a copy views its copied array (not a memoryview)
