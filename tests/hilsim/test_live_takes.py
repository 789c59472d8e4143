"""Takes: raw samples kept as given (or skipped and counted), reduced to keys within the stated
tolerance at every sample and every tick, written as a CSV track the CSV reader replays exactly.
(The issue's MIDI ramp acceptance, end to end, is in test_live_midi.py.)"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hilsim.live.takes import Take, rdp_vertical, write_csv_track
from hilsim.targets.csv_file import CsvAnimation


def sine_take(rate_hz: float = 250.0, seconds: float = 4.0, noise_deg: float = 0.0) -> Take:
    rng = np.random.default_rng(7)
    take = Take(["tail"])
    for k in range(int(seconds * rate_hz) + 1):
        t = k / rate_hz
        take.record(t, "tail", 20 * math.sin(math.pi * t) + noise_deg * rng.standard_normal())
    return take


@pytest.mark.parametrize(("tolerance", "noise"), [(0.2, 0.0), (0.5, 0.0), (0.2, 0.05), (1.0, 0.3)])
def test_reduction_holds_the_tolerance_at_every_sample_and_tick(tolerance, noise) -> None:
    take = sine_take(noise_deg=noise)
    reduced = take.reduce(tolerance)
    keys = reduced.keys_array("tail")
    t, v = take.raw("tail")
    assert 2 <= len(keys) < len(t) / 5  # it did reduce
    assert np.max(np.abs(np.interp(t, keys[:, 0], keys[:, 1]) - v)) <= tolerance
    assert reduced.max_error_deg["tail"] <= tolerance
    for rate in (250.0, 1000.0, 333.0):
        assert take.replay_error("tail", reduced, rate) <= tolerance
    # against the sine itself (what a teach-by-hand of this motion would compare with)
    ticks = np.arange(0, 4.0, 1 / 250)
    replay = np.degrees(reduced.track("tail").sample_array(ticks)[0])
    assert np.max(np.abs(replay - 20 * np.sin(np.pi * ticks))) <= tolerance + 4 * noise


def test_a_tighter_tolerance_keeps_more_keys() -> None:
    take = sine_take()
    counts = [len(take.reduce(tol).keys("tail")) for tol in (2.0, 0.5, 0.1, 0.01)]
    assert counts == sorted(counts) and counts[0] < counts[-1]


def test_rdp_vertical_keeps_the_ends_and_the_corners() -> None:
    t = np.arange(7, dtype=float)
    v = np.array([0.0, 0.0, 0.0, 10.0, 10.0, 10.0, 10.0])  # a step between 2 and 3
    assert rdp_vertical(t, v, 0.5).tolist() == [0, 2, 3, 6]
    assert rdp_vertical(t[:2], v[:2], 0.5).tolist() == [0, 1]
    assert rdp_vertical(t[:1], v[:1], 0.5).tolist() == [0]
    line = np.linspace(-30, 30, 1000)
    assert rdp_vertical(np.arange(1000.0), line, 1e-9).tolist() == [0, 999]


def test_record_skips_and_counts_what_it_cannot_keep() -> None:
    take = Take(["jaw"])
    assert take.record(0.0, "jaw", 1.0)
    assert take.record(0.0, "jaw", 2.0)  # the same instant: the later value wins
    assert not take.record(-1.0, "jaw", 3.0)
    assert not take.record(1.0, "jaw", math.nan)
    assert not take.record(math.inf, "jaw", 1.0)
    assert not take.record(1.0, "tail", 1.0)
    take.record_samples([(0.5, "jaw", 4.0), (1.0, "jaw", 5.0)])
    t, v = take.raw("jaw")
    assert t.tolist() == [0.0, 0.5, 1.0] and v.tolist() == [2.0, 4.0, 5.0]
    assert take.skipped == {"not_finite": 2, "out_of_order": 1, "unknown_joint": 1}
    assert len(take) == 3
    one = Take()
    one.record(2.0, "head", 7.0)
    reduced = one.reduce(0.5)
    assert reduced.keys("head") == [[2.0, 7.0]] and reduced.keys("head", origin_s=2.0) == [[0, 7]]
    assert "jaw" not in Take(["jaw"]).reduce(0.5).keys_deg  # no samples: left out
    with pytest.raises(ValueError, match="tolerance"):
        take.reduce(0)


def test_csv_track_replays_each_joint_exactly(tmp_path) -> None:
    jaw = (np.array([0.0, 0.4, 1.0]), np.array([0.0, 20.0, 5.0]))
    tail = (np.array([0.25, 0.7]), np.array([-10.0, 1.0 / 3.0]))  # other times, starts later
    path = write_csv_track(tmp_path / "take.csv", {"jaw": jaw, "tail": tail})
    anim = CsvAnimation.load(path)
    assert anim.names == ("jaw", "tail")
    probe = np.linspace(-0.5, 1.5, 401)
    for name, (t, v) in (("jaw", jaw), ("tail", tail)):
        got = np.degrees(anim.curve(name).sample_array(probe)[0])
        assert np.max(np.abs(got - np.interp(probe, t, v))) < 1e-12
    assert not (tmp_path / "take.csv.tmp").exists()
    with pytest.raises(FileExistsError, match="exists; not overwritten"):
        write_csv_track(path, {"jaw": jaw})
    write_csv_track(path, {"jaw": jaw}, overwrite=True, origin_s=-1.0)
    assert CsvAnimation.load(path).times_s.tolist() == [1.0, 1.4, 2.0]
    with pytest.raises(ValueError, match="no samples"):
        write_csv_track(tmp_path / "x.csv", {"jaw": (np.array([]), np.array([]))})


def test_replay_error_held_sees_the_steps_the_live_target_made() -> None:
    take = Take(["jaw"])
    take.record(0.0, "jaw", 0.0)
    take.record(1.0, "jaw", 10.0)  # a fader jumped: the live target held 0 until 1.0
    reduced = take.reduce(0.5)
    assert reduced.keys("jaw") == [[0.0, 0.0], [1.0, 10.0]]
    assert take.replay_error("jaw", reduced, 100) == 0.0
    assert take.replay_error("jaw", reduced, 100, held=True) == pytest.approx(9.9)


def test_a_live_take_replays_as_it_was_live_a_jump_stays_a_jump(tmp_path):
    """Two OSC values 1.3 s apart: the live target held 36 deg, then jumped to -36. The keys
    replay that (36 until the jump), not a 1.3 s ramp; the error is against the held take."""
    from hilsim.live.takes import write_take

    take = Take(["head_pan"])
    take.record(1.0, "head_pan", 36.0)
    take.record(2.3, "head_pan", -36.0)
    take.record(3.0, "head_pan", -30.0)
    out = write_take(take, tmp_path / "take", 0.5)
    keys = np.loadtxt(out["keys_csv"], delimiter=",", skiprows=1, ndmin=2)
    ticks = np.arange(1.0, 3.0, 0.004)
    replay = np.interp(ticks, keys[:, 0], keys[:, 1])
    held = np.where(ticks < 2.3 - 1e-9, 36.0, -36.0)
    held[ticks >= 3.0] = -30.0
    assert np.max(np.abs(replay - held)) <= 0.5
    assert out["max_error_deg"]["head_pan"] <= 0.5
    raw = np.loadtxt(out["raw_csv"], delimiter=",", skiprows=1, ndmin=2)
    assert len(raw) == 3  # the raw file is the samples as they came
