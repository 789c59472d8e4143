"""The HIL loop end to end on the emulator (virtual clock): what reaches the wire, and how it stops.

Most tests go through ``hilsim run`` itself with a named emulated bus, so the bus trace can be
read afterwards: every Sync Write is decoded from the bytes that were on the wire.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.clock import VirtualClock
from drivers.dxlsim import DxlBus, VirtualServo, register_bus, unregister_bus
from drivers.dxlsim.protocol import Instruction, StreamParser
from drivers.dynamixel.bus import DynamixelBus
from drivers.dynamixel.units import rad_to_ticks
from hilsim.cli import main
from hilsim.dynamics.springs import Spring
from hilsim.exit_codes import ExitCode
from hilsim.rig import load_rig
from hilsim.show.loop import HilLoop
from hilsim.show.parts import build_parts, build_targets
from hilsim.targets import TargetSet, Track
from hilsim.telemetry import TelemetryWriter
from hilsim.telemetry.reader import read_run
from tests.hilsim.clocks import NotVirtual

REPO = Path(__file__).resolve().parents[2]
TICK_RAD = 2 * math.pi / 4096

RIG = """
name = "t"
[bus]
port = "dxlsim://unused"
baud = 1000000
[loop]
rate_hz = 250
[safety]
comm_failure_budget_ms = 40
soft_start_s = 0.2
[[joints]]
name = "pan"
servo_id = 1
min_deg = -50
max_deg = 50
max_speed_deg_s = 200
max_accel_deg_s2 = 3000
spring = { frequency_hz = 3.0, damping_ratio = 0.7 }
target = { type = "keyframes", keys = [[0, 0], [0.5, 30], [1.0, -30], [1.5, 0]], easing = "ease_in_out" }
[[joints]]
name = "tail"
servo_id = 2
min_deg = -60
max_deg = 60
max_speed_deg_s = 240
max_accel_deg_s2 = 3000
spring = { m = 1.0, c = 0.8, k = 25.0 }
initial_deg = 35
target = { type = "hold", value_deg = 0 }
[[joints]]
name = "jaw"
servo_id = 3
direction = -1
min_deg = -5
max_deg = 30
spring = { frequency_hz = 5.0, damping_ratio = 0.9, response = 0.5 }
target = { type = "sine", amplitude_deg = 15, frequency_hz = 1.0, offset_deg = 12 }
"""


@pytest.fixture
def emulated(tmp_path):
    """Build a named emulated bus (trace on) and a rig file pointing at it."""
    names = []

    def _make(rig_text=RIG, *, ids=(1, 2, 3), faults=None, name="loopbus", **servo_kw):
        bus = DxlBus(
            [
                VirtualServo("XM430-W350", i, baud=1_000_000, return_delay_us=0, t=0.0, **servo_kw)
                for i in ids
            ],
            baud=1_000_000,
            clock=VirtualClock(),
            latency_timer_ms=1.0,
            faults=faults,
            trace=True,
        )
        register_bus(name, bus)
        names.append(name)
        path = tmp_path / "rig.toml"
        path.write_text(rig_text.replace("dxlsim://unused", f"dxlsim://{name}"))
        return bus, path

    yield _make
    for n in names:
        unregister_bus(n)


def run_cli(path: Path, out: Path, *extra: str) -> int:
    return main(["run", str(path), "--virtual-time", "--no-plots", "--out", str(out), *extra])


def wire_goals(bus: DxlBus) -> dict[int, np.ndarray]:
    """Goal Position ticks per servo, from every Sync Write the host put on the wire."""
    parser = StreamParser()
    goals: dict[int, list[int]] = {}
    for rec in bus.trace:
        if rec.direction != "tx":
            continue
        for frame in parser.feed(rec.data):
            p = frame.packet
            if p is None or p.instruction != Instruction.SYNC_WRITE:
                continue
            addr, size = p.params[0] | p.params[1] << 8, p.params[2] | p.params[3] << 8
            if addr != 116 or size != 4:
                continue
            body = p.params[4:]
            for k in range(0, len(body), 5):
                value = int.from_bytes(body[k + 1 : k + 5], "little", signed=True)
                goals.setdefault(body[k], []).append(value)
    return {sid: np.array(v) for sid, v in goals.items()}


def limits_in_ticks(rig):
    out = {}
    for j in rig.joints:
        ends = sorted((j.home_rad + j.direction * j.min_rad, j.home_rad + j.direction * j.max_rad))
        out[j.servo_id] = (rad_to_ticks(ends[0]), rad_to_ticks(ends[1]))
    return out


# ------------------------------------------------------------------ a clean show
def test_show_runs_and_commands_the_free_spring_along_the_exact_solution(emulated, tmp_path):
    bus, path = emulated()
    assert run_cli(path, tmp_path / "run", "--duration", "3") == 0
    run = read_run(tmp_path / "run")
    assert run.n_ticks == 751 and run.summary["exit_code"] == 0
    t = run.columns["t_sched"]
    tail = run.joint_names.index("tail")
    x_exact = np.asarray(Spring(m=1.0, c=0.8, k=25.0).exact(t, math.radians(35), 0.0)[0])
    cmd, sim = run.joint("cmd")[:, tail], run.joint("sim_x")[:, tail]
    # Released at 35° while the servo sits at 0°: soft start (0.2 s) blends it in and the speed
    # and acceleration limits let the command catch up. Wherever no limit acts the command IS the
    # spring's state, bit for bit, and from 0.6 s on that is every tick.
    free = cmd == sim
    assert np.all(free[t >= 0.6]) and free.sum() > 0.8 * len(t)
    assert np.max(np.abs(sim - x_exact)) < 1e-6  # RK4 at 4 ms against the closed form
    assert np.max(np.abs(cmd[free] - x_exact[free])) < 1e-6
    # ... and exactly that reaches the wire, as ticks.
    goals = wire_goals(bus)[2]
    assert len(goals) == run.n_ticks + 1  # every tick, plus the hold-at-start write
    assert np.array_equal(goals[1:], np.round(2048 + cmd / TICK_RAD).astype(int))
    # Present positions follow within the emulated servo's lag.
    err = np.abs(run.joint("present") - run.joint("cmd"))
    assert np.all(run.joint("status") == 0)
    assert np.degrees(np.percentile(err[t > 0.3], 99)) < 3.0
    events = [e["kind"] for e in run.events]
    assert events[0] == "start" and "exit_policy" in events


def test_soft_start_begins_at_the_present_pose(emulated, tmp_path):
    bus, path = emulated(present_position=2048 - 50)  # every servo starts 50 ticks off centre
    assert run_cli(path, tmp_path / "run", "--duration", "1") == 0
    run = read_run(tmp_path / "run")
    first = run.joint("cmd")[0]
    rig = load_rig(path)
    for j, value in zip(rig.joints, first, strict=True):
        assert value == pytest.approx(-j.direction * 50 * TICK_RAD, abs=1e-12)
    for _sid, goals in wire_goals(bus).items():
        assert goals[0] == goals[1] == 2048 - 50  # held at start, then ramps from there


# ------------------------------------------------------------------ nothing unsafe on the wire
class NanAfter(Track):
    """A target that turns NaN (or inf) at ``t_bad``."""

    def __init__(self, t_bad: float, bad: float = math.nan) -> None:
        self.t_bad, self.bad = t_bad, bad

    def sample(self, t: float) -> tuple[float, float]:
        return (self.bad, 0.0) if t >= self.t_bad else (0.3 * math.sin(t), 0.3 * math.cos(t))

    @property
    def duration(self) -> None:
        return None


def run_loop(
    bus: DxlBus,
    path: Path,
    out: Path,
    targets: TargetSet | None = None,
    duration: float = 2.0,
    patch=None,
):
    rig = load_rig(path)
    dbus = DynamixelBus.open(rig.bus.port, baud=rig.bus.baud, ids=rig.servo_ids)
    tel = TelemetryWriter(out, rig.joint_names, servo_ids=rig.servo_ids, overflow="block")
    loop = HilLoop(build_parts(rig, targets), dbus, tel, duration_s=duration)
    if patch:
        patch(loop)
    result = loop.run()
    tel.close({"exit_code": result.exit_code, "exit_reason": result.reason})
    dbus.close()
    return rig, result, read_run(out)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_target_never_reaches_the_wire(emulated, tmp_path, bad):
    bus, path = emulated()
    rig = load_rig(path)
    base = build_targets(rig)
    targets = TargetSet([NanAfter(0.6, bad), *base.tracks[1:]], rig.joint_names)
    rig, result, run = run_loop(bus, path, tmp_path / "run", targets)
    assert (
        result.exit_code == ExitCode.FAULT and "safety" in result.reason and "pan" in result.reason
    )
    assert np.all(np.isfinite(run.joint("cmd")))
    for sid, goals in wire_goals(bus).items():
        lo, hi = limits_in_ticks(rig)[sid]
        assert np.all((goals >= lo) & (goals <= hi))
    assert run.summary["faults"]


def test_non_finite_from_the_integrator_never_reaches_the_wire(emulated, tmp_path):
    bus, path = emulated()

    def poison(loop):
        step = loop.integrator.step
        calls = {"n": 0}

        def bad_step(x, v, h, t, target):
            step(x, v, h, t, target)
            calls["n"] += 1
            if calls["n"] == 100:
                v[1] = math.nan
                x[1] = math.nan

        loop.integrator.step = bad_step

    rig, result, run = run_loop(bus, path, tmp_path / "run", patch=poison)
    assert result.exit_code == ExitCode.FAULT and "tail" in result.reason
    assert run.n_ticks == 100  # the poisoned tick stops before its row: it is in the events
    (safety,) = [e for e in run.events if e["kind"] == "safety"][-1:]
    assert any(math.isnan(v) for v in safety["sim_x"])  # the offending state is kept
    assert np.all(np.isfinite(run.joint("cmd")))
    for sid, goals in wire_goals(bus).items():
        lo, hi = limits_in_ticks(rig)[sid]
        assert np.all((goals >= lo) & (goals <= hi))


@pytest.mark.parametrize("substeps", [1, 2])
def test_the_held_step_is_built_before_tick_0_and_kept(emulated, tmp_path, substeps):
    """Built in tick 0 it made a 1 kHz show's first tick overrun (scale16: tick 0's sim stage
    265-335 us, 84-135 us once built before). At the substep's h, not the period."""
    bus, path = emulated(RIG.replace("rate_hz = 250", f"rate_hz = 250\nsubsteps = {substeps}"))
    seen = {}

    def look(loop):
        seen["loop"], seen["held"] = loop, loop.integrator._held

    rig, result, run = run_loop(bus, path, tmp_path / "run", patch=look, duration=0.1)
    assert result.exit_code == 0 and run.n_ticks > 1
    held = seen["held"]
    assert held is not None and held.h == rig.loop.h_s == rig.loop.period_s / substeps
    assert seen["loop"].integrator._held is held  # the ticks used it, none built another


def test_non_finite_spring_parameter_is_refused_at_load(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(
        RIG.replace(
            "spring = { m = 1.0, c = 0.8, k = 25.0 }", "spring = { m = 1.0, c = 0.8, k = nan }"
        )
    )
    assert main(["run", str(path), "--virtual-time", "--out", str(tmp_path / "r")]) == 2
    assert not (tmp_path / "r").exists()  # nothing was opened, nothing moved


@settings(
    max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(keys=st.lists(st.tuples(st.floats(0.01, 0.4), st.floats(-400, 400)), min_size=1, max_size=6))
def test_limits_hold_on_the_wire_for_any_keyframes(emulated, tmp_path_factory, keys):
    t, rows = 0.0, [[0.0, 0.0]]
    for dt, deg in keys:
        t += dt
        rows.append([round(t, 4), deg])
    text = RIG.replace(
        'target = { type = "keyframes", keys = [[0, 0], [0.5, 30], [1.0, -30], [1.5, 0]], '
        'easing = "ease_in_out" }',
        f'target = {{ type = "keyframes", keys = {rows}, easing = "linear" }}',
    )
    bus, path = emulated(text, name=f"hyp{os.getpid()}")
    out = tmp_path_factory.mktemp("run")
    rig, result, run = run_loop(bus, path, out, duration=t + 0.3)
    assert result.exit_code == 0
    pan = rig.joints[0]
    cmd = run.joint("cmd")[:, 0]
    assert np.all(cmd >= pan.min_rad) and np.all(cmd <= pan.max_rad)
    step = np.abs(np.diff(cmd))
    assert np.all(step <= pan.max_speed_rad_s * rig.loop.period_s * (1 + 1e-9))
    goals = wire_goals(bus)[1]
    lo, hi = limits_in_ticks(rig)[1]
    assert np.all((goals >= lo) & (goals <= hi))
    assert np.all(np.abs(np.diff(goals)) <= math.ceil(pan.max_speed_rad_s * 0.004 / TICK_RAD) + 1)
    unregister_bus(f"hyp{os.getpid()}")


# ------------------------------------------------------------------ the bus fails
def test_stale_reads_never_become_positions(emulated, tmp_path):
    _bus, path = emulated(faults="drop:id=2,rate=0.2")
    code = run_cli(path, tmp_path / "run", "--duration", "2")
    run = read_run(tmp_path / "run")
    assert run.summary["exit_reason"] == "end of show"
    # the exit policy retries each step 4x; a servo losing 1 reply in 5 may still fail 4x in a
    # row (this seed does): then exit 4, naming that servo and no other
    policy = next(e for e in run.events if e["kind"] == "exit_policy")
    assert (code, policy["unconfirmed"] if code else []) in ((0, []), (4, [2]))
    status, present = run.joint("status"), run.joint("present")
    stale = status != 0
    assert stale[:, 1].sum() > 20  # the fault did strike
    assert np.all(np.isnan(present[stale]))
    assert np.all(np.isfinite(present[~stale]))


def fault_time(run, bus, t_bus: float) -> float:
    """A fault plan's time (bus clock) on the run's time axis (0 = tick 0)."""
    return t_bus - (run.summary["loop"]["clock_t0"] - bus.t0)


def test_sustained_timeouts_stop_within_the_budget(emulated, tmp_path):
    bus, path = emulated(faults="drop:id=2,at=1.0")
    assert run_cli(path, tmp_path / "run", "--duration", "5") == ExitCode.FAULT
    run = read_run(tmp_path / "run")
    reason = run.summary["exit_reason"]
    assert "servo 2 (tail)" in reason and "budget 40 ms" in reason
    last = run.columns["t_actual"][-1] + 1.0 - fault_time(run, bus, 1.0)
    # Silence starts at 1.0 s. The budget runs from the last good reading to the end of the
    # failing read, so the stopping tick starts within a tick (4 ms) plus one read timeout
    # (~4 ms) of 1.0 + 0.040 s, and never later than that.
    assert 1.0 + 0.040 - 0.010 <= last <= 1.0 + 0.040 + 0.004
    policy = [e for e in run.events if e["kind"] == "exit_policy"]
    assert policy and "servo 2" in policy[0]["message"]  # the silent servo is named as unconfirmed


def test_hardware_error_stops_naming_the_servo(emulated, tmp_path):
    bus, path = emulated(faults="hardware_error:id=3,at=0.5,bits=overheating")
    assert run_cli(path, tmp_path / "run", "--duration", "5") == ExitCode.FAULT
    run = read_run(tmp_path / "run")
    assert "servo 3 (jaw): hardware error" in run.summary["exit_reason"]
    assert run.columns["t_actual"][-1] == pytest.approx(fault_time(run, bus, 0.5), abs=0.005)


def test_unplug_stops_safely(emulated, tmp_path):
    bus, path = emulated(faults="unplug:at=0.7")
    assert run_cli(path, tmp_path / "run", "--duration", "5") == ExitCode.FAULT
    run = read_run(tmp_path / "run")
    assert run.summary["exit_reason"].startswith("bus:")
    assert run.columns["t_actual"][-1] == pytest.approx(fault_time(run, bus, 0.7), abs=0.005)
    assert any("NOT confirmed" in e["message"] for e in run.events if e["kind"] == "exit_policy")


def test_overrun_policy_stop(emulated, tmp_path):
    text = RIG.replace("rate_hz = 250", 'rate_hz = 250\noverrun_policy = "stop"')
    bus, path = emulated(text, faults="late:id=1,at=0.5,count=1,delay=0.003")
    _rig, result, _run = run_loop(bus, path, tmp_path / "run")
    assert result.exit_code == ExitCode.FAULT and "overrun" in result.reason


# ------------------------------------------------------------------ refusals before anything moves
@pytest.mark.parametrize(
    ("port", "message"),
    [
        ("dxlsim://?ids=1-2&rdt_us=0&latency_ms=1", "answers Ping  yes       no (timeout)"),
        ("dxlsim://?ids=1-3&model=XL430-W250&rdt_us=0&latency_ms=1", "XL430-W250"),
        ("dxlsim://?ids=1-3&rdt_us=0&latency_ms=16", "the bus cannot carry 250 Hz"),
    ],
)
def test_startup_refusals(tmp_path, capsys, port, message):
    path = tmp_path / "rig.toml"
    path.write_text(RIG)
    code = main(["run", str(path), "--port", port, "--virtual-time", "--out", str(tmp_path / "r")])
    assert code == 2
    assert message in capsys.readouterr().err


# ------------------------------------------------------------------ signals
@pytest.mark.parametrize(("signum", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signals_apply_the_exit_policy_and_keep_telemetry(tmp_path, signum, code):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hilsim",
            "run",
            str(REPO / "configs" / "demo.toml"),
            "--virtual-time",
            "--duration",
            "3600",
            "--out",
            str(out),
            "--no-plots",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stderr.readline()  # "hilsim run: demo: ... -> DIR": the loop is starting
        assert "hilsim run: demo" in line
        proc.send_signal(signum)
        assert proc.wait(timeout=30) == code
    finally:
        if proc.poll() is None:
            proc.kill()
    run = read_run(out)
    assert run.summary["exit_code"] == code
    assert not run.truncated  # the signal may land before the first tick: 0 rows is fine
    policy = [e for e in run.events if e["kind"] == "exit_policy"]
    signals = [e for e in run.events if e["kind"] == "signal"]
    assert len(signals) == 1
    if policy:  # the signal landed once torque was on: the exit policy ran and held all four
        assert "4 servo(s) confirmed" in policy[0]["message"]
    else:  # it landed during the start-up: nothing was energised, so nothing to undo
        assert "nothing was energised" in signals[0]["message"]


def test_realtime_scheduling_refused_is_a_warning_not_a_crash(monkeypatch):
    from hilsim.show import realtime as realtime_mod

    def refuse(*_a, **_k):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(realtime_mod.os, "sched_setscheduler", refuse)
    monkeypatch.setattr(realtime_mod.os, "sched_setaffinity", refuse)
    with pytest.warns(UserWarning) as caught:
        assert realtime_mod.try_realtime(50, 1) == "SCHED_OTHER"
    text = " ".join(str(w.message) for w in caught)
    assert "SCHED_FIFO" in text and "setcap" in text and "CPU 1" in text
    assert realtime_mod.try_realtime(None, None) == "SCHED_OTHER"  # nothing asked, nothing tried


def test_real_time_scheduling_holds_for_the_run_only(monkeypatch):
    """A show run inside a longer-lived process gives it back as it found it: policy,
    priority and CPUs (SCHED_FIFO left behind starves the host once the process busy-waits)."""
    from hilsim.show import realtime as realtime_mod

    state = {"sched": (0, 0), "cpus": {0, 1}}
    monkeypatch.setattr(realtime_mod.os, "sched_getscheduler", lambda _p: state["sched"][0])
    monkeypatch.setattr(
        realtime_mod.os, "sched_getparam", lambda _p: os.sched_param(state["sched"][1])
    )
    monkeypatch.setattr(realtime_mod.os, "sched_getaffinity", lambda _p: set(state["cpus"]))

    def setscheduler(_p, policy, param):
        state["sched"] = (policy, param.sched_priority)

    def setaffinity(_p, cpus):
        state["cpus"] = set(cpus)

    monkeypatch.setattr(realtime_mod.os, "sched_setscheduler", setscheduler)
    monkeypatch.setattr(realtime_mod.os, "sched_setaffinity", setaffinity)
    with realtime_mod.realtime(50, 1) as sched:
        assert sched == "SCHED_FIFO:50"
        assert state == {"sched": (os.SCHED_FIFO, 50), "cpus": {1}}
    assert state == {"sched": (0, 0), "cpus": {0, 1}}
    with pytest.raises(RuntimeError), realtime_mod.realtime(50, None):
        raise RuntimeError("a show that crashes still gives the process back")
    assert state == {"sched": (0, 0), "cpus": {0, 1}}


def test_only_a_real_clock_show_is_warmed_and_its_numbers_are_the_same(
    emulated, tmp_path, monkeypatch
):
    """The warm-up runs once, before tick 0, on the real clock and never in virtual time;
    warm, cold or with a warm-up that reports a failure (said in an event), the show is the
    same: every number recorded and every goal on the wire. (Its time, which the clock here
    does not see, is bounded in tests/hilsim/test_warm_up.py: no animation copied, a budget.)"""
    import hilsim.show.loop as loop_mod
    import hilsim.show.warm_up as warm_mod

    real, calls, how = warm_mod.warm_up, [], [""]

    def spy(stepper, jmap, telemetry, rec):
        calls.append(telemetry.stats._i)  # ticks recorded when it runs: none
        if how[0] == "failing":
            return "TypeError: cannot pickle 'socket' object"
        return None if how[0] == "cold" else real(stepper, jmap, telemetry, rec)

    monkeypatch.setattr(loop_mod, "warm_up", spy)
    shows = {}
    for i, way in enumerate(("warm", "cold", "failing", "virtual")):
        how[0], calls[:] = way, []
        bus, path = emulated(name=f"warmbus{i}")

        def patch(loop, way=way):
            if way != "virtual":
                loop.clock = NotVirtual(loop.clock)

        _, result, run = run_loop(bus, path, tmp_path / way, patch=patch, duration=0.4)
        assert result.exit_code == 0 and run.n_ticks == 101, way
        assert calls == ([] if way == "virtual" else [0]), way
        said = [e for e in run.events if e["kind"] == "warm_up"]
        assert len(said) == (way == "failing"), way
        if said:
            assert "tick 0 runs cold" in said[0]["message"] and "socket" in said[0]["message"]
        shows[way] = (
            [run.joint(q) for q in ("target", "sim_x", "sim_v", "cmd", "present")],
            wire_goals(bus),
        )
    for way in ("cold", "failing", "virtual"):
        for a, b in zip(shows["warm"][0], shows[way][0], strict=True):
            np.testing.assert_array_equal(a, b, err_msg=way)
        assert shows["warm"][1].keys() == shows[way][1].keys()
        for sid, goals in shows["warm"][1].items():
            np.testing.assert_array_equal(goals, shows[way][1][sid], err_msg=way)
