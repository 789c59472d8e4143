"""The ``model`` key for Protocol 1.0-framed servos, and the one-protocol-per-bus rule.

The grammar is the X-series one (:func:`drivers.dxlsim.models.models_by_id`): a model for all,
then ``IDS:MODEL`` for the IDs that differ. :func:`bus_protocol` says which emulator a spec
needs and refuses, in one line, a spec that mixes Protocol 2.0 models with Protocol 1.0 ones,
or Dynamixel P1 models with Feetech ones (one protocol per bus, as on hardware).
"""

from __future__ import annotations

from collections.abc import Iterable

from drivers.dxlsim.models import by_id, get_model
from drivers.protocol1.control_table import TABLES, ControlTable, is_protocol1_model, table_for
from drivers.protocol2.ids import format_ids


def _names(text: str) -> list[str]:
    return [item.strip().rpartition(":")[2].strip() for item in str(text).split(",")]


def _known(name: str) -> None:
    """ValueError listing every model of both protocols if ``name`` is neither's."""
    try:
        get_model(name)
    except ValueError as exc:
        raise ValueError(f"{exc}; Protocol 1.0: {', '.join(TABLES)}") from None


def bus_protocol(text: str) -> str:
    """``"2.0"`` (X series), ``"dynamixel-p1"`` or ``"feetech"`` for a ``model`` spec;
    ValueError for a mix."""
    names = [n for n in _names(text) if n]
    p1 = {n: table_for(n).family.protocol for n in names if is_protocol1_model(n)}
    if not p1:
        for n in names:
            _known(n)
        return "2.0"
    others = [n for n in names if n not in p1]
    for n in others:
        _known(n)
    if others:
        raise ValueError(
            f"one protocol per bus: {others[0]} speaks Protocol 2.0, {next(iter(p1))} "
            f"Protocol 1.0 ({p1[next(iter(p1))]})"
        )
    kinds = sorted(set(p1.values()))
    if len(kinds) > 1:
        first = {k: next(n for n, v in p1.items() if v == k) for k in kinds}
        raise ValueError(
            "one protocol per bus: " + " and ".join(f"{first[k]} ({k})" for k in kinds)
        )
    return kinds[0]


def tables_by_id(text: str, ids: Iterable[int]) -> dict[int, ControlTable]:
    """ID -> control table for a Protocol 1.0 ``model`` spec; ValueError (one line) on an
    unknown model, an ID not on the bus or named twice, or an ID left without a model."""
    return by_id(text, ids, table_for, "STS3215")


def format_tables(tables: dict[int, ControlTable]) -> str:
    """The normal form: the most common model for all, then ``IDS:MODEL`` for the others."""
    names = [t.model for t in tables.values()]
    common = max(dict.fromkeys(names), key=names.count)
    others: dict[str, list[int]] = {}
    for i, t in tables.items():
        if t.model != common:
            others.setdefault(t.model, []).append(i)
    return ",".join([common, *(f"{format_ids(ids)}:{name}" for name, ids in others.items())])
