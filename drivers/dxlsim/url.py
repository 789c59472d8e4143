"""``dxlsim://`` URLs: :class:`DxlsimUrl` owns the grammar, its defaults and the bus it builds.

``dxlsim://[NAME][?key=value&...]``. A NAME registered with :func:`register_bus` opens that
bus (no keys allowed). Otherwise the keys build a new bus: ``ids``, ``model``, ``baud``,
``rdt_us``, ``turnaround_us``, ``latency_ms``, ``clock``, ``spin_us``, ``faults``, ``seed``,
``firmware``, ``trace``. Their defaults are :class:`DxlsimUrl`'s field defaults, and nowhere
else. ``str(DxlsimUrl.parse(url))`` is the normal form, which parses back to an equal URL.

One URL, one bus, while it is in use:

* every open of a URL with the same normal form gets the bus already open (:func:`acquire_bus`);
* a port re-opened (pyserial's ``close()``/``open()``, the SDK's ``setBaudRate``) keeps its bus;
* once every port on it is closed (:func:`release_bus`), the next open powers up a fresh bus;
* the host's baud rate belongs to the port, the servos' rates to the bus.

Named buses are kept until :func:`unregister_bus`. Each key, and why the rules are so:
``docs/dxlsim.md`` (the ``dxlsim://`` URL).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import threading
import urllib.parse
import weakref
from dataclasses import dataclass, field
from typing import Any, TypedDict, Unpack

from drivers.clock import DEFAULT_SPIN_S, MonotonicClock, VirtualClock
from drivers.dxlsim.bus import DxlBus
from drivers.dxlsim.dual_axis import pair_axes
from drivers.dxlsim.faults import FaultPlan, parse_fault_plan
from drivers.dxlsim.models import format_models, models_by_id
from drivers.dxlsim.p1_models import bus_protocol, format_tables, tables_by_id
from drivers.dxlsim.p1bus import P1Bus
from drivers.dxlsim.p1servo import P1Servo
from drivers.dxlsim.servo import VirtualServo
from drivers.protocol1.control_table import ControlTable
from drivers.protocol2.ids import format_ids, parse_ids
from drivers.protocol2.wire_time import DEFAULT_TURNAROUND_S

#: Any emulated bus: Protocol 2.0 (X series) or Protocol 1.0 framing (AX/MX, Feetech).
AnyBus = DxlBus | P1Bus
#: The host's line rate when a port is opened without one (bit/s).
DEFAULT_HOST_BAUD = 1_000_000
CLOCKS = ("virtual", "real")
_KEYS = (
    "ids",
    "model",
    "baud",
    "rdt_us",
    "turnaround_us",
    "latency_ms",
    "clock",
    "spin_us",
    "faults",
    "seed",
    "firmware",
    "trace",
)
#: characters left readable in a printed URL (the fault grammar's separators)
_SAFE = ",;:=|-"
_registry: dict[str, AnyBus] = {}
_lock = threading.Lock()


def register_bus(name: str, bus: AnyBus) -> str:
    """Make ``bus`` openable as ``dxlsim://NAME``; returns that URL."""
    if not name or not name.replace("-", "").replace("_", "").isalnum():
        raise ValueError(f"bus name must be letters, digits, - or _: {name!r}")
    with _lock:
        _registry[name] = bus
    return f"dxlsim://{name}"


def unregister_bus(name: str) -> None:
    with _lock:
        _registry.pop(name, None)


class UrlChanges(TypedDict, total=False):
    """The keys :meth:`DxlsimUrl.replace` changes: its fields but ``keys`` and ``source``."""

    name: str
    ids: tuple[int, ...]
    model: str
    baud: int | None
    rdt_us: float
    turnaround_us: float
    latency_ms: float
    clock: str
    spin_us: float
    faults: str
    seed: int
    firmware: int | None
    trace: bool


@dataclass(frozen=True)
class DxlsimUrl:
    """One ``dxlsim://`` URL as data: an emulated bus described by its keys, or ``name``.

    ``ids`` may be given as text (``"1-4"``). ``baud`` None means the servos run at the
    host's rate. ``keys`` (the keys the text named: printed even at their defaults) and
    ``source`` (the text itself, for error messages) do not take part in equality.
    """

    name: str = ""
    ids: tuple[int, ...] = (1,)
    model: str = "XM430-W350"
    baud: int | None = None
    rdt_us: float = 500.0
    turnaround_us: float = DEFAULT_TURNAROUND_S * 1e6
    latency_ms: float = 0.0
    clock: str = "real"
    spin_us: float = DEFAULT_SPIN_S * 1e6
    faults: str = ""
    seed: int = 0
    firmware: int | None = None
    trace: bool = False
    keys: tuple[str, ...] = field(default=(), compare=False, repr=False)
    source: str | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        ids = parse_ids(self.ids) if isinstance(self.ids, str) else tuple(self.ids)
        values: dict[str, Any] = {
            "ids": tuple(int(i) for i in ids),
            "rdt_us": float(self.rdt_us),
            "turnaround_us": float(self.turnaround_us),
            "latency_ms": float(self.latency_ms),
            "spin_us": float(self.spin_us),
            "seed": int(self.seed),
            "trace": bool(self.trace),
            "clock": str(self.clock).lower(),
            "baud": None if self.baud is None else int(self.baud),
            "firmware": None if self.firmware is None else int(self.firmware),
        }
        try:  # the normal form names each model once, in its e-Manual spelling
            values["model"] = _normal_model(self.model, values["ids"])
        except ValueError:
            values["model"] = str(self.model)  # reported by _fault_plan(), naming the key
        for key, value in values.items():
            object.__setattr__(self, key, value)
        if self.clock not in CLOCKS:
            raise ValueError(f"clock: must be 'virtual' or 'real', got {self.clock!r}")
        if self.name and (self.keys or any(getattr(self, k) != _DEFAULTS[k] for k in _KEYS)):
            raise ValueError(f"{self.source or self.name!r}: a named bus takes no ?keys")

    # --- text ----------------------------------------------------------------------------
    @classmethod
    def parse(cls, url: str) -> DxlsimUrl:
        """The URL as data. Raises ValueError naming the URL, the key, the value and what
        is allowed (one line)."""
        parts = urllib.parse.urlsplit(url)
        if parts.scheme.lower() != "dxlsim":
            raise ValueError(f"not a dxlsim:// URL: {url!r}")
        pairs = urllib.parse.parse_qsl(parts.query, keep_blank_values=True)
        query: dict[str, str] = {}
        for key, value in pairs:
            query[key] = value  # the last one wins
        name = parts.netloc + parts.path.strip("/")
        if name:
            if query:
                raise ValueError(f"{url!r}: a named bus takes no ?keys (configure it in Python)")
            return cls(name=name, source=url)
        unknown = sorted(set(query) - set(_KEYS))
        if unknown:
            raise ValueError(
                f"{url!r}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(_KEYS)}"
            )

        def bad(key: str, message: str) -> ValueError:
            return ValueError(f"{url!r}: {key}: {message}")

        def number(key: str, kind: type, allowed: str) -> Any:
            text = query[key]
            try:
                value = kind(text)
            except ValueError:
                raise bad(key, f"expected {allowed}, got {text!r}") from None
            if kind is float and not (math.isfinite(value) and value >= 0.0):
                raise bad(key, f"expected {allowed}, got {text!r}")
            return value

        values: dict[str, Any] = {}
        if "ids" in query:
            try:
                values["ids"] = tuple(parse_ids(query["ids"]))
            except ValueError as exc:
                message = str(exc)
                if len(message) > 120:  # "... got [253, 254, ...]": one line, not a screenful
                    message = message[:120] + " …]"
                raise bad("ids", message) from None
        allowed = {
            "baud": (int, "bit/s as an integer, e.g. 1000000"),
            "rdt_us": (float, "µs, a multiple of 2 in 0..508"),
            "turnaround_us": (float, "µs, a finite number >= 0"),
            "latency_ms": (float, "ms, a finite number >= 0 (0, 1, 16, ...)"),
            "spin_us": (float, "µs, a finite number >= 0"),
            "seed": (int, "an integer"),
            "firmware": (int, "an integer 0..255"),
        }
        for key, (kind, what) in allowed.items():
            if key in query:
                values[key] = number(key, kind, what)
        if "clock" in query:
            values["clock"] = query["clock"].lower()
            if values["clock"] not in CLOCKS:
                raise bad("clock", f"must be 'virtual' or 'real', got {values['clock']!r}")
        for key in ("model", "faults"):
            if key in query:
                values[key] = query[key]
        if "trace" in query:
            values["trace"] = query["trace"] not in ("0", "", "false", "no")
        keys = tuple(dict.fromkeys(key for key, _ in pairs))
        parsed = cls(**values, keys=keys, source=url)
        parsed._fault_plan()  # the model and the fault plan are known
        return parsed

    def __str__(self) -> str:
        if self.name:
            return f"dxlsim://{self.name}"
        items = []
        for key in _KEYS:
            value = getattr(self, key)
            if value is None or (key not in self.keys and value == _DEFAULTS[key]):
                continue
            items.append((key, _text(value)))
        return "dxlsim://?" + urllib.parse.urlencode(items, safe=_SAFE) if items else "dxlsim://"

    def replace(self, **changes: Unpack[UrlChanges]) -> DxlsimUrl:
        """A copy with ``changes``; the keys changed are printed even at their defaults."""
        keys = self.keys + tuple(k for k in changes if k in _KEYS and k not in self.keys)
        return dataclasses.replace(self, **changes, keys=keys, source=None)

    # --- the bus -------------------------------------------------------------------------
    def _where(self) -> str:
        return self.source if self.source is not None else str(self)

    def _bad(self, key: str, message: str) -> ValueError:
        """One line naming the URL, the key, the value and what is allowed."""
        return ValueError(f"{self._where()!r}: {key}: {message}")

    def _fault_plan(self) -> FaultPlan:
        try:
            _normal_model(self.model, self.ids)
        except ValueError as exc:
            raise self._bad("model", str(exc)) from None
        try:
            return parse_fault_plan(self.faults, seed=self.seed)
        except ValueError as exc:
            raise self._bad("faults", str(exc)) from None

    def build_bus(self, host_baud: int = DEFAULT_HOST_BAUD) -> AnyBus:
        """The bus this URL names (registered) or describes (new, host side at
        ``host_baud``). Raises ValueError saying what is wrong."""
        if self.name:
            with _lock:
                bus = _registry.get(self.name)
                known = ", ".join(sorted(_registry)) or "none registered"
            if bus is None:
                raise ValueError(f"no emulated bus named {self.name!r} ({known})")
            return bus
        faults = self._fault_plan()
        try:
            clock = (
                VirtualClock() if self.clock == "virtual" else MonotonicClock(self.spin_us / 1e6)
            )
        except ValueError as exc:
            raise self._bad("spin_us", str(exc)) from None
        t = clock.now()
        servo_baud = host_baud if self.baud is None else self.baud
        if bus_protocol(self.model) != "2.0":
            return self._build_p1(faults, clock, t, servo_baud, host_baud)
        models = models_by_id(self.model, self.ids)
        try:
            servos = [
                VirtualServo(
                    models[i],
                    i,
                    baud=servo_baud,
                    return_delay_us=self.rdt_us,
                    firmware=self.firmware,
                    t=t,
                )
                for i in self.ids
            ]
            pairs = [s for s in servos if s.model.axes == 2]
            for a, b in zip(pairs[::2], pairs[1::2], strict=True):
                pair_axes(a, b)
        except ValueError as exc:  # the model refuses the baud, the Return Delay Time or firmware
            key = next((k for k in ("baud", "rdt_us", "firmware") if k in str(exc)), "servos")
            key = "rdt_us" if "return_delay" in str(exc) else key
            key = "baud" if "bps" in str(exc) else key
            raise self._bad(key, str(exc)) from None
        try:
            return DxlBus(
                servos,
                baud=host_baud,
                clock=clock,
                latency_timer_ms=self.latency_ms,
                turnaround_us=self.turnaround_us,
                faults=faults,
                trace=self.trace,
            )
        except ValueError as exc:
            raise ValueError(f"{self._where()!r}: {exc}") from None

    def _build_p1(
        self, faults: FaultPlan, clock: Any, t: float, servo_baud: int, host_baud: int
    ) -> P1Bus:
        """A Protocol 1.0-framed bus (Dynamixel AX/MX P1, Feetech STS/SCS)."""
        tables = tables_by_id(self.model, self.ids)
        try:
            servos = [
                P1Servo(
                    tables[i],
                    i,
                    baud=servo_baud if self.baud is not None else _p1_baud(tables[i], servo_baud),
                    return_delay_us=self.rdt_us,
                    firmware=self.firmware,
                    t=t,
                )
                for i in self.ids
            ]
        except ValueError as exc:
            key = "rdt_us" if "return_delay" in str(exc) else "baud"
            raise self._bad(key, str(exc)) from None
        try:
            return P1Bus(
                servos,
                baud=host_baud,
                clock=clock,
                latency_timer_ms=self.latency_ms,
                turnaround_us=self.turnaround_us,
                faults=faults,
                trace=self.trace,
            )
        except ValueError as exc:
            raise ValueError(f"{self._where()!r}: {exc}") from None


def _p1_baud(table: ControlTable, host_baud: int) -> int:
    """The servos' rate when the URL names none: the host's if the model has a Baud Rate
    value for it, else the model's factory rate (the host then hears nothing, as on a wire)."""
    try:
        P1Servo(table, 1, baud=host_baud)
    except ValueError:
        return table.family.baud_rates[table.item("Baud Rate").default or 0]
    return host_baud


def _normal_model(text: str, ids: tuple[int, ...]) -> str:
    """The ``model`` key's normal form, for either protocol (ValueError naming the problem)."""
    if bus_protocol(text) == "2.0":
        return format_models(models_by_id(text, ids))
    return format_tables(tables_by_id(text, ids))


_DEFAULTS = {f.name: f.default for f in dataclasses.fields(DxlsimUrl)}


def _text(value: object) -> str:
    """A field's value as URL text that parses back to it."""
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float):
        return str(int(value)) if value.is_integer() and abs(value) < 1e15 else repr(value)
    if isinstance(value, tuple):
        return format_ids(value)
    return str(value)


def bus_from_url(url: str, host_baud: int = DEFAULT_HOST_BAUD) -> AnyBus:
    """A bus a ``dxlsim://`` URL names or describes (a new one for ``?keys``, not shared:
    ports use :func:`acquire_bus`). Raises ValueError saying what is wrong."""
    return DxlsimUrl.parse(url).build_bus(host_baud=host_baud)


class _Live:
    """A bus some port has open: a weak reference and how many ports have it open."""

    __slots__ = ("ref", "users")

    def __init__(self, ref: weakref.ref[AnyBus]) -> None:
        self.ref = ref
        self.users = 0


#: normal form -> the bus ports have open under it
_live: dict[str, _Live] = {}


def _forget(key: str, ref: weakref.ref[AnyBus]) -> None:
    with _lock:
        entry = _live.get(key)
        if entry is not None and entry.ref is ref:
            del _live[key]


def acquire_bus(
    url: str, host_baud: int = DEFAULT_HOST_BAUD, keep: AnyBus | None = None
) -> tuple[AnyBus, str]:
    """The bus a port opening ``url`` at ``host_baud`` is connected to, and its key for
    :func:`release_bus`: a named bus; the bus another port has open under the same normal
    form; ``keep`` (the bus this port had before it was closed); else a new one. The host
    side is set to ``host_baud``, the servos keep theirs. Raises ValueError."""
    parsed = DxlsimUrl.parse(url)
    if parsed.name:
        named = parsed.build_bus(host_baud=host_baud)
        named.baud = int(host_baud)
        return named, ""
    key = str(parsed)
    with _lock:
        entry = _live.get(key)
        bus = entry.ref() if entry is not None else None
    if entry is None or bus is None:  # (no entry: no bus)
        bus = keep if keep is not None else parsed.build_bus(host_baud=host_baud)
        with _lock:
            entry = _live[key] = _Live(weakref.ref(bus, functools.partial(_forget, key)))
    with _lock:
        entry.users += 1
    bus.baud = int(host_baud)
    return bus, key


def release_bus(key: str, bus: AnyBus) -> None:
    """A port that had ``bus`` open (from :func:`acquire_bus`) closed. The last one to close
    ends the sharing: the next open of the URL powers up a fresh bus."""
    if not key:
        return
    with _lock:
        entry = _live.get(key)
        if entry is None or entry.ref() is not bus:
            return
        entry.users -= 1
        if entry.users <= 0:
            del _live[key]


def live_buses() -> dict[str, AnyBus]:
    """The buses ports have open now, by normal form (for tests and diagnostics)."""
    with _lock:
        pairs = [(key, entry.ref()) for key, entry in _live.items()]
    return {key: bus for key, bus in pairs if bus is not None}
