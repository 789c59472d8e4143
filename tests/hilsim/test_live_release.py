"""Live joints handed back to the show: OSC ``/hilsim/release``, ``release_after_s``,
``Show.release``, and the status line saying which layer drives each joint.

The OSC datagrams are built by python-osc (a client's own encoder), fed at chosen ticks of a
virtual-time show on the emulator."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import hilsim
from hilsim.live.controls import Controls
from hilsim.rig import load_rig
from hilsim.show.parts import build_parts, with_show
from hilsim.show.session import open_bus, open_telemetry, port_for, run_show
from hilsim.show.stop import StopFlag
from hilsim.telemetry.reader import read_run

builder = pytest.importorskip("pythonosc.osc_message_builder")

PERIOD = 0.004
SPEED = 200.0  # deg/s: head_pan's speed limit
RIG = f"""
name = "release"
[bus]
port = "dxlsim://?ids=1-2&rdt_us=0&latency_ms=1"
[loop]
rate_hz = 250
[safety]
soft_start_s = 0.1
[[joints]]
name = "head_pan"
servo_id = 1
min_deg = -60
max_deg = 60
max_speed_deg_s = {SPEED}
max_accel_deg_s2 = 5000
spring = {{ frequency_hz = 4.0, damping_ratio = 1.0, response = 0.0 }}
target = {{ type = "hold", value_deg = 0 }}
[[joints]]
name = "jaw"
servo_id = 2
min_deg = 0
max_deg = 20
spring = {{ frequency_hz = 6.0, damping_ratio = 0.9, response = 0.0 }}
target = {{ type = "hold", value_deg = 5 }}
"""

SHOW = """
[clips.sway]
head_pan = { type = "sine", amplitude_deg = 10, frequency_hz = 0.2 }
jaw = { type = "hold", value_deg = 2 }
[idle]
clips = ["sway"]
[inputs.osc]
port = 9000
joints = { head_pan = [-50, 50] }
"""
SENDER = ("127.0.0.1", 5000)


def message(address: str, *args: float) -> bytes:
    m = builder.OscMessageBuilder(address)
    for a in args:
        m.add_arg(a)
    return m.build().dgram


def run(tmp_path: Path, show_text: str, duration: float, sends: dict[int, list[bytes]], *,
        watch=None):  # fmt: skip
    """The show in virtual time; ``sends[k]``: datagrams arriving during tick k (seen at tick
    k + 1); ``watch(k, director)`` after each tick."""
    (tmp_path / "rig.toml").write_text(RIG)
    (tmp_path / "show.toml").write_text(show_text)
    rig = load_rig(tmp_path / "rig.toml")
    parts = with_show(build_parts(rig), str(tmp_path / "show.toml"), False, virtual=True)
    director = parts.director
    real_tick = director.tick
    seen: dict[int, str] = {}

    def tick(k, t, present):
        real_tick(k, t, present)
        seen[k] = director.now_playing
        for data in sends.get(k, ()):
            director.osc.feed(k * PERIOD, data, SENDER)
        if watch is not None:
            watch(k, director)

    director.tick = tick
    bus = open_bus(rig, port_for(rig, True))
    tel = open_telemetry(rig, tmp_path / "run", True)
    try:
        result = run_show(parts, bus, tel, duration_s=duration, stop=StopFlag())
    finally:
        bus.close()
    r = read_run(tmp_path / "run")
    return SimpleNamespace(result=result, run=r, status=seen, director=director)


def deg(r, quantity: str, joint: int = 0) -> np.ndarray:
    return np.degrees(r.run.joint(quantity)[:, joint])


def idle_deg(t: np.ndarray) -> np.ndarray:
    return 10.0 * np.sin(2 * math.pi * 0.2 * t)


def test_osc_release_hands_head_pan_back_to_idle_through_its_spring(tmp_path):
    """A live value takes head_pan from the idle sway; /hilsim/release/head_pan gives it
    back: the target is the idle's again at the next tick, the command never steps more than
    the speed limit allows, and the joint follows the idle afterwards."""
    take, release = 250, 1000  # 1 s, 4 s
    r = run(tmp_path, SHOW, 7.0, {take: [message("/hilsim/joint/head_pan", 0.9)],
                                  release: [message("/hilsim/release/head_pan")]})  # fmt: skip
    assert r.result.exit_code == 0
    target, cmd, present = deg(r, "target"), deg(r, "cmd"), deg(r, "present")
    t = np.arange(len(target)) * PERIOD
    np.testing.assert_allclose(target[: take + 1], idle_deg(t[: take + 1]), atol=1e-9)
    assert np.all(target[take + 1 : release + 1] == pytest.approx(40.0))  # live: 0.9 of ±50
    np.testing.assert_allclose(target[release + 1 :], idle_deg(t[release + 1 :]), atol=1e-9)
    assert abs(cmd[release] - 40.0) < 0.5  # the joint was there when released
    steps = np.abs(np.diff(cmd))
    assert steps.max() <= SPEED * PERIOD + 1e-9  # no jump, ever
    back = t > release * PERIOD + 1.5
    assert np.abs(present[back] - idle_deg(t[back])).max() < 1.5  # follows the idle again
    kinds = [(e["kind"], e.get("joint"), e["source"]) for e in r.run.events
             if e["kind"].startswith(("live_", "release_"))]  # fmt: skip
    assert kinds == [("live_take", "head_pan", "osc"), ("live_release", "head_pan", "osc")]
    rel = next(e for e in r.run.events if e["kind"] == "live_release")
    assert rel["to"] == "idle sway" and "/hilsim/release/head_pan" in rel["reason"]
    assert rel["t"] == pytest.approx(release * PERIOD)
    assert r.status[take - 1].startswith("head_pan idle sway, jaw idle sway")
    assert r.status[take + 1].startswith("head_pan live osc, jaw idle sway")
    assert r.status[release + 1].startswith("head_pan idle sway")


def test_release_all_a_button_up_and_a_joint_that_is_not_held(tmp_path):
    """/hilsim/release frees every live joint; a first argument 0 (a button let go) is no
    press; releasing what no input holds is one release_ignored line; an unknown joint is a
    counted drop."""
    sends = {
        100: [message("/hilsim/joint/head_pan", 1.0)],
        200: [message("/hilsim/release", 0)],  # the button's release: nothing
        300: [message("/hilsim/release", 1)],
        400: [message("/hilsim/release/jaw"), message("/hilsim/release/nose")],
    }
    r = run(tmp_path, SHOW, 2.0, sends)
    target = deg(r, "target")
    assert target[299] == pytest.approx(50.0) and target[301] != pytest.approx(50.0)
    kinds = [e["kind"] for e in r.run.events if e["kind"].startswith(("live_", "release_"))]
    assert kinds == ["live_take", "live_release", "release_ignored"]
    ignored = next(e for e in r.run.events if e["kind"] == "release_ignored")
    assert ignored["message"] == "OSC /hilsim/release/jaw: jaw is not held by a live input"
    assert r.result.summary["live"]["osc_drops"]["unknown"] == 1


RELEASE_AFTER = SHOW.replace("port = 9000", "port = 9000\nrelease_after_s = 0.5")


def test_release_after_s_hands_back_a_joint_whose_value_is_not_refreshed(tmp_path):
    """release_after_s = 0.5: values at 1.0 and 1.2 s keep head_pan; none after: released at
    the first tick past 1.7 s, and never LOST (the input no longer holds it)."""
    sends = {250: [message("/hilsim/joint/head_pan", 0.9)],
             300: [message("/hilsim/joint/head_pan", 0.9)]}  # fmt: skip
    r = run(tmp_path, RELEASE_AFTER, 5.0, sends)
    rel = [e for e in r.run.events if e["kind"] == "live_release"]
    assert len(rel) == 1 and rel[0]["t"] == pytest.approx(301 * PERIOD + 0.5, abs=PERIOD)
    assert "release_after_s 0.5" in rel[0]["reason"]
    assert not [e for e in r.run.events if e["kind"] == "input_lost"]  # lost_after_s is 2 s
    assert not any("LOST" in line for line in r.status.values())
    target = deg(r, "target")
    k = round(rel[0]["t"] / PERIOD)
    assert target[k - 1] == pytest.approx(40.0)  # the release's tick samples the idle
    t = np.arange(len(target)) * PERIOD
    np.testing.assert_allclose(target[k:], idle_deg(t[k:]), atol=1e-9)


def test_by_default_a_lost_input_holds_its_joint_and_the_status_says_lost(tmp_path):
    """No release_after_s (the default): the old behaviour, a lost input holds the joint
    (LOST on the status line) until a release, after which LOST is gone."""
    sends = {250: [message("/hilsim/joint/head_pan", 0.9)],
             1500: [message("/hilsim/release/head_pan")]}  # fmt: skip
    r = run(tmp_path, SHOW, 7.0, sends)
    lost = [e for e in r.run.events if e["kind"] == "input_lost"]
    assert len(lost) == 1 and lost[0]["t"] == pytest.approx(251 * PERIOD + 2.0, abs=PERIOD)
    assert r.status[1200].startswith("head_pan LOST osc, jaw idle sway")
    assert deg(r, "target")[1500] == pytest.approx(40.0)  # held while lost
    assert r.status[1502].startswith("head_pan idle sway")
    assert not any("LOST" in r.status[k] for k in range(1502, len(r.status)))


def test_a_release_after_s_longer_than_lost_after_s_shows_lost_then_releases(tmp_path):
    text = SHOW.replace("port = 9000", "port = 9000\nlost_after_s = 0.5\nrelease_after_s = 2")
    r = run(tmp_path, text, 4.0, {250: [message("/hilsim/joint/head_pan", 0.2)]})
    kinds = [e["kind"] for e in r.run.events if e["kind"] in ("input_lost", "live_release")]
    assert kinds == ["input_lost", "live_release"]
    assert r.status[500].startswith("head_pan LOST osc")
    assert r.status[900].startswith("head_pan idle sway")


def test_a_cue_shows_on_each_joint_it_drives_and_its_progress(tmp_path):
    text = (
        SHOW
        + """
[clips.scare]
jaw = { type = "keyframes", keys = [[0, 15], [2, 15]] }
[cues.scare]
trigger = "at:1.0"
clip = "scare"
"""
    )
    r = run(tmp_path, text, 2.0, {100: [message("/hilsim/joint/head_pan", 0.5)]})
    assert r.status[300] == "head_pan live osc, jaw cue scare; cue scare (0.2/2.0 s)"


def test_show_release_from_python(tmp_path):
    """Show.set_joint takes a joint, Show.release hands it back (to the rig's own target
    here: the show has no clips); both reach the loop at its next tick."""
    (tmp_path / "rig.toml").write_text(RIG)
    with hilsim.Show(tmp_path / "rig.toml", virtual_time=True, duration=3.0, live=True,
                     out=tmp_path / "run") as show:  # fmt: skip
        director = show.parts.director
        real_tick = director.tick

        def tick(k, t, present):
            real_tick(k, t, present)
            if k == 250:
                show.release("head_pan")
            elif k == 400:
                show.set_joint("jaw", 12.0)
            elif k == 500:
                show.release()

        director.tick = tick
        with pytest.raises(KeyError, match="no joint 'nose'"):
            show.release("nose")
        show.set_joint("head_pan", 30.0)
        result = show.run()
    assert result.exit_code == 0
    run_ = read_run(tmp_path / "run")
    target = np.degrees(run_.joint("target"))
    assert target[250, 0] == pytest.approx(30.0) and target[251, 0] == pytest.approx(0.0)
    assert target[401, 1] == pytest.approx(12.0) and target[501, 1] == pytest.approx(5.0)
    rel = [(e["joint"], e["source"], e["to"]) for e in run_.events if e["kind"] == "live_release"]
    assert rel == [("head_pan", "api", "rig"), ("jaw", "api", "rig")]
    with pytest.raises(hilsim.ShowError, match="show file"):
        hilsim.Show(tmp_path / "rig.toml", virtual_time=True, duration=0.1).release()


def test_controls_release_drops_a_value_set_before_it_not_one_after():
    c = Controls(["a", "b"])
    c.set_joint("a", 1.0)
    c.release("a")
    c.release("a")
    p = c.poll(0.0)
    assert p.values == {} and p.releases == ["a"]
    c.release()
    c.set_joint("b", 2.0)
    p = c.poll(0.0)
    assert p.values == {"b": 2.0} and p.releases == [None]
    with pytest.raises(KeyError):
        c.release("z")


def test_a_standing_value_takes_a_released_joint_again_only_once_it_changes():
    """A gamepad or Bottango reports its value every tick: after a release, the same value
    does not take the joint back; a moved axis does."""
    from hilsim.live.live_layer import LiveLayer

    tracks = [SimpleNamespace(live=None)]
    layer = LiveLayer(["jaw"], tracks, {"gamepad": 1.0}, lambda i: "idle rest")
    assert layer.take(0, 0.5, "gamepad", 0.0, standing=True).kind == "live_take"
    assert layer.take(0, 0.5, "gamepad", 0.5, standing=True) is None  # not fresh
    assert [e.kind for e in layer.expire(1.1)] == ["live_release"]  # unchanged for 1.1 s
    assert layer.take(0, 0.5, "gamepad", 1.2, standing=True) is None
    assert tracks[0].live is None and layer.label(0) == "idle rest"
    assert layer.take(0, 0.6, "gamepad", 1.3, standing=True).kind == "live_take"
    assert layer.label(0) == "live gamepad"


@pytest.mark.parametrize(
    ("section", "words"),
    [
        ("[inputs.osc]\nrelease_after_s = -1", "inputs.osc.release_after_s: must be > 0"),
        ("[inputs.midi]\nrelease_after_s = 0", "inputs.midi.release_after_s: must be > 0"),
        (
            '[inputs.gamepad]\nrelease_after_s = "soon"\n[[inputs.gamepad.button]]\n'
            'button = 0\ntrigger = "key:s"',
            "inputs.gamepad.release_after_s: must be a number of seconds > 0",
        ),
    ],
)
def test_a_bad_release_after_s_is_one_line(tmp_path, section, words):
    (tmp_path / "rig.toml").write_text(RIG)
    (tmp_path / "show.toml").write_text(section + "\n")
    with pytest.raises(hilsim.RigError, match=words.replace(".", r"\.")):
        hilsim.Show(tmp_path / "rig.toml", virtual_time=True, show=tmp_path / "show.toml")


def test_release_after_s_is_read_for_each_live_input(tmp_path):
    from hilsim.live.bottango_config import from_table
    from hilsim.live.director import release_after
    from hilsim.live.showfile import load_show

    (tmp_path / "show.toml").write_text(
        "[inputs.osc]\nrelease_after_s = 3\n[inputs.midi]\nrelease_after_s = 1.5\n"
    )
    spec = load_show(tmp_path / "show.toml", load_rig_text(tmp_path), lambda *a: None)
    assert release_after(spec) == {"osc": 3.0, "midi": 1.5, "gamepad": None, "bottango": None,
                                   "sacn": None, "artnet": None}  # fmt: skip
    table = {"effectors": {"0": {"joint": "jaw", "degrees": [0, 20]}}, "release_after_s": 2}
    assert from_table(table, "b", ["jaw"]).release_after_s == 2.0


def load_rig_text(tmp_path: Path) -> hilsim.Rig:
    (tmp_path / "rig.toml").write_text(RIG)
    return load_rig(tmp_path / "rig.toml")


def test_the_status_figures_name_each_joints_layer(tmp_path):
    """On the real clock, Show.run's on_status figures carry what drives each joint."""
    (tmp_path / "rig.toml").write_text(RIG)
    seen: list[dict] = []
    with hilsim.Show(tmp_path / "rig.toml", duration=1.2, live=True,
                     out=tmp_path / "run") as show:  # fmt: skip
        show.set_joint("jaw", 10.0)
        show.run(on_status=seen.append)
    assert seen and seen[-1]["layers"] == {"head_pan": "rig", "jaw": "live api"}


def test_a_release_pressed_again_and_again_is_said_once_a_second(tmp_path):
    sends = {k: [message("/hilsim/release")] for k in range(10, 400, 10)}  # 39 presses
    r = run(tmp_path, SHOW, 1.7, sends)
    ignored = [e for e in r.run.events if e["kind"] == "release_ignored"]
    assert [round(e["t"], 3) for e in ignored] == [0.04, 1.04]
    live = r.result.summary["live"]
    assert live["releases_ignored"] == 39
    assert live["joints_taken"] == live["joints_released"] == 0


def test_midi_release_after_s_counts_each_controller_message_as_fresh(tmp_path):
    """MIDI CC with release_after_s = 0.5: a fader moved until 1.0 s keeps head_pan; the
    joint goes back to the idle sway at the first tick past 1.5 s."""
    mido = pytest.importorskip("mido")
    text = (
        SHOW.split("[inputs.osc]")[0]
        + """
[inputs.midi]
release_after_s = 0.5
[[inputs.midi.cc]]
joint = "head_pan"
channel = 1
control = 7
degrees = [-30, 30]
"""
    )
    (tmp_path / "rig.toml").write_text(RIG)
    (tmp_path / "show.toml").write_text(text)
    rig = load_rig(tmp_path / "rig.toml")
    parts = with_show(build_parts(rig), str(tmp_path / "show.toml"), False, virtual=True)
    for i in range(11):  # 0.0 .. 1.0 s, values 100 .. 110
        msg = mido.Message("control_change", channel=0, control=7, value=100 + i)
        parts.director.midi.feed(msg, i / 10)
    bus = open_bus(rig, port_for(rig, True))
    try:
        result = run_show(parts, bus, open_telemetry(rig, tmp_path / "run", True),
                          duration_s=2.5, stop=StopFlag())  # fmt: skip
    finally:
        bus.close()
    assert result.exit_code == 0
    run_ = read_run(tmp_path / "run")
    rel = [e for e in run_.events if e["kind"] == "live_release"]
    assert len(rel) == 1 and rel[0]["source"] == "midi" and rel[0]["to"] == "idle sway"
    assert 1.5 < rel[0]["t"] <= 1.5 + PERIOD + 1e-9
    target = np.degrees(run_.joint("target")[:, 0])
    k = round(rel[0]["t"] / PERIOD)
    assert target[k - 1] == pytest.approx(-30 + 60 * 110 / 127)
    t = np.arange(len(target)) * PERIOD
    np.testing.assert_allclose(target[k:], idle_deg(t[k:]), atol=1e-9)


def test_python_osc_over_a_real_socket_takes_and_releases_a_joint():
    """python-osc's SimpleUDPClient sends a value and a release to the receiver's real UDP
    socket; the director's poll applies them in order (no wall-clock figure is asserted)."""
    import threading

    udp_client = pytest.importorskip("pythonosc.udp_client")
    from hilsim.live.osc import OscInput, listen

    fed = threading.Semaphore(0)

    class Signalled(OscInput):
        def feed(self, t, data, sender):
            super().feed(t, data, sender)
            fed.release()

    inp = Signalled({"head_pan": (-50.0, 50.0)}, releasable=["head_pan", "jaw"])
    rx = listen(inp, 0, clock=lambda: 2.0)
    try:
        client = udp_client.SimpleUDPClient(*rx.address)
        client.send_message("/hilsim/joint/head_pan", 0.9)
        assert fed.acquire(timeout=5.0), "the receiver did not feed the packet"
        inp.poll(2.0)
        assert inp.target("head_pan") == pytest.approx(40.0)
        client.send_message("/hilsim/release/head_pan", [])
        assert fed.acquire(timeout=5.0), "the receiver did not feed the packet"
        (ev,) = inp.poll(2.004)
        assert ev.kind == "release" and ev.detail["joint"] == "head_pan"
        assert inp.target("head_pan") is None  # forgotten: nothing held, nothing to lose
    finally:
        rx.close()


def test_a_joint_taken_from_osc_by_another_input_is_not_lost_by_osc(tmp_path):
    """OSC sets head_pan, then Show.set_joint takes it: OSC going quiet is no input_lost for
    head_pan (OSC no longer holds it, so it holds nothing there to lose)."""

    def watch(k, d):
        if k == 100:
            d.api.set_joint("head_pan", 5.0)

    r = run(tmp_path, SHOW, 3.0, {50: [message("/hilsim/joint/head_pan", 0.9)]}, watch=watch)
    takes = [(e["source"], e["from"]) for e in r.run.events if e["kind"] == "live_take"]
    assert takes == [("osc", "idle sway"), ("api", "live osc")]
    assert not [e for e in r.run.events if e["kind"] == "input_lost"]
    assert r.status[700].startswith("head_pan live api")
