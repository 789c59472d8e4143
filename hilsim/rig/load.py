"""Read and validate a rig file: :func:`load_rig`, one reader per section.

Defaults, bounds and the allowed-key lists come from the fields of :mod:`hilsim.rig.model` and
:mod:`hilsim.rig.forms` (their :class:`~hilsim.rig.keys.Key` metadata); this module adds only the
checks that span keys or sections.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import tomllib
from pathlib import Path
from typing import Any

from drivers.p1bus.table import Protocol, family_of, protocol_of
from drivers.protocol2.control_table import model_number, no_load_speed_deg_s, series
from hilsim.dynamics.integrators import INTEGRATORS
from hilsim.dynamics.springs import Spring
from hilsim.dynamics.stability import check_stability
from hilsim.rig.bus import BUS_NAME_RE, SERIES_MAX_BAUD, SUPPORTED_BAUDS, BusConfig
from hilsim.rig.clips import read_clips
from hilsim.rig.forms import (
    MAX_DAMPING_RATIO,
    MAX_FEEDFORWARD,
    SPRING_HZ_RANGE,
    WHY_HZ,
    WHY_Z,
    AnimatorSpring,
    PhysicsSpring,
)
from hilsim.rig.joint_map import JointMap
from hilsim.rig.keys import toml_keys
from hilsim.rig.model import (
    KNOWN_MODELS,
    MAX_STEPS_PER_S,
    NAME_RE,
    SERVO_ID_RANGE,
    WATCHDOG_MAX_MS,
    WATCHDOG_UNIT_MS,
    JointConfig,
    LoopConfig,
    Rig,
    RigError,
    SafetyConfig,
    TelemetryConfig,
)
from hilsim.rig.reader import Reader, build, finish, read_key, read_table

log = logging.getLogger("hilsim.rig")


def _one_protocol_per_bus(path: Path, joints: list[JointConfig], named: bool) -> None:
    """Every servo on one bus speaks one protocol: a servo of another never answers right."""
    first: dict[str | None, tuple[int, Protocol]] = {}
    for i, j in enumerate(joints):
        proto = protocol_of(j.model)
        assert proto is not None  # (the joint's reader checked the model)
        k, seen = first.setdefault(j.bus, (i, proto))
        if seen is not proto:
            where = f"buses.{j.bus}" if named else "bus"
            raise RigError(
                f"{path}: joints[{i}].model: one protocol per bus: {j.name} is a {j.model} "
                f"({proto}) but {joints[k].name} on the same {where} is a {joints[k].model} "
                f"({seen}); put them on separate [buses.<name>] tables"
            )


# ------------------------------------------------------------------------------------ the springs
def _spring(r: Reader, name: str) -> Spring:
    s = r.sub(name, required=True)
    keys = set(s.table)
    physics, animation = set(toml_keys(PhysicsSpring)), set(toml_keys(AnimatorSpring))
    if keys & physics and keys & animation:
        raise r.fail(
            name,
            "give either physics terms (m, c, k[, b]) or animator terms "
            "(frequency_hz, damping_ratio[, response]), not both",
        )
    try:
        if keys & animation:
            spring = Spring.from_animation(**read_table(s, AnimatorSpring))
            finish(s, AnimatorSpring)
        else:
            terms = read_table(s, PhysicsSpring)
            _check_physics_spring(s, **terms)
            spring = Spring(**terms)
            finish(s, PhysicsSpring)
    except ValueError as exc:
        if isinstance(exc, RigError):
            raise
        raise r.fail(name, str(exc)) from None
    return spring


def _check_physics_spring(s: Reader, m: float, c: float, k: float, b: float) -> None:
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
            f"within {f_lo:g}..{f_hi:g} Hz ({WHY_HZ})",
        )
    if not zeta <= MAX_DAMPING_RATIO:
        raise s.fail(
            "c",
            f"the damping ratio c/(2√(k·m)) = {zeta:.3g} must be <= {MAX_DAMPING_RATIO:g} "
            f"({WHY_Z}), got c = {c:g}",
        )
    b_max = MAX_FEEDFORWARD * (c + critical)
    if not abs(b) <= b_max:
        raise s.fail(
            "b",
            f"|b| must be <= {MAX_FEEDFORWARD:g}·(c + 2√(k·m)) = {b_max:.3g} for this spring "
            f"(a velocity feed-forward stronger than that is a slip), got {b:g}",
        )


# ------------------------------------------------------------------------------------- the joints
def _joint(path: Path, table: dict[str, Any], index: int) -> JointConfig:
    r = Reader(path, table, f"joints[{index}]")
    v: dict[str, Any] = {}  # file values (degrees, ms) by field name

    def key(field_name: str, **extra: Any) -> Any:
        v[field_name] = read_key(r, JointConfig, field_name, **extra)
        return v[field_name]

    name = key("name")
    if not name.isidentifier():
        raise r.fail(
            "name", f"use letters, digits and _ (it names telemetry columns), got {name!r}"
        )
    servo_id = key("servo_id")
    id_lo, id_hi = SERVO_ID_RANGE
    if not id_lo <= servo_id <= id_hi:
        raise r.fail("servo_id", f"must be {id_lo}..{id_hi}, got {servo_id}")
    key("bus")  # which of the rig's buses: checked against them in _on_buses
    model = key("model")
    if protocol_of(model) is None:
        raise r.fail(
            "model",
            f"unknown servo model {model!r}; known: {', '.join(KNOWN_MODELS)} "
            "(a -T or -R suffix is fine)",
        )
    if family_of(model) is None:
        try:
            model_number(model)
        except ValueError:
            raise r.fail(
                "model",
                f"{model} (Dynamixel Protocol 2.0) is not run by hilsim yet; the X series is",
            ) from None
    home = key("home_rad")
    direction = key("direction")
    if direction not in (1, -1):
        raise r.fail("direction", f"must be 1 or -1, got {direction}")
    lo, hi = key("min_rad"), key("max_rad")
    if hi <= lo:
        raise r.fail("max_deg", f"must be greater than min_deg ({lo}), got {hi}")
    servo = JointMap([home], [direction])  # degrees here: the map is linear
    fam = family_of(model)
    for edge, value in (("min_deg", lo), ("max_deg", hi)):
        servo_deg = servo.servo_angle(0, value)
        if not -180.0 <= servo_deg <= 180.0:
            raise r.fail(
                edge,
                f"home_deg + direction*{edge} = {servo_deg:g} deg is outside one "
                "servo turn (-180..180 deg around tick 2048)",
            )
        if fam is not None and fam.max_tick < 4095:  # AX, SCS: 1024 ticks over 300 degrees
            reach = 180.0 * fam.center_tick / (fam.ticks_per_turn / 2.0)
            if not -reach <= servo_deg <= reach:
                raise r.fail(
                    edge,
                    f"home_deg + direction*{edge} = {servo_deg:g} deg is beyond what a "
                    f"{model} turns (-{reach:g}..{reach:g} deg around tick {fam.center_tick})",
                )
    for field_name in ("max_speed_rad_s", "max_accel_rad_s2"):
        key(field_name)
    key("tracking_tolerance_rad")
    key("tracking_time_s")
    v["spring"] = _spring(r, "spring")
    key("target", hint='e.g. { type = "keyframes", keys = [[0, 0], [1, 30]] }')
    initial = key("initial_rad")
    if initial is not None and not lo <= initial <= hi:
        raise r.fail("initial_deg", f"must lie within min_deg..max_deg ({lo}..{hi}), got {initial}")
    finish(r, JointConfig)
    spring = v.pop("spring")
    return build(JointConfig, v, spring=spring)


# ----------------------------------------------------------------------------------- the sections
def _bus(b: Reader, port: str | None) -> BusConfig:
    """``[bus]``, or one ``[buses.<name>]`` table: the same keys."""
    if port is None:
        port = read_key(b, BusConfig, "port")
    else:  # the CLI's --port: the file's port is not read
        b.used.add("port")
    bauds = ", ".join(str(x) for x in SUPPORTED_BAUDS)
    values = read_table(b, BusConfig, skip=("port", "baud"))
    baud = read_key(b, BusConfig, "baud", hint=f"one of {bauds} bit/s")
    if baud not in SUPPORTED_BAUDS:
        raise b.fail("baud", f"{baud} bit/s is not a servo baud rate; allowed: {bauds}")
    finish(b, BusConfig)
    return build(BusConfig, {"port": port, "baud": baud, **values})


def _buses(top: Reader, port: str | None) -> tuple[tuple[str, BusConfig], ...]:
    """``((name, BusConfig), ...)`` of the ``[buses.<name>]`` tables in file order; ``()`` for a
    rig with one ``[bus]`` (read by the caller)."""
    if "buses" not in top.table:
        return ()
    if "bus" in top.table:
        raise top.fail("buses", "give one [bus] table or [buses.<name>] tables, not both")
    if port is not None:
        raise top.fail(
            "buses", "--port replaces the port of a rig's one [bus]; this rig names a port in "
            "each [buses.<name>] table"
        )  # fmt: skip
    tables = top.sub("buses")
    if not tables.table:
        raise top.fail("buses", "at least one [buses.<name>] table is needed")
    buses: list[tuple[str, BusConfig]] = []
    ports: dict[str, str] = {}
    for name, table in tables.table.items():
        tables.used.add(name)
        if not BUS_NAME_RE.fullmatch(name):
            raise tables.fail(
                name, "a bus name names its run directory: letters, digits, _ and - (at most "
                f"32, a letter, digit or _ first), got {name!r}"
            )  # fmt: skip
        if not isinstance(table, dict):
            raise tables.fail(name, "must be a table ([buses.<name>] with the keys of [bus])")
        bus = _bus(Reader(top.path, table, f"buses.{name}"), None)
        # one device under two names is one port (its real path); a URL as written
        port_id = os.path.realpath(bus.port) if bus.port.startswith("/") else bus.port.strip()
        same = ports.setdefault(port_id, name)
        if same != name:
            raise tables.fail(
                f"{name}.port", f"{bus.port!r} is already the port of buses.{same}: one port is "
                "one bus (give each bus its own port, or its joints one [buses.<name>] table)"
            )  # fmt: skip
        buses.append((name, bus))
    return tuple(buses)


def _on_buses(
    path: Path, joints: tuple[JointConfig, ...], buses: tuple[tuple[str, BusConfig], ...]
) -> tuple[JointConfig, ...]:
    """Each joint's ``bus`` checked against the rig's buses (the only one filled in); a servo
    ID once per bus; every bus with a joint."""
    names = [name for name, _ in buses]
    out = []
    for i, j in enumerate(joints):
        where = f"{path}: joints[{i}].bus"
        if not buses and j.bus is not None:
            raise RigError(
                f"{where}: this rig has one [bus]; name buses with [buses.<name>] tables to "
                f"put joints on them, got {j.bus!r}"
            )
        if buses and j.bus is None:
            if len(buses) > 1:
                raise RigError(
                    f"{where}: missing: this rig has {len(buses)} buses ({', '.join(names)}); "
                    f"name the one servo {j.servo_id} ({j.name}) is on"
                )
            j = dataclasses.replace(j, bus=names[0])
        if buses and j.bus not in names:
            raise RigError(f"{where}: no bus named {j.bus!r}; this rig's: {', '.join(names)}")
        out.append(j)
    seen: dict[tuple[str | None, int], int] = {}
    for i, j in enumerate(out):
        first = seen.setdefault((j.bus, j.servo_id), i)
        if first != i:
            on = f" on bus {j.bus!r}" if j.bus is not None else ""
            raise RigError(
                f"{path}: joints[{i}].servo_id: servo_id {j.servo_id!r} is already used by "
                f"joints[{first}]{on}"
            )
    _one_protocol_per_bus(path, out, bool(buses))
    for name in names:
        if not any(j.bus == name for j in out):
            raise RigError(
                f'{path}: buses.{name}: no joint is on this bus (a joint says bus = "{name}")'
            )
    return tuple(out)


def _loop(top: Reader) -> tuple[LoopConfig, int]:
    """The loop table, and the most substeps its rate allows."""
    lp = top.sub("loop")
    values = read_table(lp, LoopConfig, skip=("substeps",))
    if values["integrator"] not in INTEGRATORS:
        raise lp.fail(
            "integrator",
            f"must be one of {', '.join(INTEGRATORS)}; got {values['integrator']!r}",
        )
    rate_hz = values["rate_hz"]
    max_substeps = max(1, int(MAX_STEPS_PER_S // rate_hz))
    values["substeps"] = read_key(
        lp,
        LoopConfig,
        "substeps",
        hi=max_substeps,
        why=f"at {rate_hz:g} Hz: at most {MAX_STEPS_PER_S:,} integrator steps a second, "
        "each costs 10-30 us of CPU",
    )
    finish(lp, LoopConfig)
    return build(LoopConfig, values), max_substeps


def _check_watchdog(sf: Reader, ms: float) -> None:
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


def _safety(top: Reader, loop: LoopConfig) -> SafetyConfig:
    sf = top.sub("safety")
    safety = build(SafetyConfig, read_table(sf, SafetyConfig))
    if safety.watchdog_ms is not None:
        _check_watchdog(sf, safety.watchdog_ms)
    if safety.comm_failure_budget_ms < 1000.0 / loop.rate_hz:
        raise sf.fail(
            "comm_failure_budget_ms",
            f"must be at least one tick ({1000.0 / loop.rate_hz:g} ms), "
            f"got {safety.comm_failure_budget_ms:g}",
        )
    finish(sf, SafetyConfig)
    return safety


def _telemetry(top: Reader) -> TelemetryConfig:
    tl = top.sub("telemetry")
    telemetry = build(TelemetryConfig, read_table(tl, TelemetryConfig))
    finish(tl, TelemetryConfig)
    return telemetry


def _joints(top: Reader) -> tuple[JointConfig, ...]:
    raw_joints = read_key(top, Rig, "joints", hint="one [[joints]] table per joint")
    if not raw_joints:
        raise top.fail("joints", "at least one [[joints]] table is needed")
    joints = []
    for i, table in enumerate(raw_joints):
        if not isinstance(table, dict):
            raise top.fail(f"joints[{i}]", "must be a table ([[joints]])")
        joints.append(_joint(top.path, table, i))
    seen: dict[str, int] = {}
    for i, j in enumerate(joints):  # servo IDs: once per bus (_on_buses)
        if j.name in seen:
            raise RigError(
                f"{top.path}: joints[{i}].name: joint name {j.name!r} is already used by "
                f"joints[{seen[j.name]}]"
            )
        seen[j.name] = i
    return tuple(joints)


# --------------------------------------------------------------------------------------- the file
def _read_toml(path: Path) -> tuple[str, dict[str, Any]]:
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
        return text, tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RigError(f"{path}: not valid TOML: {exc}") from None


def _check_stable(
    path: Path, loop: LoopConfig, max_substeps: int, joints: tuple[JointConfig, ...]
) -> None:
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


def _check_speeds(path: Path, joints: tuple[JointConfig, ...]) -> None:
    """A speed limit beyond the model's no-load speed is a warning (the servo cannot
    follow such commands even unloaded; the show still runs, lagging)."""
    for i, j in enumerate(joints):
        top = no_load_speed_deg_s(j.model)
        asked = math.degrees(j.max_speed_rad_s)
        if top is not None and asked > top:
            log.warning(
                "%s: joints[%d].max_speed_deg_s (%s) = %g °/s is beyond the %s's no-load speed, "
                "%g °/s (%g rpm): it lags such commands even unloaded; lower it to %d or name "
                "a faster model",
                path, i, j.name, asked, j.model, top, top / 6.0, int(top),
            )  # fmt: skip


def load_rig(path: str | Path, *, port: str | None = None, bus: str | None = None) -> Rig:
    """Read and validate a rig file. ``port`` overrides ``bus.port`` (the CLI's ``--port``);
    ``bus`` picks one of a rig's ``[buses.<name>]`` (a rig with several needs it). Raises
    :class:`RigError` (a ValueError) naming the file and key on any problem, including a spring
    that the configured integrator and rate cannot integrate stably."""
    return select_bus(load_rigs(path, port=port), bus)


def select_bus(rigs: tuple[Rig, ...], bus: str | None) -> Rig:
    """The rig of bus ``bus`` among :func:`load_rigs`' (None: the only one). Raises RigError."""
    path, names = rigs[0].path, ", ".join(str(r.bus_name) for r in rigs)
    if bus is None:
        if len(rigs) == 1:
            return rigs[0]
        raise RigError(
            f"{path}: this figure is on {len(rigs)} buses ({names}); give --bus NAME "
            "(hilsim run starts one process per bus)"
        )
    for rig in rigs:
        if rig.bus_name == bus:
            return rig
    if rigs[0].bus_name is None:
        raise RigError(f"{path}: has one [bus] and no [buses.<name>] tables; got --bus {bus!r}")
    raise RigError(f"{path}: no bus named {bus!r}; this rig's: {names}")


def load_rigs(path: str | Path, *, port: str | None = None) -> tuple[Rig, ...]:
    """Every bus of a rig file as a rig of its own (its joints and bus; the rest shared), in
    file order; a rig with one ``[bus]`` is one. Raises RigError."""
    path = Path(path)
    text, data = _read_toml(path)
    top = Reader(path, data, "")

    name = top.get("name", str, path.stem)
    if not NAME_RE.fullmatch(name):
        given = "" if "name" in data else ' (the file name; set name = "..." to choose one)'
        raise top.fail(
            "name",
            f"it names the run directory, so use letters, digits, _ - + . and inner spaces "
            f"(at most 100; no / or .., no leading dot or dash), got {name!r}{given}",
        )
    buses = _buses(top, port)
    bus = None if buses else _bus(top.sub("bus", required=True), port)  # None: buses
    loop, max_substeps = _loop(top)
    safety = _safety(top, loop)
    telemetry = _telemetry(top)
    joints = _on_buses(path, _joints(top), buses)
    clips, play = read_clips(top, joints)
    finish(top, Rig)

    by_name: dict[str | None, BusConfig] = dict(buses) if bus is None else {None: bus}
    for i, j in enumerate(joints):
        top_baud = SERIES_MAX_BAUD.get(series(j.model.strip().upper()))
        baud = by_name[j.bus].baud
        if top_baud is not None and baud > top_baud:
            where = f"buses.{j.bus}" if j.bus is not None else "bus"
            raise RigError(
                f"{path}: joints[{i}].model: {j.model} ({series(j.model.upper())} series) runs "
                f"at most {top_baud} bit/s, but {where}.baud = {baud}"
            )
    _check_stable(path, loop, max_substeps, joints)
    _check_speeds(path, joints)
    if len(buses) > 1 and loop.cpu is not None:
        raise top.fail("loop.cpu", "would pin every bus's process to one CPU; leave it out")
    shared = dict(path=path, name=name, loop=loop, safety=safety, telemetry=telemetry, text=text)
    shared.update(clips=clips, play=play)
    if bus is not None:
        return (Rig(bus=bus, joints=joints, **shared),)
    return tuple(
        Rig(bus=cfg, buses=((b, cfg),), joints=tuple(j for j in joints if j.bus == b), **shared)
        for b, cfg in buses
    )
