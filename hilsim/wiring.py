"""From a loaded rig to the objects a run needs: target tracks and the driver's expectations."""

from __future__ import annotations

from pathlib import Path

from drivers.dynamixel.startup import Expectation, StartupReport
from drivers.dynamixel.startup import ReadMode as BusReadMode
from drivers.protocol2.wire_time import cycle_bytes, cycle_time_s
from hilsim.rig import ReadMode, Rig, RigError
from hilsim.targets import TargetSet, track_from_spec
from hilsim.targets.csv_file import CsvAnimation

#: Fraction of a tick the bus transaction may take; the rest is for the host.
BUS_SHARE_OF_TICK = 0.8


def build_targets(rig: Rig) -> TargetSet:
    """One track per joint from the rig's ``target`` tables; errors name file and key."""
    cache: dict[Path, CsvAnimation] = {}
    tracks = []
    for i, joint in enumerate(rig.joints):
        try:
            tracks.append(
                track_from_spec(
                    joint.target, base_dir=rig.base_dir, joint_name=joint.name, csv_cache=cache
                )
            )
        except (ValueError, OSError) as exc:
            raise RigError(f"{rig.path}: joints[{i}].target ({joint.name}): {exc}") from None
    return TargetSet(tracks, rig.joint_names)


def return_delay_budget_us(rig: Rig, latency_timer_ms: float = 0.0) -> float:
    """The largest Return Delay Time with which the bus traffic still fits in a tick."""
    n = len(rig.joints)
    fast = rig.bus.read is not ReadMode.PLAIN
    base = cycle_time_s(n, rig.bus.baud, fast, latency_s=latency_timer_ms * 1e-3)
    spare = BUS_SHARE_OF_TICK * rig.loop.period_s - base
    return max(0.0, spare / (1 if fast else n) * 1e6)


def bus_capacity_problem(rig: Rig, report: StartupReport, latency_timer_ms: float) -> str | None:
    """Why this bus cannot carry the rig's tick rate, or None if it can.

    Uses the wire-time model (:mod:`drivers.protocol2.wire_time`) with what the start-up check
    found: the read mode in force, each servo's Return Delay Time, and the adapter latency timer in
    force. The bus may use at most ``BUS_SHARE_OF_TICK`` of a tick.
    """
    n = len(rig.joints)
    fast = report.read_mode is BusReadMode.FAST
    rdts = [s.return_delay_us * 1e-6 for s in report.servos]
    cycle = cycle_time_s(
        n, report.baud, fast, return_delay_s=rdts, latency_s=latency_timer_ms * 1e-3
    )
    budget = BUS_SHARE_OF_TICK * rig.loop.period_s
    if cycle <= budget:
        return None
    wire = 10.0 * cycle_bytes(n, fast) / report.baud
    waits = rdts[0] if fast else sum(rdts)
    return (
        f"the bus cannot carry {rig.loop.rate_hz:g} Hz: one tick's Sync Write + "
        f"{'Fast ' if fast else ''}Sync Read takes {cycle * 1e3:.2f} ms (wire "
        f"{wire * 1e3:.2f} ms at {report.baud} bps, Return Delay {waits * 1e3:.2f} ms, USB "
        f"latency timer {latency_timer_ms:g} ms, servo turnaround) against {budget * 1e3:.2f} ms "
        f"({BUS_SHARE_OF_TICK:.0%} of a {rig.loop.period_s * 1e3:g} ms tick). Lower "
        f"loop.rate_hz to {BUS_SHARE_OF_TICK / cycle:.0f} or less, or shorten the cycle: Return "
        "Delay Time 0, a higher baud rate, a 1 ms latency timer, Fast Sync Read (`hilsim bench` "
        "shows each)."
    )


def expectations(rig: Rig, latency_timer_ms: float = 0.0) -> list[Expectation]:
    """What each servo must look like for this rig to run (checked before anything moves)."""
    rdt_max = return_delay_budget_us(rig, latency_timer_ms)
    out = []
    for j in rig.joints:
        ends = (j.home_rad + j.direction * j.min_rad, j.home_rad + j.direction * j.max_rad)
        out.append(
            Expectation(
                id=j.servo_id,
                model=j.model,
                position_range_rad=(min(ends), max(ends)),
                return_delay_us_max=rdt_max,
            )
        )
    return out
