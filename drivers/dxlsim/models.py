"""Dynamixel X-series servo models: control tables, ranges, motor figures.

A :class:`ServoModel` is a frozen record: the model's control table as a tuple of
:class:`Field` (address, size, access, default, own range), the figures the motion model
needs (no-load speed, nominal voltage, current unit, lag) and the firmware thresholds for
Fast Sync/Bulk Read and Control Table Backup. The e-Manual's tables themselves, with the
page each model follows, are data in :mod:`drivers.dxlsim.model_data`; this module builds
the models from them (:data:`MODELS`) and looks them up (:func:`get_model`). Field names
are snake_case of the e-Manual names (``"Goal Position"`` -> ``goal_position``); lookups
also accept the e-Manual spelling.

Units used throughout the emulator (e-Manual):

- position: pulse, 4096 per revolution;
- velocity: 0.229 rev/min = :data:`PULSE_PER_S_PER_VELOCITY_UNIT` pulse/s;
- profile acceleration: 214.577 rev/min² = :data:`PULSE_PER_S2_PER_ACCEL_UNIT` pulse/s².
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import cached_property
from typing import TypeVar

# Protocol and control-table facts shared with the host-side driver live in one place.
import drivers.protocol2.control_table as _ct
from drivers.protocol2.ids import format_ids, parse_ids

from .model_data import (
    ALIASES,
    BACKUP_MIN_FIRMWARE,
    GOAL_RANGE_FROM,
    MODEL_DATA,
    X_TABLE,
    Row,
)
from .model_spec import ModelSpec

T = TypeVar("T")

PULSES_PER_REV = 4096
#: Present/Goal/Profile Velocity unit, rev/min.
VELOCITY_UNIT_RPM = 0.229
#: Profile Acceleration unit, rev/min².
ACCEL_UNIT_RPM2 = 214.577
#: One velocity unit in pulse/s (0.229 rev/min × 4096 / 60 ≈ 15.633).
PULSE_PER_S_PER_VELOCITY_UNIT = VELOCITY_UNIT_RPM * PULSES_PER_REV / 60.0
#: One acceleration unit in pulse/s² (214.577 rev/min² × 4096 / 3600 ≈ 244.14).
PULSE_PER_S2_PER_ACCEL_UNIT = ACCEL_UNIT_RPM2 * PULSES_PER_REV / 3600.0
#: Addresses below this are EEPROM: write-locked while Torque Enable is 1.
EEPROM_END = _ct.EEPROM_END
#: Baud Rate (addr 8) index -> bits per second. A model accepts indices 0..field.hi.
BAUD_RATES: tuple[int, ...] = tuple(_ct.BAUD_RATES[i] for i in sorted(_ct.BAUD_RATES))
PWM_FULL_SCALE = 885  # Goal/Present PWM unit is 0.113 %, so 885 is 100 % duty


@dataclass(frozen=True)
class Field:
    """One control-table item.

    ``lo``/``hi`` is the field's *own* range: a write outside it is a Data Range Error.
    Limits that depend on other fields (Goal Position within the position limits, Goal
    Velocity within Velocity Limit, ...) are checked by the servo (Data Limit Error).
    ``choices``, when not empty, lists the only accepted values (Operating Mode).
    Values are little-endian, two's complement when ``signed``.
    """

    addr: int
    size: int  # bytes: 1, 2 or 4
    name: str
    access: str  # "R" or "RW"
    default: int
    lo: int
    hi: int
    signed: bool = False
    choices: tuple[int, ...] = ()

    # Computed once per field (a Write checks them on every packet); the field is frozen.
    @cached_property
    def eeprom(self) -> bool:
        """True for addresses < 64 (locked while torque is on)."""
        return self.addr < EEPROM_END

    @cached_property
    def writable(self) -> bool:
        return self.access == "RW"

    @cached_property
    def end(self) -> int:
        """First address after this field."""
        return self.addr + self.size

    def accepts(self, value: int) -> bool:
        """True when ``value`` lies in the field's own range (and choices)."""
        if self.choices:
            return value in self.choices
        return self.lo <= value <= self.hi


@dataclass(frozen=True)
class ServoModel:
    """One servo model: its control table and the figures the motion model uses.

    Motor figures are e-Manual specifications at ``nominal_voltage_v``; the inertia and
    running current are rough values that only make Present Current plausible.
    """

    name: str
    model_number: int
    firmware: int  # default firmware version (addr 6)
    fields: tuple[Field, ...]
    no_load_speed_rpm: float  # at nominal_voltage_v
    nominal_voltage_v: float
    current_unit_ma: float | None  # None: addr 126 is Present Load (0.1 % of stall)
    stall_torque_nm: float
    stall_current_a: float
    fast_read_min_firmware: int
    #: First firmware with Control Table Backup (0x20), Backup Ready, Startup Configuration
    #: and Drive Mode bit 3 (e-Manual: V45 on X430/X540, V46 on X330).
    backup_min_firmware: int = 45
    #: Axes in one case sharing one communication module (2 on the 2XL430).
    axes: int = 1
    reflected_inertia_kgm2: float = 0.01  # rotor inertia seen at the horn (× gear ratio²)
    running_current_a: float = 0.1  # friction current while turning
    lag_time_constant_s: float = 0.008  # first-order lag of the horn behind the trajectory
    in_position_pulses: int = 8  # Moving Status bit0 band around Goal Position
    ambient_temperature_c: float = 30.0

    @cached_property
    def by_addr(self) -> dict[int, Field]:
        """Fields by start address."""
        return {f.addr: f for f in self.fields}

    @cached_property
    def _by_name(self) -> dict[str, Field]:
        return {f.name: f for f in self.fields}

    @cached_property
    def indirect(self) -> dict[int, int]:
        """Indirect Data n's address -> Indirect Address n's address, from this model's own
        rows (X430/X540: 56 pairs in two blocks; X330: 20 pairs at 168-206 / 208-227)."""
        by_name = self._by_name
        return {
            f.addr: by_name[f"indirect_address_{f.name.removeprefix('indirect_data_')}"].addr
            for f in self.fields
            if f.name.startswith("indirect_data_")
        }

    @cached_property
    def byte_owner(self) -> tuple[Field | None, ...]:
        """``byte_owner[a]`` is the field covering address ``a`` (None in gaps)."""
        owner: list[Field | None] = [None] * self.table_end
        for f in self.fields:
            for a in range(f.addr, f.end):
                owner[a] = f
        return tuple(owner)

    @cached_property
    def table_end(self) -> int:
        """First address after the last defined field (662: Indirect Data 56 is at 661)."""
        return max(f.end for f in self.fields)

    @cached_property
    def baud_rates(self) -> tuple[int, ...]:
        """Supported baud rates in bps, indexed by the Baud Rate (addr 8) value."""
        return BAUD_RATES[: self.field("baud_rate").hi + 1]

    @cached_property
    def no_load_speed_pulse_s(self) -> float:
        """No-load speed at nominal voltage, pulse/s."""
        return self.no_load_speed_rpm * PULSES_PER_REV / 60.0

    def has(self, key: int | str) -> bool:
        """True when the model defines a field at this start address or with this name."""
        try:
            self.field(key)
        except KeyError:
            return False
        return True

    def field(self, key: int | str) -> Field:
        """The field starting at address ``key`` (int) or named ``key`` (str).

        Names may be snake_case or the e-Manual spelling (``"Goal Position"``).
        Raises KeyError when the model has no such field.
        """
        if isinstance(key, int):
            found = self.by_addr.get(key)
        else:
            found = self._by_name.get(normalize_name(key))
        if found is None:
            raise KeyError(f"{self.name} has no control-table field {key!r}")
        return found

    def field_at(self, addr: int) -> Field | None:
        """The field covering address ``addr``, or None for a gap or beyond the table."""
        if 0 <= addr < self.table_end:
            return self.byte_owner[addr]
        return None

    def baud_index(self, bps: int) -> int:
        """Baud Rate (addr 8) value for ``bps``; ValueError when the model lacks it."""
        rates = self.baud_rates
        if bps not in rates:
            raise ValueError(f"{self.name} does not support {bps} bps; choose one of {rates}")
        return rates.index(bps)

    def supports_fast_read(self, firmware: int | None = None) -> bool:
        """True when Fast Sync/Bulk Read exist on this firmware (default: the model's)."""
        fw = self.firmware if firmware is None else firmware
        return fw >= self.fast_read_min_firmware


def normalize_name(name: str) -> str:
    """``"Secondary(Shadow) ID"`` -> ``"secondary_shadow_id"``; snake_case passes through."""
    out = []
    for ch in name.strip().lower():
        out.append(ch if ch.isalnum() else "_")
    return "_".join(part for part in "".join(out).split("_") if part)


# --- building a model from the data ---------------------------------------------------
#: Firmware a model reports by default (addr 6): every model here has Fast Sync Read,
#: Control Table Backup and Drive Mode bit 3 on it.
DEFAULT_FIRMWARE = 46


def _build(name: str, data: ModelSpec) -> ServoModel:
    """Apply one model's differences to the shared table (the only code for the data)."""
    firmware = data.get("firmware", DEFAULT_FIRMWARE)
    rows = {row[2]: row for row in X_TABLE if row[2] not in data.get("drop", ())}
    for row in data.get("add", ()):
        rows[row[2]] = row
    for fname, (default, lo, hi) in data["table"].items():
        rows[fname] = _with(rows[fname], default, lo, hi)
    for fname, default in (("model_number", data["model_number"]), ("firmware_version", firmware)):
        rows[fname] = _with(rows[fname], default, rows[fname][5], rows[fname][6])
    for goal, limit in GOAL_RANGE_FROM.items():
        if goal in rows:
            hi = rows[limit][6]
            rows[goal] = _with(rows[goal], rows[goal][4], -hi, hi)
    choices = {"operating_mode": tuple(data["modes"]), **data.get("choices", {})}
    fields = tuple(Field(*r, choices=choices.get(r[2], ())) for r in sorted(rows.values()))
    family = _ct.series(name)
    return ServoModel(
        name=name,
        model_number=data["model_number"],
        firmware=firmware,
        fields=fields,
        no_load_speed_rpm=data["no_load_speed_rpm"],
        nominal_voltage_v=data["nominal_voltage_v"],
        current_unit_ma=data["current_unit_ma"],
        stall_torque_nm=data["stall_torque_nm"],
        stall_current_a=data["stall_current_a"],
        fast_read_min_firmware=_ct.FAST_READ_MIN_FIRMWARE[family],
        backup_min_firmware=BACKUP_MIN_FIRMWARE[family],
        axes=data.get("axes", ServoModel.axes),
        reflected_inertia_kgm2=data["reflected_inertia_kgm2"],
        running_current_a=data["running_current_a"],
    )


def _with(row: Row, default: int, lo: int, hi: int) -> Row:
    """``row`` with its default and range replaced."""
    addr, size, fname, access, _, _, _, signed = row
    return (addr, size, fname, access, default, lo, hi, signed)


#: All known models by name.
MODELS: dict[str, ServoModel] = {name: _build(name, data) for name, data in MODEL_DATA.items()}


def get_model(name_or_number: str | int | ServoModel) -> ServoModel:
    """The model called ``name_or_number`` (case-insensitive; "-T"/"-R" suffix allowed)
    or with that model number. Raises ValueError listing the known models."""
    if isinstance(name_or_number, ServoModel):
        return name_or_number
    key = name_or_number
    if isinstance(key, str) and key.strip().isdigit():
        key = int(key)
    if isinstance(key, int) and not isinstance(key, bool):
        for m in MODELS.values():
            if m.model_number == key:
                return m
    elif isinstance(key, str):
        wanted = key.strip().upper()
        for suffix in ("-T", "-R"):
            if wanted.endswith(suffix) and wanted[: -len(suffix)] in MODELS:
                wanted = wanted[: -len(suffix)]
        wanted = ALIASES.get(wanted, wanted)
        if wanted in MODELS:
            return MODELS[wanted]
    close = difflib.get_close_matches(str(name_or_number).strip().upper(), [*MODELS, *ALIASES], 1)
    hint = f"did you mean {close[0]}? " if close else ""
    raise ValueError(
        f"unknown servo model {name_or_number!r}; {hint}known: {', '.join(MODELS)} "
        "(or their Model Numbers)"
    )


def by_id(text: str, ids: Iterable[int], lookup: Callable[[str], T], example: str) -> dict[int, T]:
    """ID -> whatever ``lookup`` makes of each model name in a ``model`` spec: a model for all
    and/or ``IDS:MODEL`` items, comma separated. Raises ValueError (one line) on an unknown
    model (``lookup``'s), an ID not on the bus or named twice, or an ID left without a model."""
    ids = tuple(ids)
    default: tuple[str, T] | None = None
    named: dict[int, T] = {}
    for item in str(text).split(","):
        where, sep, name = item.strip().rpartition(":")
        found = lookup(name.strip())
        if not sep:
            if default is not None:
                raise ValueError(f"two models for all IDs: {default[0]} and {name.strip()}")
            default = (name.strip(), found)
            continue
        for i in parse_ids(where):
            if i not in ids:
                raise ValueError(
                    f"ID {i} ({item.strip()}) is not on the bus (ids={format_ids(ids)})"
                )
            if i in named:
                raise ValueError(f"ID {i} is given two models")
            named[i] = found
    missing = [i for i in ids if i not in named and default is None]
    if missing:
        raise ValueError(f"no model for ID {format_ids(missing)}; add one for all, e.g. {example}")
    return {i: named[i] if default is None else named.get(i, default[1]) for i in ids}


def models_by_id(text: str, ids: Iterable[int]) -> dict[int, ServoModel]:
    """ID -> model for every ID on a bus, from the ``model`` key of a ``dxlsim://`` URL or
    ``hilsim emulate --model``. ``text`` is a model for all
    (``XM430-W350``) and/or ``IDS:MODEL`` items (``1-2:2XL430-W250,3:XM540-W270``), comma
    separated; a 2XL430-W250's axes are taken two by two in ID order, so their count is even.
    Raises ValueError (one line) as :func:`by_id` does, or on an odd number of dual-axis IDs."""
    models = by_id(text, ids, get_model, "XM430-W350")
    dual = [i for i in sorted(models) if models[i].axes == 2]
    if len(dual) % 2:
        raise ValueError(
            f"a 2XL430-W250 has two axes, each with its own ID: give it an even number of IDs "
            f"(got {format_ids(dual)}; its axes are paired in ID order)"
        )
    return models


def format_models(models: dict[int, ServoModel]) -> str:
    """The normal form of the ``model`` key: the most common model for all, then
    ``IDS:MODEL`` for the others (first-seen order)."""
    names = [m.name for m in models.values()]
    common = max(dict.fromkeys(names), key=names.count)
    others: dict[str, list[int]] = {}
    for i, m in models.items():
        if m.name != common:
            others.setdefault(m.name, []).append(i)
    return ",".join([common, *(f"{format_ids(ids)}:{name}" for name, ids in others.items())])
