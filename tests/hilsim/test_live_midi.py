"""MIDI CC -> joint: the issue's acceptance (CC 7 ramp -> head_pan, recorded and reduced), 14-bit
pairs, channels as users count them, lost input, a full inbox, bad mappings, the optional extra."""

from __future__ import annotations

import json
import math
import sys
import types

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilsim.live.inbox import Inbox
from hilsim.live.midi import (
    CcMapping,
    LiveExtraError,
    MidiCcInput,
    open_midi_input,
    require_mido,
)
from hilsim.live.takes import Take
from hilsim.targets.csv_file import CsvAnimation
from hilsim.targets.spec import track_from_spec

mido = pytest.importorskip("mido")

RATE_HZ = 250


def cc(channel: int, control: int, value: int):
    """A control change as a user names it (channel 1-16)."""
    return mido.Message("control_change", channel=channel - 1, control=control, value=value)


def test_acceptance_cc7_ramp_to_head_pan_recorded_and_reduced(tmp_path) -> None:
    midi = MidiCcInput([CcMapping("head_pan", channel=1, control=7, min_deg=-30, max_deg=30)])
    for v in range(128):  # 0 -> 127 at 100 Hz over 1.27 s
        midi.feed(cc(1, 7, v), v / 100)
    take = Take(["head_pan"])
    ticks = [k / RATE_HZ for k in range(int(1.5 * RATE_HZ) + 1)]
    live: dict[float, float] = {}
    for t in sorted([*ticks, 0.63]):  # 0.63 s is between two 250 Hz ticks; poll it too
        polled = midi.poll(t)
        take.record_samples(polled.samples)
        live[t] = polled.values["head_pan"]
        assert not polled.events
    assert live[0.0] == -30.0
    assert round(live[0.63], 2) == -0.24 and live[0.63] == pytest.approx(-30 + 60 * 63 / 127)
    assert all(live[t] == 30.0 for t in ticks if t >= 1.27)
    assert len(take.raw("head_pan")[0]) == 128
    raw_csv = CsvAnimation.load(take.write_raw_csv(tmp_path / "raw.csv"))
    assert len(raw_csv.times_s) == 128 and raw_csv.names == ("head_pan",)

    reduced = take.reduce(0.5)
    keys = reduced.keys("head_pan")
    assert len(keys) <= 3
    assert reduced.max_error_deg["head_pan"] <= 0.5
    # the replay, as the rig and the CSV reader build it, against the live target at every tick
    from_rig = track_from_spec({"type": "keyframes", "keys": keys}, joint_name="head_pan")
    path = reduced.write_csv(tmp_path / "take.csv")
    from_csv = CsvAnimation.load(path).curve("head_pan")
    tick_arr = np.array(ticks)
    live_arr = np.array([live[t] for t in ticks])
    for track in (reduced.track("head_pan"), from_rig, from_csv):
        replay = np.degrees(track.sample_array(tick_arr)[0])
        assert np.max(np.abs(replay - live_arr)) <= 0.5
    assert take.replay_error("head_pan", reduced, RATE_HZ, held=True) <= 0.5
    assert take.replay_error("head_pan", reduced, RATE_HZ) <= 0.5


def test_channels_are_counted_from_one_and_other_messages_move_nothing() -> None:
    midi = MidiCcInput([CcMapping("jaw", channel=10, control=1, min_deg=0, max_deg=20)])
    midi.feed(cc(1, 1, 127), 0.0)  # channel 1: not ours
    midi.feed(mido.Message("note_on", channel=9, note=1, velocity=127), 0.0)
    midi.feed(cc(10, 2, 127), 0.0)  # our channel, another controller
    polled = midi.poll(0.0)
    assert polled.values == {"jaw": None} and polled.samples == []
    assert midi.ignored == 3 and midi.applied == 0
    midi.feed(mido.Message("control_change", channel=9, control=1, value=127), 0.01)
    assert midi.poll(0.01).values["jaw"] == 20.0


def test_inverted_range_and_messages_wait_for_their_time() -> None:
    midi = MidiCcInput([CcMapping("tail", 1, 20, min_deg=45, max_deg=-45)])
    midi.feed(cc(1, 20, 0), 0.5)
    midi.feed(cc(1, 20, 127), 1.0)
    assert midi.poll(0.499).values["tail"] is None  # not yet due
    assert midi.poll(0.5).values["tail"] == 45.0
    assert midi.poll(0.9).samples == []
    polled = midi.poll(2.0)
    assert polled.values["tail"] == -45.0 and polled.samples == [(1.0, "tail", -45.0)]


def test_14_bit_pair_msb_then_lsb_is_one_sample() -> None:
    midi = MidiCcInput([CcMapping("head_tilt", 1, 1, min_deg=-40, max_deg=40, fine=True)])
    midi.feed(cc(1, 33, 100), 0.0)  # an LSB before any MSB: nothing to refine
    assert midi.poll(0.0).values["head_tilt"] is None and midi.ignored == 1
    midi.feed(cc(1, 1, 64), 0.010)
    midi.feed(cc(1, 33, 1), 0.0101)
    polled = midi.poll(0.02)
    raw = 64 * 128 + 1
    assert polled.values["head_tilt"] == pytest.approx(-40 + 80 * raw / 16383)
    assert polled.samples == [(0.0101, "head_tilt", polled.values["head_tilt"])]
    midi.feed(cc(1, 33, 0), 0.03)  # a fine move alone
    assert midi.poll(0.03).values["head_tilt"] == pytest.approx(-40 + 80 * 8192 / 16383)
    midi.feed(cc(1, 1, 127), 0.04)  # an MSB alone resets the LSB to 0
    midi.feed(cc(1, 33, 127), 0.05)
    assert midi.poll(0.04).values["head_tilt"] == pytest.approx(-40 + 80 * 127 * 128 / 16383)
    assert midi.poll(0.05).values["head_tilt"] == 40.0


def test_lost_input_holds_with_one_event_and_resumes() -> None:
    midi = MidiCcInput([CcMapping("jaw", 1, 7, 0, 20)], lost_after_s=0.5)
    midi.feed(cc(1, 7, 127), 0.0)
    midi.feed(mido.Message("active_sensing"), 0.3)  # keeps the port alive, moves nothing
    events, lost_at = [], None
    for k in range(int(1.2 * RATE_HZ)):
        t = k / RATE_HZ
        polled = midi.poll(t)
        events += polled.events
        if polled.lost and lost_at is None:
            lost_at = t
        assert polled.values["jaw"] == 20.0 or t < 0.0  # held throughout
    assert [e.kind for e in events] == ["input_lost"]
    assert lost_at == pytest.approx(0.804)  # the first tick more than 0.5 s after 0.3 s
    detail = events[0].as_dict()
    assert detail["held_deg"] == {"jaw": 20.0} and detail["silent_since_s"] == 0.3
    json.dumps(detail)
    midi.feed(cc(1, 7, 0), 1.3)
    polled = midi.poll(1.3)
    assert not polled.lost and polled.values["jaw"] == 0.0
    assert [e.kind for e in polled.events] == ["input_resumed"]


def test_a_port_that_never_sends_is_lost_from_the_first_poll() -> None:
    midi = MidiCcInput([CcMapping("jaw", 1, 7, 0, 20)], lost_after_s=1.0)
    assert not midi.poll(10.0).lost  # the timer starts here
    assert not midi.poll(11.0).lost
    polled = midi.poll(11.004)
    assert polled.lost and polled.values == {"jaw": None}
    assert [e.kind for e in polled.events] == ["input_lost"]


def test_a_full_inbox_drops_the_oldest_and_says_so_once() -> None:
    midi = MidiCcInput([CcMapping("jaw", 1, 7, 0, 127)], capacity=4)
    for v in range(10):
        midi.feed(cc(1, 7, v), v / 1000)
    polled = midi.poll(1.0)
    assert polled.values["jaw"] == 9.0  # the newest survive
    assert [s[2] for s in polled.samples] == [6.0, 7.0, 8.0, 9.0]
    assert [(e.kind, e.detail["dropped"]) for e in polled.events] == [("inbox_overflow", 6)]
    assert midi.poll(1.1).events == [] and midi.inbox.dropped == 6


def test_inbox_refuses_time_going_backwards_in_the_producer() -> None:
    box = Inbox(2)
    box.put(1.0, "a")
    with pytest.raises(ValueError, match="before the previous one"):
        box.put(0.5, "b")
    with pytest.raises(ValueError, match="finite"):
        box.put(math.nan, "c")
    with pytest.raises(ValueError, match="capacity"):
        Inbox(0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"channel": 0}, "channel must be 1-16, got 0"),
        ({"channel": 17}, "channel must be 1-16, got 17"),
        ({"control": 128}, "control must be 0-127, got 128"),
        ({"control": 32, "fine": True}, "control must be 0-31 (a 14-bit pair's MSB"),
        ({"min_deg": 10.0, "max_deg": 10.0}, "min_deg and max_deg are both 10.0"),
        ({"max_deg": math.inf}, "max_deg must be a number of degrees within ±36000"),
        ({"min_deg": -1e308, "max_deg": 1e308}, "min_deg must be a number of degrees within"),
        ({"joint": ""}, "joint must be a non-empty name"),
    ],
)
def test_a_bad_mapping_is_one_line(kwargs, message) -> None:
    args = {"joint": "jaw", "channel": 1, "control": 7, "min_deg": 0.0, "max_deg": 20.0}
    with pytest.raises(ValueError) as err:
        CcMapping(**{**args, **kwargs})
    assert message in str(err.value) and "\n" not in str(err.value)


def test_mappings_that_collide_are_refused() -> None:
    with pytest.raises(ValueError, match="joint 'jaw' is mapped twice"):
        MidiCcInput([CcMapping("jaw", 1, 7, 0, 20), CcMapping("jaw", 1, 8, 0, 20)])
    with pytest.raises(ValueError, match="channel 1 control 39 is used by both 'jaw' and 'tail'"):
        MidiCcInput([CcMapping("jaw", 1, 39, 0, 20), CcMapping("tail", 1, 7, 0, 20, fine=True)])
    with pytest.raises(ValueError, match="lost_after_s"):
        MidiCcInput([CcMapping("jaw", 1, 7, 0, 20)], lost_after_s=0)
    with pytest.raises(ValueError, match="lost_after_s"):
        MidiCcInput([CcMapping("jaw", 1, 7, 0, 20)], lost_after_s=True)


def test_missing_mido_is_one_line_naming_the_extra(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "mido", None)
    with pytest.raises(LiveExtraError, match=r"pip install 'hilsim\[live\]'"):
        require_mido()


def _fake_mido(monkeypatch, opened: list):
    fake = types.ModuleType("mido")
    fake.get_input_names = lambda: ["Faders:0"]

    def open_input(name, callback):
        opened.append(callback)
        return types.SimpleNamespace(name=name, close=lambda: opened.append("closed"))

    fake.open_input = open_input
    monkeypatch.setitem(sys.modules, "mido", fake)


def test_a_port_stamps_each_message_with_the_loop_clock_on_arrival(monkeypatch) -> None:
    opened: list = []
    _fake_mido(monkeypatch, opened)
    midi = MidiCcInput([CcMapping("jaw", 1, 7, 0, 127)])
    clock = iter([0.25, 0.5])
    with open_midi_input("Faders:0", [midi], now=lambda: next(clock)) as port:
        assert port.name == "Faders:0"
        opened[0](cc(1, 7, 10))  # mido's callback thread
        opened[0](cc(1, 7, 20))
    assert opened[-1] == "closed"
    assert midi.poll(0.3).values["jaw"] == 10.0 and midi.poll(0.5).values["jaw"] == 20.0
    with pytest.raises(ValueError, match="no MIDI input port 'Nope'; the ports are: 'Faders:0'"):
        open_midi_input("Nope", [midi], now=lambda: 0.0)


def test_a_port_without_the_backend_names_the_extra(monkeypatch) -> None:
    if __import__("importlib").util.find_spec("rtmidi") is not None:
        pytest.skip("python-rtmidi is installed: the backend is there")
    with pytest.raises(LiveExtraError, match=r"backend .*pip install 'hilsim\[live\]'"):
        open_midi_input(None, [], now=lambda: 0.0)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.sampled_from([0xF1, 0xB0, 0xBF, 0xF0, 0xF7, 0x7F, 0x01, 0x07, 0x21, 0x76])
        | st.integers(0, 255),
        max_size=400,
    ).map(bytes),
    st.lists(st.floats(0, 0.05), min_size=1, max_size=50),
)
def test_fuzz_any_midi_bytes_move_joints_only_within_their_ranges(data, gaps) -> None:
    """Whatever bytes a port delivers (mido's parser turns them into messages), the inputs never
    raise, a joint stays within its range, and the show time is finite or None."""
    from hilsim.live.timecode import MtcChase

    maps = [CcMapping("jaw", 1, 7, 0, 20), CcMapping("pan", 16, 1, 30, -30, fine=True)]
    midi, chase = MidiCcInput(maps, lost_after_s=0.1, capacity=16), MtcChase(freewheel_s=0.05)
    parser = mido.Parser()
    parser.feed(data)
    t = 0.0
    for i, msg in enumerate(parser):
        t += gaps[i % len(gaps)]
        midi.feed(msg, t)
        chase.feed(msg, t)
        if i % 3 == 0:
            polled, synced = midi.poll(t), chase.poll(t)
            jaw, pan = polled.values["jaw"], polled.values["pan"]
            assert jaw is None or 0 <= jaw <= 20
            assert pan is None or -30 <= pan <= 30
            assert synced.show_time_s is None or math.isfinite(synced.show_time_s)
    midi.poll(t + 1.0)
    chase.poll(t + 1.0)
