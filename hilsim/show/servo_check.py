"""The start-up check's one refusal: every problem the host can see, in one table.

:func:`check_everything` runs the driver's check (:meth:`DynamixelBus.check`), and when a
servo is silent, looks for it at the other baud rates of its family and checks it there too
(so a factory servo at 57600 bit/s shows its Return Delay Time and the rest at once); then
the bus's capacity at the rig's rate, as the servos are now and as ``hilsim setup`` will
leave them. Each row names its joint; the fix column names the rig key to change or the
``hilsim setup`` command that writes the servos. Nothing is written there.

:func:`use_tick_block`, once everything passed: each servo's health in the tick's own read
where the bus has room for it (:mod:`drivers.dynamixel.tick_block`: RAM only, read back,
written by the bus with the first torque on).
"""

from __future__ import annotations

import shlex
from collections.abc import Collection
from dataclasses import dataclass
from typing import TYPE_CHECKING

from drivers.dynamixel.errors import Mismatch, StartupMismatch
from drivers.dynamixel.startup import ReadMode, ServoState, StartupReport, check_servo
from drivers.protocol2.wire_time import cycle_time_s
from hilsim.rig import Rig

if TYPE_CHECKING:
    from drivers.dynamixel.bus import DynamixelBus
    from drivers.dynamixel.startup import Expectation

#: rows whose cure is a register ``hilsim setup`` writes
SETUP_ITEMS = frozenset(
    {
        "baud",
        "Return Delay Time",
        "Status Return Level",
        "Operating Mode",
        "position range",
        "Shutdown (torque cut on)",
        "bus capacity",
    }
)


@dataclass(frozen=True)
class Problem:
    """One row of the refusal: a servo (None: the bus) and its joint."""

    servo_id: int | None
    joint: str
    item: str
    expected: str
    found: str
    fix: str


def setup_return_delay_us(rig: Rig) -> float:
    """The Return Delay Time ``hilsim setup`` writes (µs): the rig's, else 0."""
    return rig.bus.return_delay_us or 0.0


def setup_command(rig: Rig) -> str:
    """The command that brings the servos to what ``rig`` expects."""
    bus = f" --bus {shlex.quote(rig.bus_name)}" if rig.bus_name else ""
    return (
        f"hilsim setup {shlex.quote(str(rig.path))}{bus} --port {shlex.quote(rig.bus.port)} --yes"
    )


def baud_problems(
    rig: Rig, names: dict[int, tuple[int, str]], elsewhere: dict[int, int]
) -> list[Problem]:
    """A row for each servo that answers at another baud than the rig's (``elsewhere``: ID ->
    the baud it answered at); the fix is the setup command."""
    return [
        Problem(
            sid,
            names[sid][1],
            "baud",
            f"{rig.bus.baud} bit/s",
            f"{baud} bit/s (answers there, not at {rig.bus.baud})",
            setup_command(rig),
        )
        for sid, baud in sorted(elsewhere.items())
    ]


def check_everything(
    rig: Rig,
    bus: DynamixelBus,
    exps: list[Expectation],
    budget_s: float,
    latency_ms: float,
) -> tuple[StartupReport | None, list[Problem], list[str]]:
    """The driver's check plus what it cannot see; returns (report when it passed, every
    problem, notes worth a line under the table)."""
    rows: list[Mismatch] = []
    report: StartupReport | None = None
    try:
        report = bus.check(exps)
        states = list(report.servos)
    except StartupMismatch as exc:
        rows = list(exc.rows)
        states = []
    silent = [r.servo_id for r in rows if r.item == "answers Ping"]
    elsewhere: dict[int, int] = {}
    answered: list[int] = []
    if silent:
        answered, elsewhere, more_rows, more_states = _look_elsewhere(bus, exps, silent)
        rows = [r for r in rows if r.servo_id not in elsewhere] + more_rows
        states += more_states
    if report is None:
        states += _states_of_the_rest(bus, exps, rows, states)
    names = {j.servo_id: (i, j.name) for i, j in enumerate(rig.joints)}
    problems = [problem_row(rig, r, names, answered, bus.link.baud) for r in rows]
    problems += baud_problems(rig, names, elsewhere)
    notes: list[str] = []
    baud_now = min((elsewhere.get(s.id, bus.link.baud) for s in states), default=bus.link.baud)
    cap = _capacity(rig, bus, states, baud_now, budget_s, latency_ms)
    if cap is not None:
        problems.append(cap[0])
        notes.append(cap[1])
    problems.sort(key=lambda p: (p.servo_id is None, p.servo_id or 0))
    return report, problems, notes


def _look_elsewhere(
    bus: DynamixelBus, exps: list[Expectation], silent: list[int]
) -> tuple[list[int], dict[int, int], list[Mismatch], list[ServoState]]:
    """Who answered at the bus's baud; at which other baud each silent servo answers, and
    its own check there. The link is back at the bus's baud afterwards."""
    from drivers.dynamixel.configure import X_SERIES, find
    from drivers.dynamixel.errors import DynamixelError

    link, home = bus.link, bus.link.baud
    try:
        answered = sorted(link.broadcast_ping())
        link.settle()
    except DynamixelError:
        answered = []
    elsewhere: dict[int, int] = {}
    rows: list[Mismatch] = []
    states: list[ServoState] = []
    by_id = {e.id: e for e in exps}
    try:
        for baud in X_SERIES.probe_order(home)[1:]:
            left = [sid for sid in silent if sid not in elsewhere]
            if not left:
                break
            try:
                hits = find(link, (baud,), left)
            except ValueError:  # a rate this port cannot set
                continue
            for f in hits:
                if f.id not in left:
                    continue
                elsewhere[f.id] = baud
                found = check_servo(
                    link, by_id[f.id], attempts=1 + bus.retries, fast_required=False
                )
                rows += found.rows
                if found.state is not None:
                    states.append(found.state)
    finally:
        link.set_baud(home)
    return answered, elsewhere, rows, states


def _states_of_the_rest(
    bus: DynamixelBus, exps: list[Expectation], rows: list[Mismatch], have: list[ServoState]
) -> list[ServoState]:
    """The states of servos the failed check read (its report is lost with the failure):
    read again, for the capacity estimate."""
    seen = {s.id for s in have} | {r.servo_id for r in rows if r.item == "answers Ping"}
    out = []
    for e in exps:
        if e.id in seen:
            continue
        found = check_servo(bus.link, e, attempts=1 + bus.retries, fast_required=False)
        if found.state is not None:
            out.append(found.state)
    return out


def problem_row(
    rig: Rig,
    r: Mismatch,
    names: dict[int, tuple[int, str]],
    answered: list[int],
    baud: int,
    *,
    range_item: str = "position range",
    setup_items: Collection[str] = SETUP_ITEMS,
    who: str = "IDs",
) -> Problem:
    """One table row from a start-up mismatch: its joint, and a fix that names the rig key or
    the setup command. A family names its range item and the items setup writes; ``who``
    names the IDs listed as answering when a servo is silent."""
    i, joint = names.get(r.servo_id, (-1, ""))
    fix, found = r.fix, r.found
    if r.item == "model":
        model = r.found.split(" (")[0]
        fix = f'joints[{i}].model = "{model}" (or the servo the rig names)'
    elif r.item == "answers Ping":
        listed = ", ".join(map(str, answered)) if answered else "none"
        found = f"{r.found}; {who} answering at {baud}: {listed}; no answer at any other baud"
        fix = f"check ID, power and wiring (`hilsim setup ... --id OLD:{r.servo_id}` renames one)"
    elif r.item == range_item:
        fix = f"{setup_command(rig)} (widens the limits), or narrow joints[{i}].min_deg/max_deg"
    elif r.item in setup_items:
        fix = setup_command(rig)
    return Problem(r.servo_id, joint, r.item, r.expected, found, fix)


def _capacity(
    rig: Rig,
    bus: DynamixelBus,
    states: list[ServoState],
    baud_now: int,
    budget_s: float,
    latency_ms: float,
) -> tuple[Problem, str] | None:
    """The capacity row (None when the bus carries the rate): now, and after setup."""
    n = len(rig.joints)
    latency = latency_ms * 1e-3
    known = len(states) == n
    fast_now = bus.read_mode is ReadMode.FAST
    fast_after = rig.bus.read is ReadMode.FAST or (
        rig.bus.read is ReadMode.AUTO and known and all(s.fast_read for s in states)
    )
    after = cycle_time_s(
        n,
        rig.bus.baud,
        fast_after,
        return_delay_s=setup_return_delay_us(rig) * 1e-6,
        latency_s=latency,
    )
    now = None
    if known:
        by_id = {s.id: s for s in states}
        rdts = [by_id[sid].return_delay_us * 1e-6 for sid in rig.servo_ids]
        now = cycle_time_s(n, baud_now, fast_now, return_delay_s=rdts, latency_s=latency)
    rate = rig.loop.rate_hz
    limit = f"<= {budget_s * 1e3:.2f} ms a tick"
    if after > budget_s:
        most = budget_s / after * rate
        found = f"{after * 1e3:.2f} ms after setup" + (
            f", {now * 1e3:.2f} ms now" if now is not None else ""
        )
        fix = f"loop.rate_hz = {int(most)} or less (or fewer servos, a faster baud)"
    elif now is not None and now > budget_s:
        found = f"{now * 1e3:.2f} ms now, {after * 1e3:.2f} ms after setup"
        fix = setup_command(rig)
    else:
        return None
    when = "even after setup" if after > budget_s else "as the servos are now"
    why = (
        f"the bus cannot carry {rate:g} Hz {when}: one tick's Sync Write + Sync "
        f"Read takes {found}, against {budget_s * 1e3:.2f} ms of a {rig.loop.period_s * 1e3:g} ms "
        f"tick (USB latency timer {latency_ms:g} ms; `hilsim bench` shows each cost)"
    )
    return Problem(None, "", "bus capacity", f"{rate:g} Hz: {limit}", found, fix), why


def use_tick_block(
    rig: Rig, bus: DynamixelBus, report: StartupReport, budget_s: float, latency_ms: float
) -> list[str]:
    """Have the tick's Fast Sync Read carry every servo's torque and Bus Watchdog with its
    position (:meth:`DynamixelBus.use_tick_block`) when the bus can and the cycle with those
    bytes still fits in ``budget_s``; else the health is read between ticks, as the notes
    returned say (the block is written with the first torque on)."""
    from drivers.dynamixel.tick_block import SIZE

    if bus.read_mode is not ReadMode.FAST:
        return []  # (the plain read's note says why already)
    if not rig.bus.health_in_tick:
        return ["health read between ticks: `bus.health_in_tick = false`"]
    if not bus.tick_block_possible():
        return [
            "health read between ticks: Indirect Data 1 is not at one address on every "
            "servo (X330 beside X430/X540), so one Sync Read cannot carry it"
        ]
    rdts = [s.return_delay_us * 1e-6 for s in report.servos]
    n, latency = len(report.servos), latency_ms * 1e-3
    with_block = cycle_time_s(
        n, bus.link.baud, True, return_delay_s=rdts, latency_s=latency, read_data_bytes=SIZE
    )
    if with_block > budget_s:
        return [
            f"health read between ticks: the tick's read with each servo's health "
            f"({SIZE} bytes a servo, not 4) takes {with_block * 1e3:.2f} ms a tick, over "
            f"the bus's {budget_s * 1e3:.2f} ms"
        ]
    bus.use_tick_block()
    return []


def render(problems: list[Problem]) -> str:
    """The problems as one aligned table."""
    head = ("id", "joint", "item", "expected", "found", "fix")
    cells = [head] + [
        (
            "bus" if p.servo_id is None else str(p.servo_id),
            p.joint,
            p.item,
            p.expected,
            p.found,
            p.fix,
        )
        for p in problems
    ]
    widths = [max(len(row[c]) for row in cells) for c in range(len(head))]
    lines = []
    for k, row in enumerate(cells):
        lines.append("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip())
        if k == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)
