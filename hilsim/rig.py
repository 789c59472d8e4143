"""Rig configuration: one TOML file describes a figure's bus, loop, joints, safety and telemetry.

Loaded into frozen dataclasses. Degrees live only here, at the edge: every angle in the
dataclasses is in radians. Every error names the file, the key and what is allowed, e.g.::

    configs/demo.toml: joints[2].max_deg: must be greater than min_deg (-30.0), got -40.0

A minimal file::

    [bus]
    port = "dxlsim://?ids=1-2&rdt_us=0"    # or /dev/ttyUSB0, or a pty path
    baud = 1000000

    [loop]
    rate_hz = 500

    [[joints]]
    name = "head_pan"
    servo_id = 1
    min_deg = -60
    max_deg = 60
    spring = { frequency_hz = 3.0, damping_ratio = 0.7 }
    target = { type = "sine", amplitude_deg = 30, frequency_hz = 0.25 }

See ``configs/demo.toml`` for every key with comments.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

from drivers.servo_bus import ExitPolicy  # hold | relax: the bus carries it out
from hilsim.integrators import INTEGRATORS
from hilsim.springs import Spring
from hilsim.stability import check_stability


class RigError(ValueError):
    """A rig file that cannot be used; the message names the file and the key."""


class ReadMode(StrEnum):
    AUTO = "auto"
    FAST = "fast"
    PLAIN = "plain"


class OverrunPolicy(StrEnum):
    WARN = "warn"  # count it and carry on from the next deadline in the future
    STOP = "stop"  # treat an overrun as a fault: safe stop


@dataclass(frozen=True)
class BusConfig:
    port: str
    baud: int = 1_000_000
    read: ReadMode = ReadMode.AUTO
    latency_timer_ms: float | None = None  # None: detect (hardware) or the emulator's own


@dataclass(frozen=True)
class LoopConfig:
    rate_hz: float = 500.0
    integrator: str = "rk4"
    substeps: int = 1
    spin_us: float = 200.0
    overrun_policy: OverrunPolicy = OverrunPolicy.WARN
    realtime_priority: int | None = None  # SCHED_FIFO priority 1..99, when permitted
    cpu: int | None = None  # pin the loop to this CPU, when permitted

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def h_s(self) -> float:
        """Integrator step: the tick period divided by the substep count."""
        return self.period_s / self.substeps


@dataclass(frozen=True)
class SafetyConfig:
    exit_policy: ExitPolicy = ExitPolicy.HOLD
    comm_failure_budget_ms: float = 50.0
    watchdog_ms: float | None = 100.0  # Bus Watchdog armed while running (20 ms units); None: off
    soft_start_s: float = 1.0
    exit_retries: int = 3


@dataclass(frozen=True)
class TelemetryConfig:
    out_dir: str = "runs"
    flush_interval_s: float = 0.5


@dataclass(frozen=True)
class JointConfig:
    """One joint. Angles in radians; ``home_rad`` is the servo angle (0 = tick 2048) at which
    the joint angle is 0, and ``direction`` (+1/-1) maps joint angle to servo angle."""

    name: str
    servo_id: int
    model: str
    home_rad: float
    direction: int
    min_rad: float
    max_rad: float
    max_speed_rad_s: float
    max_accel_rad_s2: float
    spring: Spring
    target: dict[str, Any] = field(hash=False, compare=False)
    initial_rad: float | None = None  # spring's starting angle; None: the present pose


@dataclass(frozen=True)
class Rig:
    path: Path
    name: str
    bus: BusConfig
    loop: LoopConfig
    safety: SafetyConfig
    telemetry: TelemetryConfig
    joints: tuple[JointConfig, ...]
    text: str = field(repr=False, compare=False, default="")

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def servo_ids(self) -> tuple[int, ...]:
        return tuple(j.servo_id for j in self.joints)

    @property
    def base_dir(self) -> Path:
        """Relative file names in the rig (animations) are relative to the rig file."""
        return self.path.parent

    def spring_bank(self) -> Spring:
        """All joints' springs as one bank, in joint order."""
        return Spring.stack([j.spring for j in self.joints])


# ---------------------------------------------------------------------------------------- parsing
_SPRING_PHYSICS = ("m", "c", "k", "b")
_SPRING_ANIMATION = ("frequency_hz", "damping_ratio", "response")


class _Reader:
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
                raise RigError(
                    f"{self.path}: missing {self.key(name)}" + (f" ({allowed})" if allowed else "")
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
        self, name: str, default: Any = ..., *, positive: bool = False, nonnegative: bool = False
    ) -> float:
        value = self.get(name, float, default)
        if value is None:
            return value
        if not math.isfinite(value):
            raise self.fail(name, f"must be a finite number, got {value!r}")
        if positive and value <= 0:
            raise self.fail(name, f"must be > 0, got {value!r}")
        if nonnegative and value < 0:
            raise self.fail(name, f"must be >= 0, got {value!r}")
        return value

    def choice(self, name: str, enum: type[StrEnum], default: StrEnum) -> StrEnum:
        value = self.get(name, str, default.value)
        try:
            return enum(value)
        except ValueError:
            allowed = ", ".join(e.value for e in enum)
            raise self.fail(name, f"must be one of {allowed}; got {value!r}") from None

    def sub(self, name: str, *, required: bool = False) -> _Reader:
        table = self.get(name, dict, ... if required else {})
        return _Reader(self.path, table, self.key(name))

    def finish(self, allowed: tuple[str, ...] | None = None) -> None:
        unknown = sorted(set(self.table) - self.used)
        if unknown:
            names = ", ".join(allowed or sorted(self.used))
            where = self.where or "the top level"
            raise RigError(
                f"{self.path}: unknown key(s) {', '.join(unknown)} in {where}; allowed: {names}"
            )


def _spring(r: _Reader, name: str) -> Spring:
    s = r.sub(name, required=True)
    keys = set(s.table)
    if keys & set(_SPRING_PHYSICS) and keys & set(_SPRING_ANIMATION):
        raise r.fail(
            name,
            "give either physics terms (m, c, k[, b]) or animator terms "
            "(frequency_hz, damping_ratio[, response]), not both",
        )
    try:
        if keys & set(_SPRING_ANIMATION):
            spring = Spring.from_animation(
                s.number("frequency_hz", positive=True),
                s.number("damping_ratio", nonnegative=True),
                s.number("response", 0.0),
            )
            s.finish(_SPRING_ANIMATION)
        else:
            spring = Spring(
                m=s.number("m", positive=True),
                c=s.number("c", nonnegative=True),
                k=s.number("k", positive=True),
                b=s.number("b", 0.0),
            )
            s.finish(_SPRING_PHYSICS)
    except ValueError as exc:
        if isinstance(exc, RigError):
            raise
        raise r.fail(name, str(exc)) from None
    return spring


def _joint(path: Path, table: dict[str, Any], index: int) -> JointConfig:
    r = _Reader(path, table, f"joints[{index}]")
    name = r.get("name", str)
    if not name.isidentifier():
        raise r.fail(
            "name", f"use letters, digits and _ (it names telemetry columns), got {name!r}"
        )
    servo_id = r.get("servo_id", int)
    if not 0 <= servo_id <= 252:
        raise r.fail("servo_id", f"must be 0..252, got {servo_id}")
    model = r.get("model", str, "XM430-W350")
    home = r.number("home_deg", 0.0)
    direction = r.get("direction", int, 1)
    if direction not in (1, -1):
        raise r.fail("direction", f"must be 1 or -1, got {direction}")
    lo, hi = r.number("min_deg"), r.number("max_deg")
    if hi <= lo:
        raise r.fail("max_deg", f"must be greater than min_deg ({lo}), got {hi}")
    for edge, value in (("min_deg", lo), ("max_deg", hi)):
        servo_deg = home + direction * value
        if not -180.0 <= servo_deg <= 180.0:
            raise r.fail(
                edge,
                f"home_deg + direction*{edge} = {servo_deg:g} deg is outside one "
                "servo turn (-180..180 deg around tick 2048)",
            )
    speed = r.number("max_speed_deg_s", 180.0, positive=True)
    accel = r.number("max_accel_deg_s2", 3000.0, positive=True)
    spring = _spring(r, "spring")
    target = r.get("target", dict, allowed='e.g. { type = "keyframes", keys = [[0, 0], [1, 30]] }')
    initial = r.number("initial_deg", None) if "initial_deg" in table else None
    if initial is not None and not lo <= initial <= hi:
        raise r.fail("initial_deg", f"must lie within min_deg..max_deg ({lo}..{hi}), got {initial}")
    r.finish()
    rad = math.radians
    return JointConfig(
        name=name,
        servo_id=servo_id,
        model=model,
        home_rad=rad(home),
        direction=direction,
        min_rad=rad(lo),
        max_rad=rad(hi),
        max_speed_rad_s=rad(speed),
        max_accel_rad_s2=rad(accel),
        spring=spring,
        target=dict(target),
        initial_rad=None if initial is None else rad(initial),
    )


def load_rig(path: str | Path, *, port: str | None = None) -> Rig:
    """Read and validate a rig file. ``port`` overrides ``bus.port`` (the CLI's ``--port``).

    Raises :class:`RigError` (a ValueError) naming the file and key on any problem, including
    a spring that the configured integrator and rate cannot integrate stably.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise RigError(f"{path}: cannot read rig file: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RigError(f"{path}: not valid TOML: {exc}") from None
    top = _Reader(path, data, "")

    name = top.get("name", str, path.stem)

    b = top.sub("bus", required=True)
    bus = BusConfig(
        port=port if port is not None else b.get("port", str),
        baud=b.get("baud", int, 1_000_000),
        read=b.choice("read", ReadMode, ReadMode.AUTO),
        latency_timer_ms=b.number("latency_timer_ms", None, nonnegative=True),
    )
    if port is not None:
        b.used.add("port")
    if bus.baud <= 0:
        raise b.fail("baud", f"must be positive, got {bus.baud}")
    b.finish(("port", "baud", "read", "latency_timer_ms"))

    lp = top.sub("loop")
    integrator = lp.get("integrator", str, "rk4")
    if integrator not in INTEGRATORS:
        raise lp.fail("integrator", f"must be one of {', '.join(INTEGRATORS)}; got {integrator!r}")
    loop = LoopConfig(
        rate_hz=lp.number("rate_hz", 500.0, positive=True),
        integrator=integrator,
        substeps=lp.get("substeps", int, 1),
        spin_us=lp.number("spin_us", 200.0, nonnegative=True),
        overrun_policy=lp.choice("overrun_policy", OverrunPolicy, OverrunPolicy.WARN),
        realtime_priority=lp.get("realtime_priority", int, None),
        cpu=lp.get("cpu", int, None),
    )
    if loop.substeps < 1:
        raise lp.fail("substeps", f"must be >= 1, got {loop.substeps}")
    if loop.realtime_priority is not None and not 1 <= loop.realtime_priority <= 99:
        raise lp.fail("realtime_priority", f"must be 1..99, got {loop.realtime_priority}")
    lp.finish(
        (
            "rate_hz",
            "integrator",
            "substeps",
            "spin_us",
            "overrun_policy",
            "realtime_priority",
            "cpu",
        )
    )

    sf = top.sub("safety")
    watchdog = sf.number("watchdog_ms", 100.0, nonnegative=True)
    safety = SafetyConfig(
        exit_policy=sf.choice("exit_policy", ExitPolicy, ExitPolicy.HOLD),
        comm_failure_budget_ms=sf.number("comm_failure_budget_ms", 50.0, positive=True),
        watchdog_ms=watchdog or None,
        soft_start_s=sf.number("soft_start_s", 1.0, nonnegative=True),
        exit_retries=sf.get("exit_retries", int, 3),
    )
    if safety.watchdog_ms is not None and not 20.0 <= safety.watchdog_ms <= 127 * 20.0:
        raise sf.fail("watchdog_ms", f"must be 0 (off) or 20..2540 (20 ms units), got {watchdog}")
    if safety.comm_failure_budget_ms < 1000.0 / loop.rate_hz:
        raise sf.fail(
            "comm_failure_budget_ms",
            f"must be at least one tick ({1000.0 / loop.rate_hz:g} ms), "
            f"got {safety.comm_failure_budget_ms:g}",
        )
    if safety.exit_retries < 1:
        raise sf.fail("exit_retries", f"must be >= 1, got {safety.exit_retries}")
    sf.finish(
        ("exit_policy", "comm_failure_budget_ms", "watchdog_ms", "soft_start_s", "exit_retries")
    )

    tl = top.sub("telemetry")
    telemetry = TelemetryConfig(
        out_dir=tl.get("out_dir", str, "runs"),
        flush_interval_s=tl.number("flush_interval_s", 0.5, positive=True),
    )
    tl.finish(("out_dir", "flush_interval_s"))

    raw_joints = top.get("joints", list, allowed="one [[joints]] table per joint")
    if not raw_joints:
        raise top.fail("joints", "at least one [[joints]] table is needed")
    joints = []
    for i, table in enumerate(raw_joints):
        if not isinstance(table, dict):
            raise top.fail(f"joints[{i}]", "must be a table ([[joints]])")
        joints.append(_joint(path, table, i))
    top.finish(("name", "bus", "loop", "safety", "telemetry", "joints"))

    for attr, what in (("name", "joint name"), ("servo_id", "servo_id")):
        seen: dict[Any, int] = {}
        for i, j in enumerate(joints):
            value = getattr(j, attr)
            if value in seen:
                raise RigError(
                    f"{path}: joints[{i}].{attr}: {what} {value!r} is already used by "
                    f"joints[{seen[value]}]"
                )
            seen[value] = i

    for i, j in enumerate(joints):
        report = check_stability(j.spring, loop.h_s, loop.integrator)
        if not report.stable:
            fix = (
                f"\nSet loop.substeps = {report.min_substeps * loop.substeps}, "
                "or soften the spring."
                if report.min_substeps is not None
                else ""
            )
            raise RigError(
                f"{path}: joints[{i}].spring ({j.name}) at {loop.rate_hz:g} Hz x "
                f"{loop.substeps} substep(s): {report.message}{fix}"
            )
    return Rig(
        path=path,
        name=name,
        bus=bus,
        loop=loop,
        safety=safety,
        telemetry=telemetry,
        joints=tuple(joints),
        text=text,
    )
