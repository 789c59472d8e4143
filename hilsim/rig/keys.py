"""What a rig-file key is: :class:`Key`, carried in a dataclass field's metadata by :func:`rig_key`.

One owner per fact: a key's TOML name, default, unit, bounds, meaning and example are written once,
on the field of :mod:`hilsim.rig.model` that receives it. The loader (:mod:`hilsim.rig.load`) takes
defaults, bounds and the allowed-key lists from there, and so does the reference generator
(:mod:`hilsim.rig.doc`, which writes ``docs/rig.md``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


#: the default of a key that must be given
REQUIRED: Any = _Required()

#: how a key is read: a finite float, an int, one of an enum's values, a string, a table, a list,
#: true or false
KINDS = ("number", "integer", "choice", "text", "table", "list", "bool")


@dataclass(frozen=True)
class Key:
    """One rig-file key.

    Attributes:
        kind: one of :data:`KINDS`.
        doc: what the key means (Markdown, one paragraph).
        toml: the key's name in the file; "" when it is the field's name.
        unit: unit in the file (``deg``, ``Hz``, ``ms`` ...); "" for none.
        default: the default in the file's unit; :data:`REQUIRED` when the key must be given.
        default_doc: said instead of the default when it is not a plain value (e.g. "the file's
            stem").
        bounds: keyword arguments of the loader's ``number``/``integer`` (``positive``,
            ``nonnegative``, ``at_least``, ``at_most``, ``lo``, ``hi``, ``why``, ``why_lo``);
            the loader applies them and the reference states them.
        allowed: what else is allowed or refused, in words (checks the bounds cannot state).
        example: a value for the reference's example; None: the default.
        convert: file value -> field value (degrees to radians, ms to s); None: the same.
    """

    kind: str
    doc: str
    toml: str = ""
    unit: str = ""
    default: Any = REQUIRED
    default_doc: str = ""
    bounds: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    allowed: str = ""
    example: Any = None
    convert: Callable[[Any], Any] | None = None

    @property
    def required(self) -> bool:
        """The file must give it (no default, and none said in words)."""
        return self.default is REQUIRED and not self.default_doc

    def to_field(self, value: Any) -> Any:
        return value if self.convert is None or value is None else self.convert(value)


def rig_key(
    kind: str, doc: str, *, default: Any = REQUIRED, compare: bool = True, **spec: Any
) -> Any:
    """A dataclass field read from the rig file (see :class:`Key`); its dataclass default is the
    file default passed through ``convert``. ``compare=False`` leaves it out of ``==`` and the
    hash."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    key = Key(kind, doc, default=default, **spec)
    meta = {"rig": key}
    if default is REQUIRED:
        return dataclasses.field(metadata=meta, compare=compare)
    if isinstance(default, dict | list):
        raise TypeError("a mutable default needs a factory")
    return dataclasses.field(default=key.to_field(default), metadata=meta, compare=compare)


def key_fields(cls: type) -> tuple[tuple[str, Key], ...]:
    """``(field name, Key)`` for every field of ``cls`` read from the rig file, in field order."""
    return tuple(
        (f.name, f.metadata["rig"]) for f in dataclasses.fields(cls) if "rig" in f.metadata
    )


def key_of(cls: type, field_name: str) -> Key:
    """The :class:`Key` on ``cls.field_name``."""
    return dict(key_fields(cls))[field_name]


def toml_name(field_name: str, key: Key) -> str:
    return key.toml or field_name


def toml_keys(cls: type) -> tuple[str, ...]:
    """The keys a table read into ``cls`` allows, in field order."""
    return tuple(toml_name(name, key) for name, key in key_fields(cls))


def number_text(x: float) -> str:
    """``1,000,000``, ``0.01``, ``-100``: a bound as the reference writes it."""
    if float(x).is_integer() and abs(x) < 1e15:
        return f"{int(x):,}"
    return f"{x:g}"


def bounds_text(key: Key) -> str:
    """The key's bounds in words, e.g. ``> 0, <= 255`` or ``1 .. 99``."""
    b = key.bounds
    parts = []
    if key.kind == "integer":
        lo, hi = b.get("lo"), b.get("hi")
        if lo is not None and hi is not None:
            parts.append(f"{number_text(lo)} .. {number_text(hi)}")
        elif lo is not None:
            parts.append(f">= {number_text(lo)}")
    at_least = b.get("at_least")
    if at_least is not None:
        parts.append(f">= {number_text(at_least)}")
    if b.get("positive") and (at_least is None or at_least <= 0):
        parts.append("> 0")
    if b.get("nonnegative") and (at_least is None or at_least < 0):
        parts.append(">= 0")
    if b.get("at_most") is not None:
        parts.append(f"<= {number_text(b['at_most'])}")
    return ", ".join(parts)


def allowed_text(key: Key) -> str:
    """Everything the reference says is allowed: the enum's values, the bounds and ``allowed``."""
    parts = []
    if key.kind == "choice":
        parts.append(" | ".join(f'`"{e.value}"`' for e in type(key.default)))
    if bounds := bounds_text(key):
        parts.append(bounds)
    if key.allowed:
        parts.append(key.allowed)
    return "; ".join(parts)


def default_value(key: Key) -> Any:
    """The default as it is written in the file (an enum's value, not the member)."""
    return key.default.value if isinstance(key.default, StrEnum) else key.default
