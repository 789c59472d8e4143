"""``dxlsim://`` URLs: build an emulated bus from a URL, or look up one registered by name.

``dxlsim://[NAME][?key=value&...]``. With a NAME registered through :func:`register_bus`,
the port opens that bus (keys are then not allowed). Otherwise a new bus is built:

=============== ==================================================== ===============
key             meaning                                              default
=============== ==================================================== ===============
ids             servo IDs, e.g. ``1-4`` or ``1,3,5``                 ``1``
model           servo model for all of them (``XM430-W350``, ...)     ``XM430-W350``
baud            the servos' baud rate (bit/s); the host's rate is     the port's rate
                whatever the port is opened at
rdt_us          Return Delay Time in µs (multiple of 2, 0..508)       ``500`` (factory)
turnaround_us   servo processing time after the Return Delay Time     ``20``
latency_ms      USB adapter latency timer: 0, 1, 16, ...              ``0``
clock           ``virtual`` (jumps, never sleeps) or ``real``         ``virtual``
faults          fault plan, e.g. ``drop:id=2,rate=0.1;unplug:at=3``   none
seed            seed of the fault plan's generator                    ``0``
firmware        firmware version reported by every servo              model's default
trace           ``1`` to keep a timestamped trace of every byte       ``0``
=============== ==================================================== ===============
"""

from __future__ import annotations

import math
import threading
import urllib.parse

from drivers.clock import MonotonicClock, VirtualClock
from drivers.dxlsim.bus import DxlBus
from drivers.dxlsim.faults import parse_fault_plan
from drivers.dxlsim.models import get_model
from drivers.dxlsim.servo import VirtualServo
from drivers.protocol2.ids import parse_ids

_KEYS = (
    "ids",
    "model",
    "baud",
    "rdt_us",
    "turnaround_us",
    "latency_ms",
    "clock",
    "faults",
    "seed",
    "firmware",
    "trace",
)
_registry: dict[str, DxlBus] = {}
_lock = threading.Lock()


def register_bus(name: str, bus: DxlBus) -> str:
    """Make ``bus`` openable as ``dxlsim://NAME``; returns that URL."""
    if not name or not name.replace("-", "").replace("_", "").isalnum():
        raise ValueError(f"bus name must be letters, digits, - or _: {name!r}")
    with _lock:
        _registry[name] = bus
    return f"dxlsim://{name}"


def unregister_bus(name: str) -> None:
    with _lock:
        _registry.pop(name, None)


def bus_from_url(url: str, host_baud: int = 1_000_000) -> DxlBus:
    """The bus a ``dxlsim://`` URL names or describes. Raises ValueError saying what is wrong."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme.lower() != "dxlsim":
        raise ValueError(f"not a dxlsim:// URL: {url!r}")
    query = urllib.parse.parse_qs(parts.query, keep_blank_values=True, strict_parsing=False)
    name = parts.netloc + parts.path.strip("/")
    if name:
        with _lock:
            bus = _registry.get(name)
        if bus is None:
            known = ", ".join(sorted(_registry)) or "none registered"
            raise ValueError(f"no emulated bus named {name!r} ({known})")
        if query:
            raise ValueError(f"{url!r}: a named bus takes no ?keys (configure it in Python)")
        return bus
    unknown = sorted(set(query) - set(_KEYS))
    if unknown:
        raise ValueError(
            f"{url!r}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(_KEYS)}"
        )

    def get(key: str, default: str) -> str:
        return query.get(key, [default])[-1]

    def bad(key: str, message: str) -> ValueError:
        """One line naming the URL, the key, the value and what is allowed."""
        return ValueError(f"{url!r}: {key}: {message}")

    def number(key: str, default: str, kind: type, allowed: str) -> float:
        text = get(key, default)
        try:
            value = kind(text)
        except ValueError:
            raise bad(key, f"expected {allowed}, got {text!r}") from None
        if kind is float and not (math.isfinite(value) and value >= 0.0):
            raise bad(key, f"expected {allowed}, got {text!r}")
        return value

    try:
        ids = parse_ids(get("ids", "1"))
    except ValueError as exc:
        message = str(exc)
        if len(message) > 120:  # "... got [253, 254, ...]": one line, not a screenful
            message = message[:120] + " …]"
        raise bad("ids", message) from None
    servo_baud = int(number("baud", str(host_baud), int, "bit/s as an integer, e.g. 1000000"))
    rdt_us = number("rdt_us", "500", float, "µs, a multiple of 2 in 0..508")
    turnaround_us = number("turnaround_us", "20", float, "µs, a finite number >= 0")
    latency_ms = number("latency_ms", "0", float, "ms, a finite number >= 0 (0, 1, 16, ...)")
    seed = int(number("seed", "0", int, "an integer"))
    firmware = query.get("firmware")
    firmware_v = int(number("firmware", "0", int, "an integer 0..255")) if firmware else None
    clock_name = get("clock", "virtual").lower()
    if clock_name not in ("virtual", "real"):
        raise bad("clock", f"must be 'virtual' or 'real', got {clock_name!r}")
    model = get("model", "XM430-W350")
    try:
        get_model(model)
    except ValueError as exc:
        raise bad("model", str(exc)) from None
    try:
        faults = parse_fault_plan(get("faults", ""), seed=seed)
    except ValueError as exc:
        raise bad("faults", str(exc)) from None
    clock = VirtualClock() if clock_name == "virtual" else MonotonicClock()
    t = clock.now()
    try:
        servos = [
            VirtualServo(
                model, i, baud=servo_baud, return_delay_us=rdt_us, firmware=firmware_v, t=t
            )
            for i in ids
        ]
    except ValueError as exc:  # the model refuses the baud, the Return Delay Time or firmware
        key = next((k for k in ("baud", "rdt_us", "firmware") if k in str(exc)), "servos")
        key = "rdt_us" if "return_delay" in str(exc) else key
        key = "baud" if "bps" in str(exc) else key
        raise bad(key, str(exc)) from None
    try:
        return DxlBus(
            servos,
            baud=host_baud,
            clock=clock,
            latency_timer_ms=latency_ms,
            turnaround_us=turnaround_us,
            faults=faults,
            trace=get("trace", "0") not in ("0", "", "false", "no"),
        )
    except ValueError as exc:
        raise ValueError(f"{url!r}: {exc}") from None
