"""``hilsim setup`` for Feetech STS/SCS and Dynamixel Protocol 1.0 servos (AX, MX).

:class:`P1ServoSetup` has :class:`~hilsim.show.servo_setup.ServoSetup`'s interface (find,
plan, write, read back; the CLI prints both the same way) over
:mod:`drivers.p1bus.configure`: a Feetech bus is found by broadcast Ping, a Dynamixel
Protocol 1.0 one by a Ping per ID, at each of the family's bauds; Feetech's Lock is opened
for the EEPROM writes and closed after.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from drivers.dynamixel.configure import Change, Found
from drivers.p1bus.configure import P1Target, probe_order
from drivers.p1bus.link import P1Link
from drivers.p1bus.table import canonical, family_of
from hilsim.rig import Rig
from hilsim.rig.joint_map import JointMap
from hilsim.show.servo_check import setup_return_delay_us
from hilsim.show.servo_setup import SetupPlan, split_found


def p1_targets(rig: Rig, renames: Mapping[int, int] | None = None) -> dict[int, P1Target]:
    """What each of the rig's servos should be, by the ID it has *now* (``renames``:
    ``{old: new}``; a rig ID not renamed is its own)."""
    jmap = JointMap.of(rig.joints)
    renames = dict(renames or {})
    back = {new: old for old, new in renames.items()}
    out: dict[int, P1Target] = {}
    for i, j in enumerate(rig.joints):
        fam = family_of(j.model)
        assert fam is not None  # the rig's bus is of these families (the caller checked)
        lo, hi = jmap.servo_range(i, j.min_rad, j.max_rad)
        ticks = (
            round(lo * fam.ticks_per_rad) + fam.center_tick,
            round(hi * fam.ticks_per_rad) + fam.center_tick,
        )
        if j.servo_id not in back and j.servo_id in renames:
            continue  # its ID is on a servo being renamed: this joint's servo is not connected
        out[back.get(j.servo_id, j.servo_id)] = P1Target(
            j.servo_id, rig.bus.baud, setup_return_delay_us(rig), ticks
        )
    return out


class P1ServoSetup:
    """One setup session of a Protocol 1.0-framed bus on an open :class:`P1Link`."""

    def __init__(self, rig: Rig, link: P1Link, renames: Mapping[int, int] | None = None) -> None:
        fams = [family_of(j.model) for j in rig.joints]
        if None in fams or len({f.protocol for f in fams if f is not None}) != 1:
            raise ValueError("not one Protocol 1.0-framed protocol: the rig's models")
        by_rig_id = {j.servo_id: f for j, f in zip(rig.joints, fams, strict=True) if f}
        self.rig, self.link = rig, link
        self.renaming = bool(renames)
        self.targets = p1_targets(rig, renames)
        #: each servo's family, by the ID it has now (AX and MX may share a bus)
        self.fams = {now: by_rig_id[t.id] for now, t in self.targets.items()}
        #: the family that finds them (the protocol, the bauds: the same for the bus)
        self.family = by_rig_id[rig.joints[0].servo_id]
        self.names = {j.servo_id: j.name for j in rig.joints}
        self.models = {j.servo_id: canonical(j.model) for j in rig.joints}

    def bauds(self) -> list[int]:
        """The family's bauds, the rig's first, then the factory's."""
        return probe_order(self.family, self.rig.bus.baud)

    def find(self, progress: Callable[[int, list[Found]], None] | None = None) -> list[Found]:
        """Every servo answering at any baud this port can set (``progress`` per baud)."""
        from drivers.p1bus.configure import find

        found: list[Found] = []
        for baud in self.bauds():
            found += find(self.link, self.family, (baud,), self.targets, progress=progress)
            if set(self.targets) <= {f.id for f in found}:
                break  # every servo of the rig found: the slower rates are not tried
        return found

    def plan(self, found: list[Found]) -> SetupPlan:
        """Compare every rig servo found with its target (read-only)."""
        from drivers.p1bus.configure import plan, read_settings

        mine, others = split_found(found, self.targets)
        changes: list[Change] = []
        models: list[str] = []
        for sid, f in sorted(mine.items()):
            t, fam = self.targets[sid], self.fams[sid]
            if f.model_number >= 0 and f.model_name != self.models[t.id]:
                models.append(
                    f"servo {sid} ({self.names[t.id]}) is a {f.model_name}; the rig names "
                    f"{self.models[t.id]}"
                )
            self.link.set_baud(f.baud)
            settings = read_settings(self.link, fam, sid)
            changes += plan(fam, f, settings, t)
        missing = [sid for sid in self.targets if sid not in mine]
        return SetupPlan(mine, others, missing, changes, models)

    def write(self, the_plan: SetupPlan) -> tuple[list[str], list[Change], list[int]]:
        """Write the plan (baud last), then read every target back at the rig's baud."""
        from drivers.p1bus.configure import apply, verify

        problems: list[str] = []
        left: list[Change] = []
        silent: list[int] = []
        for fam in dict.fromkeys(self.fams.values()):
            mine = [c for c in the_plan.changes if self.fams[c.servo] is fam]
            problems += apply(self.link, fam, mine)
        for sid in the_plan.found:
            more, quiet = verify(self.link, self.fams[sid], [self.targets[sid]])
            left += more
            silent += quiet
        return problems, left, silent

    def read_back(self, the_plan: SetupPlan) -> list[tuple[int, str, str]]:
        """(ID, register, value) of every setting, as read now at the rig's baud."""
        from drivers.p1bus.configure import read_settings, setting_text, settings_registers

        rows = []
        self.link.set_baud(self.rig.bus.baud)
        for sid in the_plan.found:
            t, fam = self.targets[sid], self.fams[sid]
            s = read_settings(self.link, fam, t.id)
            for key, reg in [*settings_registers(fam), ("baud", fam.baud)]:
                if key in s.values:
                    rows.append((t.id, reg.name, setting_text(fam, key)(s.values[key])))
        return rows
