"""Protocol 2.0's CRC-16: polynomial 0x8005, initial value 0, MSB first, not reflected, over
the header through the last (stuffed) parameter byte. One table, shared by the emulator's codec
and the driver's Fast Sync Read parser (the SDK's own ``updateCRC`` rebuilds its table on every
call: 13 µs for one 4-servo packet).

:func:`crc16` takes two bytes per step through a 65536-entry table (built once, a few
ms): the register after two bytes depends only on ``crc ^ (b0 << 8 | b1)``, so one lookup does
the work of two rounds of :data:`CRC_TABLE`. The words are read in the machine's byte order
(``memoryview.cast("H")``), so the table is indexed and the register kept in that order too."""

from __future__ import annotations

import struct
import sys
from array import array
from collections.abc import Callable, Iterable
from functools import cache

#: what the CRC reads words from
Buffer = bytes | bytearray | memoryview


def _make_table() -> tuple[int, ...]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


#: the CRC of each high byte: crc = ((crc << 8) ^ CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
CRC_TABLE: tuple[int, ...] = _make_table()

_LITTLE = sys.byteorder == "little"
#: below this many bytes the per-byte loop is cheaper than setting up the word view
_WORD_MIN = 8
#: up to this many bytes the words come from a Struct kept per length (a packet's size)
_STRUCT_MAX = 1100


def _swap(x: int) -> int:
    return ((x & 0xFF) << 8) | (x >> 8)


def make_word_table(little: bool) -> list[int]:
    """``W[v]``: the register after the two bytes whose word (little- or big-endian, as
    ``little`` says) is ``v ^ r``, where ``r`` is the register before them in that order.

    Two rounds of the byte loop from register ``(h, l)`` over bytes ``b0 b1``: with
    ``a = h ^ b0`` the first gives ``(l ^ T[a] >> 8, T[a] & 0xFF)``, the second
    ``((T[a] & 0xFF) << 8) ^ T[b]`` with ``b = l ^ b1 ^ T[a] >> 8``: a function of ``a`` and
    ``l ^ b1`` alone, i.e. of ``crc ^ (b0 << 8 | b1)``. The CRC is linear (``T[i ^ j] =
    T[i] ^ T[j]``), so ``W[hi << 8 | lo] = W[hi << 8] ^ W[lo]``: two rows of 256 suffice,
    and the 65536 entries are one XOR of two byte strings."""
    t = CRC_TABLE
    if little:  # v = a | (l ^ b1) << 8, the result byte-swapped
        low = [_swap(t[c >> 8]) ^ (c & 0xFF) for c in t]  # W[a]
        high = [_swap(c) for c in t]  # W[b << 8]
    else:  # v = a << 8 | (l ^ b1), the result as it is
        high = [((c & 0xFF) << 8) ^ t[c >> 8] for c in t]  # W[a << 8]
        low = list(t)  # W[b]
    order = sys.byteorder
    lows = int.from_bytes(array("H", low).tobytes() * 256, order)
    highs = int.from_bytes(b"".join(array("H", (h,)).tobytes() * 256 for h in high), order)
    words = array("H")
    words.frombytes((lows ^ highs).to_bytes(2 * 65536, order))
    return words.tolist()


@cache
def big_endian_word_table() -> array[int]:
    """:func:`make_word_table` for words read big-endian (``struct`` ``">H"``), as an array
    of 16-bit values: the driver's tick reads its packets that way, and in a tick, whose
    code and data crowd the caches, an array costs fewer misses than a list of 65536 ints."""
    return array("H", make_word_table(little=False))


_WORDS: list[int] = []  # the word table for this machine, see word_table()


def word_table() -> list[int]:
    """This machine's word table, built on the first call (a few ms). The emulator calls it
    when a bus is built, so no packet ever waits for it (a real-time pty server would)."""
    if not _WORDS:
        _WORDS[:] = make_word_table(_LITTLE)
    return _WORDS


def crc16(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16 of ``data`` continuing from ``crc``."""
    table = CRC_TABLE
    n = len(data)
    if n >= _WORD_MIN:
        cls = type(data)
        view = data if cls is bytes or cls is bytearray else _byte_view(data)
        if view is not None:
            words = _WORDS or word_table()
            crc &= 0xFFFF  # as the byte loop: only the register's 16 bits count
            r = ((crc & 0xFF) << 8) | (crc >> 8) if _LITTLE else crc
            it: Iterable[int]
            if _LITTLE and n <= _STRUCT_MAX:  # the words by one unpack (see crc16_blocks)
                it = (_BODY_WORDS.get(n) or _body_words(n))(view)
            else:
                it = memoryview(view)[: n & ~1].cast("H")
            for w in it:
                r = words[r ^ w]
            crc = ((r & 0xFF) << 8) | (r >> 8) if _LITTLE else r
            if n & 1:
                crc = ((crc << 8) ^ table[((crc >> 8) ^ view[n - 1]) & 0xFF]) & 0xFFFF
            return crc
    for byte in data:
        crc = ((crc << 8) ^ table[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def _byte_view(data: object) -> memoryview | None:
    """A flat view of ``data``'s bytes, or None when it is no such buffer (a list of ints, a
    view of other items or with gaps): those take the byte loop, as they always did."""
    try:
        # any object may come here; memoryview's TypeError is the test (3.11 has no Buffer type)
        view = memoryview(data)  # type: ignore[arg-type]
    except TypeError:
        return None
    return view if view.format == "B" and view.c_contiguous else None


def crc16_blocks(bodies: list[bytes], crc: int = 0) -> list[int]:
    """The CRC of each block of a Fast Sync/Bulk Read reply: each body's CRC runs on from
    ``crc`` over everything before it, including the earlier blocks' CRCs, which the line
    carries after their bodies low byte first. Equal to::

        for body in bodies:
            crc = crc16(body, crc)
            out.append(crc)
            crc = crc16(bytes((crc & 0xFF, crc >> 8)), crc)

    In words: on a little-endian machine a CRC's own two bytes, read as a word, are the
    CRC itself, and the register is kept byte-swapped, so it is one lookup. A body's words
    come out of one ``struct`` unpack (a Struct per length, made once); an odd body's last
    byte is one step of the byte table, byte-swapped too."""
    out: list[int] = []
    if not _LITTLE:
        for body in bodies:
            crc = crc16(body, crc)
            out.append(crc)
            crc = crc16(bytes((crc & 0xFF, crc >> 8)), crc)
        return out
    words = _WORDS or word_table()
    swapped = _SWAPPED_TABLE
    crc &= 0xFFFF
    r = ((crc & 0xFF) << 8) | (crc >> 8)
    for body in bodies:
        n = len(body)
        unpack = _BODY_WORDS.get(n) or _body_words(n)
        for w in unpack(body):
            r = words[r ^ w]
        if n & 1:  # the byte loop's step, on the swapped register
            r = (r >> 8) ^ swapped[(r ^ body[n - 1]) & 0xFF]
        crc = ((r & 0xFF) << 8) | (r >> 8)
        out.append(crc)
        r = words[r ^ crc]
    return out


#: :data:`CRC_TABLE` with each entry's bytes swapped: one byte step on a swapped register
#: ``r`` is ``(r >> 8) ^ _SWAPPED_TABLE[(r ^ byte) & 0xFF]``
_SWAPPED_TABLE: tuple[int, ...] = tuple(map(_swap, CRC_TABLE))
#: body length -> the unpacker of its whole little-endian words (see crc16_blocks)
_BODY_WORDS: dict[int, Callable[[Buffer], tuple[int, ...]]] = {}


def _body_words(n: int) -> Callable[[Buffer], tuple[int, ...]]:
    unpack = _BODY_WORDS[n] = struct.Struct(f"<{n // 2}H").unpack_from
    return unpack
