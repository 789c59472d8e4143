"""MTC chase: the issue's acceptance (00:00:02:15 at 30 fps locks on the 8th quarter frame at
2.5583 s and is at 2.5667 s, the +2 frames, when the next piece 0 lands; 500 ms freewheel then
hold), docs/live.md saying the same, SMPTE arithmetic at every rate, jumps, full-frame locates,
reverse and broken streams. Quarter frames are injected with timestamps; nothing waits on real
time."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from hilsim.live.timecode import MtcChase, Smpte

mido = pytest.importorskip("mido")

REPO = Path(__file__).resolve().parents[2]

RATE_HZ = 250
FPS = {0: 24, 1: 25, 2: 30000 / 1001, 3: 30}


def quarter_frames(code: Smpte) -> list:
    """The 8 quarter frames of one code, pieces 0-7."""
    h = code.hours | code.rate << 5
    nibbles = [
        code.frames & 15, code.frames >> 4, code.seconds & 15, code.seconds >> 4,
        code.minutes & 15, code.minutes >> 4, h & 15, h >> 4,
    ]  # fmt: skip
    return [
        mido.Message("quarter_frame", frame_type=k, frame_value=n) for k, n in enumerate(nibbles)
    ]


def send_running(chase: MtcChase, first: Smpte, n_codes: int, t0: float) -> float:
    """Quarter frames of ``n_codes`` consecutive codes (2 frames apart) from local time ``t0``;
    returns the time of the last one."""
    qf = 1 / (4 * FPS[first.rate])
    nominal = round(FPS[first.rate])  # non-drop label arithmetic is enough for these tests
    frames = ((first.hours * 60 + first.minutes) * 60 + first.seconds) * nominal + first.frames
    t = t0
    for i in range(n_codes):
        f = frames + 2 * i
        s, fr = divmod(f, nominal)
        code = Smpte(s // 3600, s // 60 % 60, s % 60, fr, first.rate)
        for msg in quarter_frames(code):
            chase.feed(msg, t)
            t += qf
    return t - qf


def run(chase: MtcChase, until: float):
    """Poll every 250 Hz tick up to ``until``: [(t, show time, state)], events."""
    rows, events = [], []
    for k in range(int(until * RATE_HZ) + 1):
        t = k / RATE_HZ
        polled = chase.poll(t)
        rows.append((t, polled.show_time_s, polled.state))
        events += polled.events
    return rows, events


def test_acceptance_quarter_frames_lock_to_2_5667_s() -> None:
    data = [0x0F, 0x10, 0x22, 0x30, 0x40, 0x50, 0x60, 0x76]  # the bytes
    chase = MtcChase(freewheel_s=0.5)
    for k, b in enumerate(data):  # at 120 Hz: four per frame at 30 fps
        chase.feed(mido.Message("quarter_frame", frame_type=b >> 4, frame_value=b & 15), k / 120)
    assert chase.poll(6 / 120).show_time_s is None  # 7 of 8 pieces: not yet
    polled = chase.poll(7 / 120)
    assert polled.state == "locked" and str(polled.timecode) == "00:00:02:15"
    assert polled.show_time_s == pytest.approx(2.5667, abs=1 / 30)
    assert polled.show_time_s == pytest.approx(2.5 + 1.75 / 30)  # piece 7 is 7/4 frames late
    assert chase.poll(8 / 120).show_time_s == pytest.approx(2.5 + 2 / 30)  # the +2 frames
    assert [e.kind for e in polled.events] == ["timecode_locked"]
    locked = polled.events[0]
    assert locked.t == 7 / 120 and locked.detail["quarter_frame"] == 7  # the one it locked on
    assert locked.detail["show_time_s"] == pytest.approx(2.5 + 1.75 / 30)


def test_live_md_lock_time_is_the_chases() -> None:
    """docs/live.md's worked example: the show time at the lock (the 8th quarter frame) and at
    the code + 2 frames a quarter frame later are the chase's, and the event detail it names."""
    text = " ".join((REPO / "docs" / "live.md").read_text(encoding="utf-8").split())
    at_lock = float(re.search(r"30 fps lock the show at ([\d.]+) s", text)[1])
    plus_2 = float(re.search(r"the code \+ 2 frames \(([\d.]+) s\)", text)[1])
    assert '`"quarter_frame": 7`' in text
    data = [0x0F, 0x10, 0x22, 0x30, 0x40, 0x50, 0x60, 0x76]
    chase = MtcChase()
    for k, b in enumerate(data):
        chase.feed(mido.Message("quarter_frame", frame_type=b >> 4, frame_value=b & 15), k / 120)
    polled = chase.poll(7 / 120)
    assert polled.events[0].kind == "timecode_locked"
    assert polled.events[0].detail["quarter_frame"] == 7
    assert polled.show_time_s == pytest.approx(at_lock, abs=5e-5)  # the doc's 4 decimals
    assert chase.poll(8 / 120).show_time_s == pytest.approx(plus_2, abs=5e-5)


def test_acceptance_freewheel_500_ms_after_the_timecode_stops_then_hold() -> None:
    chase = MtcChase(freewheel_s=0.5)
    last = send_running(chase, Smpte(0, 0, 2, 15, 3), n_codes=15, t0=0.0)  # 1 s of timecode
    rows, events = run(chase, 3.0)
    locked_at_last = 2.5 + 28 / 30 + 1.75 / 30  # the 15th code is 02:15 + 28 frames
    held = locked_at_last + 0.5
    for t, show, state in rows:
        if t < 7 / 120:
            assert show is None
        elif t <= last + 0.5:
            # running: the show time follows the timecode (within a quarter frame of it)
            assert show == pytest.approx(2.5 + 1.75 / 30 + (t - 7 / 120), abs=1 / 120)
        else:
            assert (show, state) == (pytest.approx(held), "held")
    assert [e.kind for e in events] == ["timecode_locked", "timecode_stopped", "timecode_held"]
    stopped, hold = events[1], events[2]
    assert stopped.detail["last_quarter_frame_t"] == pytest.approx(last)
    assert hold.t == pytest.approx(last + 0.5, abs=1 / RATE_HZ)
    assert hold.detail["show_time_s"] == pytest.approx(held)
    json.dumps([e.as_dict() for e in events])


def test_timecode_that_runs_again_relocks_without_a_jump() -> None:
    chase = MtcChase(freewheel_s=0.2)
    send_running(chase, Smpte(0, 0, 10, 0, 1), n_codes=5, t0=0.0)  # 25 fps, 0.4 s
    send_running(chase, Smpte(0, 0, 10, 12, 1), n_codes=5, t0=1.0)  # paused, then on again
    rows, events = run(chase, 2.0)
    kinds = [e.kind for e in events]
    assert kinds == ["timecode_locked", "timecode_stopped", "timecode_held"] * 2
    assert [e.kind for e in events if e.kind == "timecode_jump"] == []
    assert rows[-1][2] == "held"


def test_a_jump_is_reported_with_from_and_to() -> None:
    chase = MtcChase()
    t = send_running(chase, Smpte(0, 0, 2, 15, 3), n_codes=2, t0=0.0)
    send_running(chase, Smpte(0, 10, 0, 0, 3), n_codes=1, t0=t + 1 / 120)
    _, events = run(chase, 0.3)
    jump = [e for e in events if e.kind == "timecode_jump"]
    assert len(jump) == 1
    assert jump[0].detail["from_s"] == pytest.approx(2.5 + 2 / 30 + 3.75 / 30, abs=1 / 120)
    assert jump[0].detail["to_s"] == pytest.approx(600 + 1.75 / 30)
    assert chase.poll(0.3).show_time_s == pytest.approx(600 + 1.75 / 30 + 0.3 - (t + 8 / 120))


@pytest.mark.parametrize(
    ("code", "seconds"),
    [
        (Smpte(1, 2, 3, 12, 0), 3723.5),  # 24 fps
        (Smpte(1, 2, 3, 12, 1), 3723.48),  # 25 fps
        (Smpte(1, 2, 3, 15, 3), 3723.5),  # 30 fps
        (Smpte(0, 1, 0, 2, 2), 1800 * 1001 / 30000),  # 29.97 df: frames 0, 1 of minute 1 skipped
        (Smpte(0, 10, 0, 0, 2), 17982 * 1001 / 30000),  # minute 10 keeps them
        (Smpte(1, 0, 0, 0, 2), 107892 * 1001 / 30000),  # an hour of df is 107892 frames
    ],
)
def test_smpte_seconds_at_every_rate(code: Smpte, seconds: float) -> None:
    assert code.problem() is None
    assert code.to_seconds() == pytest.approx(seconds, abs=1e-9)


def test_drop_frame_quarter_frames_lock_at_29_97() -> None:
    chase = MtcChase()
    for k, msg in enumerate(quarter_frames(Smpte(0, 1, 0, 2, 2))):
        chase.feed(msg, k / (4 * FPS[2]))
    polled = chase.poll(0.1)
    assert str(polled.timecode) == "00:01:00;02" and polled.events[0].detail["rate"] == "29.97df"
    lock_t = 7 / (4 * FPS[2])
    assert polled.show_time_s == pytest.approx(60.06 + 1.75 / FPS[2] + 0.1 - lock_t)


@pytest.mark.parametrize(
    "code",
    [Smpte(0, 0, 0, 30, 3), Smpte(0, 0, 0, 24, 0), Smpte(0, 60, 0, 0, 1), Smpte(0, 1, 0, 0, 2)],
)
def test_an_invalid_code_does_not_lock_and_is_said_once(code: Smpte) -> None:
    chase = MtcChase()
    assert code.problem()
    t = 0.0
    for _ in range(3):
        for msg in quarter_frames(code):
            chase.feed(msg, t)
            t += 1 / 120
    polled = chase.poll(t)
    assert polled.show_time_s is None and polled.state == "waiting"
    assert [e.kind for e in polled.events] == ["timecode_invalid"]


def test_a_missing_piece_or_a_pause_inside_a_sequence_does_not_lock() -> None:
    chase = MtcChase()
    msgs = quarter_frames(Smpte(0, 0, 2, 15, 3))
    for k, msg in enumerate(msgs):
        if k != 3:
            chase.feed(msg, k / 120)
    assert chase.poll(0.2).state == "waiting"
    for k, msg in enumerate(msgs):  # a 0.5 s pause between pieces 3 and 4
        chase.feed(msg, 1.0 + k / 120 + (0.5 if k >= 4 else 0.0))
    assert chase.poll(2.0).state == "waiting" and chase.rejected >= 2


def test_full_frame_locates_and_holds_until_quarter_frames_run() -> None:
    chase = MtcChase()
    # F0 7F 7F 01 01 hr mn sc fr F7: 01:00:00:00 at 25 fps
    chase.feed(mido.Message("sysex", data=(0x7F, 0x7F, 0x01, 0x01, 0x21, 0, 0, 0)), 0.0)
    polled = chase.poll(0.0)
    assert (polled.state, polled.show_time_s) == ("cued", 3600.0)
    assert [e.kind for e in polled.events] == ["timecode_locate"]
    assert chase.poll(5.0).show_time_s == 3600.0  # cued: holds
    send_running(chase, Smpte(1, 0, 0, 0, 1), n_codes=2, t0=6.0)
    _, events = run(chase, 6.2)
    assert [e.kind for e in events if e.t >= 6.0][:1] == ["timecode_locked"]  # no jump
    chase.feed(mido.Message("sysex", data=(0x7F, 0x7F, 0x01, 0x01, 0x21, 0, 30, 0)), 7.0)
    kinds = [e.kind for e in chase.poll(7.0).events]
    assert kinds == ["timecode_jump", "timecode_locate"]
    chase.feed(mido.Message("sysex", data=(0x7E, 0x7F, 0x09, 0x01)), 7.1)  # another SysEx
    assert chase.poll(7.1).events == [] and chase.show_time(7.1) == 3630.0


def test_offset_makes_a_timecode_show_time_zero() -> None:
    chase = MtcChase(offset_s=3600.0)
    send_running(chase, Smpte(1, 0, 0, 0, 1), n_codes=1, t0=0.0)
    assert chase.poll(7 / 100).show_time_s == pytest.approx(1.75 / 25)


def test_reverse_quarter_frames_are_not_chased_and_said_once() -> None:
    chase = MtcChase(freewheel_s=0.1)
    t = send_running(chase, Smpte(0, 0, 2, 0, 3), n_codes=2, t0=0.0)
    for i in range(3):  # the sender rewinds: pieces 7..0
        for msg in reversed(quarter_frames(Smpte(0, 0, 1, 20 - 2 * i, 3))):
            t += 1 / 120
            chase.feed(msg, t)
    rows, events = run(chase, 1.0)
    kinds = [e.kind for e in events]
    assert kinds == ["timecode_locked", "timecode_stopped", "timecode_reverse", "timecode_held"]
    assert rows[-1][2] == "held"


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"freewheel_s": -1}, "freewheel_s"),
        ({"jump_s": 0}, "jump_s"),
        ({"offset_s": float("nan")}, "offset_s"),
    ],
)
def test_bad_settings_are_one_line(kwargs, message) -> None:
    with pytest.raises(ValueError, match=message):
        MtcChase(**kwargs)
