"""A show session: a loaded rig turned into running parts, on an open bus, to its exit.

The one place where a show is put together (``hilsim run`` only prints what happens here)::

    rig = load_rig(path)                                 hilsim.rig
    parts = build_parts(rig)                             targets, joint map, safety filter,
                                                         integrator; errors name file and key
    port = port_for(rig, virtual)                        the emulator's clock chosen; spin window
    bus = open_bus(rig, port)                            DynamixelBus (or ShowRefusedError)
    notes = check_bus(rig, bus)                          cleared watchdog trips, model, limits,
                                                         Return Delay Time, bus capacity
    telemetry = open_telemetry(rig, run_dir, virtual)
    result = run_show(parts, bus, telemetry, ...)        HilLoop.run + summary.json; with
                                                         start_at, tick 0 at that instant
                                                         (several buses, one show:
                                                         hilsim.show.group)

Every refusal before torque goes on is a :class:`ShowRefusedError` (exit 2, nothing moved) with a
one-line reason. The wire-time model behind the capacity check is
:mod:`drivers.protocol2.wire_time`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from drivers.clock import MonotonicClock
from drivers.dynamixel.startup import Expectation, ReadMode
from drivers.protocol2.wire_time import cycle_time_s
from hilsim._types import JsonDict
from hilsim.rig import Rig
from hilsim.rig.joint_map import JointMap
from hilsim.show.end import ShowResult, close_quietly, crashed, end_show
from hilsim.show.loop import HilLoop
from hilsim.show.parts import Parts
from hilsim.show.stop import StopFlag

if TYPE_CHECKING:
    from drivers.dynamixel.bus import DynamixelBus
    from drivers.p1bus.guardian import Guardian
    from drivers.p1bus.startup import P1Expectation
    from hilsim.live.director import Director
    from hilsim.show.servo_check import Problem
    from hilsim.telemetry import TelemetryWriter

#: Fraction of a tick the bus transaction may take; the rest is for the host.
BUS_SHARE_OF_TICK = 0.8


class ShowRefusedError(Exception):
    """The show cannot start (nothing moved): the bus, the servos or the run directory.
    The message is one line for the user (plus a detail block for a servo mismatch)."""


# ---------------------------------------------------------------------- the bus


def real_clock(rig: Rig) -> MonotonicClock:
    """The host's clock for a show on hardware, with the rig's spin window (``loop.spin_us``:
    sleep until this close to each deadline, then spin)."""
    return MonotonicClock(rig.loop.spin_us * 1e-6)


def port_for(rig: Rig, virtual: bool) -> str:
    """The port to open: for the emulator, with its clock chosen (virtual time, or the real
    clock with the rig's spin window); hardware refuses virtual time (ValueError)."""
    port = rig.bus.port
    if not port.lower().startswith("dxlsim://"):
        if virtual:
            raise ValueError(f"--virtual-time needs the emulator (a dxlsim:// port), not {port!r}")
        return port
    from drivers.dxlsim.url import DxlsimUrl

    url = DxlsimUrl.parse(port)
    if url.name:  # a named bus brings its own clock
        return port
    if virtual:
        return str(url.replace(clock="virtual"))
    return str(url.replace(clock="real", spin_us=rig.loop.spin_us))


def p1_models(rig: Rig) -> list[str] | None:
    """The rig's servo models when they are of the Protocol 1.0-framed families (Feetech,
    Dynamixel AX/MX), None for an X-series bus (one protocol per bus: the loader checked)."""
    from drivers.p1bus.table import family_of

    models = [j.model for j in rig.joints]
    return models if family_of(models[0]) is not None else None


def open_bus(rig: Rig, port: str) -> DynamixelBus:
    """Open the bus the rig names (``port`` from :func:`port_for`): the X-series backend, or
    :class:`~drivers.p1bus.bus.P1ServoBus` for Feetech and Dynamixel Protocol 1.0 servos. Hardware
    gets a monotonic clock with the rig's spin window; the emulator brings its own clock."""
    from drivers.dynamixel.bus import DynamixelBus
    from drivers.dynamixel.errors import DynamixelError

    clock = None if port.lower().startswith("dxlsim://") else real_clock(rig)
    models = p1_models(rig)
    try:
        if models is not None:
            from drivers.p1bus.bus import P1ServoBus

            return P1ServoBus.open(  # type: ignore[return-value]  # the loop needs a ServoBus
                port,
                baud=rig.bus.baud,
                ids=rig.servo_ids,
                models=models,
                latency_timer_ms=rig.bus.latency_timer_ms,
                clock=clock,
            )
        return DynamixelBus.open(
            port,
            baud=rig.bus.baud,
            ids=rig.servo_ids,
            read_mode=rig.bus.read,
            latency_timer_ms=rig.bus.latency_timer_ms,
            clock=clock,
        )
    except (DynamixelError, ValueError, OSError) as exc:
        msg = str(exc)
        raise ShowRefusedError(
            msg if msg.startswith("cannot open") else f"cannot open {rig.bus.port}: {msg}"
        ) from None


def check_bus(rig: Rig, bus: DynamixelBus, say: Callable[[str], None]) -> list[str]:
    """Make the servos ready and check them against the rig before anything moves.

    Clears Bus Watchdog trips a previous host left, checks every servo (model, limits, Return
    Delay Time...; a silent one at the other bauds too) and that the bus can carry the tick
    rate (:func:`hilsim.show.servo_check.check_everything`). Each note is passed to ``say``
    as it is found and returned (for ``events.jsonl``). Raises :class:`ShowRefusedError`
    with one table of every problem found.
    """
    from drivers.dynamixel.errors import DynamixelError
    from hilsim.show.servo_check import check_everything, use_tick_block

    if not bus.has_watchdog:
        return check_p1_bus(rig, bus, say)
    latency_ms = bus.link.latency_timer_ms
    notes: list[str] = []
    try:
        # A previous run's "hold" exit leaves the Bus Watchdog armed; once that host is
        # gone it trips. We are the host again: clear it, and say so.
        tripped = bus.clear_watchdog_trips()
        if tripped:
            notes.append(
                f"servo(s) {', '.join(map(str, tripped))}: Bus Watchdog had tripped (a "
                "previous run's hold exit, or another program that stopped); cleared"
            )
            say(notes[-1])
        budget = BUS_SHARE_OF_TICK * rig.loop.period_s
        report, problems, why = check_everything(
            rig, bus, expectations(rig, latency_ms), budget, latency_ms
        )
    except (DynamixelError, ValueError) as exc:
        raise ShowRefusedError(f"start-up check failed on {rig.bus.port}: {exc}") from None
    if problems or report is None:
        raise _mismatch(rig, problems, why)
    block_notes = use_tick_block(rig, bus, report, budget, latency_ms)
    for note in (*report.notes, *block_notes):
        say(f"note: {note}")
    notes += [*report.notes, *block_notes]
    return notes


def _mismatch(rig: Rig, problems: list[Problem], why: Sequence[str]) -> ShowRefusedError:
    """The start-up check's one refusal: every problem in one table, then why."""
    from hilsim.show.servo_check import render

    ids = sorted({p.servo_id for p in problems if p.servo_id is not None})
    lines = [
        f"the servos on {rig.bus.port} do not match {rig.path}: {len(problems)} problem(s)"
        + (f" on servo(s) {ids}" if ids else "")
        + "; nothing moved",
        render(problems),
        *why,
    ]
    return ShowRefusedError("\n".join(lines))


def check_p1_bus(rig: Rig, bus: DynamixelBus, say: Callable[[str], None]) -> list[str]:
    """:func:`check_bus` for the Protocol 1.0-framed families (no Bus Watchdog): the reads
    fitted to the tick, then every problem in one refusal as for the X series
    (:func:`hilsim.show.servo_check_p1.check_everything_p1`: the servos in the family's
    terms, silent ones looked for at the other bauds, the bus's capacity)."""
    from drivers.dynamixel.errors import DynamixelError
    from drivers.p1bus.bus import P1ServoBus
    from hilsim.show.servo_check_p1 import check_everything_p1

    assert isinstance(bus, P1ServoBus)
    bus.plan(rig.loop.period_s)
    budget = BUS_SHARE_OF_TICK * rig.loop.period_s
    try:
        report, problems, why = check_everything_p1(rig, bus, p1_expectations(rig, bus), budget)
    except (DynamixelError, ValueError) as exc:
        raise ShowRefusedError(f"start-up check failed on {rig.bus.port}: {exc}") from None
    if problems or report is None:
        raise _mismatch(rig, problems, why)
    notes = list(report.notes)
    rate = bus.read_rate_hz(rig.loop.rate_hz)
    notes.append(f"each servo's position is read {rate:.4g} times a second ({bus.read_mode})")
    for note in notes:
        say(f"note: {note}")
    return notes


def start_guardian(
    rig: Rig, bus: DynamixelBus, run_dir: Path | None
) -> tuple[Guardian | None, str]:
    """On a bus with no Bus Watchdog, on an OS serial port: start the guardian that applies
    the exit policy if this process dies (:mod:`drivers.p1bus.guardian`), before torque goes
    on. Returns it (None when there is none to start) and the start-up line that says what
    happens if the program dies. Never refuses the show: a guardian that cannot start is said."""
    if bus.has_watchdog:
        return None, ""
    fd = getattr(getattr(bus.link.port, "ser", None), "fd", None)
    if not isinstance(fd, int) or fd < 0:
        return None, "if this program dies the emulated servos stop with it (no guardian needed)"
    from drivers.p1bus.guardian import Guardian

    relax = rig.safety.exit_policy == "relax"
    try:
        guardian = Guardian.start(
            fd,
            port=bus.link.name,
            ids=rig.servo_ids,
            models=[j.model for j in rig.joints],
            policy=str(rig.safety.exit_policy),
            run_dir=run_dir,
        )
    except OSError as exc:
        return None, (
            f"warning: cannot start the guardian ({exc.strerror or exc}): if this program dies "
            "the servos hold their last goal with torque on"
        )
    what = (
        "turns their torque off (exit policy relax), reads it back"
        if relax
        else "leaves them holding their last goal (exit policy hold)"
    )
    return guardian, (
        f"guardian (pid {guardian.pid}): if this program dies it {what} and says so in the "
        "run directory (guardian.json); if the computer stops, the servos hold their last goal"
    )


def check_teach(rig: Rig, bus: DynamixelBus, director: Director | None) -> None:
    """A show's teach-by-hand joints go limp; a servo whose Drive Mode has bit 3 set (Torque
    On by Goal Update) would turn its torque back on at the next goal, under a person's hand:
    refused before anything moves (ShowRefusedError naming the servo)."""
    from drivers.dynamixel.errors import DynamixelError
    from drivers.protocol2.control_table import DRIVE_MODE

    teach = None if director is None else director.teach
    if teach is None or not teach.limp_indices:
        return
    if not bus.has_watchdog:  # a Feetech or Dynamixel Protocol 1.0 bus
        joint = rig.joints[teach.limp_indices[0]]
        raise ShowRefusedError(
            f"teach: servo {joint.servo_id} ({joint.name}) is a {joint.model}: on these servos a "
            "goal write can turn torque back on (Feetech always does), under the hand, and every "
            "tick writes every servo's goal. Teach-by-hand runs on X-series servos only"
        )
    for i in teach.limp_indices:
        joint = rig.joints[i]
        try:
            mode = bus.link.read_item(joint.servo_id, DRIVE_MODE)
        except DynamixelError as exc:
            raise ShowRefusedError(
                f"teach: cannot read servo {joint.servo_id}'s Drive Mode: {exc}"
            ) from None
        if mode & 0x08:
            raise ShowRefusedError(
                f"teach: servo {joint.servo_id} ({joint.name}) has Drive Mode bit 3 set (Torque "
                "On by Goal Update): it would turn its torque back on under the hand. Clear it "
                f"(Drive Mode, address 10, now {mode}) or do not teach {joint.name}"
            )


def return_delay_budget_us(rig: Rig, latency_timer_ms: float = 0.0) -> float:
    """The largest Return Delay Time with which the bus traffic still fits in a tick."""
    n = len(rig.joints)
    fast = rig.bus.read is not ReadMode.PLAIN
    base = cycle_time_s(n, rig.bus.baud, fast, latency_s=latency_timer_ms * 1e-3)
    spare = BUS_SHARE_OF_TICK * rig.loop.period_s - base
    return max(0.0, spare / (1 if fast else n) * 1e6)


def p1_return_delay_budget_us(rig: Rig, bus: object) -> float:
    """The largest Return Delay Time a Protocol 1.0-framed bus's tick leaves room for: what
    is left of the tick's bus share after the cycle at Return Delay 0, over the replies."""
    from drivers.p1bus.bus import P1ServoBus

    assert isinstance(bus, P1ServoBus)
    spare = BUS_SHARE_OF_TICK * rig.loop.period_s - bus.model_cycle_s(return_delay_s=0.0)
    return max(0.0, spare / bus.per_tick * 1e6)


def p1_expectations(rig: Rig, bus: object) -> list[P1Expectation]:
    """:func:`expectations` of a Protocol 1.0-framed bus's servos."""
    from drivers.p1bus.startup import P1Expectation

    rdt_max = p1_return_delay_budget_us(rig, bus)
    if rig.bus.return_delay_us is not None:
        rdt_max = min(rdt_max, rig.bus.return_delay_us)
    jmap = JointMap.of(rig.joints)
    return [
        P1Expectation(j.servo_id, j.model, jmap.servo_range(i, j.min_rad, j.max_rad), rdt_max)
        for i, j in enumerate(rig.joints)
    ]


def expectations(rig: Rig, latency_timer_ms: float = 0.0) -> list[Expectation]:
    """What each servo must look like for this rig to run (checked before anything moves)."""
    rdt_max = return_delay_budget_us(rig, latency_timer_ms)
    if rig.bus.return_delay_us is not None:
        rdt_max = min(rdt_max, rig.bus.return_delay_us)
    jmap = JointMap.of(rig.joints)
    return [
        Expectation(
            id=j.servo_id,
            model=j.model,
            position_range_rad=jmap.servo_range(i, j.min_rad, j.max_rad),
            return_delay_us_max=rdt_max,
        )
        for i, j in enumerate(rig.joints)
    ]


# ---------------------------------------------------------------------- running it


def open_telemetry(rig: Rig, run_dir: Path, virtual: bool) -> TelemetryWriter:
    """The run's telemetry writer (raises :class:`ShowRefusedError`)."""
    from hilsim.telemetry import TelemetryWriter

    try:
        return TelemetryWriter(
            run_dir,
            rig.joint_names,
            servo_ids=rig.servo_ids,
            flush_interval_s=rig.telemetry.flush_interval_s,
            format=rig.telemetry.format,  # auto: csv, or for big runs parquet (else csv.gz)
            rate_hz=rig.loop.rate_hz,
            max_bytes=None if (mb := rig.telemetry.max_mb) is None else int(mb * 1e6),
            max_age_s=None if (h := rig.telemetry.max_age_h) is None else h * 3600.0,
            config_text=rig.text,
            # virtual time outruns any disk: wait for the writer rather than drop rows
            overflow="block" if virtual else "drop",
        )
    except (OSError, ValueError) as exc:
        raise ShowRefusedError(f"cannot write telemetry to {run_dir}: {exc}") from None


def run_show(
    parts: Parts,
    bus: DynamixelBus,
    telemetry: TelemetryWriter,
    *,
    duration_s: float | None,
    stop: StopFlag,
    on_status: Callable[[JsonDict], None] | None = None,
    start_at: float | None = None,
    on_stop: Callable[[int, str], None] | None = None,
    on_loop: Callable[[HilLoop], None] | None = None,
) -> ShowResult:
    """Run the show, then end its record (:func:`hilsim.show.end.end_show`: the outcome
    decided once, then ``summary.json``, ``docs/summary.md``, says it).

    ``start_at``: the real clock's time of tick 0 (``time.monotonic``; the buses of a figure
    share it); None: at once. A virtual clock ignores it (its show time is k·period).
    ``on_stop``: told the code and reason as the loop stops (:class:`~hilsim.show.loop.HilLoop`).
    ``on_loop``: given the loop once built, before it runs (the panel's feed reads its arrays)."""
    try:
        loop = HilLoop(
            parts,
            bus,
            telemetry,
            duration_s=duration_s,
            stop=stop,
            on_status=on_status,
            start_at=start_at,
            on_stop=on_stop,
        )
        if on_loop is not None:
            on_loop(loop)
        wall0 = time.perf_counter()
        result = loop.run()
        wall = time.perf_counter() - wall0
    except BaseException as exc:
        if parts.director is not None:
            parts.director.close_inputs()
        close_quietly(telemetry, crashed(exc))
        raise
    endless = duration_s is None and parts.targets.duration is None
    return end_show(parts, bus, telemetry, result, wall, endless=endless)
