"""The rig as data: frozen dataclasses, their policies and bounds. Every angle here is in radians.

Each field read from the rig file carries its :class:`~hilsim.rig.keys.Key` (file name, default,
unit, bounds, meaning, example) in its metadata: the loader and ``docs/rig.md`` both read it there.
(``rig_key`` returns a ``dataclasses.field``; ruff's RUF009 cannot know that, hence the noqa.)
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from drivers.clock import DEFAULT_SPIN_S
from drivers.p1bus.table import P1_MODELS
from drivers.protocol2.control_table import MODEL_NAMES
from drivers.servo_bus import ExitPolicy  # hold | relax: the bus carries it out
from hilsim.dynamics.integrators import INTEGRATORS
from hilsim.dynamics.springs import Spring
from hilsim.rig.bus import BusConfig  # the [bus] table, and each of [buses]
from hilsim.rig.keys import rig_key
from hilsim.safety.limits import DEFAULT_SOFT_START_S
from hilsim.telemetry.format import TelemetryFormat  # the [telemetry] format key's choices

if TYPE_CHECKING:
    from hilsim.rig.clips import PlayEntry  # clips reads through the reader, which needs this


class RigError(ValueError):
    """A rig file that cannot be used; the message names the file and the key."""


class OverrunPolicy(StrEnum):
    WARN = "warn"  # count it and carry on from the next deadline in the future
    STOP = "stop"  # treat an overrun as a fault: safe stop


class TelemetryFailurePolicy(StrEnum):
    """What the show does when the telemetry writer dies (disk full, I/O error)."""

    STOP = "stop"  # a safe stop through the exit policy: a show without a record is a fault
    CONTINUE = "continue"  # keep the figure moving; the run's record ends where the disk did
    AUTO = "auto"  # stop for a show with an end; continue for an endless one (the show first)

    def continues(self, *, endless: bool) -> bool:
        """Whether the show goes on when the writer dies (``auto``: when it is endless)."""
        return self is TelemetryFailurePolicy.CONTINUE or (
            self is TelemetryFailurePolicy.AUTO and endless
        )


# ----------------------------------------------------------------------------------------- bounds
#: The servo models the drivers know: the X series (Protocol 2.0, Model Number table order),
#: then the Protocol 1.0-framed families (Feetech STS/SCS, Dynamixel MX/AX).
KNOWN_MODELS: tuple[str, ...] = tuple(MODEL_NAMES.values()) + P1_MODELS
#: loop.substeps <= MAX_STEPS_PER_S / rate_hz. An integrator step costs tens of µs, so more
#: steps a second could never keep real time; at the cap a tick's integration still ends in
#: milliseconds, and a Ctrl-C is heard at once. The step costs: docs/performance.md.
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
#: tracking monitor defaults and bounds
TRACKING_TOLERANCE_DEG = 10.0
TRACKING_TIME_MS = 250.0
MAX_TRACKING_TOLERANCE_DEG = 360.0
MAX_TRACKING_TIME_MS = 60_000.0
#: servo IDs a joint may use (253 is reserved, 254 is broadcast)
SERVO_ID_RANGE = (0, 252)
#: a rig name becomes a directory name: a word character first, then word characters, ``.+-``
#: and inner spaces; no separators, no ``..``, no leading dot or dash
NAME_RE = re.compile(r"\w(?:[\w .+-]{0,98}[\w+-])?")

_SLOW = "slower, a joint takes minutes to cross its range"


def _ms_to_s(ms: float) -> float:
    return ms / 1000.0


# ----------------------------------------------------------------------------------------- model
@dataclass(frozen=True)
class LoopConfig:
    rate_hz: float = rig_key(
        "number",
        "Ticks per second: one Sync Write and one Sync Read each.",
        unit="Hz",
        default=500.0,
        bounds={"positive": True},
        allowed="the bus must carry one tick's traffic in 80 % of a tick (checked at start)",
        example=250,
    )
    integrator: str = rig_key(
        "text",
        "The springs' integrator.",
        default="rk4",
        allowed=" | ".join(f'`"{name}"`' for name in INTEGRATORS),
    )
    substeps: int = rig_key(
        "integer",
        "Integrator steps per tick; the loader says how many a stiff spring needs.",
        default=1,
        bounds={"lo": 1},
        allowed=f"at most {MAX_STEPS_PER_S:,} / rate_hz (integrator steps a second, "
        "each costs 10-30 µs of CPU)",
    )
    spin_us: float = rig_key(
        "number",
        "The most the loop spins before each deadline: it sleeps until this close, or as close "
        "as the latest of this host's wake-ups of the last few seconds (learned as it runs), "
        "whichever is less, then spins. Larger: more ticks start on time on a host that wakes "
        "threads late, at up to this much CPU a tick. 0: sleep only, the least CPU; each tick "
        "starts as late as the host wakes the thread (40-90 µs on a busy 2-core VM).",
        unit="µs",
        default=round(DEFAULT_SPIN_S * 1e6, 6),
        bounds={"nonnegative": True},
    )
    overrun_policy: OverrunPolicy = rig_key(  # noqa: RUF009
        "choice",
        "A missed deadline: `warn` counts it and carries on from the next deadline; `stop` is "
        "a safe stop.",
        default=OverrunPolicy.WARN,
    )
    realtime_priority: int | None = rig_key(
        "integer",
        "SCHED_FIFO priority for the loop, when permitted (a warning, not a crash, when not).",
        default=None,
        default_doc="none: the normal scheduler",
        bounds={"lo": 1, "hi": 99},
        example=50,
    )
    cpu: int | None = rig_key(
        "integer",
        "Pin the loop to this CPU, when permitted.",
        default=None,
        default_doc="none: not pinned",
        bounds={"lo": 0, "why_lo": "a CPU number, as in taskset -c"},
        example=1,
    )

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def h_s(self) -> float:
        """Integrator step: the tick period divided by the substep count."""
        return self.period_s / self.substeps


@dataclass(frozen=True)
class SafetyConfig:
    exit_policy: ExitPolicy = rig_key(  # noqa: RUF009
        "choice",
        "What the servos do when the show ends or stops: `hold` = goal := present position, "
        "torque on, Bus Watchdog armed; `relax` = torque off.",
        default=ExitPolicy.HOLD,
    )
    comm_failure_budget_ms: float = rig_key(
        "number",
        "A servo without a valid read for this long (at least 3 failed reads in a row; the "
        "host's own stalls are not counted) stops the show.",
        unit="ms",
        default=50.0,
        bounds={
            "positive": True,
            "at_most": MAX_COMM_FAILURE_BUDGET_MS,
            "why": "a servo silent for longer is gone; the figure would run blind",
        },
        allowed="at least one tick (1000 / rate_hz ms)",
        example=100,
    )
    watchdog_ms: float | None = rig_key(
        "number",
        "Bus Watchdog armed while running: servos stop by themselves when no packet reaches "
        "them this long (the host died). 0 turns it off.",
        unit="ms",
        default=100.0,
        bounds={"nonnegative": True},
        allowed=f"0 (off) or {WATCHDOG_UNIT_MS:g} .. {WATCHDOG_MAX_MS:g}, a multiple of "
        f"{WATCHDOG_UNIT_MS:g}",
        convert=lambda ms: ms or None,
    )
    soft_start_s: float = rig_key(
        "number",
        "Ramp from where the figure is to where the show starts.",
        unit="s",
        default=DEFAULT_SOFT_START_S,
        bounds={
            "nonnegative": True,
            "at_most": MAX_SOFT_START_S,
            "why": "a minute; longer and the figure barely moves at the start",
        },
        example=0.5,
    )
    exit_retries: int = rig_key(
        "integer",
        "Attempts to carry out the exit policy on each servo.",
        default=3,
        bounds={
            "lo": 1,
            "hi": MAX_EXIT_RETRIES,
            "why": "each retry waits on a bus that may be dead",
        },
    )


@dataclass(frozen=True)
class TelemetryConfig:
    out_dir: str = rig_key(
        "text",
        "Where run directories `<name>-<time>` are made (relative to the working directory); "
        "the command line's `--out` names one instead.",
        default="runs",
    )
    flush_interval_s: float = rig_key(
        "number",
        "How often the telemetry writer flushes its files.",
        unit="s",
        default=0.5,
        bounds={"positive": True},
    )
    on_failure: TelemetryFailurePolicy = rig_key(  # noqa: RUF009
        "choice",
        "A dead telemetry writer (disk full, I/O error): `stop` = a safe stop; `continue` = the "
        "show goes on without a record; `auto` = `stop` for a show with an end, `continue` for "
        "an endless one (a show file or `--live` without `--duration`: the show comes first; "
        "said at the start as a `startup` event).",
        default=TelemetryFailurePolicy.AUTO,
    )
    format: TelemetryFormat = rig_key(  # noqa: RUF009
        "choice",
        "How the per-tick rows are stored. `csv`: `telemetry.csv`, exact (every float64 "
        "round-trips); `csv.gz`: the same text gzip-compressed (about 1/3 the size; `zcat`, "
        "pandas, polars, duckdb read it); `parquet`: `telemetry.parquet/` part files of "
        "fixed-point integers (angles to 1 µrad, 1/1500 of a servo tick; times to 1 ns), about "
        "1/18 of the CSV; needs `pip install 'hilsim[parquet]'` (pyarrow). `auto`: `csv` while a "
        "10-minute show's CSV stays under 100 MB (rate_hz × (122 + 102 × joints) bytes/s ≤ "
        "166,667: the demo), else `parquet`, or `csv.gz` without pyarrow. A crash keeps every "
        "row up to the last flush (csv, csv.gz) or fsync, every 2 s (parquet); a full disk "
        "stops the show (`on_failure`), and a Parquet run then keeps only the parts written "
        "before it (up to 2 s of rows are lost, and the failure is noticed at the next part). "
        "`none`: no per-tick rows, only `events.jsonl`, `summary.json` and the copies (a "
        "summary-only record); `off`: nothing kept (the run directory is removed at the end, "
        "but for a take the show recorded; the terminal still says the outcome).",
        default=TelemetryFormat.AUTO,
    )
    max_mb: float | None = rig_key(
        "number",
        "A size cap on the run's rows: they are written in parts (`telemetry.parts/` for CSV, "
        "`telemetry.parquet/`) and the oldest parts are removed so the rows stay under it; "
        "each removal is a `telemetry_rotated` event and counted in the summary.",
        unit="MB",
        default=None,
        default_doc="none: no cap",
        bounds={"at_least": 0.1, "why": "a part is an eighth of the cap"},
        example=500,
    )
    max_age_h: float | None = rig_key(
        "number",
        "An age cap on the run's rows: parts whose newest row is older than this are removed, "
        "oldest first (`telemetry_rotated` events; counted in the summary).",
        unit="h",
        default=None,
        default_doc="none: no cap",
        bounds={"positive": True},
        example=24,
    )
    runs_max_mb: float | None = rig_key(
        "number",
        "A size cap on the run directories under `out_dir` (this run's aside): as a show "
        "starts there, the oldest are removed until the rest fit, each a `run_removed` event "
        "and counted in the summary. Only directories holding a run's record are touched.",
        unit="MB",
        default=None,
        default_doc="none: no cap",
        bounds={"positive": True},
        example=5000,
    )
    runs_max_age_days: float | None = rig_key(
        "number",
        "An age cap on the run directories under `out_dir`: as a show starts there, those last "
        "written longer ago are removed (`run_removed` events; counted in the summary).",
        unit="days",
        default=None,
        default_doc="none: no cap",
        bounds={"positive": True},
        example=30,
    )


@dataclass(frozen=True, kw_only=True)
class JointConfig:
    """One joint. Angles in radians; ``home_rad`` is the servo angle (0 = tick 2048) at which
    the joint angle is 0, and ``direction`` (+1/-1) maps joint angle to servo angle.

    Tracking monitor: a present position further than ``tracking_tolerance_rad`` from the
    commanded one for longer than ``tracking_time_s`` is a "following error" fault."""

    name: str = rig_key(
        "text",
        "The joint's name; it names the telemetry columns (`cmd_<name>` ...) and the default CSV "
        "column.",
        allowed="letters, digits and `_` (a Python identifier); unique",
        example="head_pan",
    )
    servo_id: int = rig_key(
        "integer",
        "The servo's ID on the bus.",
        allowed=f"{SERVO_ID_RANGE[0]} .. {SERVO_ID_RANGE[1]}; unique on its bus",
        example=1,
    )
    model: str = rig_key(
        "text",
        "The servo model; checked against the servo at start. It chooses the protocol: one "
        "protocol per bus (see [families](../README.md#servo-families)).",
        default="XM430-W350",
        allowed="a model the driver knows: " + ", ".join(KNOWN_MODELS) + " (a -T or -R suffix "
        "is fine)",
    )
    home_rad: float = rig_key(
        "number",
        "The servo angle (0 = centre tick 2048) where this joint reads 0.",
        toml="home_deg",
        unit="deg",
        default=0.0,
        convert=math.radians,
    )
    direction: int = rig_key(
        "integer",
        "Servo angle = home_deg + direction · joint angle: -1 for a joint mounted mirrored.",
        default=1,
        allowed="1 or -1",
    )
    min_rad: float = rig_key(
        "number",
        "The joint's lower limit (joint frame); the safety filter never commands beyond it.",
        toml="min_deg",
        unit="deg",
        allowed="home_deg + direction · min_deg within -180 .. 180 (one servo turn; AX and SCS "
        "servos: -150 .. 150)",
        example=-70,
        convert=math.radians,
    )
    max_rad: float = rig_key(
        "number",
        "The joint's upper limit (joint frame).",
        toml="max_deg",
        unit="deg",
        allowed="> min_deg; home_deg + direction · max_deg within -180 .. 180",
        example=70,
        convert=math.radians,
    )
    max_speed_rad_s: float = rig_key(
        "number",
        "Speed limit of the commands.",
        toml="max_speed_deg_s",
        unit="deg/s",
        default=180.0,
        bounds={"positive": True, "at_least": MIN_SPEED_DEG_S, "why": _SLOW},
        example=240,
        convert=math.radians,
    )
    max_accel_rad_s2: float = rig_key(
        "number",
        "Acceleration limit of the commands.",
        toml="max_accel_deg_s2",
        unit="deg/s²",
        default=3000.0,
        bounds={"positive": True, "at_least": MIN_ACCEL_DEG_S2, "why": _SLOW},
        example=4000,
        convert=math.radians,
    )
    spring: Spring = rig_key(  # noqa: RUF009
        "table",
        "The joint's spring, in one of two forms; see [Springs](#springs).",
        example={"frequency_hz": 2.5, "damping_ratio": 0.75},
    )
    target: dict[str, Any] = rig_key(  # noqa: RUF009
        "table",
        "What the joint follows; see [Targets](#targets).",
        example={"type": "csv", "file": "demo_animation.csv"},
        convert=dict,
        compare=False,  # a dict: not hashable
    )
    bus: str | None = rig_key(
        "text",
        "The bus the servo is on: the name of a `[buses.<name>]` table ([buses](buses.md)).",
        default=None,
        default_doc="the rig's only bus",
        allowed="a rig with one `[bus]` leaves it out; with several buses it is required",
    )
    initial_rad: float | None = rig_key(
        "number",
        "The spring's starting angle (joint frame); e.g. a free spring released there.",
        toml="initial_deg",
        unit="deg",
        default=None,
        default_doc="none: the present pose",
        allowed="within min_deg .. max_deg",
        example=35,
        convert=math.radians,
    )
    tracking_tolerance_rad: float = rig_key(
        "number",
        "A joint whose present position is further than this from its command ...",
        toml="tracking_tolerance_deg",
        unit="deg",
        default=TRACKING_TOLERANCE_DEG,
        bounds={"positive": True, "at_most": MAX_TRACKING_TOLERANCE_DEG, "why": "one turn"},
        convert=math.radians,
    )
    tracking_time_s: float = rig_key(
        "number",
        '... for longer than this is a "following error" (a safe stop).',
        toml="tracking_time_ms",
        unit="ms",
        default=TRACKING_TIME_MS,
        bounds={"positive": True, "at_most": MAX_TRACKING_TIME_MS},
        convert=_ms_to_s,
    )


@dataclass(frozen=True, kw_only=True)
class Rig:
    path: Path
    name: str = rig_key(
        "text",
        "The rig's name; it names the run directory.",
        default_doc="the file's stem",
        allowed="letters, digits, `_ - + .` and inner spaces, at most 100 (no `/` or `..`, no "
        "leading dot or dash)",
        example="demo",
    )
    bus: BusConfig = rig_key(  # noqa: RUF009
        "table", "The servo bus; see [[bus]](#bus).", default_doc="required, or `[buses]`"
    )
    #: ``((name, BusConfig), ...)`` of ``[buses.<name>]``: a rig made for one of them has it alone
    buses: tuple[tuple[str, BusConfig], ...] = rig_key(
        "table",
        "Several buses instead of `[bus]`: `[buses.<name>]` tables with the keys of `[bus]`, one "
        "process each, started together ([buses](buses.md)).",
        default=(),
        default_doc="none: one `[bus]`",
    )
    loop: LoopConfig = rig_key(  # noqa: RUF009
        "table",
        "The control loop; see [[loop]](#loop).",
        default=LoopConfig(),
        default_doc="all defaults",
    )
    safety: SafetyConfig = rig_key(  # noqa: RUF009
        "table",
        "Safe stops; see [[safety]](#safety).",
        default=SafetyConfig(),
        default_doc="all defaults",
    )
    telemetry: TelemetryConfig = rig_key(  # noqa: RUF009
        "table",
        "The run's record; see [[telemetry]](#telemetry).",
        default=TelemetryConfig(),
        default_doc="all defaults",
    )
    joints: tuple[JointConfig, ...] = rig_key(
        "list",
        "One `[[joints]]` table per joint; see [[[joints]]](#joints).",
        allowed="at least one",
    )
    clips: tuple[tuple[str, dict[str, Any]], ...] = rig_key(
        "table",
        "Named clips, `[clips.<name>]` tables of `<joint> = <target table>`; see [Clips](#clips).",
        default=(),
        default_doc="none",
        compare=False,
    )
    play: tuple[PlayEntry, ...] = rig_key(
        "list",
        "The clips the show plays, `[[play]]` tables in time order; see [Clips](#clips).",
        default=(),
        default_doc="none: each joint follows its `target`",
        compare=False,
    )
    text: str = field(repr=False, compare=False, default="")

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def servo_ids(self) -> tuple[int, ...]:
        return tuple(j.servo_id for j in self.joints)

    @property
    def bus_name(self) -> str | None:
        """The name of this rig's bus among its file's ``[buses]``; None for a ``[bus]`` rig."""
        return self.buses[0][0] if self.buses else None

    @property
    def base_dir(self) -> Path:
        """Relative file names in the rig (animations) are relative to the rig file."""
        return self.path.parent

    def spring_bank(self) -> Spring:
        """All joints' springs as one bank, in joint order."""
        return Spring.stack([j.spring for j in self.joints])
