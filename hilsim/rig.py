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

See ``configs/demo.toml`` for every key with comments. Keys with bounds that are not obvious:

============================== ======================= ==========================================
key                            default                 allowed
============================== ======================= ==========================================
``name``                       the file's stem         letters, digits, ``_ - + .`` and inner
                                                       spaces (it names the run directory)
``bus.baud``                   1000000                 9600, 57600, 115200, 1000000, 2000000,
                                                       3000000, 4000000, 4500000 (X330: ≤ 4 M)
``loop.substeps``              1                       1 .. 50,000 / rate_hz (MAX_STEPS_PER_S)
``loop.cpu``                   none                    >= 0
``safety.comm_failure_budget_ms`` 50                   one tick .. 10,000
``safety.watchdog_ms``         100                     0 (off) or 20 .. 2540, a multiple of 20
``safety.soft_start_s``        1                       0 .. 60
``safety.exit_retries``        3                       1 .. 10
``telemetry.on_failure``       ``"stop"``              ``"stop"``: a dead telemetry writer (disk
                                                       full) is a safe stop; ``"continue"``: the
                                                       show goes on without telemetry
``joints[i].model``            ``"XM430-W350"``        a model the driver knows (KNOWN_MODELS)
``joints[i].max_speed_deg_s``  180                     >= 1
``joints[i].max_accel_deg_s2`` 3000                    >= 1
``joints[i].tracking_tolerance_deg`` 10                > 0 .. 360: a joint whose present position is
                                                       further than this from its command ...
``joints[i].tracking_time_ms`` 250                     > 0 .. 60,000: ... for longer than this is a
                                                       "following error" fault
``joints[i].spring``           required                animator form: 0.01 <= frequency_hz <= 1e6,
                                                       0 <= damping_ratio <= 1000,
                                                       -100 <= response <= 100; physics form: the
                                                       same bounds on √(k/m)/2π and c/(2√(k·m)),
                                                       and |b| <= 100·(c + 2√(k·m))
============================== ======================= ==========================================
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

from drivers.protocol2.control_table import BAUD_RATES, MODEL_NAMES, model_number, series
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


class TelemetryFailurePolicy(StrEnum):
    """What the show does when the telemetry writer dies (disk full, I/O error)."""

    STOP = "stop"  # a safe stop through the exit policy: a show without a record is a fault
    CONTINUE = "continue"  # keep the figure moving; the run's record ends where the disk did


# ----------------------------------------------------------------------------------------- bounds
#: The baud rates the servos and the driver support (the driver's control table), ascending.
SUPPORTED_BAUDS: tuple[int, ...] = tuple(sorted(BAUD_RATES.values()))
#: X330 servos stop at Baud Rate index 6 (4 Mbps); X430/X540 go to index 7 (4.5 Mbps).
_SERIES_MAX_BAUD = {"X330": BAUD_RATES[6]}
#: The servo models the driver knows (Model Number table), in table order.
KNOWN_MODELS: tuple[str, ...] = tuple(MODEL_NAMES.values())
#: loop.substeps <= MAX_STEPS_PER_S / rate_hz. One integrator step (target sample + step) costs
#: 13 µs for the 4-joint demo and 30 µs for 16 joints on a desktop (rk4, measured), several times
#: more on a Raspberry Pi, so 50,000 steps a second already take 0.65-1.5 s of CPU per second of
#: show: more could never keep real time. At the cap one tick's integration is 200 steps at
#: 250 Hz (2.6-6 ms on a desktop, a few tens of ms on a Pi), so the loop still reaches its stop
#: check that often and a Ctrl-C is heard at once; 10**7 substeps took minutes per tick.
MAX_STEPS_PER_S = 50_000
#: safety bounds: a dead bus must not hold the exit for long, nor a soft start the show
MAX_EXIT_RETRIES = 10
MAX_SOFT_START_S = 60.0
#: a servo unheard from for 10 s is gone; a larger budget lets the show run blind
MAX_COMM_FAILURE_BUDGET_MS = 10_000.0
#: Bus Watchdog unit (ms) and range
WATCHDOG_UNIT_MS = 20.0
WATCHDOG_MAX_MS = 127 * WATCHDOG_UNIT_MS
#: Below 1 deg/s (speed) or 1 deg/s² (acceleration) a joint takes minutes to cross its range
#: (1 deg/s: 2 min for 120 deg; 1 deg/s² from rest to rest: 22 s for 120 deg), and at 500 Hz
#: moves 1/40 of an encoder tick per tick: no show wants that, so such a value is a slip (a
#: unit or an exponent); 1e-300 made a joint that never moved.
MIN_SPEED_DEG_S = 1.0
MIN_ACCEL_DEG_S2 = 1.0
#: spring sanity bounds (both forms): natural frequency, damping ratio, feed-forward
SPRING_HZ_RANGE = (0.01, 1e6)
MAX_DAMPING_RATIO = 1000.0
MAX_RESPONSE = 100.0
MAX_FEEDFORWARD = 100.0  # |b| <= MAX_FEEDFORWARD·(c + 2√(k·m))
#: tracking monitor defaults and bounds
TRACKING_TOLERANCE_DEG = 10.0
TRACKING_TIME_MS = 250.0
MAX_TRACKING_TOLERANCE_DEG = 360.0
MAX_TRACKING_TIME_MS = 60_000.0
#: a rig name becomes a directory name: a word character first, then word characters, ``.+-``
#: and inner spaces; no separators, no ``..``, no leading dot or dash
_NAME_RE = re.compile(r"\w(?:[\w .+-]{0,98}[\w+-])?")


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
    on_failure: TelemetryFailurePolicy = TelemetryFailurePolicy.STOP


@dataclass(frozen=True)
class JointConfig:
    """One joint. Angles in radians; ``home_rad`` is the servo angle (0 = tick 2048) at which
    the joint angle is 0, and ``direction`` (+1/-1) maps joint angle to servo angle.

    Tracking monitor: a present position further than ``tracking_tolerance_rad`` from the
    commanded one for longer than ``tracking_time_s`` is a "following error" fault."""

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
    tracking_tolerance_rad: float = math.radians(TRACKING_TOLERANCE_DEG)
    tracking_time_s: float = TRACKING_TIME_MS / 1000.0


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
        self,
        name: str,
        default: Any = ...,
        *,
        positive: bool = False,
        nonnegative: bool = False,
        at_least: float | None = None,
        at_most: float | None = None,
        why: str = "",
    ) -> float:
        """A finite float; ``at_least``/``at_most`` bound it, ``why`` is said when they refuse."""
        value = self.get(name, float, default)
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
        self, name: str, default: Any, lo: int, hi: int | None, *, why: str = "", why_lo: str = ""
    ) -> int:
        """An int in lo..hi (hi None: no upper bound); ``why``/``why_lo`` explain the bounds."""
        value = self.get(name, int, default)
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
    f_lo, f_hi = SPRING_HZ_RANGE
    try:
        if keys & set(_SPRING_ANIMATION):
            spring = Spring.from_animation(
                s.number("frequency_hz", positive=True, at_least=f_lo, at_most=f_hi, why=_WHY_HZ),
                s.number("damping_ratio", nonnegative=True, at_most=MAX_DAMPING_RATIO, why=_WHY_Z),
                s.number("response", 0.0, at_least=-MAX_RESPONSE, at_most=MAX_RESPONSE, why=_WHY_R),
            )
            s.finish(_SPRING_ANIMATION)
        else:
            m, c = s.number("m", positive=True), s.number("c", nonnegative=True)
            k, b = s.number("k", positive=True), s.number("b", 0.0)
            _check_physics_spring(s, m, c, k, b)
            spring = Spring(m=m, c=c, k=k, b=b)
            s.finish(_SPRING_PHYSICS)
    except ValueError as exc:
        if isinstance(exc, RigError):
            raise
        raise r.fail(name, str(exc)) from None
    return spring


_WHY_HZ = "slower never moves in a show; faster is beyond any loop"
_WHY_Z = "beyond it the joint creeps for minutes"
_WHY_R = "the joint would react to the target's speed 100 times over"


def _check_physics_spring(s: _Reader, m: float, c: float, k: float, b: float) -> None:
    """The animator form's bounds, on m·x'' + c·x' + k·x = k·u + b·u' (keys named)."""
    # square roots first: k/m or k·m can overflow where their roots do not (inf is refused)
    f_hz = math.sqrt(k) / math.sqrt(m) / (2.0 * math.pi)
    critical = 2.0 * math.sqrt(k) * math.sqrt(m)  # 2√(k·m)
    zeta = c / critical if critical > 0.0 else math.inf
    f_lo, f_hi = SPRING_HZ_RANGE
    if not f_lo <= f_hz <= f_hi:
        raise s.fail(
            "k",
            f"the natural frequency √(k/m)/2π = {f_hz:.3g} Hz (k = {k:g}, m = {m:g}) must lie "
            f"within {f_lo:g}..{f_hi:g} Hz ({_WHY_HZ})",
        )
    if not zeta <= MAX_DAMPING_RATIO:
        raise s.fail(
            "c",
            f"the damping ratio c/(2√(k·m)) = {zeta:.3g} must be <= {MAX_DAMPING_RATIO:g} "
            f"({_WHY_Z}), got c = {c:g}",
        )
    b_max = MAX_FEEDFORWARD * (c + critical)
    if not abs(b) <= b_max:
        raise s.fail(
            "b",
            f"|b| must be <= {MAX_FEEDFORWARD:g}·(c + 2√(k·m)) = {b_max:.3g} for this spring "
            f"(a velocity feed-forward stronger than that is a slip), got {b:g}",
        )


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
    try:
        model_number(model)
    except ValueError:
        raise r.fail(
            "model",
            f"unknown servo model {model!r}; known: {', '.join(KNOWN_MODELS)} "
            "(a -T or -R suffix is fine)",
        ) from None
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
    slow = "slower, a joint takes minutes to cross its range"
    speed = r.number("max_speed_deg_s", 180.0, positive=True, at_least=MIN_SPEED_DEG_S, why=slow)
    accel = r.number("max_accel_deg_s2", 3000.0, positive=True, at_least=MIN_ACCEL_DEG_S2, why=slow)
    tolerance = r.number(
        "tracking_tolerance_deg",
        TRACKING_TOLERANCE_DEG,
        positive=True,
        at_most=MAX_TRACKING_TOLERANCE_DEG,
        why="one turn",
    )
    tracking_ms = r.number(
        "tracking_time_ms", TRACKING_TIME_MS, positive=True, at_most=MAX_TRACKING_TIME_MS
    )
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
        tracking_tolerance_rad=rad(tolerance),
        tracking_time_s=tracking_ms / 1000.0,
    )


def _check_watchdog(sf: _Reader, ms: float) -> None:
    """0 is off (handled by the caller); else 20..2540 ms in whole 20 ms units."""
    if not WATCHDOG_UNIT_MS <= ms <= WATCHDOG_MAX_MS:
        raise sf.fail(
            "watchdog_ms",
            f"must be 0 (off) or {WATCHDOG_UNIT_MS:g}..{WATCHDOG_MAX_MS:g} (20 ms units), "
            f"got {ms:g}",
        )
    units = ms / WATCHDOG_UNIT_MS
    if abs(units - round(units)) > 1e-9:
        below = max(1, math.floor(units)) * WATCHDOG_UNIT_MS
        above = min(127, math.ceil(units)) * WATCHDOG_UNIT_MS
        raise sf.fail(
            "watchdog_ms",
            f"must be a multiple of 20 ms (the servo counts in 20 ms units): the nearest are "
            f"{below:g} and {above:g}, got {ms:g}",
        )


def load_rig(path: str | Path, *, port: str | None = None) -> Rig:
    """Read and validate a rig file. ``port`` overrides ``bus.port`` (the CLI's ``--port``).

    Raises :class:`RigError` (a ValueError) naming the file and key on any problem, including
    a spring that the configured integrator and rate cannot integrate stably.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise RigError(f"{path}: cannot read rig file: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8-sig").replace("\r\n", "\n")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise RigError(
            f"{path}: not a text file: byte {raw[exc.start]:#04x} on line {line} is not UTF-8 "
            "(a rig file is TOML text)"
        ) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RigError(f"{path}: not valid TOML: {exc}") from None
    top = _Reader(path, data, "")

    name = top.get("name", str, path.stem)
    if not _NAME_RE.fullmatch(name):
        given = "" if "name" in data else ' (the file name; set name = "..." to choose one)'
        raise top.fail(
            "name",
            f"it names the run directory, so use letters, digits, _ - + . and inner spaces "
            f"(at most 100; no / or .., no leading dot or dash), got {name!r}{given}",
        )

    b = top.sub("bus", required=True)
    bauds = ", ".join(str(x) for x in SUPPORTED_BAUDS)
    bus = BusConfig(
        port=port if port is not None else b.get("port", str),
        baud=b.get("baud", int, 1_000_000, allowed=f"one of {bauds} bit/s"),
        read=b.choice("read", ReadMode, ReadMode.AUTO),
        latency_timer_ms=b.number(
            "latency_timer_ms",
            None,
            nonnegative=True,
            at_most=255.0,
            why="a USB adapter's latency timer is 0..255 ms",
        ),
    )
    if port is not None:
        b.used.add("port")
    if bus.baud not in SUPPORTED_BAUDS:
        raise b.fail("baud", f"{bus.baud} bit/s is not a servo baud rate; allowed: {bauds}")
    b.finish(("port", "baud", "read", "latency_timer_ms"))

    lp = top.sub("loop")
    integrator = lp.get("integrator", str, "rk4")
    if integrator not in INTEGRATORS:
        raise lp.fail("integrator", f"must be one of {', '.join(INTEGRATORS)}; got {integrator!r}")
    rate_hz = lp.number("rate_hz", 500.0, positive=True)
    max_substeps = max(1, int(MAX_STEPS_PER_S // rate_hz))
    loop = LoopConfig(
        rate_hz=rate_hz,
        integrator=integrator,
        substeps=lp.integer(
            "substeps",
            1,
            1,
            max_substeps,
            why=f"at {rate_hz:g} Hz: at most {MAX_STEPS_PER_S:,} integrator steps a second, "
            "each costs 10-30 us of CPU",
        ),
        spin_us=lp.number("spin_us", 200.0, nonnegative=True),
        overrun_policy=lp.choice("overrun_policy", OverrunPolicy, OverrunPolicy.WARN),
        realtime_priority=lp.integer("realtime_priority", None, 1, 99),
        cpu=lp.integer("cpu", None, 0, None, why_lo="a CPU number, as in taskset -c"),
    )
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
        comm_failure_budget_ms=sf.number(
            "comm_failure_budget_ms",
            50.0,
            positive=True,
            at_most=MAX_COMM_FAILURE_BUDGET_MS,
            why="a servo silent for longer is gone; the figure would run blind",
        ),
        watchdog_ms=watchdog or None,
        soft_start_s=sf.number(
            "soft_start_s",
            1.0,
            nonnegative=True,
            at_most=MAX_SOFT_START_S,
            why="a minute; longer and the figure barely moves at the start",
        ),
        exit_retries=sf.integer(
            "exit_retries", 3, 1, MAX_EXIT_RETRIES, why="each retry waits on a bus that may be dead"
        ),
    )
    if safety.watchdog_ms is not None:
        _check_watchdog(sf, safety.watchdog_ms)
    if safety.comm_failure_budget_ms < 1000.0 / loop.rate_hz:
        raise sf.fail(
            "comm_failure_budget_ms",
            f"must be at least one tick ({1000.0 / loop.rate_hz:g} ms), "
            f"got {safety.comm_failure_budget_ms:g}",
        )
    sf.finish(
        ("exit_policy", "comm_failure_budget_ms", "watchdog_ms", "soft_start_s", "exit_retries")
    )

    tl = top.sub("telemetry")
    telemetry = TelemetryConfig(
        out_dir=tl.get("out_dir", str, "runs"),
        flush_interval_s=tl.number("flush_interval_s", 0.5, positive=True),
        on_failure=tl.choice("on_failure", TelemetryFailurePolicy, TelemetryFailurePolicy.STOP),
    )
    tl.finish(("out_dir", "flush_interval_s", "on_failure"))

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
        top_baud = _SERIES_MAX_BAUD.get(series(j.model.strip().upper()))
        if top_baud is not None and bus.baud > top_baud:
            raise RigError(
                f"{path}: joints[{i}].model: {j.model} ({series(j.model.upper())} series) runs "
                f"at most {top_baud} bit/s, but bus.baud = {bus.baud}"
            )

    for i, j in enumerate(joints):
        try:
            report = check_stability(j.spring, loop.h_s, loop.integrator)
        except ValueError as exc:  # rates beyond float64: the bounds above should prevent it
            raise RigError(f"{path}: joints[{i}].spring ({j.name}): {exc}") from None
        if not report.stable:
            fix = ""
            if report.min_substeps is not None or math.isfinite(report.substeps_needed):
                need = (
                    report.min_substeps * loop.substeps
                    if report.min_substeps is not None
                    else report.substeps_needed * loop.substeps
                )
                fix = (
                    f"\nSet loop.substeps = {need}, or soften the spring."
                    if need <= max_substeps
                    else f"\nIt would need loop.substeps = {need:.3g}, but at most "
                    f"{max_substeps} are allowed at {loop.rate_hz:g} Hz: soften the spring "
                    "(lower frequency_hz or k, or raise m)."
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
