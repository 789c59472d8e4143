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

import threading
import urllib.parse

from drivers.clock import MonotonicClock, VirtualClock
from drivers.dxlsim.bus import DxlBus
from drivers.dxlsim.faults import parse_fault_plan
from drivers.dxlsim.ids import parse_ids
from drivers.dxlsim.servo import VirtualServo

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
        raise ValueError(f"{url!r}: unknown key(s) {unknown}; allowed: {', '.join(_KEYS)}")

    def get(key: str, default: str) -> str:
        return query.get(key, [default])[-1]

    try:
        ids = parse_ids(get("ids", "1"))
        servo_baud = int(get("baud", str(host_baud)))
        rdt_us = float(get("rdt_us", "500"))
        turnaround_us = float(get("turnaround_us", "20"))
        latency_ms = float(get("latency_ms", "0"))
        seed = int(get("seed", "0"))
        firmware = query.get("firmware")
        firmware_v = int(firmware[-1]) if firmware else None
    except ValueError as exc:
        raise ValueError(f"{url!r}: {exc}") from None
    clock_name = get("clock", "virtual").lower()
    if clock_name not in ("virtual", "real"):
        raise ValueError(f"{url!r}: clock must be 'virtual' or 'real', got {clock_name!r}")
    clock = VirtualClock() if clock_name == "virtual" else MonotonicClock()
    model = get("model", "XM430-W350")
    t = clock.now()
    servos = [
        VirtualServo(model, i, baud=servo_baud, return_delay_us=rdt_us, firmware=firmware_v, t=t)
        for i in ids
    ]
    return DxlBus(
        servos,
        baud=host_baud,
        clock=clock,
        latency_timer_ms=latency_ms,
        turnaround_us=turnaround_us,
        faults=parse_fault_plan(get("faults", ""), seed=seed),
        trace=get("trace", "0") not in ("0", "", "false", "no"),
    )
