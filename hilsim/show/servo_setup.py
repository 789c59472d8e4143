"""``hilsim setup``'s library half: what a rig asks of each servo, found, planned, written.

:func:`targets` turns a rig into one :class:`~drivers.dynamixel.configure.Target` per
joint (its ID, the bus's baud, the Return Delay Time, Position mode, limits wide enough for
the joint, the Shutdown bits the start-up check wants). :class:`ServoSetup` finds the servos
at every baud of the family, plans the writes (:meth:`ServoSetup.plan`), writes them
(:meth:`ServoSetup.write`) and reads them back. The CLI (``hilsim.cli.setup``) prints.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from drivers.dynamixel.configure import X_SERIES, Change, Family, Found, Target
from drivers.dynamixel.startup import Expectation
from drivers.dynamixel.units import CENTER_TICK, TICKS_PER_RAD
from hilsim.rig import Rig
from hilsim.rig.joint_map import JointMap
from hilsim.show.servo_check import setup_return_delay_us

if TYPE_CHECKING:
    from drivers.dynamixel.link import Link


def targets(rig: Rig, renames: Mapping[int, int] | None = None) -> dict[int, Target]:
    """What each of the rig's servos should be, by the ID it has *now* (``renames``:
    ``{old: new}`` from ``--id OLD:NEW``; a rig ID not renamed is its own)."""
    jmap = JointMap.of(rig.joints)
    shutdown = Expectation(1).shutdown_bits
    renames = dict(renames or {})
    back = {new: old for old, new in renames.items()}
    out: dict[int, Target] = {}
    for i, j in enumerate(rig.joints):
        lo, hi = jmap.servo_range(i, j.min_rad, j.max_rad)
        ticks = np.rint(np.array([lo, hi]) * TICKS_PER_RAD) + CENTER_TICK
        now = back.get(j.servo_id, j.servo_id)
        if j.servo_id not in back and j.servo_id in renames:
            continue  # its ID is on a servo being renamed: this joint's servo is not connected
        out[now] = Target(
            id=j.servo_id,
            baud=rig.bus.baud,
            return_delay_us=setup_return_delay_us(rig),
            position_ticks=(int(ticks[0]), int(ticks[1])),
            shutdown_bits=shutdown,
        )
    return out


@dataclass
class SetupPlan:
    """What was found and what would be written."""

    found: dict[int, Found]  # by current ID, the rig's servos (renamed ones by old ID)
    others: list[Found]  # servos that answered but are not the rig's
    missing: list[int]  # current IDs the rig needs that answered at no baud
    changes: list[Change]
    models: list[str] = field(default_factory=list)  # model mismatches, one line each


def split_found(
    found: list[Found], targets: Collection[int]
) -> tuple[dict[int, Found], list[Found]]:
    """The rig's servos among those found (by current ID, the first answer of each) and the
    others (not the rig's, or the same ID answering again at another baud)."""
    mine: dict[int, Found] = {}
    others: list[Found] = []
    for f in found:
        if f.id in targets and f.id not in mine:
            mine[f.id] = f
        else:
            others.append(f)
    return mine, others


class ServoSetup:
    """One setup session on an open link (``family``: the servos' register table)."""

    def __init__(
        self,
        rig: Rig,
        link: Link,
        renames: Mapping[int, int] | None = None,
        family: Family = X_SERIES,
    ) -> None:
        self.rig, self.link, self.family = rig, link, family
        self.renaming = bool(renames)
        self.targets = targets(rig, renames)
        self.names = {j.servo_id: j.name for j in rig.joints}
        self.models = {j.servo_id: j.model for j in rig.joints}

    def bauds(self) -> list[int]:
        """The family's baud table, the rig's rate first (most servos are already there), then
        the factory's."""
        return self.family.probe_order(self.rig.bus.baud)

    def find(self, progress: Callable[[int, list[Found]], None] | None = None) -> list[Found]:
        """Every servo answering at any baud this port can set (``progress`` per baud)."""
        from drivers.dynamixel.configure import find

        found: list[Found] = []
        for baud in self.bauds():
            try:
                found += find(self.link, (baud,), self.targets, progress=progress)
            except ValueError:  # a rate this port cannot set
                continue
            if set(self.targets) <= {f.id for f in found}:
                break  # every servo of the rig found: the slow rates are not tried
        return found

    def plan(self, found: list[Found]) -> SetupPlan:
        """Compare every rig servo found with its target (read-only)."""
        from drivers.dynamixel.configure import plan, read_settings
        from drivers.protocol2.control_table import model_number

        mine, others = split_found(found, self.targets)
        changes: list[Change] = []
        models: list[str] = []
        for sid, f in sorted(mine.items()):
            t = self.targets[sid]
            if f.model_number != model_number(self.models[t.id]):
                models.append(
                    f"servo {sid} ({self.names[t.id]}) is an {f.model_name}; the rig names "
                    f"{self.models[t.id]}"
                )
            self.link.set_baud(f.baud)
            settings = read_settings(self.link, self.family, sid)
            changes += plan(self.family, f, settings, t)
        missing = [sid for sid in self.targets if sid not in mine]
        return SetupPlan(mine, others, missing, changes, models)

    def write(self, plan: SetupPlan) -> tuple[list[str], list[Change], list[int]]:
        """Write the plan (baud last), then read every target back at the rig's baud:
        (write problems, registers still different, IDs silent at the new baud)."""
        from drivers.dynamixel.configure import apply, verify

        problems = apply(self.link, self.family, plan.changes)
        wanted = [self.targets[sid] for sid in plan.found]
        left, silent = verify(self.link, self.family, wanted)
        return problems, left, silent

    def read_back(self, plan: SetupPlan) -> list[tuple[int, str, str]]:
        """(ID, register, value) of every register the plan touched, as read now."""
        from drivers.dynamixel.configure import read_settings

        rows = []
        self.link.set_baud(self.rig.bus.baud)
        for sid in plan.found:
            t = self.targets[sid]
            s = read_settings(self.link, self.family, t.id)
            for reg in self.family.registers:
                if reg.key in s.values:
                    rows.append((t.id, reg.item.name, reg.text(s.values[reg.key])))
        return rows
