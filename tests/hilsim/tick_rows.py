"""Tick records for telemetry tests, from the values of one CSV row in column order."""

from __future__ import annotations

from hilsim.telemetry.format import TickRecord


def tick_record(
    tick,
    t_sched,
    t_actual,
    target,
    sim_x,
    sim_v,
    cmd,
    present,
    status,
    t_sim_us,
    t_safety_us,
    t_bus_us,
    t_telemetry_us,
    overrun,
    comm_errors,
    host_stall_us=0.0,
) -> TickRecord:
    return TickRecord(
        target=target,
        sim_x=sim_x,
        sim_v=sim_v,
        cmd=cmd,
        present=present,
        status=status,
        tick=tick,
        t_sched=t_sched,
        t_actual=t_actual,
        t_sim_us=t_sim_us,
        t_safety_us=t_safety_us,
        t_bus_us=t_bus_us,
        t_telemetry_us=t_telemetry_us,
        overrun=overrun,
        comm_errors=comm_errors,
        host_stall_us=host_stall_us,
    )


def stats_record(t_actual, lateness_us, overrun, t_sim, t_safety, t_bus, t_tel, status, tick):
    """A record as RunStats sees it (its old positional order); t_sched from the lateness."""
    return TickRecord(
        status=status,
        tick=tick,
        t_sched=t_actual - lateness_us * 1e-6,
        t_actual=t_actual,
        t_sim_us=t_sim,
        t_safety_us=t_safety,
        t_bus_us=t_bus,
        t_telemetry_us=t_tel,
        overrun=overrun,
    )
