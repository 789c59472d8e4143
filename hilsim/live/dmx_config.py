"""``[inputs.sacn]`` and ``[inputs.artnet]``: which DMX channels drive which joints, and how.

Per joint (``[inputs.sacn.joints.<joint>]``): ``universe``, ``channel`` (1..512, the coarse one
for 16 bits), ``bits`` (8 or 16: coarse then fine, as xLights' servo models and FPP send),
``degrees`` (``[min, center, max]`` or ``[min, max]``, center halfway; default the joint's
limits) and ``zero`` (what a value of 0 means: ``hold``, the default as FPP's servo outputs,
``min``, ``center``, ``max`` or ``release``: hand the joint back to the show).

The mapping is FPP's "Scaled": 1..split-1 spans min..center and split..full spans center..max,
split being 128 (8 bits) or 32768 (16 bits: coarse 0x80 fine 0x00), full 255 or 65535.

The input's own keys: ``port``, ``interface``, ``allow``, ``multicast`` (sACN), ``broadcast``
(Art-Net), ``lost_after_s`` (2.5, E1.31's data-loss timeout), ``release_after_s``,
``max_packet_bytes``, ``rate_per_s``, ``burst``, ``max_rx_per_s``. Every key with an example:
``docs/live.md`` (sACN and Art-Net).
"""

from __future__ import annotations

import ipaddress
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from hilsim.live.dmx_packets import ARTNET_PORT, E131_PORT
from hilsim.live.inbox import MAX_LIVE_DEG
from hilsim.live.netguard import GuardConfig, read_guard
from hilsim.rig.reader import Reader

ZERO_KINDS = ("hold", "min", "center", "max", "release")
#: the universes each protocol numbers (E1.31: 1..63999; Art-Net: the 15-bit port address)
UNIVERSES = {"sacn": (1, 63999), "artnet": (0, 32767)}
DEFAULT_PORTS = {"sacn": E131_PORT, "artnet": ARTNET_PORT}
INPUT_KEYS = ("port", "interface", "allow", "multicast", "broadcast", "lost_after_s",
              "release_after_s",
              "max_packet_bytes", "rate_per_s", "burst", "max_rx_per_s", "joints")  # fmt: skip
JOINT_KEYS = ("universe", "channel", "bits", "degrees", "zero")


@dataclass(frozen=True)
class DmxJoint:
    """One joint on one or two channels of a universe (module docstring)."""

    joint: str
    universe: int
    channel: int  # 1..512; the coarse channel of a 16-bit pair
    bits: int = 8
    lo: float = -90.0  # degrees at 1
    center: float = 0.0  # degrees at the split (128 or 32768)
    hi: float = 90.0  # degrees at full (255 or 65535)
    zero: str = "hold"

    def raw(self, slots: bytes) -> int | None:
        """The channel's value (0..255 or 0..65535); None if the universe is too short."""
        i = self.channel - 1
        if self.bits == 16:
            return slots[i] << 8 | slots[i + 1] if i + 1 < len(slots) else None
        return slots[i] if i < len(slots) else None

    def degrees(self, v: int) -> float | None:
        """The angle for a non-zero value ``v``, or for 0 by ``zero`` (None: hold/release)."""
        full = 65535 if self.bits == 16 else 255
        split = (full + 1) // 2
        if v == 0:
            return {"min": self.lo, "center": self.center, "max": self.hi}.get(self.zero)
        if v < split:
            return self.lo + (self.center - self.lo) * (v - 1) / (split - 1)
        return self.center + (self.hi - self.center) * (v - split) / (full - split)


@dataclass(frozen=True)
class DmxConfig:
    """``[inputs.sacn]`` or ``[inputs.artnet]`` (``protocol``), read by :func:`read_dmx`."""

    protocol: str
    joints: tuple[DmxJoint, ...]
    port: int = E131_PORT
    guard: GuardConfig = field(default_factory=GuardConfig)
    #: join each universe's multicast group (sACN; default: when bound off loopback)
    multicast: bool = False
    #: hear the subnet's broadcast too: bound to any address (Art-Net; default: off loopback)
    broadcast: bool = False
    #: no packet from any source of a universe this long: its joints hold, one input_lost
    lost_after_s: float = 2.5
    release_after_s: float | None = None
    max_rx_per_s: float = 2000.0

    @property
    def universes(self) -> tuple[int, ...]:
        return tuple(sorted({j.universe for j in self.joints}))


def read_dmx(r: Reader, protocol: str, limits: Mapping[str, tuple[float, float]]) -> DmxConfig:
    """The section ``r`` (``inputs.sacn`` or ``inputs.artnet``); ``limits``: each joint's
    limits in degrees (the default ``degrees``). Raises RigError (one line)."""
    port = r.integer("port", DEFAULT_PORTS[protocol], lo=1, hi=65535)
    guard = read_guard(r, 638)
    off_loopback = not ipaddress.ip_address(guard.bind_address).is_loopback
    multicast = r.get("multicast", bool, protocol == "sacn" and off_loopback)
    if multicast and protocol != "sacn":
        raise r.fail("multicast", "Art-Net has no multicast groups (it is unicast or broadcast)")
    if multicast and ":" in guard.bind_address:
        raise r.fail("multicast", "sACN multicast joins are IPv4 here: name an IPv4 interface")
    broadcast = r.get("broadcast", bool, protocol == "artnet" and off_loopback)
    if broadcast and protocol != "artnet":
        raise r.fail("broadcast", "sACN is multicast or unicast (broadcast is Art-Net's)")
    if broadcast and ":" in guard.bind_address:
        raise r.fail("broadcast", "broadcast is IPv4: name an IPv4 interface")
    table = r.get("joints", dict, ...)
    if not table:
        raise r.fail("joints", "name at least one joint: [inputs.<x>.joints.<joint>]")
    joints = tuple(_joint(r, protocol, name, spec, limits) for name, spec in table.items())
    taken: dict[tuple[int, int], str] = {}
    for j in joints:
        for ch in range(j.channel, j.channel + j.bits // 8):
            other = taken.setdefault((j.universe, ch), j.joint)
            if other != j.joint:
                raise r.fail(f"joints.{j.joint}.channel",
                             f"universe {j.universe} channel {ch} is {other}'s too")  # fmt: skip
    out = DmxConfig(
        protocol=protocol,
        joints=joints,
        port=port,
        guard=guard,
        multicast=multicast,
        broadcast=broadcast,
        lost_after_s=r.number("lost_after_s", 2.5, positive=True, at_most=3600.0),
        release_after_s=r.number("release_after_s", None, positive=True, at_most=7 * 86400.0),
        max_rx_per_s=r.number("max_rx_per_s", 2000.0, positive=True, at_most=1e6),
    )
    r.finish(INPUT_KEYS)
    return out


def _joint(
    r: Reader, protocol: str, name: str, spec: object, limits: Mapping[str, tuple[float, float]]
) -> DmxJoint:
    if name not in limits:
        raise r.fail(f"joints.{name}", f"no such joint (joints: {', '.join(limits)})")
    if not isinstance(spec, dict):
        raise r.fail(f"joints.{name}", f"a table (universe, channel, ...), got {spec!r}")
    e = Reader(r.path, spec, r.key(f"joints.{name}"))
    lo_u, hi_u = UNIVERSES[protocol]
    universe = e.integer("universe", ..., lo=lo_u, hi=hi_u)
    bits = e.integer("bits", 8, lo=8, hi=16)
    if bits not in (8, 16):
        raise e.fail("bits", f"8 or 16, got {bits}")
    channel = e.integer("channel", ..., lo=1, hi=512 if bits == 8 else 511,
                        why="a 16-bit joint takes the channel and the next")  # fmt: skip
    lo, hi = limits[name]
    raw = e.get("degrees", list, [lo, hi])
    ok = (
        len(raw) in (2, 3)
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in raw)
        and all(math.isfinite(v) and abs(v) <= MAX_LIVE_DEG for v in raw)
        and raw[0] != raw[-1]
    )
    if not ok:
        raise e.fail("degrees", "[min, center, max] or [min, max] in degrees, finite, "
                     f"within ±{MAX_LIVE_DEG:g}, min != max; got {raw!r}")  # fmt: skip
    deg = [float(v) for v in raw]
    center = deg[1] if len(deg) == 3 else (deg[0] + deg[1]) / 2
    if len(deg) == 3 and not min(deg[0], deg[2]) <= center <= max(deg[0], deg[2]):
        raise e.fail("degrees", f"the center {center:g} is not between {deg[0]:g} and {deg[2]:g}")
    zero = e.get("zero", str, "hold")
    if zero not in ZERO_KINDS:
        raise e.fail("zero", f"one of {', '.join(ZERO_KINDS)}; got {zero!r}")
    e.finish(JOINT_KEYS)
    return DmxJoint(name, universe, channel, bits, deg[0], center, deg[-1], zero)
