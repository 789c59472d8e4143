"""Live inputs through the whole show (issue 14): the director in the loop, on the emulator in
virtual time, with messages injected at chosen ticks or stamped ahead of time."""

from __future__ import annotations

import itertools
import math
import struct
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from hilsim.exit_codes import ExitCode
from hilsim.rig import load_rig
from hilsim.show.parts import build_parts, with_show
from hilsim.show.session import open_bus, open_telemetry, port_for, run_show
from hilsim.show.stop import StopFlag
from hilsim.telemetry.reader import read_run

RIG = """
name = "live"
[bus]
port = "dxlsim://?ids=1-2&model=XM430-W210&rdt_us=0&latency_ms=1"
[loop]
rate_hz = 250
[safety]
soft_start_s = 0.1
[[joints]]
name = "head_pan"
servo_id = 1
model = "XM430-W210"  # 462 °/s no-load: the speed limits below fit
min_deg = -40
max_deg = 40
max_speed_deg_s = 400
max_accel_deg_s2 = 20000
spring = { frequency_hz = 6.0, damping_ratio = 0.9, response = 0.0 }
target = { type = "hold", value_deg = 0 }
[[joints]]
name = "jaw"
servo_id = 2
model = "XM430-W210"
min_deg = 0
max_deg = 20
max_speed_deg_s = 300
max_accel_deg_s2 = 20000
spring = { frequency_hz = 6.0, damping_ratio = 0.9, response = 0.0 }
target = { type = "keyframes", keys = [[0, 0], [10, 20]], easing = "linear" }
"""
PERIOD = 0.004


def pad(b: bytes) -> bytes:
    return b + b"\0" * (4 - len(b) % 4)


def osc(address: str, *floats: float) -> bytes:
    tags = "," + "f" * len(floats)
    return (
        pad(address.encode()) + pad(tags.encode()) + b"".join(struct.pack(">f", f) for f in floats)
    )


def show(
    tmp_path: Path,
    show_text: str | None,
    *,
    duration: float,
    inject=None,
    live=False,
    rig=RIG,
    open_inputs=False,
    setup=None,
    prepare=None,
):
    """Run the rig with the show file (virtual time); ``inject(k, director)`` runs after the
    director's tick k (a message arriving during tick k is seen at tick k + 1)."""
    rig_path = tmp_path / "rig.toml"
    rig_path.write_text(rig)
    show_path = None
    if show_text is not None:
        show_path = tmp_path / "show.toml"
        show_path.write_text(show_text)
    rig = load_rig(rig_path)
    parts = with_show(
        build_parts(rig), None if show_path is None else str(show_path), live, virtual=True
    )
    director = parts.director
    if prepare is not None:  # messages stamped ahead of time, before tick 0
        prepare(director)
    if inject is not None:
        real_tick = director.tick

        def tick(k, t, present):
            real_tick(k, t, present)
            inject(k, director)

        director.tick = tick
    bus = open_bus(rig, port_for(rig, True))
    if setup is not None:  # e.g. a hand on an emulated servo
        setup(bus)
    if open_inputs:  # as hilsim run does: sockets, ports, the pty, before anything moves
        director.open(bus.clock, lambda line: None)
    out = tmp_path / "run"
    tel = open_telemetry(rig, out, True)
    try:
        result = run_show(parts, bus, tel, duration_s=duration, stop=StopFlag())
    finally:
        bus.close()
    return SimpleNamespace(result=result, run=read_run(out), director=director, out=out)


def deg(run, quantity: str, joint: int) -> np.ndarray:
    return np.degrees(run.joint(quantity)[:, joint])


# ------------------------------------------------------------------ OSC
OSC_SHOW = """
[inputs.osc]
port = 9000
joints = { jaw = [0, 20] }
"""


def test_osc_joint_sets_the_target_on_the_next_tick(tmp_path):
    def inject(k, d):
        if k == 250:
            d.osc.feed(k * PERIOD, osc("/hilsim/joint/jaw", 0.5), ("127.0.0.1", 5000))

    r = show(tmp_path, OSC_SHOW, duration=1.2, inject=inject)
    target = deg(r.run, "target", 1)
    assert target[250] == pytest.approx(250 * PERIOD * 2.0)  # still the rig's own keyframes
    assert target[251] == pytest.approx(10.0)
    assert r.result.exit_code == 0
    live = r.result.summary["live"]
    assert live["live_values"] == 1 and live["takes"] == {}


def test_osc_stop_applies_the_exit_policy_and_ends_with_the_stop_code(tmp_path):
    def inject(k, d):
        if k == 100:
            d.osc.feed(k * PERIOD, osc("/hilsim/stop"), ("127.0.0.1", 5000))

    r = show(tmp_path, OSC_SHOW, duration=5.0, inject=inject)
    assert r.result.exit_code == ExitCode.STOPPED == 5
    assert "OSC /hilsim/stop" in r.result.reason
    assert r.result.summary["exit_policy_confirmed"] is True
    assert r.run.n_ticks == 102  # the stop seen at tick 101 ends the show before tick 102
    kinds = [e["kind"] for e in r.run.events]
    assert "stop" in kinds and "exit_policy" in kinds


def test_a_flood_of_malformed_packets_and_a_stranger_change_nothing(tmp_path):
    """10,000 malformed datagrams during the show and a well-formed one from a sender outside
    the allow-list: every target is the rig's own, every drop counted, no overrun."""
    rng = np.random.default_rng(7)
    junk = [
        bytes(rng.integers(0, 256, int(rng.integers(1, 200)), dtype=np.uint8)) for _ in range(64)
    ]
    text = OSC_SHOW.replace(
        "port = 9000", 'port = 9000\ninterface = "127.0.0.1"\nallow = ["127.0.0.2"]'
    )

    def inject(k, d):
        if 10 <= k < 110:  # 100 a tick for 100 ticks
            for i in range(100):
                d.osc.feed(k * PERIOD, junk[(k + i) % 64] + b"\xff", ("127.0.0.2", 5000))
        if k == 120:
            d.osc.feed(k * PERIOD, osc("/hilsim/joint/jaw", 0.9), ("127.0.0.1", 5000))

    r = show(tmp_path, text, duration=1.0, inject=inject)
    target = deg(r.run, "target", 1)
    np.testing.assert_allclose(target, np.arange(len(target)) * PERIOD * 2.0, atol=1e-9)
    drops = r.result.summary["live"]["osc_drops"]
    assert drops["sender"] == 1
    assert sum(drops.values()) == 10_001
    assert r.result.summary.get("overruns", 0) == 0
    assert r.result.exit_code == 0


def test_a_storm_of_one_cue_is_a_few_lines_a_second_and_each_trigger_acts(tmp_path):
    """/trigger/pir 1000 times a second for 3 s (the scare locked out 10 s): the trigger
    acts each time (one cue, then lockouts), but its ``cue`` and ``cue_ignored`` lines are 4,
    then one a second each, the last one saying how many it stands for."""

    def inject(k, d):
        if 250 <= k < 1000:
            for _ in range(4):
                d.osc.feed(k * PERIOD, osc("/trigger/pir"), ("127.0.0.1", 5000))

    r = show(tmp_path, SCARE_SHOW.replace('"at:3.0"', '"at:30"'), duration=5.0, inject=inject)
    kinds = [e["kind"] for e in r.run.events]
    assert kinds.count("cue_start") == 1
    assert 1 <= kinds.count("cue") <= 4 + 3 + 1 and 1 <= kinds.count("cue_ignored") <= 4 + 3 + 1
    last = [e for e in r.run.events if e["kind"] == "cue_ignored"][-1]
    assert "held back" in last["message"] and last["lines"] > 100


# ------------------------------------------------------------------ MIDI
MIDI_SHOW = """
[inputs.midi]
[[inputs.midi.cc]]
joint = "head_pan"
channel = 1
control = 7
degrees = [-30, 30]
[record]
tolerance_deg = 0.5
"""


def test_midi_cc_ramp_drives_the_joint_and_records_a_take(tmp_path):
    """The issue's MIDI acceptance through the loop: CC 7 ch 1 0->127 at 100 Hz over 1.27 s,
    stamped ahead of time (v at v/100 s): -30 deg at 0, -0.24 at 0.63 s, +30 from 1.27 s."""
    mido = pytest.importorskip("mido")

    def prepare(d):
        for v in range(128):
            d.midi.feed(mido.Message("control_change", channel=0, control=7, value=v), v / 100)

    r = show(tmp_path, MIDI_SHOW, duration=2.0, prepare=prepare)
    target = deg(r.run, "target", 0)
    t = np.arange(len(target)) * PERIOD
    assert target[0] == pytest.approx(-30.0)
    i063 = int(np.searchsorted(t, 0.63 - 1e-9))  # the tick at 0.632 s: the last value is v = 63
    assert target[i063] == pytest.approx(-30 + 60 * 63 / 127, abs=1e-9)  # -0.236 deg
    assert target[i063] == pytest.approx(-0.24, abs=0.005)
    assert np.all(target[t >= 1.27] == pytest.approx(30.0))
    assert np.all(target[t < 1.27] < 30.0)
    takes = r.result.summary["live"]["takes"]["live"]
    assert takes["raw_samples"] == {"head_pan": 128}
    assert takes["keys"]["head_pan"] <= 3
    # the reduced take replays within 0.5 deg of the raw take at every tick
    raw = np.loadtxt(r.out / "take" / "raw.csv", delimiter=",", skiprows=1)
    keys = np.loadtxt(r.out / "take" / "keys.csv", delimiter=",", skiprows=1, ndmin=2)
    ticks = np.arange(0, 1.27 + 1e-9, PERIOD)
    assert (
        np.max(
            np.abs(
                np.interp(ticks, keys[:, 0], keys[:, 1]) - np.interp(ticks, raw[:, 0], raw[:, 1])
            )
        )
        <= 0.5
    )
    held = raw[np.searchsorted(raw[:, 0], ticks + 1e-12, side="right") - 1, 1]  # as it was live
    assert np.max(np.abs(np.interp(ticks, keys[:, 0], keys[:, 1]) - held)) <= 0.5
    assert (r.out / "take" / "take.toml").read_text().startswith("# a take")


# ------------------------------------------------------------------ MTC
MTC_SHOW = """
[inputs.mtc]
freewheel_s = 0.5
"""


def test_mtc_chase_locks_the_show_time_then_freewheels_and_holds(tmp_path):
    """Quarter frames for 00:00:02:15 at 30 fps at 120 Hz from 1.0 s; the jaw follows its rig
    keyframes (2 deg/s) at the chased show time; 500 ms after the timecode stops it holds."""
    mido = pytest.importorskip("mido")
    data = [0x0F, 0x10, 0x22, 0x30, 0x40, 0x50, 0x60, 0x76]

    def inject(k, d):
        if k == 0:
            for i, b in enumerate(data):
                d.chase.feed(mido.Message("quarter_frame", frame_type=b >> 4, frame_value=b & 15),
                             1.0 + i / 120)  # fmt: skip

    r = show(tmp_path, MTC_SHOW, duration=2.5, inject=inject)
    target = deg(r.run, "target", 1)
    t = np.arange(len(target)) * PERIOD
    locked = t[np.argmax(target > 0.5)]  # the first tick after the 8th quarter frame
    assert 1.0 + 7 / 120 <= locked <= 1.0 + 7 / 120 + PERIOD + 1e-9
    show_t = target[t == locked][0] / 2.0
    assert show_t == pytest.approx(2 + 15 / 30 + 2 / 30, abs=1 / 30)  # 2.5667 s, the review's
    # exactly: the code + 7/4 frames at the 8th quarter frame, run on to this tick
    assert show_t == pytest.approx(2.5 + 1.75 / 30 + locked - (1.0 + 7 / 120), abs=1e-6)
    held = target[t > locked + 0.5 + 1 / 30 + PERIOD]
    assert np.all(held == held[0])  # freewheel over, the show time holds
    assert held[0] == pytest.approx(target[t == locked][0] + 2.0 * 0.5, abs=2.0 / 30 + 0.01)
    kinds = [e["kind"] for e in r.run.events]
    assert {"timecode_locked", "timecode_stopped", "timecode_held"} <= set(kinds)


# ------------------------------------------------------------------ the files
def test_a_show_file_mistake_is_one_line(tmp_path, capsys):
    from hilsim.cli import main

    (tmp_path / "rig.toml").write_text(RIG)
    bad = tmp_path / "show.toml"
    for text, words in [
        ("[inputs.osc]\nport = 70000\n", "inputs.osc.port"),
        ("[inputs.midi]\n[[inputs.midi.cc]]\njoint = 'nose'\ncontrol = 7\ndegrees = [0, 1]\n",
         "no such joint 'nose'"),
        ("[inputs.osc]\ninterface = '10.0.0.5'\n", "allow"),
        ("[inputs.nope]\n", "unknown key(s) nope"),
        ("[record]\ntolerance_deg = -1\n", "record.tolerance_deg"),
        ("not toml [", "not valid TOML"),
    ]:  # fmt: skip
        bad.write_text(text)
        out = tmp_path / f"r{len(words)}"
        code = main(["run", str(tmp_path / "rig.toml"), "--show", str(bad), "--virtual-time",
                     "--duration", "0.1", "--no-plots", "--out", str(out)])  # fmt: skip
        err = capsys.readouterr().err
        assert code == 2, text
        assert words in err and "Traceback" not in err, err
        assert len(err.strip().splitlines()) == 1, err


# ------------------------------------------------------------------ the show runtime
SCARE_SHOW = """
[clips.idle]
jaw = { type = "hold", value_deg = 10 }
[clips.scare]
jaw = { type = "keyframes", keys = [[0, 30], [0.5, 25], [1.0, 5]] }
[idle]
clips = ["idle"]
[cues.scare]
trigger = ["osc:/trigger/pir", "at:3.0"]
clip = "scare"
then = "idle"
lockout_s = 10
[inputs.osc]
port = 9000
"""


def test_a_triggered_scare_is_within_the_limits_and_a_second_trigger_is_locked_out(tmp_path):
    """The issue's show acceptance: idle holds the jaw at 10 deg; the scare clip starts at
    30 deg (the jaw opened to 40 deg for this) when triggered at 3.0 s; the commanded jaw never steps more
    than its speed limit x period; a second trigger inside the lockout is ignored and logged."""

    def inject(k, d):
        if k == 1000:  # 4.0 s: inside the 10 s lockout
            d.osc.feed(k * PERIOD, osc("/trigger/pir"), ("127.0.0.1", 5000))

    slow = RIG.replace("max_speed_deg_s = 300", "max_speed_deg_s = 100")
    slow = slow.replace("min_deg = 0\nmax_deg = 20", "min_deg = 0\nmax_deg = 40")
    r = show(tmp_path, SCARE_SHOW, duration=6.0, inject=inject, rig=slow)
    assert r.result.exit_code == 0
    target, cmd = deg(r.run, "target", 1), deg(r.run, "cmd", 1)
    t = np.arange(len(target)) * PERIOD
    assert np.all(target[(t > 1.0) & (t < 3.0)] == pytest.approx(10.0))
    assert target[t == 3.0][0] == pytest.approx(30.0)  # the cut, on the tick it was due
    assert np.all(target[(t > 4.0) & (t < 6.0)] == pytest.approx(10.0))  # idle again
    steps = np.abs(np.diff(cmd))
    assert steps.max() <= 100 * PERIOD + 1e-9  # max_speed_deg_s x period
    assert steps[(t[1:] > 3.0) & (t[1:] < 3.2)].max() > 0.99 * 100 * PERIOD  # the limit acted
    events = [(e["kind"], round(e["t"], 3)) for e in r.run.events if e.get("source") == "show"]
    kinds = [k for k, _ in events]
    assert ("cue_start", 3.0) in events and ("cue_end", 4.0) in events
    ignored = [e for e in r.run.events if e["kind"] == "cue_ignored"]
    assert len(ignored) == 1 and ignored[0]["reason"] == "lockout"
    assert ignored[0]["t"] == pytest.approx(1001 * PERIOD)
    assert kinds.count("cue_start") == 1


# ------------------------------------------------------------------ Bottango live, over a pty
SC1 = "sC,0,0,2000,4096,513,0,7110,-763,814"


def hashed(cmd: str) -> bytes:
    return f"{cmd},h{sum(cmd.encode())}\n".encode()


def test_bottango_over_a_pty_moves_the_jaw_as_the_export_does(tmp_path):
    """The issue's Bottango acceptance end to end: the show opens its pty (the link a user
    points Bottango at); at tick 10 the test, playing the app, sends the handshake, the
    registration, a time sync and the curve, reading each answer before the next line (as
    the app waits for OK). The jaw's target then equals the imported export of the same curve
    at the driver's time; a bad hash moves nothing; STOP ends the show with the stop code."""
    import os
    import select

    from hilsim.targets.formats.bottango import read_export
    from hilsim.targets.formats.common import UnitMap

    link = tmp_path / "bottango"
    text = f"""
[inputs.bottango]
transport = "pty"
link = "{link}"
[inputs.bottango.effectors."0"]
joint = "jaw"
signal = [1000, 2000]
degrees = [0, 20]
"""
    answers: list[bytes] = []

    def talk(fd: int, line: bytes) -> bytes:
        os.write(fd, line)
        got = b""
        while not got.endswith(b"OK\n") and not got.endswith(b"HASH_FAIL\n"):
            ready = select.select([fd], [], [], 5.0)[0]  # a safety net, never a timing
            assert ready, f"no answer to {line!r} (so far {got!r})"
            got += os.read(fd, 256)
        answers.append(got)
        return got

    state = {}

    def inject(k, d):
        if k == 10:
            import termios
            import tty

            fd = os.open(link, os.O_RDWR | os.O_NOCTTY)
            tty.setraw(fd, termios.TCSANOW)
            state["fd"] = fd
            assert talk(fd, hashed("hRQ,144")) == b"btngoHSK,0.8.0c1,144\nOK\n"
            talk(fd, hashed("rSVPin,0,1000,2000,3000,1500"))
            talk(fd, hashed("tSYN,0"))
            talk(fd, hashed(SC1))
            assert talk(fd, b"xUC,0,h369\n") == b"HASH_FAIL\n"  # would clear the curve
        if k == 700:
            os.write(state["fd"], hashed("STOP"))
            ready = select.select([state["fd"]], [], [], 5.0)[0]
            assert ready
            answers.append(os.read(state["fd"], 256))

    r = show(tmp_path, text, duration=5.0, inject=inject, open_inputs=True)
    os.close(state["fd"])
    assert r.result.exit_code == ExitCode.STOPPED
    assert "BOOT" in answers[-1].decode()
    stops = [e for e in r.run.events if e["kind"] == "stop"]
    assert [e.get("source") for e in stops] == ["bottango", None]  # said once, then the loop's
    target = deg(r.run, "target", 1)
    t = np.arange(len(target)) * PERIOD
    sync_t = r.director.bottango._sync_t  # the show time the tSYN line arrived
    assert 10 * PERIOD <= sync_t < 11 * PERIOD
    export = tmp_path / "GeneratedCodeAnimations.cpp"
    export.write_text(
        'const char SETUP_DATA_0[] PROGMEM = "rSVPin,0,1000,2000,3000,1500\\n";\n'
        f'const char ANIM_0_DATA0[] PROGMEM = "{SC1}\\n";\n'
    )
    track = read_export(export).track(0, "0", signal=UnitMap((1000, 2000), (0, 20), "us"))
    after = (t >= 11 * PERIOD) & (t <= 700 * PERIOD)
    expected = [math.degrees(track.sample(x - sync_t)[0]) for x in t[after]]
    np.testing.assert_allclose(target[after], expected, atol=1e-9)
    assert target[t == 1.0 + 11 * PERIOD][0] == pytest.approx(
        math.degrees(track.sample(1.0 + 11 * PERIOD - sync_t)[0])
    )


def test_a_clips_sound_starts_with_it_in_virtual_time(tmp_path):
    """A cue's sound is started on the cue's tick at its first sample, 120 ms late as the
    show asks (silent backend in virtual time: scheduled and logged, not played)."""
    import wave

    with wave.open(str(tmp_path / "scream.wav"), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(8000)
        w.writeframes(b"\x00\x10" * 8000)
    text = SCARE_SHOW.replace("[inputs.osc]\nport = 9000\n", "").replace(
        "[idle]", '[sounds]\nscare = { file = "scream.wav", offset_ms = 120 }\n[idle]'
    )
    r = show(tmp_path, text, duration=4.5, open_inputs=True)
    assert r.result.exit_code == 0
    started = [e for e in r.run.events if e["kind"] == "sound_start"]
    assert len(started) == 1 and started[0]["t"] == pytest.approx(3.0)
    assert "scream.wav" in started[0]["message"] and started[0]["start_frame"] == 0
    assert started[0]["heard_at_s"] == pytest.approx(3.12)
    assert r.result.summary["live"]["audio"]["played"] == 1


def test_the_shipped_demo_show_runs(tmp_path):
    """configs/shows/demo_show.toml on configs/demo.toml in virtual time (inputs not opened):
    idle clips alternate, the every:45 scare fires at 45 s and idle resumes after it."""
    repo = Path(__file__).resolve().parents[2]
    rig = load_rig(repo / "configs" / "demo.toml")
    parts = with_show(build_parts(rig), str(repo / "configs/shows/demo_show.toml"), False,
                      virtual=True)  # fmt: skip
    bus = open_bus(rig, port_for(rig, True))
    tel = open_telemetry(rig, tmp_path / "run", True)
    try:
        result = run_show(parts, bus, tel, duration_s=50.0, stop=StopFlag())
    finally:
        bus.close()
    assert result.exit_code == 0
    events = read_run(tmp_path / "run").events
    starts = [
        (e["kind"], e.get("clip"), round(e["t"], 3)) for e in events if e.get("source") == "show"
    ]
    assert ("cue_start", "scare", 45.0) in starts
    idle = [e["clip"] for e in events if e["kind"] == "clip_start" and not e.get("resumed")]
    assert set(idle) == {"breathe", "look_around"}
    assert all(a != b for a, b in itertools.pairwise(idle))  # random, never twice in a row
    assert any(k == "idle_resume" and t > 45.0 for k, _, t in starts)


def test_a_timecode_jump_is_a_limited_move_never_a_step(tmp_path):
    """Locked at 00:00:05:00, then the timecode jumps back to 00:00:01:00 (a rewind): the
    target steps back 8 deg at once, the commanded jaw moves back within its speed and
    acceleration limits, and the jump is an event."""
    mido = pytest.importorskip("mido")

    def frames(seconds: int) -> list[int]:
        return [0x00, 0x10, 0x20 | seconds, 0x30, 0x40, 0x50, 0x60, 0x76]

    def inject(k, d):
        if k == 0:
            for start, sec in ((1.0, 5), (1.5, 1)):
                for i, b in enumerate(frames(sec)):
                    msg = mido.Message("quarter_frame", frame_type=b >> 4, frame_value=b & 15)
                    d.chase.feed(msg, start + i / 120)

    slow = RIG.replace("max_speed_deg_s = 300", "max_speed_deg_s = 60")
    r = show(tmp_path, MTC_SHOW, duration=3.0, inject=inject, rig=slow)
    target, cmd = deg(r.run, "target", 1), deg(r.run, "cmd", 1)
    assert np.min(np.diff(target)) < -7.0  # the target jumped back ~8 deg
    steps = np.diff(cmd)
    assert np.max(np.abs(steps)) <= 60 * PERIOD + 1e-9  # the command never did
    assert np.max(np.abs(np.diff(steps))) <= 20000 * PERIOD**2 + 1e-9
    assert any(e["kind"] == "timecode_jump" for e in r.run.events)


def test_teach_by_hand_records_what_the_hand_did(tmp_path):
    """The review's R2.3 through the loop: the jaw's servo goes limp while the head is held;
    a hand moves the jaw as a 0.5 Hz +-9 deg sine around 10 deg (inside its 0..20 deg
    limits: beyond them the command stays at the limit) for 4 s; the recorded take,
    reduced within 0.2 deg, replays within 0.2 deg of the sine at every tick; the command
    follows the hand (torque coming back moves nothing); "hold" stiffens the jaw where it was
    left and the run ends cleanly."""
    servos = {}

    def setup(bus):
        emu = bus.link.port.ser.bus  # the emulated bus behind the dxlsim:// port
        servos["jaw"] = emu.servo(2)
        pulses = 4096 / 360
        emu.servo(2).hand(lambda t: 2048 + pulses * (10 + 9 * math.sin(math.pi * t)))

    text = '[teach]\njoints = ["jaw"]\ntolerance_deg = 0.2\n'
    r = show(tmp_path, text, duration=4.0, setup=setup)
    assert r.result.exit_code == 0, r.result.reason
    assert r.result.summary["exit_policy_confirmed"] is True
    t0 = r.result.summary["loop"]["clock_t0"]  # the emulator's time of tick 0
    present, cmd = deg(r.run, "present", 1), deg(r.run, "cmd", 1)
    t = np.arange(len(present)) * PERIOD
    assert np.max(np.abs(present[1:] - (10 + 9 * np.sin(np.pi * (t0 + t[1:]))))) < 0.2
    assert np.max(np.abs(cmd[2:] - present[1:-1])) < 1e-9  # the goal is where the hand was
    teach = r.result.summary["live"]["takes"]["teach"]
    keys = np.loadtxt(teach["keys_csv"], delimiter=",", skiprows=1, ndmin=2)
    origin = teach["origin_s"]
    ticks = t[(t >= origin) & (t <= t[-1])]
    replay = np.interp(ticks - origin, keys[:, 0], keys[:, 1])
    assert np.max(np.abs(replay - (10 + 9 * np.sin(np.pi * (t0 + ticks))))) <= 0.2
    assert servos["jaw"].torque_enabled  # held again by the exit policy


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("[inputs.osc]\njoints = { jaw = [-1e308, 1e308] }\n", "inputs.osc.joints.jaw"),
        ("[inputs.mtc]\noffset_s = 1e300\n", "inputs.mtc.offset_s"),
        ("[clips.a]\njaw = { type = 'hold', value_deg = 1 }\n[[timeline]]\nat_s = 1e308\n"
         "clip = 'a'\n", "timeline[0].at_s"),
        ("[clips.z]\njaw = { type = 'keyframes', keys = [[0, 1]] }\n[cues.a]\nclip = 'z'\n"
         "then = 'b'\ntrigger = 'at:0.1'\n[cues.b]\nclip = 'z'\nthen = 'a'\n", "cues.a.then"),
    ],
)  # fmt: skip
def test_the_reviews_hostile_show_files_are_refused_in_one_line(tmp_path, capsys, text, words):
    """A range that overflows to inf, an offset or a time far out, a round of cues through
    clips that end at once: refused at load (exit 2, one line naming the key), never a fault
    or a flood mid-show."""
    from hilsim.cli import main

    (tmp_path / "rig.toml").write_text(RIG)
    (tmp_path / "show.toml").write_text(text)
    code = main(["run", str(tmp_path / "rig.toml"), "--show", str(tmp_path / "show.toml"),
                 "--virtual-time", "--duration", "1", "--no-plots", "--out", str(tmp_path / "r")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and words in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1, err


def test_a_live_value_out_of_range_is_never_a_target(tmp_path):
    """Belt and braces: a value an input lets through that is not finite never becomes a
    target (counted), so it can never stop the show with a safety fault."""

    def inject(k, d):
        if k == 10:
            d._set("jaw", math.nan, k * PERIOD)
            d._set("jaw", math.inf, k * PERIOD)

    r = show(tmp_path, OSC_SHOW, duration=0.2, inject=inject)
    assert r.result.exit_code == 0
    assert r.result.summary["live"]["values_refused"] == 2


def test_a_midi_note_fires_a_cue(tmp_path):
    """A cue's "midi:note:60" trigger through the MIDI input: the note-on at 1.0 s starts the
    cue on the 1.0 s tick; a note-off and another note move nothing."""
    mido = pytest.importorskip("mido")
    text = SCARE_SHOW.replace('["osc:/trigger/pir", "at:3.0"]', '"midi:note:60"').replace(
        "[inputs.osc]\nport = 9000\n", "[inputs.midi]\n"
    )

    def prepare(d):
        d.midi_triggers.feed(mido.Message("note_on", note=61, velocity=90), 0.5)
        d.midi_triggers.feed(mido.Message("note_on", note=60, velocity=0), 0.6)  # an "off"
        d.midi_triggers.feed(mido.Message("note_on", note=60, velocity=100), 1.0)

    r = show(tmp_path, text, duration=1.5, prepare=prepare)
    starts = [e for e in r.run.events if e["kind"] == "cue_start"]
    assert len(starts) == 1 and starts[0]["t"] == pytest.approx(1.0)
    assert starts[0]["trigger"] == "midi:note:60:ch1"


def test_teach_refuses_a_servo_that_turns_its_torque_on_by_goal(tmp_path):
    """Drive Mode bit 3 (Torque On by Goal Update) on a teach joint's servo: the goals the loop
    writes would stiffen it under the hand. Refused before anything moves, naming the servo."""
    from hilsim.show.session import ShowRefusedError, check_teach

    rig_path = tmp_path / "rig.toml"
    rig_path.write_text(RIG)
    (tmp_path / "show.toml").write_text('[teach]\njoints = ["jaw"]\n')
    rig = load_rig(rig_path)
    parts = with_show(build_parts(rig), str(tmp_path / "show.toml"), False, virtual=True)
    bus = open_bus(rig, port_for(rig, True))
    try:
        check_teach(rig, bus, parts.director)  # factory Drive Mode 0: fine
        bus.link.write(2, 10, bytes([0x08]))
        with pytest.raises(ShowRefusedError, match=r"servo 2 \(jaw\) has Drive Mode bit 3"):
            check_teach(rig, bus, parts.director)
    finally:
        bus.close()
