"""Shows on Feetech STS and Dynamixel AX buses through ``hilsim run`` (virtual time, the P1 stub
bus of tests/p1_stub.py): the rig names the model and the right protocol is spoken, and the
fault matrix's rows that apply to these families hold on a Feetech bus: a dropped or corrupt
reply, a silent servo, a hardware error bit, a torque loss, a host stall (no Bus Watchdog: said,
the show goes on), an exit policy that cannot be confirmed, Ctrl-C and SIGTERM."""

from __future__ import annotations

import itertools
import math
import os
import signal
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from drivers.dxlsim import register_bus, unregister_bus
from drivers.protocol1 import packet
from hilsim.cli import main
from hilsim.exit_codes import ExitCode
from hilsim.rig import RigError, load_rig
from hilsim.telemetry.reader import Run, read_run
from hilsim.telemetry.stats import comm_errors
from tests.hilsim.test_fault_matrix import StallAt, events, replace_track
from tests.p1_stub import P1StubBus

RIG = """
name = "sts"
[bus]
port = "dxlsim://unused"
[loop]
rate_hz = 250
[safety]
comm_failure_budget_ms = 40
soft_start_s = 0.2
watchdog_ms = 100
exit_policy = "hold"
exit_retries = 2
[[joints]]
name = "pan"
servo_id = 1
model = "STS3215"
min_deg = -50
max_deg = 50
spring = { frequency_hz = 3.0, damping_ratio = 0.7 }
target = { type = "keyframes", keys = [[0, 0], [0.5, 30], [1.0, -30], [1.5, 0]] }
[[joints]]
name = "tilt"
servo_id = 2
model = "STS3215"
min_deg = -40
max_deg = 40
spring = { frequency_hz = 3.0, damping_ratio = 0.7 }
target = { type = "sine", amplitude_deg = 20, frequency_hz = 0.7 }
[[joints]]
name = "jaw"
servo_id = 3
model = "STS3215"
direction = -1
min_deg = -5
max_deg = 30
spring = { frequency_hz = 5.0, damping_ratio = 0.9 }
target = { type = "sine", amplitude_deg = 15, frequency_hz = 1.0, offset_deg = 12 }
"""
_names = itertools.count()


@dataclass
class Emu:
    stub: P1StubBus
    path: Path
    out: Path

    def run(self, *extra: str, duration: float | None = 1.5) -> int:
        args = ["run", str(self.path), "--virtual-time", "--no-plots", "--out", str(self.out)]
        if duration is not None:
            args += ["--duration", str(duration)]
        return main([*args, *extra])

    def read(self) -> Run:
        return read_run(self.out)

    def writes_after(self, t: float) -> list[packet.Packet]:
        start = next(
            (i for i, (ts, _) in enumerate(self.stub.sent) if ts >= t), len(self.stub.sent)
        )
        return self.stub.instructions(start)


@pytest.fixture
def emulated(tmp_path):
    names: list[str] = []

    def make(rig_text: str = RIG, models: dict[int, str] | None = None) -> Emu:
        stub = P1StubBus(models or {1: "STS3215", 2: "STS3215", 3: "STS3215"})
        name = f"p1show{os.getpid()}-{next(_names)}"
        register_bus(name, stub)
        names.append(name)
        path = tmp_path / f"{name}.toml"
        path.write_text(rig_text.replace("dxlsim://unused", f"dxlsim://{name}"))
        return Emu(stub, path, tmp_path / f"run-{name}")

    yield make
    for n in names:
        unregister_bus(n)


def sync_writes(pkts: list[packet.Packet]) -> list[packet.Packet]:
    return [p for p in pkts if p.code == packet.Inst.SYNC_WRITE]


# ----------------------------------------------------------------------------- the rig
def test_a_rig_names_feetech_servos_and_runs_with_no_comm_error(emulated, capsys):
    emu = emulated()
    assert emu.run() == ExitCode.OK
    run = emu.read()
    s = run.summary
    assert s["read_mode"] == "sync read" and s["read_hz_per_servo"] == 250.0
    assert comm_errors(s) == 0 and s["exit_policy_confirmed"] is True
    err = capsys.readouterr().err
    assert "no Bus Watchdog" in err
    # every tick one Sync Write of Goal Position (42) and one Sync Read (0x82) of all three
    pkts = emu.stub.instructions()
    reads = [p for p in pkts if p.code == packet.Inst.SYNC_READ]
    assert len(reads) >= run.n_ticks
    assert all(p.params == bytes((56, 2, 1, 2, 3)) for p in reads)
    assert {packet.parse_sync_write(p.params)[0] for p in sync_writes(pkts)} == {42}
    # the last Sync Write is the last commanded pose
    _, last = packet.parse_sync_write(sync_writes(pkts)[-1].params)
    cmd = [run.columns[f"cmd_{j}"][-1] for j in ("pan", "tilt", "jaw")]
    ticks = [
        round(c * d * 4096 / (2 * math.pi)) + 2048 for c, d in zip(cmd, (1, 1, -1), strict=True)
    ]
    assert [int.from_bytes(last[i], "little") for i in (1, 2, 3)] == ticks


def test_one_protocol_per_bus_is_refused_in_one_line(tmp_path):
    path = tmp_path / "mixed.toml"
    path.write_text(RIG.replace('model = "STS3215"\ndirection', 'model = "XM430-W350"\ndirection'))
    with pytest.raises(
        RigError,
        match=r"joints\[2\]\.model: one protocol per bus: jaw is a "
        r"XM430-W350 \(Dynamixel Protocol 2.0\) but pan .* STS3215 \(Feetech",
    ):
        load_rig(path)


def test_an_mx_reflashed_to_protocol_2_is_named_and_not_guessed(tmp_path):
    path = tmp_path / "mx.toml"
    path.write_text(RIG.replace('"STS3215"', '"MX-28-P2"'))
    with pytest.raises(RigError, match=r"MX-28-P2 \(Dynamixel Protocol 2.0\) is not run by hilsim"):
        load_rig(path)


def test_an_ax_figure_reads_each_servo_at_the_rate_the_summary_states(emulated, capsys):
    rig = RIG.replace('"STS3215"', '"AX-12A"').replace("rate_hz = 250", "rate_hz = 100")
    rig = rig.replace("comm_failure_budget_ms = 40", "comm_failure_budget_ms = 100")
    emu = emulated(rig, {1: "AX-12A", 2: "AX-12A", 3: "AX-12A"})
    assert emu.run(duration=2.0) == ExitCode.OK
    run = emu.read()
    s = run.summary
    assert s["read_mode"] == "single reads in rotation" and comm_errors(s) == 0
    hz = s["read_hz_per_servo"]
    assert 0 < hz <= 100 and f"read {hz:.4g} times a second" in capsys.readouterr().err
    for j in ("pan", "tilt", "jaw"):
        ok = np.count_nonzero(run.columns[f"status_{j}"] == 0)
        assert ok / (run.n_ticks / 100.0) == pytest.approx(hz, rel=0.05)


# ----------------------------------------------------------------------------- the fault rows
def test_row_01_one_missing_reply_keeps_running_with_no_number_made_up(emulated):
    emu = emulated()

    def drop():
        emu.stub.servos[2].drop = 1

    emu.stub.at(1.0, drop)
    assert emu.run() == ExitCode.OK
    run = emu.read()
    assert run.summary["stale_reads"] == {"pan": 0, "tilt": 1, "jaw": 0}
    stale = run.columns["status_tilt"] == 1
    assert stale.sum() == 1 and np.isnan(run.columns["present_tilt"][stale]).all()
    assert np.isfinite(run.columns["present_pan"]).all()


def test_row_03_a_silent_servo_beyond_the_budget_is_a_safe_stop(emulated):
    emu = emulated()

    def silence():
        emu.stub.servos[3].silent = True

    emu.stub.at(1.0, silence)
    code = emu.run(duration=3)
    run = emu.read()
    reason = run.summary["exit_reason"]
    assert "servo 3 (jaw)" in reason and "no valid reading" in reason
    assert code == ExitCode.FAULT  # the fault's code; the hold it could not confirm is named
    assert run.summary["exit_policy_confirmed"] is False
    assert "servo 3" in run.summary["exit_policy"]
    assert run.columns["t_actual"][-1] < 1.2  # stopped within the budget, not at 3 s


def test_row_05_corrupt_replies_are_discarded_and_the_show_goes_on(emulated):
    emu = emulated()

    def corrupt():
        emu.stub.servos[1].corrupt = 3

    emu.stub.at(0.8, corrupt)
    assert emu.run() == ExitCode.OK
    run = emu.read()
    assert run.summary["stale_reads"]["pan"] == 3 and run.summary["stale_reads"]["tilt"] == 0
    assert events(run, "corrupt_reply")


def test_row_12_a_hardware_error_bit_is_a_safe_stop_naming_the_cause(emulated):
    emu = emulated()

    def overheat():
        emu.stub.servos[2].err = 0x04

    emu.stub.at(1.0, overheat)
    assert emu.run() == ExitCode.FAULT
    reason = emu.read().summary["exit_reason"]
    assert "servo 2 (tilt)" in reason and "overheating" in reason


def test_row_13_a_torque_loss_is_a_safe_stop(emulated):
    emu = emulated()

    def limp():
        s = emu.stub.servos[1]
        s.set("Torque Enable", 0)
        s.torque_sticks_off = True

    emu.stub.at(0.6, limp)
    assert emu.run(duration=3) != ExitCode.OK
    s = emu.read().summary
    assert "servo 1 (pan)" in s["exit_reason"]
    assert "torque off" in s["exit_reason"] or "Torque Enable reads 0" in s["exit_reason"]


def test_row_24_a_host_stall_longer_than_watchdog_ms_is_said_and_the_show_goes_on(
    emulated, monkeypatch, capsys
):
    """No Bus Watchdog: a 200 ms host stall (safety.watchdog_ms = 100) is the host's hiccup,
    not a fault: an event says the servos held their last goal that long, the summary counts
    it, no servo is blamed and the show runs to its end."""
    holder: dict = {}
    replace_track(monkeypatch, 1, lambda tr: StallAt(tr, holder["clock"], 0.8, 0.2))
    emu = emulated()
    holder["clock"] = emu.stub.clock
    assert emu.run() == ExitCode.OK
    assert "held their last goal through 1 host stall(s)" in capsys.readouterr().err
    run = emu.read()
    s = run.summary
    assert s["exit_reason"] == "end of show"
    assert comm_errors(s) == 0 and s["exit_policy_confirmed"] is True
    held = events(run, "held_last_goal")
    assert len(held) == 1
    msg = held[0]["message"]
    assert "held their last goal for 2" in msg and "no Bus Watchdog" in msg
    assert "not a servo fault" in msg and "the show goes on" in msg
    assert held[0]["held_ms"] >= 190
    stalls = s["loop"]["host_stalls"]
    assert stalls["held_last_goal"] == 1 and stalls["held_max_ms"] >= 190
    assert not events(run, "recovered")


def test_row_24_a_short_host_stall_is_caught_up(emulated, monkeypatch):
    holder: dict = {}
    replace_track(monkeypatch, 1, lambda tr: StallAt(tr, holder["clock"], 0.8, 0.05))
    emu = emulated()
    holder["clock"] = emu.stub.clock
    assert emu.run() == ExitCode.OK
    assert comm_errors(emu.read().summary) == 0


def test_row_29_an_exit_policy_that_cannot_be_confirmed_is_exit_code_4(emulated):
    emu = emulated()

    def hook(data: bytes) -> None:  # the exit's first step: Torque Enable read (1 byte)
        late = emu.stub.clock.now() > 1.0  # (torque on at the start reads it back too)
        if late and data[2] == 2 and data[4] == packet.Inst.READ and data[5:7] == b"\x28\x01":
            emu.stub.servos[2].silent = True

    emu.stub.hook = hook
    assert emu.run() == ExitCode.UNSAFE_EXIT
    s = emu.read().summary
    assert s["exit_policy_confirmed"] is False and "servo 2" in s["exit_policy"]


@pytest.mark.parametrize(
    ("signum", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["SIGINT", "SIGTERM"]
)
def test_rows_25_26_a_signal_mid_show_applies_the_exit_policy(emulated, signum, code):
    emu = emulated()
    fired: dict = {}

    def hook(data: bytes) -> None:
        if not fired and emu.stub.clock.now() >= 0.9 and data[4] == packet.Inst.SYNC_WRITE:
            fired["t"] = emu.stub.clock.now()
            assert signal.getsignal(signum) not in (signal.SIG_DFL, signal.default_int_handler)
            signal.raise_signal(signum)

    emu.stub.hook = hook
    assert emu.run() == code
    run = emu.read()
    s = run.summary
    assert s["exit_code"] == code and signal.Signals(signum).name in s["exit_reason"]
    assert s["exit_policy_confirmed"] is True
    after = emu.writes_after(fired["t"] + 1e-9)
    assert len(sync_writes(after)) == 0  # no goal after the signal's tick ...
    held = [p for p in after if p.code == packet.Inst.WRITE and p.params[0] == 42]
    assert {p.id for p in held} == {1, 2, 3}  # ... but the hold: goal := present, read back


def test_bench_measures_the_feetech_bus_against_its_wire_model(tmp_path, capsys):
    """`hilsim bench RIG` on the virtual clock: the tick's bus calls take exactly the wire
    model (12 STS3215, Sync Write + Sync Read, Return Delay 0, no latency: 1.84 ms)."""
    rig = RIG.split("[[joints]]")[0].replace(
        "dxlsim://unused", "dxlsim://?ids=1-12&model=STS3215&rdt_us=0&latency_ms=0"
    )
    for i in range(1, 13):
        rig += (
            f'[[joints]]\nname = "j{i}"\nservo_id = {i}\nmodel = "STS3215"\nmin_deg = -50\n'
            "max_deg = 50\nspring = { frequency_hz = 2.0, damping_ratio = 0.8 }\n"
            'target = { type = "hold", value_deg = 0 }\n'
        )
    path = tmp_path / "sts12.toml"
    path.write_text(rig)
    argv = ["bench", str(path), "--clock", "virtual", "--quick", "--out", str(tmp_path / "b")]
    assert main(argv) == 0
    import json

    got = json.loads((tmp_path / "b" / "bench.json").read_text())["p1_bus"]
    assert got["model_s"] == pytest.approx(1.84e-3, abs=1e-9)
    assert got["achieved_s"] == pytest.approx(got["model_s"], rel=1e-6)
    assert got["failed_reads"] == 0 and got["read_hz_per_servo"] == 250.0
    assert got["bus_s"] == pytest.approx(got["model_s"], rel=1e-6)  # all of it the bus's
    out = capsys.readouterr().out
    assert "1.840 ms a tick" in out and "of which bus time 1.840 ms a tick (+0.0 %" in out


def test_the_joint_plot_draws_a_rotation_buses_present_line_through_its_unread_ticks(emulated):
    rig = RIG.replace('"STS3215"', '"AX-12A"')  # at 250 Hz fewer than three reads fit a tick
    emu = emulated(rig, {1: "AX-12A", 2: "AX-12A", 3: "AX-12A"})
    assert emu.run(duration=1.0) == ExitCode.OK
    from hilsim.telemetry.joint_plots import joints_figure

    run = emu.read()
    fig = joints_figure(run)
    for j, ax in zip(("pan", "tilt", "jaw"), fig.axes, strict=False):
        (line,) = [ln for ln in ax.lines if ln.get_label() == "present (read back)"]
        asked = np.count_nonzero(run.columns[f"status_{j}"] != 4)
        assert 0 < asked < run.n_ticks and len(line.get_xdata()) == asked
        assert np.isfinite(line.get_ydata()).all()  # one line, not dots between NaNs


def test_teach_by_hand_is_refused_on_a_feetech_bus(emulated):
    """A Feetech goal write turns torque back on, and every tick writes every goal: a limp
    joint would stiffen under the hand. Refused before anything moves, naming the servo."""
    import types

    from drivers.p1bus.bus import P1ServoBus
    from hilsim.live.teach import Teach, TeachConfig
    from hilsim.show.session import ShowRefusedError, check_teach

    emu = emulated()
    rig = load_rig(emu.path)
    bus = P1ServoBus.open(rig.bus.port, baud=1_000_000, ids=rig.servo_ids, models=["STS3215"] * 3)
    try:
        names = rig.joint_names
        teach = Teach(names, TeachConfig.from_table({"joints": ["jaw"]}, "show.toml: teach", names))
        with pytest.raises(ShowRefusedError, match=r"teach: servo 3 \(jaw\) is a STS3215"):
            check_teach(rig, bus, types.SimpleNamespace(teach=teach))  # type: ignore[arg-type]
    finally:
        bus.close()
    assert not [p for p in emu.stub.instructions() if p.code in (3, 0x83)]  # nothing written


def test_an_ax_joint_beyond_300_degrees_is_refused_at_load(tmp_path):
    path = tmp_path / "ax.toml"
    path.write_text(RIG.replace('"STS3215"', '"AX-12A"').replace("max_deg = 50", "max_deg = 160"))
    with pytest.raises(RigError, match=r"joints\[0\]\.max_deg: .*160 deg is beyond what a AX-12A "
                       r"turns \(-150\.\.150 deg around tick 512\)"):  # fmt: skip
        load_rig(path)


def test_feetech_health_reads_fill_the_same_condition_record(emulated):
    """The Protocol 1.0 health read covers load, voltage and temperature: the loop keeps them
    in the record the X-series condition reads fill, and the summary has the extremes."""
    emu = emulated()
    emu.stub.servos[2].set("Present Temperature", 52)
    emu.stub.servos[3].set("Present Voltage", 74)  # 7.4 V
    assert emu.run() == ExitCode.OK
    cond = emu.read().summary["loop"]["servo_condition"]
    assert cond["pan"] == {"max_temperature_c": 31.0, "min_voltage_v": cond["pan"]["min_voltage_v"]}
    assert cond["tilt"]["max_temperature_c"] == 52.0
    assert cond["jaw"]["min_voltage_v"] == 7.4
    assert all(5.0 <= c["min_voltage_v"] <= 13.0 for c in cond.values())
