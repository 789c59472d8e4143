"""Animation targets: easings, generators, CSV curves, the target set and the spec builder."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilsim.targets import (
    EASINGS,
    Hold,
    Keyframes,
    Sine,
    SpecError,
    Step,
    TargetSet,
    track_from_spec,
)
from hilsim.targets.csv_file import CsvAnimation, CsvCurve, CsvFormatError

CONFIGS = Path(__file__).resolve().parents[2] / "configs"

# e(τ) and e'(τ) written out independently of the implementation
REFERENCE = {
    "linear": (lambda u: u, lambda u: 1.0),
    "step": (lambda u: 0.0, lambda u: 0.0),
    "ease_in": (lambda u: u**3, lambda u: 3 * u**2),
    "ease_out": (lambda u: 1 - (1 - u) ** 3, lambda u: 3 * (1 - u) ** 2),
    "ease_in_out": (
        lambda u: 4 * u**3 if u < 0.5 else 1 - (2 - 2 * u) ** 3 / 2,
        lambda u: 12 * u**2 if u < 0.5 else 3 * (2 - 2 * u) ** 2,
    ),
    "sine_in_out": (
        lambda u: (1 - math.cos(math.pi * u)) / 2,
        lambda u: math.pi / 2 * math.sin(math.pi * u),
    ),
    # two keys: the end tangents are zero, so the Hermite cubic is smoothstep
    "smooth": (lambda u: u * u * (3 - 2 * u), lambda u: 6 * u * (1 - u)),
}


def test_reference_covers_every_easing():
    assert set(REFERENCE) == set(EASINGS)


@pytest.mark.parametrize("easing", EASINGS)
@pytest.mark.parametrize("u", [0.0, 0.1, 0.25, 0.5, 0.6, 0.9])
def test_single_segment_matches_the_easing_formula(easing, u):
    t0, t1, v0, v1 = 2.0, 4.5, 0.3, -0.7
    track = Keyframes([t0, t1], [v0, v1], easing)
    e, de = REFERENCE[easing]
    t = t0 + u * (t1 - t0)
    assert track.value(t) == pytest.approx(v0 + (v1 - v0) * e(u), abs=1e-12)
    assert track.velocity(t) == pytest.approx((v1 - v0) * de(u) / (t1 - t0), abs=1e-12)


@pytest.mark.parametrize("easing", EASINGS)
def test_keys_are_hit_exactly_and_held_outside(easing):
    track = Keyframes([0.0, 1.0, 2.5], [0.1, 0.5, -0.2], easing)
    assert track.sample(-5.0) == (0.1, 0.0)
    assert track.value(0.0) == 0.1
    assert track.value(1.0) == 0.5
    assert track.sample(2.5) == (-0.2, 0.0)
    assert track.sample(1e9) == (-0.2, 0.0)
    assert track.duration == 2.5


@pytest.mark.parametrize("easing", ["ease_in_out", "sine_in_out", "smooth"])
def test_rest_at_the_ends(easing):
    track = Keyframes([0.0, 2.0], [0.0, 1.0], easing)
    assert track.velocity(0.0) == pytest.approx(0.0, abs=1e-15)
    assert track.velocity(2.0 - 1e-9) == pytest.approx(0.0, abs=1e-8)


def test_peak_speed_factors_in_the_docstring():
    # peak velocity = factor · Δv/Δt; sampled densely
    for easing, factor in [("linear", 1), ("ease_in", 3), ("ease_out", 3), ("ease_in_out", 3),
                           ("sine_in_out", math.pi / 2), ("smooth", 1.5)]:  # fmt: skip
        track = Keyframes([0.0, 1.0], [0.0, 1.0], easing)
        ts = np.append(np.linspace(0, 1, 2001)[:-1], 1 - 1e-12)
        peak = max(abs(track.velocity(t)) for t in ts)
        assert peak == pytest.approx(factor, rel=1e-5), easing


def test_step_holds_until_the_next_key():
    track = Keyframes([0.0, 1.0, 2.0], [0.0, 0.4, 0.1], "step")
    assert track.value(0.999999) == 0.0
    assert track.value(1.0) == 0.4
    assert track.value(1.5) == 0.4
    assert track.value(2.0) == 0.1
    assert track.velocity(1.5) == 0.0


def test_per_segment_easing():
    track = Keyframes([0.0, 1.0, 2.0], [0.0, 1.0, 0.0], ["step", "linear"])
    assert track.easing == ("step", "linear")
    assert track.value(0.5) == 0.0
    assert track.value(1.5) == pytest.approx(0.5)


key_sets = st.integers(2, 7).flatmap(
    lambda k: st.tuples(
        st.lists(st.floats(0.05, 3.0), min_size=k - 1, max_size=k - 1),
        st.lists(st.floats(-2.0, 2.0), min_size=k, max_size=k),
    )
)


def _keys(gaps, values):
    return np.concatenate([[0.0], np.cumsum(gaps)]), np.array(values)


@settings(max_examples=60, deadline=None)
@given(key_sets, st.sampled_from(EASINGS), st.floats(0.0, 1.0))
def test_velocity_matches_finite_differences(keys, easing, frac):
    times, values = _keys(*keys)
    track = Keyframes(times, values, easing)
    t = frac * times[-1]
    # keep the difference inside one piece: away from keys and from ease_in_out's midpoints
    knots = np.concatenate([times, (times[:-1] + times[1:]) / 2])
    h = 1e-6
    if np.min(np.abs(knots - t)) < 10 * h:
        return
    fd = (track.value(t + h) - track.value(t - h)) / (2 * h)
    assert track.velocity(t) == pytest.approx(fd, rel=1e-5, abs=1e-5)


@settings(max_examples=60, deadline=None)
@given(key_sets, st.sampled_from([e for e in EASINGS if e != "step"]))
def test_values_are_continuous_at_keys(keys, easing):
    times, values = _keys(*keys)
    track = Keyframes(times, values, easing)
    for t, v in zip(times, values, strict=True):
        assert track.value(t - 1e-12) == pytest.approx(v, abs=1e-9)
        assert track.value(t) == pytest.approx(v, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(key_sets)
def test_smooth_is_c1_and_never_overshoots_its_keys(keys):
    times, values = _keys(*keys)
    track = Keyframes(times, values, "smooth")
    eps = 1e-10  # |acceleration| < 1e5 rad/s² for these keys, so the left limit is within 1e-5
    for t in times:  # C1, including the holds before the first and after the last key
        left, right = track.velocity(t - eps), track.velocity(t)
        assert left == pytest.approx(right, abs=1e-5)
    for i in range(len(times) - 1):
        lo, hi = sorted(values[i : i + 2])
        us = np.linspace(times[i], times[i + 1], 41)
        seg = [track.value(t) for t in us]
        assert min(seg) >= lo - 1e-12 and max(seg) <= hi + 1e-12


def test_smooth_uses_catmull_rom_tangents_on_monotone_keys():
    track = Keyframes([0.0, 1.0, 3.0], [0.0, 1.0, 2.5], "smooth")
    # (2.5 − 0) / (3 − 0), within 3× the smaller secant (0.75)
    assert track.velocity(1.0) == pytest.approx(2.5 / 3.0)


def test_single_key_is_a_hold():
    track = Keyframes([1.0], [0.3])
    assert track.sample(0.0) == (0.3, 0.0)
    assert track.sample(5.0) == (0.3, 0.0)
    assert track.duration == 1.0


@pytest.mark.parametrize(
    "times, values, match",
    [
        ([0.0, 1.0, 1.0], [0, 1, 2], r"key 2 \(t = 1.0 s\) is not after key 1"),
        ([0.0, 2.0, 1.0], [0, 1, 2], r"key 2"),
        ([0.0, math.nan], [0, 1], r"key 1: time must be finite"),
        ([0.0, 1.0], [0, math.inf], r"key 1: value must be finite"),
        ([0.0, 1.0], [0, 1e306], r"key 1: value 5.7\d*e\+307° is beyond ±92160° \(256 turns"),
        ([], [], r"non-empty"),
        ([0.0, 1.0], [0.0], r"one length"),
        ([0.0, 5e-324], [0.0, 1.0], r"key 1"),  # a subnormal gap: 1/Δt overflows
    ],
)
def test_keyframe_validation(times, values, match):
    with pytest.raises(ValueError, match=match):
        Keyframes(times, values)


def test_unknown_easing_lists_the_choices():
    with pytest.raises(ValueError, match=r"unknown easing 'bounce'.*linear, step, ease_in"):
        Keyframes([0, 1], [0, 1], "bounce")
    with pytest.raises(ValueError, match=r"segment 1"):
        Keyframes([0, 1, 2], [0, 1, 0], ["linear", "cubic"])
    with pytest.raises(ValueError, match=r"one per segment \(2\), got 3"):
        Keyframes([0, 1, 2], [0, 1, 0], ["linear"] * 3)


def test_keyframes_arrays_are_read_only():
    track = Keyframes([0, 1], [0, 1])
    with pytest.raises(ValueError):
        track.times_s[0] = 5.0


# --------------------------------------------------------------------------- generators


def test_hold_step_sine():
    assert Hold(0.2).sample(123.0) == (0.2, 0.0)
    step = Step(1.0, -0.1, 0.3)
    assert step.sample(0.99) == (-0.1, 0.0)
    assert step.sample(1.0) == (0.3, 0.0)
    sine = Sine(0.5, 2.0, phase_rad=0.25, offset_rad=0.1)
    t = 0.37
    w = 2 * math.pi * 2.0
    assert sine.value(t) == pytest.approx(0.1 + 0.5 * math.sin(w * t + 0.25))
    assert sine.velocity(t) == pytest.approx(0.5 * w * math.cos(w * t + 0.25))
    h = 1e-6
    assert sine.velocity(t) == pytest.approx((sine.value(t + h) - sine.value(t - h)) / (2 * h))
    for gen in (Hold(0.0), step, sine):
        assert gen.duration is None


def test_generator_validation():
    with pytest.raises(ValueError, match="frequency_hz must be >= 0"):
        Sine(0.1, -1.0)
    with pytest.raises(ValueError, match="value_rad must be finite"):
        Hold(math.nan)
    with pytest.raises(ValueError, match="at_s must be finite"):
        Step(math.inf, 0.0, 1.0)


# ---------------------------------------------------------------------------------- CSV


def _write(tmp_path: Path, text: str, name: str = "anim.csv") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_csv_loads_degrees_as_radians_and_interpolates(tmp_path):
    path = _write(
        tmp_path,
        "# a comment\ntime_s, jaw ,tail\n0.0,0,10\n\n0.5,30,10\n1.5,-30,20\n",
    )
    anim = CsvAnimation.load(path)
    assert anim.names == ("jaw", "tail")
    assert anim.duration == 1.5
    np.testing.assert_allclose(anim.columns["jaw"], np.radians([0, 30, -30]))
    jaw = anim.curve("jaw")
    assert isinstance(jaw, CsvCurve)
    assert jaw.value(0.25) == pytest.approx(math.radians(15))
    assert jaw.velocity(0.25) == pytest.approx(math.radians(60))
    assert jaw.velocity(0.5) == pytest.approx(math.radians(-60))  # a row starts the next segment
    assert jaw.value(1.0) == pytest.approx(0.0, abs=1e-15)
    assert jaw.sample(-1.0) == (0.0, 0.0)
    assert jaw.sample(2.0) == (pytest.approx(math.radians(-30)), 0.0)
    assert jaw.duration == 1.5


def test_csv_accepts_a_utf8_bom_and_other_time_headers(tmp_path):
    path = tmp_path / "bom.csv"
    path.write_bytes("\ufeffTime,jaw\r\n0,1\r\n1,2\r\n".encode())
    assert CsvAnimation.load(path).names == ("jaw",)


@pytest.mark.parametrize(
    "text, line, match",
    [
        ("time_s,jaw\n0,0\n0.1,abc\n", 3, r"column 'jaw': 'abc' is not a number"),
        ("time_s,jaw\n0,0\n0.1,nan\n", 3, r"'nan' is not finite"),
        ("time_s,jaw\n0,0\n0.1,1e308\n", 3, r"'jaw': 1e308° is beyond ±92160° \(256 turns\)"),
        ("time_s,jaw\n0,92160\n0.1,-92161\n", 3, r"'jaw': -92161° is beyond"),
        ("time_s,jaw\n0,0\n0.1,\n", 3, r"'' is not a number"),
        ("time_s,jaw\n0,0\n# note\n0.1,1\n0.1,2\n", 5, r"time 0.1 s is not after 0.1 s on line 4"),
        ("time_s,jaw\n0,0\n0.1,1,2\n", 3, r"3 cells, but the header has 2"),
        ("jaw,tail\n0,0\n", 1, r"first column must be the time in seconds.*got 'jaw'"),
        ("time_s\n0\n", 1, r"no joint columns"),
        ("time_s,jaw,jaw\n0,0,0\n", 1, r"'jaw' appears twice"),
        ("time_s,jaw,\n0,0,0\n", 1, r"empty name"),
        ("# only a comment\n", 1, r"no header row"),
        ("time_s,jaw\n", 2, r"no data rows"),
    ],
)
def test_csv_errors_name_file_and_line(tmp_path, text, line, match):
    path = _write(tmp_path, text)
    with pytest.raises(CsvFormatError, match=match) as info:
        CsvAnimation.load(path)
    assert str(info.value).startswith(f"{path}:{line}: ")
    assert info.value.line == line


def test_csv_missing_column(tmp_path):
    anim = CsvAnimation.load(_write(tmp_path, "time_s,jaw\n0,0\n"))
    with pytest.raises(CsvFormatError, match=r"anim.csv:1: no column 'tail'; .* are jaw"):
        anim.curve("tail")


def test_demo_animation_is_plausible():
    anim = CsvAnimation.load(CONFIGS / "demo_animation.csv")
    assert anim.names == ("head_pan", "head_tilt", "jaw", "tail")
    assert anim.duration == pytest.approx(20.0)
    np.testing.assert_allclose(np.diff(anim.times_s), 0.05, atol=1e-9)
    for name, col in anim.columns.items():
        deg = np.degrees(col)
        assert np.all(np.abs(deg) <= 60.0), name
        assert deg[0] == 0.0 and deg[-1] == 0.0, name  # starts and ends at rest in the zero pose
        assert np.ptp(deg) > 10.0, name  # it does move
    # the demo rig's jaw limits are -5..35 deg
    assert np.degrees(anim.columns["jaw"]).min() >= 0.0


# ---------------------------------------------------------------------------- target set


def test_target_set_fills_preallocated_arrays():
    tracks = [Hold(0.1), Sine(0.2, 0.5), Keyframes([0, 2], [0, 1], "linear")]
    ts = TargetSet(tracks, names=["a", "b", "c"])
    assert ts.n_joints == 3
    assert ts.duration == 2.0
    pos, vel = np.full(3, np.nan), np.full(3, np.nan)
    ts.sample(0.5, pos, vel)
    np.testing.assert_allclose(pos, [0.1, 0.2, 0.25])
    np.testing.assert_allclose(vel, [0.0, 0.0, 0.5], atol=1e-12)
    pos2 = np.full(3, np.nan)
    ts.sample(0.5, pos2)
    np.testing.assert_array_equal(pos2, pos)


def test_target_set_callable_for_the_integrator():
    ts = TargetSet([Sine(1.0, 0.25), Hold(0.5)])
    u, du = ts(1.0)
    assert u[0] == pytest.approx(1.0) and du[0] == pytest.approx(0.0, abs=1e-12)
    u2, _ = ts(0.0)
    assert u2 is u  # the set's own buffers, reused
    assert u[0] == pytest.approx(0.0)


def test_target_set_duration_and_validation():
    assert TargetSet([Hold(0.0), Sine(0.1, 1.0)]).duration is None
    assert TargetSet([Keyframes([0, 3], [0, 1]), Keyframes([0, 5], [0, 1])]).duration == 5.0
    assert TargetSet([Hold(0.0)]).names == ("joint0",)
    with pytest.raises(ValueError, match="at least one track"):
        TargetSet([])
    with pytest.raises(ValueError, match="2 names for 1 tracks"):
        TargetSet([Hold(0.0)], names=["a", "b"])
    with pytest.raises(ValueError, match="track 0 is not a Track"):
        TargetSet([0.5])  # type: ignore[list-item]


# ------------------------------------------------------------------------- spec builder


def build(spec, **kw):
    kw.setdefault("joint_name", "jaw")
    kw.setdefault("base_dir", CONFIGS)
    return track_from_spec(spec, **kw)


def test_specs_build_tracks_in_radians():
    kf = build({"type": "keyframes", "keys": [[0.0, 0.0], [1.0, 30], [2.5, -10.0]],
                "easing": "ease_in_out"})  # fmt: skip
    assert isinstance(kf, Keyframes)
    assert kf.value(1.0) == pytest.approx(math.radians(30))
    assert kf.easing == ("ease_in_out", "ease_in_out")
    kf2 = build({"type": "keyframes", "keys": [[0, 0], [1, 10], [2, 0]],
                 "easing": ["smooth", "step"]})  # fmt: skip
    assert kf2.easing == ("smooth", "step")
    assert build({"type": "keyframes", "keys": [[0, 0], [1, 10]]}).easing == ("linear",)
    sine = build({"type": "sine", "amplitude_deg": 20, "frequency_hz": 0.5, "phase_deg": 90})
    assert sine.value(0.0) == pytest.approx(math.radians(20))
    step = build({"type": "step", "at_s": 1.0, "before_deg": 0, "after_deg": 15})
    assert step.value(2.0) == pytest.approx(math.radians(15))
    assert build({"type": "hold", "value_deg": -45}).value(0.0) == pytest.approx(-math.pi / 4)


def test_csv_spec_defaults_to_the_joint_column_and_loads_once(tmp_path, monkeypatch):
    _write(tmp_path, "time_s,jaw,tail\n0,0,0\n1,10,20\n")
    calls = []
    real = CsvAnimation.load.__func__

    def counting(cls, path):
        calls.append(path)
        return real(cls, path)

    monkeypatch.setattr(CsvAnimation, "load", classmethod(counting))
    cache: dict = {}
    jaw = build({"type": "csv", "file": "anim.csv"}, base_dir=tmp_path, csv_cache=cache)
    tail = build({"type": "csv", "file": "anim.csv"}, base_dir=tmp_path, joint_name="tail",
                 csv_cache=cache)  # fmt: skip
    other = build({"type": "csv", "file": "anim.csv", "column": "tail"}, base_dir=tmp_path,
                  csv_cache=cache)  # fmt: skip
    assert len(calls) == 1 and list(cache) == [(tmp_path / "anim.csv").resolve()]
    assert jaw.value(1.0) == pytest.approx(math.radians(10))
    assert tail.value(1.0) == other.value(1.0) == pytest.approx(math.radians(20))


def test_demo_csv_spec():
    track = build({"type": "csv", "file": "demo_animation.csv"}, joint_name="head_pan")
    assert track.duration == pytest.approx(20.0)


@pytest.mark.parametrize(
    "spec, key, match",
    [
        ({}, "type", r"missing; allowed: audio, blender_servo, bottango, csv, fseq, hold, keyframes, layers, lipsync, midi, sine, step"),
        ({"type": "spline"}, "type", r"unknown target type 'spline'; allowed: audio, blender_servo, bottango, csv"),
        ({"type": "sine", "amplitude": 20, "frequency_hz": 1}, "amplitude",
         r"unknown key for a 'sine' target; allowed: type, amplitude_deg, frequency_hz, phase_deg"),
        ({"type": "sine", "amplitude_deg": 20}, "frequency_hz",
         r"missing; a 'sine' target needs amplitude_deg, frequency_hz"),
        ({"type": "sine", "amplitude_deg": "20", "frequency_hz": 1}, "amplitude_deg",
         r"must be a number, got '20'"),
        ({"type": "sine", "amplitude_deg": 20, "frequency_hz": -1}, "frequency_hz", r">= 0"),
        ({"type": "hold", "value_deg": True}, "value_deg", r"must be a number, got True"),
        ({"type": "hold", "value_deg": math.inf}, "value_deg", r"must be finite"),
        ({"type": "hold", "value_deg": 1e308}, "value_deg", r"within ±92160° \(256 turns\)"),
        (
            {"type": "sine", "amplitude_deg": 1, "frequency_hz": 1, "offset_deg": -1e6},
            "offset_deg",
            r"within ±92160°",
        ),
        ({"type": "step", "at_s": 1, "before_deg": 0}, "after_deg", r"missing"),
        ({"type": "keyframes", "keys": []}, "keys", r"non-empty list of \[time_s, deg\] pairs"),
        ({"type": "keyframes", "keys": [[0, 0], [1]]}, "keys[1]", r"must be a \[time_s, deg\]"),
        ({"type": "keyframes", "keys": [[0, 0], [1, "x"]]}, "keys[1][1]", r"must be a number"),
        ({"type": "keyframes", "keys": [[0, 0], [0, 1]]}, "keys",
         r"times must strictly increase: key 1"),
        ({"type": "keyframes", "keys": [[0, 0], [1, 1]], "easing": "bounce"}, "easing",
         r"unknown easing 'bounce'; choose one of linear, step"),
        ({"type": "keyframes", "keys": [[0, 0], [1, 1]], "easing": ["linear", "step"]}, "easing",
         r"one name, or one per segment \(1\), got 2"),
        ({"type": "keyframes", "keys": [[0, 0], [1, 1]], "easing": 3}, "easing",
         r"must be a name or a list of names"),
        ({"type": "csv", "file": "nope.csv"}, "file", r"no such file: .*nope.csv"),
        ({"type": "csv", "file": 3}, "file", r"must be a file name"),
        ({"type": "csv", "file": "demo_animation.csv", "column": "wing"}, "column",
         r"demo_animation.csv:1: no column 'wing'; the joint columns are head_pan"),
        ({"type": "csv", "file": "demo_animation.csv"}, "column",
         r"no column 'ear' \(the column defaults to the joint name\)"),
    ],
)  # fmt: skip
def test_spec_errors_name_the_key(spec, key, match):
    with pytest.raises(SpecError, match=match) as info:
        build(spec, joint_name="ear")
    assert info.value.key == key
    assert str(info.value).startswith(f"{key}: ")
    assert isinstance(info.value, ValueError)


def test_csv_format_errors_pass_through_the_spec_builder(tmp_path):
    _write(tmp_path, "time_s,jaw\n0,0\n1,x\n")
    with pytest.raises(CsvFormatError, match=r"anim.csv:3: column 'jaw'"):
        build({"type": "csv", "file": "anim.csv"}, base_dir=tmp_path)


# ----------------------------------------------------------------------- many times at once


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-90.0, 90.0), min_size=1, max_size=6),
    st.lists(st.sampled_from(EASINGS), min_size=5, max_size=5),
)
def test_sample_array_agrees_with_sample(values, easings):
    """The vectorised sampler (for load-time checks) against the per-tick one, every track type."""
    times = np.cumsum(np.linspace(0.3, 1.1, len(values)))
    tracks = [
        Keyframes(times, np.radians(values), easings[: len(values) - 1]),
        Sine(0.4, 1.3, 0.2, -0.1),
        Step(1.0, -0.2, 0.3),
        Hold(0.25),
        CsvCurve(times, np.radians(values)),  # the default: one sample() call per time
    ]
    t = np.concatenate([np.linspace(-1.0, times[-1] + 1.0, 397), times, [1.0]])
    for track in tracks:
        pos, vel = track.sample_array(t)
        assert pos.shape == vel.shape == t.shape
        expected = np.array([track.sample(float(x)) for x in t])
        np.testing.assert_allclose(pos, expected[:, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(vel, expected[:, 1], rtol=1e-12, atol=1e-9)
    grid = np.linspace(0.0, 2.0, 6).reshape(2, 3)  # any shape
    assert tracks[0].sample_array(grid)[0].shape == (2, 3)


# ------------------------------------------------------------------ layers
def test_layers_add_their_targets_and_velocities():
    from hilsim.targets import Layered

    spec = {
        "type": "layers",
        "layers": [
            {"type": "sine", "amplitude_deg": 10, "frequency_hz": 1.0},
            {"type": "keyframes", "keys": [[0, 0], [2, 20]]},
        ],
    }
    track = track_from_spec(spec, joint_name="jaw")
    assert isinstance(track, Layered) and track.duration == 2.0
    pos, vel = track.sample(0.25)
    assert math.degrees(pos) == pytest.approx(10.0 + 2.5)
    assert math.degrees(vel) == pytest.approx(10.0 * 2 * math.pi * math.cos(math.pi / 2) + 10.0)
    arr_pos, arr_vel = track.sample_array([0.25, 1.0])
    assert arr_pos[0] == pytest.approx(pos) and arr_vel[0] == pytest.approx(vel)
    endless = track_from_spec({"type": "layers", "layers": [spec["layers"][0]]}, joint_name="j")
    assert endless.duration is None


@pytest.mark.parametrize(
    ("layers", "match"),
    [
        ([], "layers: must be a non-empty list"),
        ("sine", "layers: must be a non-empty list"),
        ([3], r"layers\[0\]: must be a target table"),
        ([{"type": "hold"}], r"layers\[0\]\.value_deg: missing"),
        ([{"type": "hold", "value_deg": 1}, {"type": "hold", "value": 1}], r"layers\[1\]\.value:"),
    ],
)
def test_bad_layers_name_the_layer_and_key(layers, match):
    with pytest.raises(SpecError, match=match):
        track_from_spec({"type": "layers", "layers": layers}, joint_name="jaw")


def test_layers_cannot_nest_without_end():
    spec: dict = {"type": "hold", "value_deg": 1}
    for _ in range(6):
        spec = {"type": "layers", "layers": [spec]}
    with pytest.raises(SpecError, match="nested more than 4 deep"):
        track_from_spec(spec, joint_name="jaw")
