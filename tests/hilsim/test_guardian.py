"""The guardian on a bus with no Bus Watchdog (drivers/p1bus/guardian.py): ``hilsim emulate`` of
three STS3215 on a pseudo-terminal, ``hilsim run`` on it in a subprocess. Killed with SIGKILL,
the show applies no exit policy: the guardian does (relax: torque off, read back) and says so
in the run directory; a show that ends by itself, or on Ctrl-C, leaves the guardian silent.
Torque is read back through the pty with our own P1 link. Behaviour, not speed: each wait
is on a line of output or a pipe's end."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import tty
from pathlib import Path

import pytest

from drivers.p1bus.guardian import RECORD_FILE, Guardian
from drivers.p1bus.link import P1Link
from drivers.p1bus.table import family_of
from drivers.protocol1 import packet
from tests.emulate_pty import emulated_pty
from tests.hilsim.test_p1_show import RIG

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a Linux pty")

IDS = (1, 2, 3)
HILSIM = (sys.executable, "-m", "hilsim")
STS = family_of("STS3215")


@pytest.fixture(scope="module")
def pty() -> object:
    with emulated_pty("--ids", "1-3", "--model", "STS3215") as (_proc, path):
        yield path


def _rig(tmp_path: Path, port: str, policy: str) -> Path:
    text = RIG.replace("dxlsim://unused", port).replace(
        'exit_policy = "hold"', f'exit_policy = "{policy}"'
    )
    path = tmp_path / f"{policy}.toml"
    path.write_text(text.replace("[bus]\n", "[bus]\nbaud = 1000000\n", 1))
    return path


def _torque(port: str) -> dict[int, int]:
    link = P1Link.open(port, baud=1_000_000)
    try:
        return {sid: link.read_reg(STS, sid, STS.torque_enable) for sid in IDS}
    finally:
        link.close()


def _start_show(rig: Path, out: Path) -> tuple[subprocess.Popen[str], list[str]]:
    """``hilsim run`` in a session of its own, read until the show runs with torque on (its
    first status line); returns the process and the lines so far."""
    proc = subprocess.Popen(
        [*HILSIM, "run", str(rig), "--duration", "60", "--no-plots", "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    lines: list[str] = []
    for line in proc.stderr:
        lines.append(line)
        if "status: t " in line:
            return proc, lines
    proc.wait()
    pytest.fail("the show never ran: " + "".join(lines))


def _rest(proc: subprocess.Popen[str]) -> str:
    """The rest of stderr: it ends when the show's process and its guardian (which shares
    the stream) have both exited."""
    rest = proc.stderr.read()
    proc.wait(timeout=60)
    return rest


def test_sigkill_with_exit_policy_relax_the_guardian_turns_torque_off(pty, tmp_path):
    out = tmp_path / "run"
    proc, lines = _start_show(_rig(tmp_path, pty, "relax"), out)
    assert any("guardian (pid" in line and "turns their torque off" in line for line in lines)
    os.kill(proc.pid, signal.SIGKILL)
    err = _rest(proc)
    assert proc.returncode == -signal.SIGKILL
    assert "hilsim guardian: the show's process" in err and "read back 0 on all 3" in err
    assert _torque(pty) == dict.fromkeys(IDS, 0)
    record = json.loads((out / RECORD_FILE).read_text())
    assert record["policy"] == "relax" and record["confirmed"] == list(IDS)
    assert record["unconfirmed"] == [] and record["show_pid"] == proc.pid
    last = json.loads((out / "events.jsonl").read_text().splitlines()[-1])
    assert last["kind"] == "guardian" and last["message"] == record["message"]


def test_sigkill_with_exit_policy_hold_the_guardian_says_they_hold(pty, tmp_path):
    out = tmp_path / "run"
    proc, _ = _start_show(_rig(tmp_path, pty, "hold"), out)
    os.kill(proc.pid, signal.SIGKILL)
    err = _rest(proc)
    assert "exit policy hold: nothing to do" in err
    assert _torque(pty) == dict.fromkeys(IDS, 1)  # they hold their last goal
    record = json.loads((out / RECORD_FILE).read_text())
    assert record["policy"] == "hold" and record["action"].startswith("none")
    # (the next show on this port starts from servos with torque on: the rig's exit is hold)


def test_a_show_that_ends_by_itself_leaves_the_guardian_silent(pty, tmp_path):
    out = tmp_path / "run"
    rig = _rig(tmp_path, pty, "relax")
    done = subprocess.run(
        [*HILSIM, "run", str(rig), "--duration", "1", "--no-plots", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )  # (returns once the guardian, which shares stderr, has exited too)
    assert done.returncode == 0, done.stderr
    assert "guardian (pid" in done.stderr and "hilsim guardian:" not in done.stderr
    assert not (out / RECORD_FILE).exists()
    assert _torque(pty) == dict.fromkeys(IDS, 0)  # the show's own exit policy


def test_ctrl_c_to_the_terminal_is_the_shows_and_the_guardian_stays_silent(pty, tmp_path):
    out = tmp_path / "run"
    proc, _ = _start_show(_rig(tmp_path, pty, "relax"), out)
    os.killpg(proc.pid, signal.SIGINT)  # the terminal's process group: the show, not its guardian
    err = _rest(proc)
    assert "exit policy 'relax': 3 servo(s) confirmed" in err
    assert "hilsim guardian:" not in err and not (out / RECORD_FILE).exists()


def test_the_guardian_never_writes_while_the_show_lives(tmp_path):
    """On a bare pty pair: nothing on the wire while the pipe is open or after a release;
    the pipe's end without a release: a Sync Write of Torque Enable 0, then read-backs."""
    silent_master, silent_slave = os.openpty()
    tty.setraw(silent_slave)
    g = Guardian.start(
        silent_slave, port="pty", ids=IDS, models=["STS3215"] * 3, policy="relax", run_dir=tmp_path
    )
    assert not select.select([silent_master], [], [], 0.5)[0]  # (a bounded look, not a speed)
    g.release()
    assert g.proc.returncode == 0
    assert not select.select([silent_master], [], [], 0.2)[0]
    assert not (tmp_path / RECORD_FILE).exists()

    master, slave = os.openpty()
    tty.setraw(slave)  # as pyserial leaves a port: bytes as they are
    g = Guardian.start(
        slave, port="pty", ids=IDS, models=["STS3215"] * 3, policy="relax", run_dir=tmp_path
    )
    os.close(g._fd)  # the show's process gone: its end of the pipe closed, no release
    g._fd = -1
    sw = packet.sync_write(STS.torque_enable.addr, 1, {i: b"\x00" for i in IDS})
    first = b""
    while len(first) < len(sw) + 8 and select.select([master], [], [], 20)[0]:
        first += os.read(master, 100)
    assert first.startswith(sw)
    assert first[len(sw) :].startswith(packet.read(1, STS.torque_enable.addr, 1))
    g.proc.wait(timeout=60)  # nobody answers: read-backs time out, said unconfirmed
    record = json.loads((tmp_path / RECORD_FILE).read_text())
    assert record["unconfirmed"] == list(IDS) and "NOT confirmed" in record["message"]
