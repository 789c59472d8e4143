"""Clips on a show's timeline: a joint's target cut from clip to clip, and every cut within
the joint's speed and acceleration limits once through the spring and the safety filter."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hilsim.rig import load_rig
from hilsim.show.parts import build_parts
from hilsim.show.preview import preview
from hilsim.targets import Hold, Keyframes, TargetSet
from hilsim.targets.clips import ClipSequence, Cue, sequence_for

RIG = """
name = "c"
[bus]
port = "dxlsim://?ids=1"
[loop]
rate_hz = 250
[safety]
soft_start_s = 0.2
[[joints]]
name = "jaw"
servo_id = 1
min_deg = -5
max_deg = 40
max_speed_deg_s = 120
max_accel_deg_s2 = 2000
spring = { frequency_hz = 8.0, damping_ratio = 0.6, response = 1.0 }
target = { type = "hold", value_deg = 0 }
"""

D = math.radians


def clips() -> dict:
    return {
        "idle": {"jaw": Hold(D(10))},
        "scare": {"jaw": Keyframes([0.0, 0.5, 1.0], [D(30), D(35), D(5)])},
        "blink": {},  # drives no jaw: the jaw goes back to its base
    }


def test_the_clip_playing_drives_the_joint_from_its_own_start():
    seq = sequence_for(
        "jaw", Hold(D(-1)), [Cue(3.0, "scare"), Cue(0.0, "idle", loop=True)], clips()
    )
    assert math.degrees(seq.value(1.0)) == pytest.approx(10)
    assert math.degrees(seq.value(3.0)) == pytest.approx(30)  # the cut: the clip's t = 0
    assert math.degrees(seq.value(3.5)) == pytest.approx(35)
    assert math.degrees(seq.value(9.0)) == pytest.approx(5)  # held after its end
    assert seq.duration == 4.0
    base = sequence_for("jaw", Hold(D(-1)), [Cue(1.0, "blink")], clips())
    assert math.degrees(base.value(0.5)) == math.degrees(base.value(2.0)) == pytest.approx(-1)


def test_a_looped_clip_starts_again_at_its_end():
    seq = sequence_for("jaw", Hold(0.0), [Cue(1.0, "scare", loop=True)], clips())
    assert seq.value(1.25) == pytest.approx(seq.value(2.25)) == pytest.approx(seq.value(3.25))
    assert seq.duration is None


def test_bad_cues_are_named():
    with pytest.raises(KeyError, match="no clip 'boo'"):
        sequence_for("jaw", Hold(0.0), [Cue(1.0, "boo")], clips())
    with pytest.raises(ValueError, match="finite time >= 0"):
        Cue(-1.0, "idle")
    with pytest.raises(ValueError, match="strictly increase"):
        ClipSequence(Hold(0.0), ((1.0, None, False), (1.0, None, False)))


def test_every_cut_is_within_the_joints_speed_and_acceleration(tmp_path: Path):
    """Issue 13, item 2 (and issue 14's idle/scare case): idle holds 10 deg, the scare clip
    starts at 30 deg at 3.0 s and ends at 5 deg, then back to idle: the target jumps, the
    command never steps more than max speed x period nor changes its step more than max
    acceleration x period^2."""
    path = tmp_path / "c.toml"
    path.write_text(RIG)
    rig = load_rig(path)
    cues = [Cue(0.0, "idle", loop=True), Cue(3.0, "scare"), Cue(4.2, "idle", loop=True)]
    targets = TargetSet([sequence_for("jaw", Hold(0.0), cues, clips())], rig.joint_names)
    p = preview(build_parts(rig, targets), 6.0)
    jaw = p.cmd_deg[:, 0]
    dt = rig.loop.period_s
    steps = np.diff(jaw)
    assert np.abs(steps).max() <= 120 * dt + 1e-9
    assert np.abs(np.diff(steps)).max() <= 2000 * dt * dt + 1e-9
    target = p.target_deg[:, 0]
    assert np.abs(np.diff(target)).max() > 19.9  # the target itself jumped at the cuts
    assert jaw[round(2.9 / dt)] == pytest.approx(10.0, abs=0.01)
    assert jaw[round(3.0 / dt) : round(4.2 / dt)].max() > 30.0  # it got there, within limits
    assert jaw[-1] == pytest.approx(10.0, abs=0.01)


# ------------------------------------------------------------------ the rig's [clips] and [[play]]
CLIPS = """
[clips.idle]
jaw = { type = "hold", value_deg = 10 }

[clips.scare]
jaw = { type = "keyframes", keys = [[0, 30], [0.5, 35], [1.0, 5]] }

[[play]]
at_s = 0
clip = "idle"
loop = true

[[play]]
at_s = 3.0
clip = "scare"
"""


def test_a_rigs_play_drives_its_joints(tmp_path: Path, capsys):
    from hilsim.cli import main

    path = tmp_path / "c.toml"
    path.write_text(RIG + CLIPS)
    rig = load_rig(path)
    assert [p.clip for p in rig.play] == ["idle", "scare"] and rig.play[0].loop
    targets = build_parts(rig).targets
    assert targets.duration == 4.0
    assert main(["tracks", str(path), "--at", "1,3,3.5,9", "--json"]) == 0
    import json

    assert json.loads(capsys.readouterr().out)["jaw"] == pytest.approx([10, 30, 35, 5])
    # the shipped example: Bottango's Idle and Talk, cut at 1.0 s and 4.5 s
    repo = Path(__file__).resolve().parents[2]
    p = preview(build_parts(load_rig(repo / "configs" / "clips.toml")), 8.0)
    dt = 1 / 250
    assert np.abs(np.diff(p.cmd_deg, axis=0)).max() <= 400 * dt + 1e-9


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (CLIPS.replace("jaw = { type = \"hold\"", "nose = { type = \"hold\""),
         "clips.idle.nose: no such joint"),
        (CLIPS.replace('clip = "scare"', 'clip = "boo"'), r"play\[1\].clip: no clip 'boo'"),
        (CLIPS.replace("at_s = 3.0", "at_s = 0"), r"play\[1\].at_s: must be after"),
        (CLIPS.replace("at_s = 3.0", "at_s = -1"), r"play\[1\].at_s"),
        (CLIPS.replace("loop = true", "loop = 1"), r"play\[0\].loop"),
        (CLIPS.replace('clip = "idle"', 'clip = "idle"\nspeed = 2'), r"unknown key\(s\) speed"),
        (CLIPS.split("[[play]]")[0], "clips: no \\[\\[play\\]\\] entry plays them"),
        (CLIPS.replace('jaw = { type = "hold", value_deg = 10 }', "jaw = 3"),
         "clips.idle.jaw: must be a target table"),
    ],
)  # fmt: skip
def test_bad_clips_and_plays_are_one_line(tmp_path: Path, text, match):
    path = tmp_path / "c.toml"
    path.write_text(RIG + text)
    with pytest.raises(ValueError, match=match):
        load_rig(path)


def test_a_bad_target_in_a_clip_is_named_at_build(tmp_path: Path):
    from hilsim.rig import RigError

    path = tmp_path / "c.toml"
    path.write_text(RIG + CLIPS.replace("value_deg = 10", "value = 10"))
    with pytest.raises(RigError, match=r"clips\.idle\.jaw: value:"):
        build_parts(load_rig(path))
