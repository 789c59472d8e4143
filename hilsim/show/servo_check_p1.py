"""The start-up check's one refusal on a Feetech or Dynamixel Protocol 1.0 bus.

As :func:`hilsim.show.servo_check.check_everything` does for the X series, in the family's
terms: the driver's check (:meth:`~drivers.p1bus.bus.P1ServoBus.check`), each silent servo
looked for at the family's other bauds (a Feetech broadcast Ping, a Dynamixel Ping per ID) and
checked there, and the bus's capacity at the rig's rate, now and after ``hilsim setup``; each
row names its joint, and its fix the rig key or the ``hilsim setup`` command. The rows are
:class:`~hilsim.show.servo_check.Problem` and print with the same
:func:`~hilsim.show.servo_check.render`. Nothing is written here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from drivers.dynamixel.errors import CommError, Mismatch, StartupMismatch
from hilsim.rig import Rig
from hilsim.show.servo_check import (
    Problem,
    baud_problems,
    problem_row,
    setup_command,
    setup_return_delay_us,
)

if TYPE_CHECKING:
    from drivers.p1bus.bus import P1ServoBus
    from drivers.p1bus.startup import P1Expectation, P1StartupReport

#: rows whose cure is a register ``hilsim setup`` writes (the family's names for them)
P1_SETUP_ITEMS = frozenset(
    {
        "Baud Rate",
        "Return Delay Time",
        "Status Return Level",
        "Response Status Level",
        "mode",
        "Phase",
    }
)


def check_everything_p1(
    rig: Rig, bus: P1ServoBus, exps: list[P1Expectation], budget_s: float
) -> tuple[P1StartupReport | None, list[Problem], list[str]]:
    """The driver's check plus what it cannot see; returns (report when it passed, every
    problem, notes worth a line under the table)."""
    rows: list[Mismatch] = []
    report = None
    try:
        report = bus.check(exps)
    except StartupMismatch as exc:
        rows = list(exc.rows)
    silent = [r.servo_id for r in rows if r.item == "answers Ping"]
    elsewhere: dict[int, int] = {}
    rdts: list[float] = []
    if silent:
        elsewhere, more, rdts = _look_elsewhere(bus, exps, silent)
        rows = [r for r in rows if r.servo_id not in elsewhere] + more
    names = {j.servo_id: (i, j.name) for i, j in enumerate(rig.joints)}
    answered = [sid for sid in rig.servo_ids if sid not in silent]
    problems = [_problem(rig, r, names, answered, bus.link.baud) for r in rows]
    problems += baud_problems(rig, names, elsewhere)
    notes: list[str] = []
    baud_now = min(elsewhere.values(), default=bus.link.baud)  # the slowest servo's rate
    cap = _capacity(rig, bus, budget_s, rdts, baud_now, known=len(silent) == len(elsewhere))
    if cap is not None:
        problems.append(cap[0])
        notes.append(cap[1])
    problems.sort(key=lambda p: (p.servo_id is None, p.servo_id or 0))
    return (report if not problems else None), problems, notes


def _look_elsewhere(
    bus: P1ServoBus, exps: list[P1Expectation], silent: list[int]
) -> tuple[dict[int, int], list[Mismatch], list[float]]:
    """At which other baud each silent servo answers, its own check there, and the Return
    Delay Times read there (s). The link is back at the bus's baud afterwards."""
    from drivers.p1bus.configure import find, probe_order
    from drivers.p1bus.startup import check_servo

    link, home = bus.link, bus.link.baud
    by_id = {e.id: e for e in exps}
    elsewhere: dict[int, int] = {}
    rows: list[Mismatch] = []
    rdts: list[float] = []
    try:
        for fam in dict.fromkeys(bus.by_id[s] for s in silent):  # one family, in practice
            ids = [s for s in silent if bus.by_id[s] is fam]
            for baud in probe_order(fam, home)[1:]:
                left = [s for s in ids if s not in elsewhere]
                if not left:
                    break
                for f in find(link, fam, (baud,), left):
                    if f.id not in left:
                        continue
                    elsewhere[f.id] = baud
                    found = check_servo(link, fam, by_id[f.id], 1 + bus.retries)
                    rows += found.rows
                    if found.return_delay_s is not None:
                        rdts.append(found.return_delay_s)
    except CommError:
        pass  # what was found so far is said; the rest stays silent
    finally:
        link.set_baud(home)
    return elsewhere, rows, rdts


def _problem(
    rig: Rig, r: Mismatch, names: dict[int, tuple[int, str]], answered: list[int], baud: int
) -> Problem:
    if r.item == "registers" and "no reply" in r.found:
        fix = f"it answers Ping but not Read (Status Return Level 0?): {setup_command(rig)}"
        return Problem(r.servo_id, names.get(r.servo_id, (-1, ""))[1], r.item, r.expected,
                       r.found, fix)  # fmt: skip
    return problem_row(
        rig, r, names, answered, baud,
        range_item="angle limits", setup_items=P1_SETUP_ITEMS, who="rig IDs",
    )  # fmt: skip


def _capacity(
    rig: Rig, bus: P1ServoBus, budget_s: float, rdts: list[float], baud_now: int, *, known: bool
) -> tuple[Problem, str] | None:
    """The capacity row (None when the bus carries the rate): now, and after setup."""
    after = bus.model_cycle_s(return_delay_s=setup_return_delay_us(rig) * 1e-6)
    now = None
    if known:
        rdt_now = max([bus.return_delay_s, *rdts])
        now = bus.model_cycle_s(return_delay_s=rdt_now, baud=baud_now)
    rate = rig.loop.rate_hz
    if after > budget_s:
        found = f"{after * 1e3:.2f} ms after setup" + (
            f", {now * 1e3:.2f} ms now" if now is not None else ""
        )
        most = int(budget_s / after * rate)
        fix = f"loop.rate_hz = {most} or less (or fewer servos, a faster baud)"
    elif now is not None and now > budget_s:
        found = f"{now * 1e3:.2f} ms now, {after * 1e3:.2f} ms after setup"
        fix = setup_command(rig)
    else:
        return None
    when = "even after setup" if after > budget_s else "as the servos are now"
    why = (
        f"the bus cannot carry {rate:g} Hz {when}: one tick's Sync Write + {bus.read_mode} "
        f"takes {found}, against {budget_s * 1e3:.2f} ms of a {rig.loop.period_s * 1e3:g} ms "
        f"tick (USB latency timer {bus.link.latency_timer_ms:g} ms; `hilsim bench` shows each "
        "cost)"
    )
    return Problem(
        None, "", "bus capacity", f"{rate:g} Hz: <= {budget_s * 1e3:.2f} ms a tick", found, fix
    ), why
