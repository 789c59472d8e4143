"""Bottango exports: generated code, SD-card files and JSON give identical exact Bézier tracks.

Fixtures are written by ``tools/samples_bottango.py``'s functions into ``tmp_path``; the
numbers are issue 13's acceptance and the animation-ecosystem review's (R3, §2.2).
"""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hilsim.targets.formats.bottango import read_export
from hilsim.targets.formats.bottango_curve import Y_MAX, BezierSegment, BezierTrack
from hilsim.targets.formats.common import FormatError, UnitMap

_spec = importlib.util.spec_from_file_location(
    "samples_bottango", Path(__file__).resolve().parents[2] / "tools" / "samples_bottango.py"
)
samples = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("samples_bottango", samples)  # its dataclass needs its module
_spec.loader.exec_module(samples)

US = UnitMap((1000, 2000), (0, 40), "us")
SEG1 = "sC,0,0,2000,4096,513,0,7110,-763,814"
SEG2 = "sC,0,2000,1000,7110,331,-354,2277,-331,931"
REVIEW = (
    ["rSVPin,0,1000,2000,3000,1500"],
    [samples.Anim("", [SEG1, SEG2], (0, 0, 0, 10, 0, 1, 0, 0))],
)


def _forms(tmp_path: Path, setup=None, anims=None) -> dict[str, Path]:
    setup, anims = REVIEW if setup is None else (setup, anims)
    return {
        "code": samples.write_code(tmp_path / "GeneratedCodeAnimations.cpp", setup, anims),
        "sd": samples.write_sd(tmp_path / "card", setup, anims),
        "json": samples.write_json(tmp_path / "export.json", setup, anims),
    }


def deg(track, t: float) -> float:
    return math.degrees(track.value(t))


# ------------------------------------------------------------------------------ acceptance
@pytest.mark.parametrize("form", ["code", "sd", "json"])
def test_issue_13_acceptance_from_every_form(tmp_path, form):
    """sC,0,0,2000,4096,513,0,7110,-763,814 on 1000-2000 µs mapped to 0-40°: 29.97° ± 0.025°
    at t = 1.000 s (1749.33 µs), from the generated-code, SD-card and JSON forms alike."""
    export = read_export(_forms(tmp_path)[form])
    assert export.form == form
    track = export.track(0, "0", signal=US)
    assert deg(track, 1.0) == pytest.approx(29.97, abs=0.025)
    us = export.track(0, "0", signal=UnitMap((1000, 2000), (1000, 2000), "us"))
    assert deg(us, 1.0) == pytest.approx(1749.33, abs=0.005)


@pytest.mark.parametrize("form", ["code", "sd", "json"])
def test_review_r3_numbers(tmp_path, form):
    track = read_export(_forms(tmp_path)[form]).track(0, "0", signal=US)
    for t, want in [(0.0, 20.00), (1.0, 29.97), (2.0, 34.72), (2.25, 30.92), (3.0, 11.12)]:
        assert deg(track, t) == pytest.approx(want, abs=0.02), t
    identity = read_export(_forms(tmp_path)[form]).track(
        0, "0", signal=UnitMap((0, 1), (0, 1), "us")
    )
    for t, us in [(2.0, 1867.92), (2.25, 1773.11), (3.0, 1277.95)]:
        assert deg(identity, t) == pytest.approx(us, abs=0.005)


def test_review_table_of_the_first_segment(tmp_path):
    track = read_export(_forms(tmp_path)["code"]).track(0, "0", signal=US)
    for t, y in [(0.0, 4096.0), (0.5, 4866.54), (1.0, 6138.49), (1.5, 7059.04), (2.0, 7110.0)]:
        assert track.sample_y(t)[0] == pytest.approx(y, abs=0.005)


def test_three_forms_give_identical_tracks(tmp_path):
    exports = {f: read_export(p) for f, p in _forms(tmp_path, samples.SETUP, samples.ANIMS).items()}
    times = np.linspace(-0.5, 4.0, 901)
    ref = None
    for export in exports.values():
        got = []
        for idx, eff, loop in [(0, "0", False), (0, "643", False), (1, "0", False), (1, "0", True)]:
            tr = export.track(idx, eff, signal=US, loop=loop)
            got.append(tr.sample_array(times))
        shapes = [(a.segments, a.loop_segments) for a in export.animations.values()]
        configs = [a.config for a in export.animations.values()]
        if ref is None:
            ref = (got, shapes, configs, export.effectors.keys())
            continue
        for (p0, v0), (p1, v1) in zip(ref[0], got, strict=True):
            assert np.array_equal(p0, p1) and np.array_equal(v0, v1)
        assert (shapes, configs, export.effectors.keys()) == ref[1:]


def test_config_is_reported_as_text(tmp_path):
    for p in _forms(tmp_path).values():
        cfg = read_export(p).animation(0).config
        assert cfg.describe() == "trigger on input 10, rising (HIGH), no loop"
    anims = [samples.Anim("a", [SEG1], (1, 1, 0, 0, 0, 0, 0, 0)),
             samples.Anim("b", [SEG1], (0, 0, 0, 4, 1, 2, 100, 200)),
             samples.Anim("c", [SEG1], (0, 0, 1, 7, 1, 0, 0, 0))]  # fmt: skip
    export = read_export(_forms(tmp_path / "x", REVIEW[0], anims)["sd"])
    assert [a.config.describe() for a in export.animations.values()] == [
        "plays on start, looping, no loop",
        "trigger on input 4, analog value in 100-200, loop",
        "idle animation (plays, looping, when nothing else does), "
        "trigger on input 7, falling (LOW), loop",
    ]


def test_names_effectors_and_info(tmp_path):
    export = read_export(_forms(tmp_path, samples.SETUP, samples.ANIMS)["code"])
    assert export.animation("Idle").index == 1 and export.animation(0).name == "Talk"
    i2c = export.effectors["643"]
    assert (i2c.kind, i2c.address, i2c.pin, i2c.signal_min, i2c.signal_max) == (
        "I2C servo", 64, 3, 2000, 1000,
    )  # fmt: skip
    assert export.effectors["0"].start == 1500
    assert any("sCO" in s for s in export.info) and any("rECOnOff" in s for s in export.info)
    # the I2C servo runs 2000 -> 1000 µs: movement 1 (y 8192) is 1000 µs = 0°
    assert deg(export.track(0, "643", signal=US), 1.5) == pytest.approx(0.0, abs=1e-12)


# ---------------------------------------------------------------------------- the curve
def _bisect_y(seg: BezierSegment, x: float) -> float:
    lo, hi = 0.0, 1.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if seg._x(mid) < x else (lo, mid)
    return seg._y(0.5 * (lo + hi))


def test_time_parameter_is_solved_to_rounding_not_to_a_millisecond():
    seg = BezierSegment.from_command(0, 2000, 4096, 513, 0, 7110, -763, 814)
    assert seg.monotone
    for x in np.linspace(0, 2000, 257):
        u = seg.solve_u(float(x))
        assert abs(seg._x(u) - x) < 1e-9
        assert seg.value_rate(float(x))[0] == pytest.approx(_bisect_y(seg, float(x)), abs=1e-8)


def test_velocity_is_dy_dt():
    track = BezierTrack(
        [BezierSegment.from_command(0, 2000, 4096, 513, 0, 7110, -763, 814)], 0.0, 1.0
    )
    for t in (0.1, 0.77, 1.0, 1.93):
        h = 1e-6
        fd = (track.value(t + h) - track.value(t - h)) / (2 * h)
        assert track.velocity(t) == pytest.approx(fd, rel=1e-6)


@given(
    st.integers(0, 5000), st.integers(-3000, 6000), st.integers(-3000, 6000),
    st.integers(0, 8192), st.integers(0, 8192), st.integers(-4000, 4000), st.integers(-4000, 4000),
)  # fmt: skip
def test_any_handles_give_a_solution_on_the_curve(dur, c1x, c2x, y0, y1, c1y, c2y):
    seg = BezierSegment.from_command(0, dur, y0, c1x, c1y, y1, c2x, c2y)
    monotone_handles = 0 <= c1x <= dur and -dur <= c2x <= 0
    if monotone_handles:  # proven in docs/targets.md (Bottango curves), even when they cross
        assert seg.monotone
    for x in (0.0, dur / 3, dur / 2, dur * 0.9, float(dur)):
        u = seg.solve_u(x)
        assert 0.0 <= u <= 1.0
        if dur:
            assert abs(seg._x(u) - x) <= 1e-9 * max(dur, abs(c1x), abs(c2x), 1)
            # the first time the curve reaches x: x(u') < x for every smaller u'
            before = [seg._x(float(g)) for g in np.linspace(0.0, u, 64)[:-1]]
            assert max(before, default=0.0) <= x + 1e-9 * max(dur, abs(c1x), abs(c2x), 1)
        y, rate = seg.value_rate(x)
        assert math.isfinite(y) and math.isfinite(rate)


@pytest.mark.parametrize("c1x,c2x", [(1000, -1000), (900, -900), (0, 0), (1000, 0), (0, -1000)])
def test_handles_within_the_segment_are_monotone_even_crossed(c1x, c2x):
    seg = BezierSegment.from_command(0, 1000, 0, c1x, 0, 8192, c2x, 0)
    assert seg.monotone
    xs = [seg._x(float(u)) for u in np.linspace(0, 1, 4001)]
    assert min(np.diff(xs)) >= -1e-9


def test_folding_curve_is_followed_forward_and_reported(tmp_path):
    # handles crossing in time: x(u) runs past 1000 ms and back
    fold = "sC,0,0,1000,0,1500,0,8192,-1500,0"
    export = read_export(_forms(tmp_path, [], [samples.Anim("f", [fold])])["json"])
    assert any("runs back in time" in s for s in export.info)
    seg = export.animation(0).segments["0"][0]
    assert not seg.monotone
    for x in (100.0, 500.0, 900.0):
        u = seg.solve_u(x)
        assert abs(seg._x(u) - x) < 1e-9
        assert all(seg._x(v) < x for v in np.linspace(0, u, 200)[:-1])


def test_holds_gaps_instants_and_clamp(tmp_path):
    anim = samples.Anim(
        "h",
        [
            "sC,5,500,700,1000,200,0,3000,-200,0",  # 0.5-1.2 s
            "sCT,bell,1500",  # a (skipped) trigger event at 1.5 s: it still times the sCI
            "sCI,5,6000",  # acts when the stream reaches it: at 1.5 s
            "sC,5,2000,1000,6000,300,9000,8000,-300,9000",  # overshoots 8192
        ],
    )
    export = read_export(_forms(tmp_path, [], [anim])["code"])
    track = export.track(0, "5", movement=UnitMap((0, 1), (0, 100), "movement"))
    y = lambda t: track.sample_y(t)[0]  # noqa: E731
    assert y(0.0) == y(0.25) == 1000 and track.velocity(0.25) == 0.0  # before: first start
    assert y(1.3) == y(1.49) == 3000 and track.velocity(1.3) == 0.0  # gap: the end value
    assert y(1.5) == y(1.9) == 6000  # the instant move at 1.5 s, held until the next curve
    assert y(2.5) == 8192 and track.velocity(2.5) == 0.0  # clamped as the firmware clamps
    assert y(2.05) == pytest.approx(7410.897, abs=1e-3) and track.velocity(2.05) > 0
    assert y(2.999) == pytest.approx(8029.948, abs=1e-3) and track.velocity(2.999) < 0
    assert y(10.0) == 8000 and track.duration == 3.0
    assert deg(track, 1.6) == pytest.approx(100 * 6000 / 8192)
    with pytest.raises(FormatError, match="no signal range"):
        export.track(0, "5", signal=US)


def test_overlapping_curves_are_refused(tmp_path):
    anim = samples.Anim("", [SEG1, "sC,0,1500,1000,7110,331,-354,2277,-331,931"])
    path = _forms(tmp_path, [], [anim])["sd"]
    with pytest.raises(
        FormatError, match=r"data.txt:line 2: .*1500-2500 ms overlaps the one at 0-2000"
    ):
        read_export(path)


def test_sync_relay_hash_and_tsyn(tmp_path):
    sync = "sSY,sC,1,0,1000,0,100,0,8192,-100,0;2,0,1000,8192,100,0,0,-100,0;"
    cmds = [sync, "sR,0,sSY,sC,5,0,1000,0,100,0,4096,-100,0;", "tSYN,1000",
            "sC,1,0,1000,8192,100,0,0,-100,0"]  # fmt: skip
    hashed = "xUC,4"
    cmds.insert(0, f"{hashed},h{sum(map(ord, hashed))}")
    export = read_export(
        # (a limit of 3000 us/s, which this curve never reaches: the limit is tested below)
        _forms(tmp_path, ["rSVPin,1,500,2500,3000,1500"], [samples.Anim("", cmds)])["json"]
    )
    assert sorted(export.animation(0).segments) == ["0/5", "1", "2"]
    assert [s.start_ms for s in export.animation(0).segments["1"]] == [0, 1000]
    track = export.track(0, "1", signal=UnitMap((500, 2500), (-90, 90), "us"))
    assert deg(track, 1.0) == pytest.approx(90.0)
    bad = _forms(tmp_path / "h", [], [samples.Anim("", ["xUC,4,h369"])])["sd"]
    with pytest.raises(FormatError, match=r"data.txt:line 1: .*hash h369 does not match"):
        read_export(bad)


def test_track_api_errors(tmp_path):
    export = read_export(_forms(tmp_path)["code"])
    with pytest.raises(ValueError, match="exactly one"):
        export.track(0, "0")
    with pytest.raises(ValueError, match="exactly one"):
        export.track(0, "0", signal=US, movement=US)
    with pytest.raises(FormatError, match="no curve for effector '7'; it has curves for 0"):
        export.track(0, "7", signal=US)
    with pytest.raises(FormatError, match="no animation 3"):
        export.track(3, "0", signal=US)


def test_registrations_of_every_kind(tmp_path):
    setup = [
        "rSVPin,1,1000,2000,3000,1500",
        "xE",  # deregisters everything before it
        "rSVPin,2,900,2100,3000,1500",
        "rMTR,m1,-100,100,50,0",
        "rSTDir,7,8,1,-400,400,1000,0",
        "rSTPin,3,4,5,6,-200,200,500,10",
        "rECC,ev,2.5,0.25,13",
        "upE,2,1100,1900,3000",
        "rSVPin,9,1000,2000,3000,1500",
        "xUE,9",
    ]
    curves = [f"sC,{e},0,1000,0,250,0,8192,-250,0" for e in ("2", "m1", "7", "3", "ev")]
    export = read_export(_forms(tmp_path, setup, [samples.Anim("", curves)])["json"])
    eff = export.effectors
    assert sorted(eff) == ["2", "3", "7", "ev", "m1"]
    assert (eff["2"].signal_min, eff["2"].signal_max, eff["2"].kind) == (1100, 1900, "pin servo")
    assert (eff["m1"].kind, eff["m1"].signal_min, eff["m1"].unit) == (
        "custom motor",
        -100,
        "signal",
    )
    assert (eff["7"].kind, eff["7"].signal_min, eff["7"].signal_max) == ("stepper", -400, 400)
    assert (eff["3"].pin, eff["3"].start, eff["3"].unit) == (3, 10, "steps")
    assert (eff["ev"].kind, eff["ev"].signal_min, eff["ev"].start) == ("curved event", None, 0.25)
    steps = export.track(0, "7", signal=UnitMap((-400, 400), (-180, 180), "steps"))
    assert deg(steps, 1.0) == pytest.approx(180.0)
    assert deg(steps, 0.0) == pytest.approx(0.0)  # parked at its start, 0 steps
    with pytest.raises(FormatError, match="'ev' has no signal range"):
        export.track(0, "ev", signal=US)
    assert deg(export.track(0, "ev", movement=UnitMap((0, 1), (0, 10))), 1.0) == pytest.approx(10)


def test_instant_first_and_vertical_tangent(tmp_path):
    cmds = ["sCI,0,2048", "sC,0,1000,1000,2048,0,3000,6000,0,-3000"]  # zero-length handles
    export = read_export(_forms(tmp_path, [], [samples.Anim("", cmds)])["sd"])
    track = export.track(0, "0", movement=UnitMap((0, 1), (0, 8192)))
    assert deg(track, 0.0) == pytest.approx(2048) and deg(track, 0.999) == pytest.approx(2048)
    u, du = track.sample(1.0)  # vertical tangent: the slope over the 1 ms around it
    assert math.degrees(u) == pytest.approx(2048) and math.isfinite(du) and du > 0
    assert deg(track, 2.0) == pytest.approx(6000)
    # the SD card's anims/ directory itself is a valid path too
    assert read_export(tmp_path / "card" / "anims").animation(0).segments == (
        export.animation(0).segments
    )


# ------------------------------------------------- the driver: start signal and speed limit
IDENTITY = UnitMap((0, 1), (0, 1), "us")  # deg() of such a track reads the signal in µs


@pytest.mark.parametrize("form", ["code", "sd", "json"])
def test_before_its_first_curve_an_effector_sits_at_its_start_signal(tmp_path, form):
    """Registered with start 1200 µs, first curve at 500 ms from 1500 µs: the driver parks
    the servo at 1200 µs until then (not at the curve's 1500), then moves it to the curve at
    its speed limit, 3000 µs/s: 1350 µs at 550 ms; on the curve from there (1625 µs at its
    middle, 1750 µs at its end)."""
    setup = ["rSVPin,0,1000,2000,3000,1200"]
    anim = samples.Anim("", ["sC,0,500,1000,4096,200,0,6144,-200,0"])
    export = read_export(_forms(tmp_path, setup, [anim])[form])
    us = export.track(0, "0", signal=IDENTITY)
    for t in (-1.0, 0.0, 0.25, 0.4999):
        assert deg(us, t) == pytest.approx(1200.0) and us.velocity(t) == 0.0
    assert deg(us, 0.55) == pytest.approx(1350.0)
    assert math.degrees(us.velocity(0.55)) == pytest.approx(3000.0)
    assert deg(us, 1.0) == pytest.approx(1625.0) and deg(us, 1.5) == pytest.approx(1750.0)
    assert us.duration == 1.5
    movement = export.track(0, "0", movement=UnitMap((0, 1), (0, 1), "movement"))
    assert deg(movement, 0.25) == pytest.approx(0.2)  # 1200 µs of 1000-2000


@pytest.mark.parametrize("form", ["code", "sd", "json"])
def test_the_registered_speed_limit_is_applied_as_the_driver_applies_it(tmp_path, form):
    """Registered at 500 µs/s; a straight curve 1500 -> 2000 µs in 400 ms from 1.0 s (1250
    µs/s): the signal moves at 500 µs/s and arrives at 2.0 s, not 1.4 s; a later curve
    slower than the limit (250 µs/s) is followed exactly."""
    setup = ["rSVPin,0,1000,2000,500,1500"]
    cmds = ["sC,0,1000,400,4096,0,0,8192,0,0", "sC,0,3000,1000,8192,0,0,6144,0,0"]
    export = read_export(_forms(tmp_path, setup, [samples.Anim("", cmds)])[form])
    us = export.track(0, "0", signal=IDENTITY)
    want = {0.5: 1500, 1.0: 1500, 1.2: 1600, 1.4: 1700, 1.8: 1900, 2.0: 2000, 2.5: 2000,
            3.5: 1875, 4.0: 1750}  # fmt: skip
    for t, signal in want.items():
        assert deg(us, t) == pytest.approx(signal), t
    assert math.degrees(us.velocity(1.2)) == pytest.approx(500.0)
    assert math.degrees(us.velocity(3.5)) == pytest.approx(-250.0)
    assert us.behind == ((1.0, 2.0),) and us.duration == 4.0
    deg40 = export.track(0, "0", signal=US)  # the limit is the signal's, whatever the map
    assert deg(deg40, 1.4) == pytest.approx(28.0) and deg(deg40, 2.0) == pytest.approx(40.0)


def _stepped(bare: BezierTrack, rate: float, times: np.ndarray, dt: float) -> np.ndarray:
    """An independent check: the driver's rule stepped in time, every ``dt`` the signal moves
    toward the curve (held at its start before it) by at most ``rate·dt``."""
    out, v, k = [], bare.sample_y(-1.0)[0], 0
    for t in times:
        while k * dt < t:
            k += 1
            target = bare.sample_y(k * dt)[0]
            v = target if abs(target - v) <= rate * dt else v + math.copysign(rate * dt, target - v)
        out.append(v)
    return np.array(out)


@pytest.mark.parametrize("form", ["code", "json"])
def test_the_limited_signal_matches_the_rule_stepped_in_time(tmp_path, form):
    """The review's curves at 200 µs/s, and a folding curve and one overshooting 8192 at 2000
    µs/s, all starting after 0 ms: the exact track agrees with the rule stepped every 0.1 ms."""
    setup = ["rSVPin,0,1000,2000,200,1000", "rSVPin,1,1000,2000,2000,1800"]
    cmds = ["sC,0,250,2000,4096,513,0,7110,-763,814", "sC,0,2250,1000,7110,331,-354,2277,-331,931",
            "sC,1,300,700,1000,1400,0,7000,-200,0", "sC,1,1200,600,7000,300,9000,2000,-300,9000",
            "sC,1,1800,300,1000,100,0,8000,-100,0"]  # fmt: skip
    export = read_export(_forms(tmp_path, setup, [samples.Anim("", cmds)])[form])
    times = np.linspace(-0.2, 5.0, 521)
    for eid, rate in (("0", 200 * 8.192), ("1", 2000 * 8.192)):
        track = export.track(0, eid, movement=UnitMap((0, 1), (0, 8192), "movement"))
        assert track.behind, eid
        segs = export.animation(0).segments[eid]
        bare = BezierTrack(segs, 0.0, 1.0, "", track.base.start_y)
        got = np.degrees(track.sample_array(times)[0])
        assert np.max(np.abs(got - _stepped(bare, rate, times, 1e-4))) < 3 * rate * 1e-4, eid


# ------------------------------------------------------------------------------ bad inputs
BAD_LINES = [
    ("sC,0,0,2000,4096,513,0,7110,-763", "sC takes 9 fields"),  # truncated
    ("sC,0,0,2000,4096,513,0,7110,-763,8x4", "endControlY must be an integer"),
    ("sC,0,0,2000,9000,513,0,7110,-763,814", r"startY must be in 0\.\.8192"),
    ("sC,0,0,-5,4096,513,0,7110,-763,814", "durationMs must be >= 0"),
    ("sQ,0,1", "unknown command 'sQ'"),
    ("sC,,0,2000,4096,513,0,7110,-763,814", "identifier is empty"),
    ("sCO,lamp", "sCO needs an identifier and a startMs"),
    ("sCT,lamp,soon", "startMs must be an integer"),
]


@pytest.mark.parametrize(("line", "match"), BAD_LINES)
@pytest.mark.parametrize("form", ["code", "sd", "json"])
def test_bad_command_names_file_and_line(tmp_path, form, line, match):
    path = _forms(tmp_path, ["rSVPin,0,1000,2000,3000,1500"], [samples.Anim("", [SEG1, line])])[
        form
    ]
    with pytest.raises(FormatError, match=match) as err:
        read_export(path)
    where = {"code": "line ", "sd": "line 2", "json": "item "}[form]
    assert err.value.where.startswith(where) and err.value.path.startswith(str(path))


def test_bad_files(tmp_path):
    def err(name: str, content: str | bytes, form=None) -> str:
        p = tmp_path / name
        p.write_bytes(content if isinstance(content, bytes) else content.encode())
        with pytest.raises(FormatError) as e:
            read_export(p, form)
        assert str(p) in str(e.value)
        return str(e.value)

    assert "no Bottango export data" in err("empty.cpp", "")
    assert "no Bottango export data" in err("other.cpp", "int main() { return 0; }\n")
    assert "byte 3: binary data" in err("bin.cpp", b"abc\0def")
    assert "byte 1: not UTF-8" in err("bin2.cpp", b"a\xff")
    assert 'line 2: unterminated " literal' in err(
        "trunc.cpp", 'x\nconst char SETUP_DATA_0[] PROGMEM = "rSVPin,0,10'
    )
    assert "line 1: unterminated /* comment" in err("c.cpp", "/* const char")
    assert "no ';'" in err("semi.cpp", 'const char ANIM_0_DATA0[] PROGMEM = "sC"')
    assert "must be string literals" in err("m.cpp", "const char ANIM_0_DATA0[] = MACRO;")
    assert "unknown escape \\q" in err("e.cpp", 'const char ANIM_0_DATA0[] = "\\q";')
    assert "part 0 of it is not" in err("p.cpp", f'const char ANIM_0_DATA1[] = "{SEG1}";')
    assert "declared twice" in err(
        "d.cpp", f'const char ANIM_0_DATA0[] = "{SEG1}";\nconst char ANIM_0_DATA0[] = "";'
    )
    assert "line 1: ANIM_0_CONFIG must be {8 integers}" in err(
        "cfg.cpp", "const uint16_t ANIM_0_CONFIG[] PROGMEM = { 0, 0, 0, 10, 0, 1, 0 };"
    )
    assert "line 1: playOnPinHigh is 3; allowed 0 (low)" in err(
        "cfg3.cpp", "const uint16_t ANIM_0_CONFIG[] PROGMEM = { 0, 0, 0, 10, 0, 3, 0, 0 };"
    )
    assert "not an integer" in err(
        "cfg4.cpp", "const uint16_t ANIM_0_CONFIG[] = {0,0,0,a,0,1,0,0};"
    )
    assert "outside 0-65535" in err(
        "cfg5.cpp", "const uint16_t ANIM_0_CONFIG[] = {0,0,0,70000,0,1,0,0};"
    )
    assert "line 1: not JSON" in err("t.json", '["sC,0,0,2000')
    assert "no Bottango commands" in err("e.json", "[]")
    assert "expected a JSON array" in err("n.json", "42")
    assert "item [1]: expected command strings" in err("x.json", '[["rSVPin,0,1,2,3,4"], [1, 2]]')
    assert "nested too deeply" in err("deep.json", "[" * 100000 + "]" * 100000)


def test_bad_sd_cards(tmp_path):
    with pytest.raises(FormatError, match="no anims/ directory"):
        read_export(tmp_path)
    card = samples.write_sd(tmp_path / "c", *REVIEW)
    (card / "anims" / "0" / "config.txt").write_text("0\n0\n0\n10\n0\n1\n0\n")
    with pytest.raises(FormatError, match=r"config.txt: 7 numbers; a config has 8"):
        read_export(card)
    (card / "anims" / "0" / "config.txt").write_text("0\n0\n0\n10\n0\n3\n0\n0\n")
    with pytest.raises(FormatError, match=r"config.txt: playOnPinHigh is 3; allowed 0"):
        read_export(card)
    (card / "anims" / "0" / "data.txt").unlink()
    with pytest.raises(FormatError, match=r"anims/0: no data.txt"):
        read_export(card)
    empty = tmp_path / "e" / "anims"
    empty.mkdir(parents=True)
    with pytest.raises(FormatError, match="empty SD-card export"):
        read_export(empty)
    with pytest.raises(FormatError, match="no such file"):
        read_export(tmp_path / "nope.cpp")


def test_json_shapes_are_read_liberally(tmp_path):
    flat = tmp_path / "flat.json"
    flat.write_text(json.dumps(["rSVPin,0,1000,2000,3000,1500", f"{SEG1}\n{SEG2}\n"]))
    flat2 = samples.write_json(tmp_path / "flat2.json", *REVIEW, flat=True)
    assert json.loads(flat2.read_text()) == ["rSVPin,0,1000,2000,3000,1500", SEG1, SEG2]
    blocks = tmp_path / "blocks.json"
    blocks.write_text(json.dumps([["rSVPin,0,1000,2000,3000,1500"], [SEG1, SEG2], [SEG1]]))
    a, b, c = read_export(flat), read_export(blocks), read_export(flat2)
    assert a.animation(0).segments == c.animation(0).segments
    assert sorted(b.animations) == [0, 1]
    t = np.linspace(0, 3.5, 50)
    assert np.array_equal(
        a.track(0, "0", signal=US).sample_array(t)[0], b.track(0, "0", signal=US).sample_array(t)[0]
    )
    assert deg(a.track(0, "0", signal=US), 1.0) == pytest.approx(29.97, abs=0.025)


# ------------------------------------------------------------------------------- fuzzing
# A fuzz test that asserted nothing once a file was read would pass on any track at all: each
# checks what every accepted export holds, and that every refusal is the module's one line.
DEG90 = UnitMap((0, 1), (0, 90), "movement")


def _refused(exc: FormatError, path: Path) -> None:
    """The module's one line: ``file:where: what``, the file first, a short reason."""
    text = str(exc)
    assert text.startswith(str(path)) and exc.detail, text
    assert len(text.splitlines()) == 1 and len(exc.detail) < 400, text


def _start_deg(eff) -> float | None:
    """An effector's registered start on the 0-90° map (where the servo may park before its
    first curve), or None when there is no registration to place it."""
    if eff is None:
        return None
    if eff.signal_min is None:  # a curved event: its start is a movement already
        return 90.0 * eff.start
    if eff.signal_min == eff.signal_max:
        return None
    return 90.0 * (eff.start - eff.signal_min) / (eff.signal_max - eff.signal_min)


def _accepted(export, form: str) -> None:
    """Every effector's curves, in every animation and loop: in time order from 0 ms, none
    overlapping, values in 0..8192; and its track as :func:`_track_holds` says."""
    assert export.form == form
    for anim in export.animations.values():
        for loop, table in ((False, anim.segments), (True, anim.loop_segments)):
            for eid, segs in table.items():
                assert segs
                for s in segs:
                    assert s.start_ms >= 0 and s.dur_ms >= 0 and math.isfinite(s.end_ms)
                    assert 0 <= s.y0 <= Y_MAX and 0 <= s.y1 <= Y_MAX
                for a, b in pairwise(segs):
                    assert a.start_ms <= b.start_ms and a.end_ms <= b.start_ms
                _track_holds(export, anim.index, eid, loop)


def _track_holds(export, index: int, eid: str, loop: bool) -> None:
    """One effector's track, mapped the rig's two ways onto 0-90° (movement, and the
    registered signal range when there is one): finite at any time, within 0-90° (or the
    registered start, where the servo may sit before the first curve), as long as its curves
    (longer where the registered speed limit holds the driver's signal back)."""
    anim = export.animation(index)
    segs = (anim.loop_segments if loop else anim.segments)[eid]
    eff = export.effectors.get(eid)
    maps = [{"movement": DEG90}]
    if eff is not None and eff.signal_min is not None and eff.signal_min != eff.signal_max:
        maps.append({"signal": UnitMap((eff.signal_min, eff.signal_max), (0, 90), eff.unit)})
    start = _start_deg(eff) or 0.0
    lo, hi = min(0.0, start) - 1e-9, max(90.0, start) + 1e-9
    end_s = segs[-1].end_ms / 1000
    times = {-1.0, 0.0, end_s, end_s + 1.0}
    for s in segs:
        times |= {s.start_ms / 1000, (s.start_ms + s.dur_ms / 2) / 1000, s.end_ms / 1000}
    for kw in maps:
        track = export.track(index, eid, loop=loop, **kw)
        if getattr(track, "behind", ()):  # the registered speed limit: the signal may arrive later
            assert track.duration >= end_s
        else:
            assert track.duration == end_s
        for t in sorted(times | {track.duration}):
            u, du = track.sample(t)
            assert math.isfinite(u) and math.isfinite(du), (eid, t)
            assert lo <= math.degrees(u) <= hi, (eid, t, math.degrees(u))


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


_GOOD = {  # the shipped sample in each form: the accepted path runs on every test run
    "code": samples.code_text(samples.SETUP, samples.ANIMS).encode(),
    "json": json.dumps([*samples.SETUP, *samples.ANIMS[0].data]).encode(),
    "sd": "".join(c + "\n" for c in samples.ANIMS[0].data).encode(),
}


@settings(max_examples=150)
@given(st.binary(max_size=300), st.sampled_from(["code", "json", "sd"]))
@example(_GOOD["code"], "code").via("the shipped sample")
@example(_GOOD["json"], "json").via("the shipped sample")
@example(_GOOD["sd"], "sd").via("the shipped sample")
def test_random_bytes_give_only_format_errors(fuzz_dir, data, form):
    p = fuzz_dir / f"f.{'json' if form == 'json' else 'cpp'}"
    p.write_bytes(data)
    if form == "sd":
        (fuzz_dir / "bytes" / "anims" / "0").mkdir(parents=True, exist_ok=True)
        (fuzz_dir / "bytes" / "anims" / "0" / "data.txt").write_bytes(data)
        p = fuzz_dir / "bytes"
    try:
        export = read_export(p, form)
    except FormatError as exc:
        _refused(exc, p)
        return
    _accepted(export, form)


_ATOMS = ["sC", "sCI", "rSVPin", "rSVI2C", "rMTR", "sSY", "sR", "upE", "xE", "xUC", "tSYN",
          "sCO", ",", ";", "*", "0", "1", "-5", "8192", "9999999999", "h12", "\n", "\\n", '"',
          "/", "ANIM_0_DATA0[] = ", "SETUP_DATA_0[] = ", "ANIM_0_CONFIG[] = {", "}", " "]  # fmt: skip


@settings(max_examples=200)
@given(st.lists(st.sampled_from(_ATOMS), max_size=60), st.sampled_from(["code", "json", "sd"]))
@example(["sCI", ",", "0", ",", "8192", "\n", "sC", ",", "0", ",", "0", ",", "1", ",", "8192",
          ",", "0", ",", "0", ",", "0", ",", "0", ",", "0"], "json").via("a curve")  # fmt: skip
def test_random_command_text_gives_only_format_errors(fuzz_dir, atoms, form):
    text = "".join(atoms)
    if form == "sd":
        d = fuzz_dir / "card" / "anims" / "0"
        d.mkdir(parents=True, exist_ok=True)
        (d / "data.txt").write_text(text)
        p = fuzz_dir / "card"
    elif form == "json":
        p = fuzz_dir / "g.json"
        p.write_text(json.dumps(text.split("\n")))
    else:
        p = fuzz_dir / "g.cpp"
        p.write_text(f'const char ANIM_0_DATA0[] = "{text}";\n{text}')
    try:
        export = read_export(p, form)
    except FormatError as exc:
        _refused(exc, p)
        return
    _accepted(export, form)


_FIELD = st.one_of(
    st.integers(-10, 9000).map(str), st.integers(-(10**12), 10**12).map(str),
    st.sampled_from(["", "x", "1.5", " 7", "0x10", "1e3", "nan", "e" * 300]),
)  # fmt: skip
_NAMES = ["sC", "sCI", "rSVPin", "rSVI2C", "rMTR", "rECC", "rSTDir", "upE", "xUE", "xC", "tSYN"]
_ANY_COMMAND = st.tuples(
    st.sampled_from([*_NAMES, "sCO"]), st.lists(_FIELD, min_size=0, max_size=10)
).map(lambda c: ",".join([c[0], *c[1]]))
_CURVE = st.tuples(
    st.integers(0, 500), st.integers(0, 3000), st.integers(0, 8192), st.integers(-4000, 6000),
    st.integers(-9000, 9000), st.integers(-6000, 4000), st.integers(-9000, 9000),
)  # fmt: skip


def _chain(curves: list[tuple[int, ...]]) -> list[str]:
    """sC commands one after another on effector 0 (gaps between), any handles."""
    out, t, y = [], 0, 4096
    for gap, dur, y1, c1x, c1y, c2x, c2y in curves:
        t += gap
        out.append(f"sC,0,{t},{dur},{y},{c1x},{c1y},{y1},{c2x},{c2y}")
        t, y = t + dur, y1
    return out


#: (a chain of curves on effector 0, up to two other commands, where they go in the chain)
_COMMANDS = st.tuples(
    st.lists(_CURVE, min_size=1, max_size=6).map(_chain),
    st.lists(_ANY_COMMAND, max_size=2),
    st.integers(0, 6),
)


@settings(max_examples=150)
@given(_COMMANDS, st.sampled_from(["code", "json", "sd"]))
@example(([SEG1], [f"upE,{'e' * 300},1,2,3"], 1), "json").via("a long unknown identifier")
@example(([SEG1, SEG2], ["sCI, 7,100", "sCI,0,5"], 1), "sd").via("instant moves")
def test_random_commands_give_tracks_or_format_errors(fuzz_dir, parts, form):
    chain, others, at = parts
    commands = chain[:at] + others + chain[at:]
    sub = fuzz_dir / f"cmd-{form}"
    sub.mkdir(exist_ok=True)
    kinds = {"code": "GeneratedCodeAnimations.cpp", "sd": "card", "json": "e.json"}
    writer = {"code": samples.write_code, "sd": samples.write_sd, "json": samples.write_json}
    setup = ["rSVPin,0,1000,2000,3000,1500"]
    path = writer[form](sub / kinds[form], setup, [samples.Anim("", commands)])
    try:
        export = read_export(path, form)
    except FormatError as exc:
        _refused(exc, path)
        return
    _accepted(export, form)
    # the tracks are the input's: effector 0's chain, and an effector for each other curve
    curves = [c.split(",") for c in others if c.split(",")[0] in ("sC", "sCI")]
    segments = export.animation(0).segments
    assert set(segments) == {"0"} | {f[1].strip() for f in curves}
    assert len(segments["0"]) == len(chain) + sum(f[1].strip() == "0" for f in curves)
    if not curves and not any(c.startswith("tSYN") for c in others):
        want = [BezierSegment.from_command(*map(int, c.split(",")[2:])) for c in chain]
        assert list(segments["0"]) == want
        track = export.track(0, "0", movement=DEG90)
        if getattr(track, "behind", ()):  # the registered speed limit holds the signal back
            assert track.duration >= want[-1].end_ms / 1000
        else:
            assert track.duration == want[-1].end_ms / 1000


def test_shipped_samples_are_the_generators(tmp_path):
    """configs/animations/bottango/ is what tools/samples_bottango.py writes, and reads."""
    samples.main(tmp_path)
    shipped = Path(samples.OUT)
    files = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(shipped) for p in shipped.rglob("*") if p.is_file())
    for rel in files:
        assert (tmp_path / rel).read_bytes() == (shipped / rel).read_bytes(), rel
    for path in (
        shipped / "GeneratedCodeAnimations.cpp",
        shipped / "sd",
        shipped / "commands.json",
    ):
        assert deg(read_export(path).track(0, "0", signal=US), 1.0) == pytest.approx(
            29.97, abs=0.025
        )
