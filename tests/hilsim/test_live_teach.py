"""Teach-by-hand (hilsim.live.teach), the limp joints of the servo watch, and the review's R2.3
acceptance on the emulator in virtual time: a hand moves joint 1 as a 0.5 Hz ±20° sine while
its torque is off; the take, reduced within 0.2°, replays within 0.2° of the sine."""

from __future__ import annotations

import math
import os
import tomllib
from types import SimpleNamespace

import numpy as np
import pytest

from drivers.dynamixel.bus import DynamixelBus
from drivers.servo_bus import PresentReading
from hilsim.live.teach import HALF_COUNT_DEG, Teach, TeachConfig
from hilsim.rig.joint_map import JointMap
from hilsim.show.monitors import FollowingMonitor
from hilsim.show.servo_watch import LoopFaultError, ServoWatch
from hilsim.targets.spec import track_from_spec

NAMES = ("jaw", "pan")
WHERE = "show.toml: teach"
TICKS_PER_DEG = 4096 / 360


# ------------------------------------------------------------------ [teach]
def test_config_from_table() -> None:
    c = TeachConfig.from_table({"joints": ["pan", "jaw"], "tolerance_deg": 0.3}, WHERE, NAMES)
    assert c == TeachConfig(("jaw", "pan"), 0.3)  # rig order
    assert TeachConfig.from_table({"joints": ["jaw"]}, WHERE, NAMES).tolerance_deg == 0.2


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({}, "show.toml: teach.joints: missing"),
        ({"joints": []}, "show.toml: teach.joints: must be a non-empty list"),
        ({"joints": "jaw"}, "show.toml: teach.joints: must be a non-empty list"),
        ({"joints": ["tail"]}, "show.toml: teach.joints: no such joint 'tail' (joints: jaw, pan)"),
        ({"joints": ["jaw", "jaw"]}, "show.toml: teach.joints: a joint is named twice"),
        ({"joints": ["jaw"], "tolerance_deg": 0}, "show.toml: teach.tolerance_deg: must be > 0"),
        ({"joints": ["jaw"], "tolerance_deg": "1"}, "show.toml: teach.tolerance_deg: must be a"),
        ({"joints": ["jaw"], "tolerance_deg": True}, "show.toml: teach.tolerance_deg: must be a"),
        ({"joints": ["jaw"], "speed": 1}, "show.toml: teach.speed: unknown key"),
        ([], "show.toml: teach: must be a table"),
    ],
)
def test_config_errors_are_one_line_naming_the_key(table, message) -> None:
    with pytest.raises(ValueError) as info:
        TeachConfig.from_table(table, WHERE, NAMES)
    assert str(info.value).startswith(message)
    assert "\n" not in str(info.value)


# ------------------------------------------------------------------ the take
def test_record_keeps_the_limp_joints_and_targets_follow_present() -> None:
    teach = Teach(NAMES, ["pan"])
    assert teach.limp_indices == (1,)
    assert teach.reduce_deg == pytest.approx(0.2 - HALF_COUNT_DEG)
    teach.record(0.0, [1.0, 5.0])
    teach.record(0.01, [1.0, math.nan])  # no reading: no sample, the live value holds
    teach.record(0.02, [1.0, 6.0])
    assert teach.take.raw("pan")[1].tolist() == [5.0, 6.0]
    assert teach.take.skipped["not_finite"] == 1
    assert teach.targets_deg([1.0, 7.5]) == {"pan": 7.5}
    assert teach.targets_deg([1.0, math.nan]) == {}
    assert teach.summary()["samples"] == {"pan": 2}
    with pytest.raises(ValueError, match="one present position per joint"):
        teach.record(0.03, [1.0])


def test_finish_writes_raw_keys_and_a_clip_that_replays(tmp_path) -> None:
    teach = Teach(NAMES, TeachConfig(("jaw",), 0.5))
    for k in range(101):  # from show time 2 s: the files start at 0
        teach.record(2.0 + k * 0.01, [10.0 * k * 0.01, 0.0])
    out = teach.finish(tmp_path / "teach")
    assert out["written"] and out["origin_s"] == 2.0
    assert out["raw_samples"] == {"jaw": 101} and out["keys"] == {"jaw": 2}
    raw = (tmp_path / "teach" / "raw.csv").read_text().splitlines()
    assert raw[0] == "time_s,jaw" and len(raw) == 102 and raw[1].startswith("0.0,")
    doc = tomllib.loads((tmp_path / "teach" / "take.toml").read_text())
    track = track_from_spec(doc["clips"]["take"]["jaw"], joint_name="jaw")
    assert math.degrees(track.sample(0.5)[0]) == pytest.approx(5.0)
    assert sorted(p.name for p in (tmp_path / "teach").iterdir()) == [
        "keys.csv",
        "raw.csv",
        "take.toml",
    ]


def test_nothing_recorded_writes_nothing(tmp_path) -> None:
    teach = Teach(NAMES, ["jaw"])
    teach.record(0.0, [math.nan, 0.0])
    assert teach.finish(tmp_path / "teach")["written"] is False
    assert not (tmp_path / "teach").exists()


@pytest.mark.parametrize("fail_at", [1, 2, 3])
def test_the_take_files_are_whole_or_absent(tmp_path, monkeypatch, fail_at) -> None:
    """The disk fails while the n-th file is written: that file and the ones after it are
    absent (never half written), the ones before it whole."""
    teach = Teach(NAMES, ["jaw"])
    for k in range(50):
        teach.record(k * 0.01, [math.sin(k / 5), 0.0])
    real_fsync, calls = os.fsync, []

    def fsync(fd: int) -> None:
        calls.append(fd)
        if len(calls) == fail_at:
            raise OSError(28, "No space left on device")
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(OSError, match="No space"):
        teach.finish(tmp_path)
    names = ["raw.csv", "keys.csv", "take.toml"]
    for i, name in enumerate(names):
        assert (tmp_path / name).exists() == (i < fail_at - 1), name
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert teach.finish(tmp_path)["written"]  # a second try overwrites with whole files
    assert tomllib.loads((tmp_path / "take.toml").read_text())["clips"]["take"]["jaw"]


# ------------------------------------------------------------------ limp joints in the watch
def test_following_monitor_exempt() -> None:
    m = FollowingMonitor([0.1, 0.1], [0.02, 0.02], 0.01)
    m.exempt(frozenset({0}))
    for _ in range(10):
        assert m.update([5.0, 0.0], [0.0, 0.0]) is None
    m.exempt(frozenset())
    assert m.update([5.0, 0.0], [0.0, 0.0]) is None
    assert m.update([5.0, 0.0], [0.0, 0.0]).joint == 0


@pytest.fixture
def limp_show():
    """Two servos held, servo 1 (jaw) then limp, a ServoWatch over them, events kept."""
    bus = DynamixelBus.open(
        "dxlsim://?ids=1-2&rdt_us=0&clock=virtual", baud=1_000_000, ids=[1, 2], read_mode="fast"
    )
    joints = [
        SimpleNamespace(name=n, servo_id=i + 1, tracking_tolerance_rad=0.1, tracking_time_s=0.05)
        for i, n in enumerate(NAMES)
    ]
    events: list = []
    watch = ServoWatch(
        bus,
        joints,
        JointMap([0.0, 0.0], [1.0, 1.0]),
        period_s=0.01,
        comm_budget_ms=40,
        watchdog_s=0.1,
        event=lambda *a, **k: events.append(a),
        rejoin=lambda i, x: None,
    )
    bus.set_torque(True)
    bus.arm_watchdog(0.1)
    bus.set_torque(False, ids=[1])
    watch.set_limp([0])
    yield SimpleNamespace(bus=bus, dx=bus.link.port.ser.bus, watch=watch, events=events)
    bus.close()


def run_ticks(show, n: int, present=(0.0, 0.0), cmd=(0.0, 0.0)) -> None:
    """``n`` ticks of reads, following and health reads (time to spare on each)."""
    bus, watch, reading = show.bus, show.watch, PresentReading.empty((1, 2))
    for k in range(n):
        bus.clock.wait_until(bus.clock.now() + 0.01)
        bus.read_present(reading)
        watch.check_reads(reading, bus.clock.now(), 0.0, False)
        watch.check_following(list(present), list(cmd))
        watch.maybe_read_health(1.0, bus.clock.now(), k)


def test_a_limp_joint_with_torque_off_runs_without_fault(limp_show) -> None:
    run_ticks(limp_show, 100, present=(0.5, 0.0))  # the jaw far from its command
    limp_show.watch.after_bus_silence(0.06, 100)  # reads every servo's whole health
    run_ticks(limp_show, 10)
    assert limp_show.watch.health.reads >= 20


def test_a_held_joint_with_torque_cut_still_stops_the_show(limp_show) -> None:
    limp_show.dx.servo(2).cut_torque(limp_show.bus.clock.now())
    with pytest.raises(LoopFaultError, match=r"servo 2 \(pan\): torque off"):
        run_ticks(limp_show, 50)


def test_a_held_joint_that_does_not_follow_still_stops_the_show(limp_show) -> None:
    with pytest.raises(LoopFaultError, match=r"servo 2 \(pan\): following error"):
        run_ticks(limp_show, 20, present=(0.5, 0.5))


def test_a_limp_joint_with_a_hardware_error_stops_the_show(limp_show) -> None:
    limp_show.dx.servo(1).inject_hardware_error(0x04, limp_show.bus.clock.now())
    with pytest.raises(
        LoopFaultError, match=r"servo 1 \(jaw\): hardware error: Hardware Error Status 0x04"
    ):
        run_ticks(limp_show, 2)


def test_a_limp_joint_that_restarted_stops_the_show(limp_show) -> None:
    limp_show.dx.servo(1).brownout(limp_show.bus.clock.now())  # RAM back: watchdog 0
    with pytest.raises(LoopFaultError, match=r"servo 1 \(jaw\): reset"):
        run_ticks(limp_show, 50)


def test_set_limp_refuses_a_joint_that_is_not_there(limp_show) -> None:
    with pytest.raises(ValueError, match=r"limp joints \[2\]"):
        limp_show.watch.set_limp([2])


# ------------------------------------------------------------------ R2.3 acceptance
def test_r2_3_a_sine_taught_by_hand_replays_within_0_2_deg(tmp_path) -> None:
    """dxlsim, virtual time: joint 1 (jaw) limp, a hand moves it as a 0.5 Hz ±20° sine; 4 s
    recorded each tick at 100 Hz as the loop would (goals of the limp joint = its present
    position); reduced within 0.2°, the keys replayed (linear Keyframes) are within 0.2° of
    the sine at every tick."""
    rate, seconds = 100, 4.0
    bus = DynamixelBus.open(
        "dxlsim://?ids=1-2&rdt_us=0&clock=virtual", baud=1_000_000, ids=[1, 2], read_mode="fast"
    )
    try:
        clock, dx = bus.clock, bus.link.port.ser.bus
        bus.set_torque(True)
        teach = Teach(NAMES, TeachConfig.from_table({"joints": ["jaw"]}, WHERE, NAMES))
        bus.set_torque(False, ids=[bus.ids[i] for i in teach.limp_indices])
        t0 = clock.now() + 0.01  # tick 0

        def sine_deg(t_show: float) -> float:
            return 20.0 * math.sin(2 * math.pi * 0.5 * t_show)

        dx.servo(1).hand(lambda t: 2048.0 + sine_deg(t - t0) * TICKS_PER_DEG)
        reading = PresentReading.empty(bus.ids)
        goals = [0.0, 0.0]
        n_ticks = round(seconds * rate) + 1
        for k in range(n_ticks):
            clock.wait_until(t0 + k / rate)
            bus.write_goals(np.radians(goals))  # harmless to the limp servo: no motion
            bus.read_present(reading)
            assert reading.all_ok
            present = np.degrees(reading.positions).tolist()  # joint frame = servo frame here
            teach.record(k / rate, present)
            for joint, deg in teach.targets_deg(present).items():
                goals[NAMES.index(joint)] = deg  # the limp joint's target = where it is
        assert not dx.servo(1).torque_enabled and dx.servo(2).torque_enabled
        assert abs(dx.servo(2).motion.position - 2048) < 1  # the held joint never moved
        out = teach.finish(tmp_path / "teach")
    finally:
        bus.close()
    assert out["raw_samples"] == {"jaw": n_ticks}
    keys = tomllib.loads((tmp_path / "teach" / "take.toml").read_text())["clips"]["take"]["jaw"]
    replay = track_from_spec(keys, joint_name="jaw")
    ticks = np.arange(n_ticks) / rate
    err = [abs(math.degrees(replay.sample(t)[0]) - sine_deg(t)) for t in ticks]
    assert max(err) <= 0.2, max(err)
    assert out["keys"]["jaw"] < n_ticks / 4  # a reduction worth the name
