"""The pieces every animation-format reader shares: errors, unit maps, sampled tracks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hilsim.targets.formats.common import FormatError, SampledTrack, UnitMap


def test_format_error_names_file_and_position():
    assert str(FormatError("a.bin", "byte 17", "bad magic")) == "a.bin:byte 17: bad magic"
    assert str(FormatError("a.bin", "", "empty file")) == "a.bin: empty file"


def test_unit_map_through_two_points_either_way():
    us = UnitMap((1000, 2000), (0, 40), "us")
    assert us.to_deg(1749.33) == pytest.approx(29.9732)
    assert math.degrees(us.to_rad(1500)) == pytest.approx(20.0)
    rev = UnitMap((2000, 1000), (0, 40))
    assert rev.to_deg(1000) == pytest.approx(40.0)


@pytest.mark.parametrize(
    ("source", "degrees", "match"),
    [
        ((1000, 1000), (0, 40), "equal"),
        ((1000, math.nan), (0, 40), "finite"),
        ((1000, 2000), (0,), "two finite"),
        ((True, 2000), (0, 40), "two finite"),
    ],
)
def test_impossible_unit_maps_are_refused(source, degrees, match):
    with pytest.raises(ValueError, match=match):
        UnitMap(source, degrees, "us")


def test_sampled_track_hold_and_linear():
    t, v = [0.0, 1.0, 2.0], [0.0, 1.0, 3.0]
    hold = SampledTrack(t, v, "hold")
    assert hold.sample(0.5) == (0.0, 0.0) and hold.sample(1.5) == (1.0, 0.0)
    assert hold.sample(-1.0) == (0.0, 0.0) and hold.sample(5.0) == (3.0, 0.0)
    lin = SampledTrack(t, v, "linear")
    assert lin.sample(1.5) == (2.0, 2.0) and lin.duration == 2.0
    times = np.linspace(-1, 3, 41)
    for track in (hold, lin):
        pos, vel = track.sample_array(times)
        expected = [track.sample(float(x)) for x in times]
        assert np.allclose(pos, [p for p, _ in expected])
        assert np.allclose(vel, [d for _, d in expected])
    with pytest.raises(ValueError, match="interpolation"):
        SampledTrack(t, v, "cubic")
    single = SampledTrack([1.0], [2.0], "linear")
    assert single.sample(0.0) == (2.0, 0.0) and single.sample_array([0.0, 2.0])[0].tolist() == [
        2.0,
        2.0,
    ]
