"""Servo ID lists as people write them: ``1-4``, ``1,3,5``, ``1-3,7``."""

from __future__ import annotations

from collections.abc import Iterable


def parse_ids(text: str) -> list[int]:
    """Parse an ID list; IDs must be 0..252 and unique. Raises ValueError naming the problem."""
    ids: list[int] = []
    for part in filter(None, (p.strip() for p in str(text).split(","))):
        lo, dash, hi = part.partition("-")
        try:
            first = int(lo)
            last = int(hi) if dash else first
        except ValueError:
            raise ValueError(
                f"bad servo ID {part!r} in {text!r}: use forms like 1-4 or 1,3,5"
            ) from None
        if last < first:
            raise ValueError(f"bad ID range {part!r}: {last} < {first}")
        ids.extend(range(first, last + 1))
    if not ids:
        raise ValueError(f"no servo IDs in {text!r}")
    bad = [i for i in ids if not 0 <= i <= 252]
    if bad:
        shown = ", ".join(map(str, bad[:5])) + (f" … ({len(bad)} in all)" if len(bad) > 5 else "")
        raise ValueError(f"servo IDs must be 0..252, got {shown}")
    if len(set(ids)) != len(ids):
        raise ValueError(f"repeated servo ID in {text!r}")
    return ids


def format_ids(ids: Iterable[int]) -> str:
    """``(1, 2, 3, 5)`` -> ``"1-3,5"`` (order kept)."""
    runs: list[list[int]] = []
    for i in ids:
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return ",".join(f"{a}-{b}" if b > a else str(a) for a, b in runs)
