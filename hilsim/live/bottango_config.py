"""``[inputs.bottango]``: the Bottango live driver's settings (:func:`from_table`). What the
driver does: :mod:`hilsim.live.bottango_live`; how to point Bottango at it: ``docs/live.md``.

Keys (all optional but ``effectors``)::

    transport = "pty"            # "pty" (Bottango's USB serial driver) or "tcp" (its network
                                 #   driver: hilsim connects to the app, like that driver)
    link = "/tmp/bottango"       # pty: a symlink to the pty (a stale symlink is replaced,
                                 #   any other file there is an error)
    host = "127.0.0.1"           # tcp: where Bottango listens; not the loopback: name it in
    port = 59225                 #   allow = ["192.168.1.20"] (netguard's rule)
    allow = []
    driver_version = "0.8.0c1"   # the handshake's version (default: the transport's driver)
    require_hash = true          # default: pty true, tcp false (a hash given is checked)
    max_line = 512               # longer lines are dropped (64..4096)
    max_lines_per_s = 2000       # the receiver reads at most this many lines a second

    [inputs.bottango.effectors."0"]    # the effector identifier Bottango registers (pin, ...)
    joint = "jaw"
    signal = [1000, 2000]              # optional; default: the registration's min..max
    degrees = [0, 40]

Every error is one ``ValueError`` line naming ``<where>.<key>``.
"""

from __future__ import annotations

import ipaddress
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from hilsim.live.inbox import MAX_LIVE_DEG
from hilsim.live.netguard import GuardConfig, NetGuard, NetGuardError
from hilsim.targets.formats.common import UnitMap

SERIAL_VERSION = "0.8.0c1"  # BottangoArduinoDriver BasicCommands.h DRIVER_VERSION
NETWORK_VERSION = "CUSTOM9"  # BottangoNetworkedDriver CallbacksAndConfiguration.py apiVersion
DEFAULT_PORT = 59225  # the network driver's port (the app listens)
MAX_LINE = 512
#: the widest signal an effector map may give (either end): PWM µs, steps, ...
MAX_SIGNAL = 1e9
_KEYS = ("transport", "link", "host", "port", "allow", "driver_version", "require_hash",
         "max_line", "max_lines_per_s", "release_after_s", "effectors")  # fmt: skip


@dataclass(frozen=True)
class EffectorMap:
    """Bottango effector -> a joint: the signal ``signal_lo``..``signal_hi`` (µs for servos)
    maps linearly to ``deg_lo``..``deg_hi``; signal bounds None: the registration's min..max."""

    joint: str
    signal_lo: float | None
    signal_hi: float | None
    deg_lo: float
    deg_hi: float

    def unit_map(self, reg_lo: float, reg_hi: float) -> UnitMap:
        """The export reader's :class:`UnitMap` from the signal to degrees."""
        lo, hi = self.signal_lo, self.signal_hi
        if lo is None or hi is None:  # no [signal]: the export's register range (both or none)
            lo, hi = reg_lo, reg_hi
        return UnitMap((lo, hi), (self.deg_lo, self.deg_hi), "signal")


@dataclass(frozen=True)
class BottangoConfig:
    """``[inputs.bottango]`` as :func:`from_table` reads it."""

    effectors: Mapping[str, EffectorMap]
    transport: str = "pty"
    link: str | None = None
    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    allow: tuple[str, ...] = ()
    driver_version: str | None = None  # None: the transport's driver's
    require_hash: bool | None = None  # None: pty True, tcp False
    max_line: int = MAX_LINE
    max_lines_per_s: float = 2000.0
    #: an effector's value unchanged this long hands its joint back to the show (None: held)
    release_after_s: float | None = None


def _pair(v: Any, key: str, limit: float) -> tuple[float, float]:
    if (
        not isinstance(v, list | tuple)
        or len(v) != 2
        or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
        or not all(math.isfinite(x) and abs(x) <= limit for x in v)
    ):
        raise ValueError(f"{key}: two numbers [low, high] within ±{limit:g}, got {v!r}")
    return float(v[0]), float(v[1])


def _effectors(table: Any, where: str, joints: Iterable[str]) -> dict[str, EffectorMap]:
    key = f"{where}.effectors"
    if not isinstance(table, dict) or not table:
        raise ValueError(
            f'{key}: a table of effectors, e.g. [inputs.bottango.effectors."0"] joint = "jaw", '
            "degrees = [0, 40]"
        )
    names = tuple(joints)
    out: dict[str, EffectorMap] = {}
    used: dict[str, str] = {}  # joint -> the effector driving it
    for eid, spec in table.items():
        k = f'{key}."{eid}"'
        if not eid.isascii() or not eid.isprintable() or "," in eid or not 0 < len(eid) <= 16:
            raise ValueError(f"{k}: an effector identifier is 1-16 ASCII characters, no comma")
        if not isinstance(spec, dict):
            raise ValueError(f"{k}: a table (joint, degrees, signal)")
        extra = sorted(set(spec) - {"joint", "degrees", "signal"})
        if extra:
            raise ValueError(f"{k}.{extra[0]}: unknown key (known: joint, degrees, signal)")
        joint = spec.get("joint")
        if joint not in names:
            raise ValueError(f"{k}.joint: {joint!r} is not a joint of the rig ({', '.join(names)})")
        if joint in used:
            raise ValueError(f"{k}.joint: {joint} is already driven by effector {used[joint]!r}")
        used[joint] = eid
        if "degrees" not in spec:
            raise ValueError(f"{k}.degrees: missing (the joint's degrees at the signal's ends)")
        d = _pair(spec["degrees"], f"{k}.degrees", MAX_LIVE_DEG)
        s: tuple[float | None, float | None] = (None, None)
        if "signal" in spec:
            s = _pair(spec["signal"], f"{k}.signal", MAX_SIGNAL)
            if s[0] == s[1]:
                raise ValueError(f"{k}.signal: the two ends are equal ({s[0]:g})")
        out[eid] = EffectorMap(joint, s[0], s[1], d[0], d[1])
    return out


def from_table(table: dict[str, Any], where: str, joint_names: Iterable[str]) -> BottangoConfig:
    """``[inputs.bottango]`` (see the module docstring) -> :class:`BottangoConfig`."""
    if not isinstance(table, dict):
        raise ValueError(f"{where}: a table")
    extra = sorted(set(table) - set(_KEYS))
    if extra:
        raise ValueError(f"{where}.{extra[0]}: unknown key (known: {', '.join(_KEYS)})")
    transport = table.get("transport", "pty")
    if transport not in ("pty", "tcp"):
        raise ValueError(f'{where}.transport: "pty" or "tcp", got {transport!r}')
    kw: dict[str, Any] = {"transport": transport}
    for key in ("link", "host", "driver_version"):
        v = table.get(key)
        if v is not None and (not isinstance(v, str) or not v):
            raise ValueError(f"{where}.{key}: a non-empty string, got {v!r}")
    if "link" in table:
        if transport != "pty":
            raise ValueError(f'{where}.link: only with transport = "pty"')
        kw["link"] = table["link"]
    v = table.get("driver_version")
    if v is not None:
        if not (v.isascii() and v.isprintable()) or "," in v or len(v) > 32:
            raise ValueError(f"{where}.driver_version: 1-32 ASCII characters, no comma")
        kw["driver_version"] = v
    if "require_hash" in table:
        if not isinstance(table["require_hash"], bool):
            raise ValueError(f"{where}.require_hash: true or false")
        kw["require_hash"] = table["require_hash"]
    for key, lo, hi in (("max_line", 64, 4096), ("port", 1, 65535)):
        if key in table:
            v = table[key]
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ValueError(f"{where}.{key}: an integer in {lo}..{hi}, got {v!r}")
            kw[key] = v
    if "max_lines_per_s" in table:
        v = table["max_lines_per_s"]
        if isinstance(v, bool) or not isinstance(v, int | float) or not 1 <= v <= 1e6:
            raise ValueError(f"{where}.max_lines_per_s: a number in 1..1e6, got {v!r}")
        kw["max_lines_per_s"] = float(v)
    _release_after(table, where, kw)
    if transport == "tcp":
        _tcp(table, where, kw)
    elif any(k in table for k in ("host", "port", "allow")):
        k = next(k for k in ("host", "port", "allow") if k in table)
        raise ValueError(f'{where}.{k}: only with transport = "tcp"')
    return BottangoConfig(_effectors(table.get("effectors"), where, joint_names), **kw)


def _release_after(table: dict[str, Any], where: str, kw: dict[str, Any]) -> None:
    if "release_after_s" in table:
        v = table["release_after_s"]
        if isinstance(v, bool) or not isinstance(v, int | float) or not 0 < v <= 7 * 86400:
            raise ValueError(f"{where}.release_after_s: seconds, > 0 (a week at most), got {v!r}")
        kw["release_after_s"] = float(v)


def _tcp(table: dict[str, Any], where: str, kw: dict[str, Any]) -> None:
    allow = table.get("allow", [])
    if not isinstance(allow, list) or not all(isinstance(a, str) for a in allow):
        raise ValueError(f'{where}.allow: a list of addresses, e.g. ["192.168.1.20"]')
    host = table.get("host", "127.0.0.1")
    host = "127.0.0.1" if host == "localhost" else host
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        raise ValueError(f"{where}.host: an IP address (e.g. 127.0.0.1), got {host!r}") from None
    try:
        guard = NetGuard(GuardConfig(allow=tuple(allow)))
    except NetGuardError as exc:
        raise ValueError(f"{where}.allow: {exc}") from None
    if not loopback and not guard.sender_allowed(host):
        raise ValueError(
            f"{where}.host: {host} is not the loopback: a figure driven from the network needs "
            f'the host named in allow = ["{host}"]'
        )
    kw["host"], kw["allow"] = host, tuple(allow)
