"""Typed access to one TOML table with file/key-path error messages: :class:`Reader`, and
:func:`read_key`, which reads a dataclass field's key with the default and bounds its
:class:`~hilsim.rig.keys.Key` gives."""

from __future__ import annotations

import difflib
import math
from enum import StrEnum
from types import EllipsisType
from typing import TYPE_CHECKING, Any, TypeVar

from hilsim.rig.keys import REQUIRED, key_fields, key_of, toml_keys, toml_name
from hilsim.rig.model import RigError

if TYPE_CHECKING:
    from pathlib import Path

#: a default: a number, or None for a key that may be left out (then the value may be None)
_Number = TypeVar("_Number", float, None)
_Integer = TypeVar("_Integer", int, None)
_T = TypeVar("_T")


class Reader:
    """Typed access to one table of the TOML with file/key-path error messages."""

    def __init__(self, path: Path, table: dict[str, Any], where: str) -> None:
        self.path, self.table, self.where = path, table, where
        self.used: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.where}.{name}" if self.where else name

    def fail(self, name: str, message: str) -> RigError:
        return RigError(f"{self.path}: {self.key(name)}: {message}")

    def get(
        self, name: str, kind: type | tuple[type, ...], default: Any = ..., *, allowed: str = ""
    ) -> Any:
        self.used.add(name)
        if name not in self.table:
            if default is ...:
                typo = difflib.get_close_matches(name, [str(k) for k in self.table], 1, 0.75)
                raise RigError(
                    f"{self.path}: missing {self.key(name)}"
                    + (f" ({allowed})" if allowed else "")
                    + (f"; the table has {typo[0]!r}: a typo?" if typo else "")
                )
            return default
        value = self.table[name]
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
            expected = (
                kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
            )
            raise self.fail(
                name, f"expected {expected}, got {value!r}" + (f" ({allowed})" if allowed else "")
            )
        return value

    def number(
        self,
        name: str,
        default: _Number | EllipsisType = ...,
        *,
        positive: bool = False,
        nonnegative: bool = False,
        at_least: float | None = None,
        at_most: float | None = None,
        why: str = "",
    ) -> float | _Number:
        """A finite float; ``at_least``/``at_most`` bound it, ``why`` is said when they refuse."""
        value: float | _Number = self.get(name, float, default)
        if value is None:
            return value
        if not math.isfinite(value):
            raise self.fail(name, f"must be a finite number, got {value!r}")
        if positive and value <= 0:
            raise self.fail(name, f"must be > 0, got {value!r}")
        if nonnegative and value < 0:
            raise self.fail(name, f"must be >= 0, got {value!r}")
        reason = f" ({why})" if why else ""
        if at_least is not None and value < at_least:
            raise self.fail(name, f"must be >= {at_least:g}{reason}, got {value!r}")
        if at_most is not None and value > at_most:
            raise self.fail(name, f"must be <= {at_most:g}{reason}, got {value!r}")
        return value

    def integer(
        self,
        name: str,
        default: _Integer | EllipsisType,
        *,
        lo: int,
        hi: int | None = None,
        why: str = "",
        why_lo: str = "",
    ) -> int | _Integer:
        """An int in lo..hi (hi None: no upper bound); ``why``/``why_lo`` explain the bounds."""
        value: int | _Integer = self.get(name, int, default)
        if value is None:
            return value
        if value < lo:
            raise self.fail(name, f"must be >= {lo}{f' ({why_lo})' if why_lo else ''}, got {value}")
        if hi is not None and value > hi:
            raise self.fail(name, f"must be <= {hi}{f' ({why})' if why else ''}, got {value}")
        return value

    def choice(self, name: str, enum: type[StrEnum], default: StrEnum) -> StrEnum:
        value = self.get(name, str, default.value)
        try:
            return enum(value)
        except ValueError:
            allowed = ", ".join(e.value for e in enum)
            raise self.fail(name, f"must be one of {allowed}; got {value!r}") from None

    def sub(self, name: str, *, required: bool = False) -> Reader:
        table = self.get(name, dict, ... if required else {})
        return Reader(self.path, table, self.key(name))

    def finish(self, allowed: tuple[str, ...] | None = None) -> None:
        unknown = sorted(set(self.table) - self.used)
        if unknown:
            names = ", ".join(allowed or sorted(self.used))
            where = self.where or "the top level"
            raise RigError(
                f"{self.path}: unknown key(s) {', '.join(unknown)} in {where}; allowed: {names}"
            )


_TYPES = {"text": str, "table": dict, "list": list, "integer": int, "bool": bool}


def read_key(r: Reader, cls: type, field_name: str, *, hint: str = "", **bounds: Any) -> Any:
    """The file's value (in the file's unit) of the key behind ``cls.field_name``: its default
    when absent, checked against its bounds (``bounds`` adds to them: limits known only now).
    ``hint`` is said when the key is missing or of the wrong type."""
    key = key_of(cls, field_name)
    name = toml_name(field_name, key)
    default = ... if key.default is REQUIRED else key.default
    bounds = {**key.bounds, **bounds}
    if key.kind == "number":
        return r.number(name, default, **bounds)
    if key.kind == "choice":
        return r.choice(name, type(key.default), key.default)
    if key.kind == "integer" and "lo" in bounds:
        return r.integer(name, default, **bounds)
    return r.get(name, _TYPES[key.kind], default, allowed=hint)


def build(cls: type[_T], values: dict[str, Any], **fixed: Any) -> _T:
    """``cls`` from file values keyed by field name (each passed through its key's ``convert``)
    and ``fixed`` field values taken as they are."""
    keys = dict(key_fields(cls))
    return cls(**{name: keys[name].to_field(v) for name, v in values.items()}, **fixed)


def read_table(r: Reader, cls: type, *, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    """Every key of ``cls`` but ``skip``, in field order: file values keyed by field name."""
    return {name: read_key(r, cls, name) for name, _ in key_fields(cls) if name not in skip}


def finish(r: Reader, cls: type) -> None:
    """Refuse keys ``cls`` does not have, listing those it has."""
    r.finish(toml_keys(cls))
