"""hilsim.Show, the one way to run a show from Python: the README's example, a stop from
another thread on the real clock, a refusal before anything moves, cues and live joints."""

from __future__ import annotations

import contextlib
import io
import json
import re
import threading
from pathlib import Path

import numpy as np
import pytest

import hilsim
from drivers.clock import VirtualClock
from drivers.dxlsim import DxlBus, VirtualServo, register_bus, unregister_bus
from drivers.dxlsim.protocol import Instruction, StreamParser
from hilsim.exit_codes import ExitCode
from hilsim.telemetry.reader import read_run

REPO = Path(__file__).resolve().parents[2]

RIG = """
name = "api"
[bus]
port = "PORT"
[loop]
rate_hz = 250
[safety]
soft_start_s = 0.1
[[joints]]
name = "head"
servo_id = 1
min_deg = -40
max_deg = 40
spring = { frequency_hz = 6.0, damping_ratio = 0.9, response = 0.0 }
target = { type = "hold", value_deg = 0 }
[[joints]]
name = "jaw"
servo_id = 2
min_deg = 0
max_deg = 20
spring = { frequency_hz = 6.0, damping_ratio = 0.9, response = 0.0 }
target = { type = "hold", value_deg = 5 }
"""

SHOW = """
[clips.open]
jaw = { type = "hold", value_deg = 15 }
[cues.open]
trigger = "key:o"
clip = "open"
"""


def _rig(tmp_path: Path, port: str) -> Path:
    path = tmp_path / "rig.toml"
    path.write_text(RIG.replace("PORT", port))
    return path


def _readme_example() -> str:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text.split("## From Python", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_readme_example_runs(tmp_path, monkeypatch):
    """The README's "From Python" block, as written: exit code 0, a run directory, 501 ticks."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "configs").symlink_to(REPO / "configs")
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(_readme_example(), "README.md", "exec"), {})
    code, run_dir, ticks = out.getvalue().split()
    assert (code, ticks) == ("0", "501")
    assert Path(run_dir).is_dir() and (Path(run_dir) / "summary.json").is_file()


def test_stop_from_another_thread_ends_a_real_clock_show_through_the_exit_policy(tmp_path):
    """The show runs on the real clock (the emulator's default); a second thread stops it once
    it is under way: exit code 5, the reason says who stopped it, the exit policy confirmed."""
    rig = _rig(tmp_path, "dxlsim://?ids=1-2&rdt_us=0&latency_ms=1")
    under_way = threading.Event()
    with hilsim.Show(rig, out=tmp_path / "run") as show:
        stopper = threading.Thread(target=lambda: under_way.wait(30) and show.stop())
        stopper.start()
        result = show.run(on_status=lambda status: under_way.set())
        stopper.join()
    assert under_way.is_set()
    assert result.exit_code == ExitCode.STOPPED
    assert result.reason == "stopped by Show.stop()"
    assert result.summary["exit_policy_confirmed"] is True
    assert result.exit_policy.startswith("exit policy 'hold': 2 servo(s) confirmed")
    assert result.ticks > 0 and result.summary["exit_code"] == ExitCode.STOPPED
    events = [json.loads(line) for line in (tmp_path / "run" / "events.jsonl").open()]
    assert [e["kind"] for e in events if e["kind"] in ("stop", "exit_policy")] == [
        "stop",
        "exit_policy",
    ]


@pytest.fixture
def mismatched(tmp_path):
    """A named emulated bus of XL430s, and a rig that expects XM430s (the default model)."""
    bus = DxlBus(
        [VirtualServo("XL430-W250", i, baud=1_000_000, return_delay_us=0, t=0.0) for i in (1, 2)],
        baud=1_000_000,
        clock=VirtualClock(),
        trace=True,
    )
    register_bus("apimismatch", bus)
    yield bus, _rig(tmp_path, "dxlsim://apimismatch")
    unregister_bus("apimismatch")


def test_a_rig_that_does_not_match_the_bus_is_refused_before_anything_moves(mismatched, tmp_path):
    bus, rig = mismatched
    show = hilsim.Show(rig, out=tmp_path / "run")
    with pytest.raises(hilsim.ShowRefusedError) as info, show:
        pytest.fail("entered a show whose servos do not match")
    assert "do not match" in str(info.value) and "XL430-W250" in str(info.value)
    sent = [f.packet.instruction for rec in bus.trace if rec.direction == "tx"
            for f in StreamParser().feed(rec.data)]  # fmt: skip
    assert sent and Instruction.SYNC_WRITE not in sent and Instruction.WRITE not in sent
    assert not any(s.torque_enabled for s in bus.servos)
    assert not (tmp_path / "run").exists()  # the directory made for it is gone again
    with pytest.raises(hilsim.ShowError):
        show.run()


def test_a_show_runs_once_and_only_once_open(tmp_path):
    rig = _rig(tmp_path, "dxlsim://?ids=1-2&rdt_us=0&latency_ms=1")
    show = hilsim.Show(rig, virtual_time=True, duration=0.1, out=tmp_path / "run")
    with pytest.raises(hilsim.ShowError, match="open the show first"):
        show.run()
    with show:
        assert show.run().exit_code == 0
        with pytest.raises(hilsim.ShowError, match="runs once"):
            show.run()


def test_cue_and_set_joint_reach_the_show_through_the_springs(tmp_path):
    """A cue and a live value given before tick 0 take effect at tick 0; the events say the
    program fired the cue; the live value, like every input, is a target for the spring."""
    rig = _rig(tmp_path, "dxlsim://?ids=1-2&rdt_us=0&latency_ms=1")
    show_file = tmp_path / "show.toml"
    show_file.write_text(SHOW)
    with hilsim.Show(
        rig, virtual_time=True, duration=1.0, show=show_file, out=tmp_path / "run"
    ) as show:
        with pytest.raises(KeyError, match="no cue 'shut'"):
            show.cue("shut")
        with pytest.raises(KeyError, match="no joint 'tail'"):
            show.set_joint("tail", 1.0)
        with pytest.raises(ValueError, match="not a joint angle"):
            show.set_joint("head", float("nan"))
        show.cue("open")
        show.set_joint("head", 30.0)
        result = show.run()
    assert result.exit_code == 0
    run = read_run(tmp_path / "run")
    starts = [e for e in run.events if e["kind"] == "cue_start"]
    assert starts and starts[0]["trigger"] == "api:cue/open"
    target, spring = np.degrees(run.joint("target")), np.degrees(run.joint("sim_x"))
    assert target[0] == pytest.approx([30.0, 15.0])  # head live, jaw the cue's clip
    assert 29.0 < spring[-1, 0] < 31.0  # the spring followed it


def test_cues_need_a_show_file(tmp_path):
    rig = _rig(tmp_path, "dxlsim://?ids=1-2&rdt_us=0&latency_ms=1")
    show = hilsim.Show(rig, virtual_time=True, duration=0.1)
    with pytest.raises(hilsim.ShowError, match="show file"):
        show.cue("open")
