"""``hilsim tracks``: targets at show times as JSON, and the offline preview (springs and
safety filter, no bus)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from hilsim.cli import main
from hilsim.rig import load_rig, load_rigs
from hilsim.show.parts import build_parts
from hilsim.show.preview import preview, targets_at

RIG = """
name = "t"
[bus]
port = "dxlsim://?ids=1-2"
[loop]
rate_hz = 100
[safety]
soft_start_s = 0.2
[telemetry]
out_dir = "{out}"
[[joints]]
name = "jaw"
servo_id = 1
min_deg = 0
max_deg = 20
max_speed_deg_s = 50
max_accel_deg_s2 = 3000
spring = {{ frequency_hz = 4.0, damping_ratio = 0.8 }}
target = {{ type = "keyframes", keys = [[0, 0], [0.5, 30], [1.0, 0]] }}
[[joints]]
name = "pan"
servo_id = 2
min_deg = -90
max_deg = 90
max_speed_deg_s = 300
max_accel_deg_s2 = 3000
spring = {{ frequency_hz = 2.0, damping_ratio = 1.0 }}
target = {{ type = "sine", amplitude_deg = 10, frequency_hz = 0.5 }}
"""


def rig_file(tmp_path: Path) -> Path:
    path = tmp_path / "t.toml"
    path.write_text(RIG.format(out=tmp_path / "runs"))
    return path


def test_at_json_prints_each_joints_target_in_degrees(tmp_path, capsys):
    assert main(["tracks", str(rig_file(tmp_path)), "--at", "0,0.25,0.5,2", "--json"]) == 0
    values = json.loads(capsys.readouterr().out)
    assert list(values) == ["jaw", "pan"]
    assert values["jaw"] == pytest.approx([0.0, 15.0, 30.0, 0.0])
    assert values["pan"] == pytest.approx([10 * math.sin(math.pi * t) for t in (0, 0.25, 0.5, 2)])


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--at", "0,x"], "'x' is not a time"),
        (["--at", "-1"], "finite time >= 0"),
        (["--at", "nan"], "finite time >= 0"),
        (["--json"], "--json needs --at"),
        (["--duration", "0"], "--duration must be"),
        (["--out", "preview.txt"], "ending in .png"),
    ],
)
def test_bad_options_are_one_line_and_exit_2(tmp_path, capsys, argv, match):
    assert main(["tracks", str(rig_file(tmp_path)), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hilsim tracks: ")
    assert match in err[0]


def test_a_missing_rig_is_one_line(tmp_path, capsys):
    assert main(["tracks", str(tmp_path / "nope.toml")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_preview_warns_of_the_limits_and_writes_the_plot(tmp_path, capsys):
    out = tmp_path / "p.png"
    assert main(["tracks", str(rig_file(tmp_path)), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "warning: jaw: target 20.4° at t = 0.34 s is beyond max_deg 20°" in err
    assert "exceeds max_speed_deg_s 50" in err
    assert "jaw: the safety filter would change the command on" in err
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_preview_runs_the_loops_filter_the_command_never_breaks_a_limit(tmp_path):
    rig = load_rig(rig_file(tmp_path))
    p = preview(build_parts(rig), 1.5)
    assert p.t.size == 151 and p.cmd_deg.shape == (151, 2)
    jaw = p.cmd_deg[:, 0]
    assert jaw.max() <= 20.0 + 1e-9 and jaw.min() >= -1e-9
    assert np.abs(np.diff(jaw)).max() <= 50 * 0.01 + 1e-9  # speed limit x period
    assert p.clamped[:, 0].any()  # the spring reaches for 30 deg: the filter holds it at 20
    # the targets the preview saw are the targets hilsim tracks --at prints
    at = targets_at(build_parts(rig), [0.3, 0.7])
    assert at["jaw"] == pytest.approx([p.target_deg[30, 0], p.target_deg[70, 0]])


def test_an_endless_animation_is_previewed_for_a_stated_span(tmp_path, capsys):
    text = RIG.format(out=tmp_path / "runs").replace(
        'target = { type = "keyframes", keys = [[0, 0], [0.5, 30], [1.0, 0]] }',
        'target = { type = "hold", value_deg = 5 }',
    )
    path = tmp_path / "e.toml"
    path.write_text(text)
    assert main(["tracks", str(path)]) == 0
    err = capsys.readouterr().err
    assert "never ends: previewing its first 20 s" in err
    assert (tmp_path / "runs" / "t-tracks.png").is_file()


def test_a_rig_with_several_buses_shows_every_bus_or_the_one_asked_for(tmp_path, capsys):
    """As ``hilsim run`` runs the whole figure: every bus's joints, bus by bus; --bus one."""
    rig = str(Path(__file__).resolve().parents[2] / "configs" / "two_buses.toml")
    assert main(["tracks", rig, "--at", "0,0.5", "--json"]) == 0
    every = json.loads(capsys.readouterr().out)
    assert list(every) == [f"l{i}" for i in range(1, 9)] + [f"r{i}" for i in range(1, 9)]
    assert main(["tracks", rig, "--bus", "right", "--at", "0,0.5", "--json"]) == 0
    right = json.loads(capsys.readouterr().out)
    assert right == {k: v for k, v in every.items() if k.startswith("r")}
    assert main(["tracks", rig, "--at", "0.5"]) == 0  # as text: a line per joint
    assert len(capsys.readouterr().out.splitlines()) == 16

    out = tmp_path / "two.png"
    assert main(["tracks", rig, "--duration", "1", "--out", str(out)]) == 0, capsys.readouterr()
    assert out.is_file()
    from hilsim.show.preview import combine

    rigs = load_rigs(rig)
    each = [preview(build_parts(r), 1.0) for r in rigs]
    whole = combine(each, ["left", "right"])
    assert whole.joints == tuple(every) and whole.buses == ("left",) * 8 + ("right",) * 8
    np.testing.assert_array_equal(whole.cmd_deg[:, 8:], each[1].cmd_deg)
    assert whole.max_deg[8:] == each[1].max_deg


def test_the_filter_warning_names_the_limit_its_figure_and_the_key(tmp_path, capsys):
    assert main(["tracks", str(rig_file(tmp_path)), "--out", str(tmp_path / "p.png")]) == 0
    line = next(x for x in capsys.readouterr().err.splitlines() if "jaw: the safety filter" in x)
    # the jaw's target goes to 30° against max_deg 20 and at 120°/s against 50
    assert "soft start: " in line and "position (the spring goes " in line
    assert "° beyond max_deg 20°: keep the target off the limit" in line
    assert "speed (the spring asks up to " in line and "of max_speed_deg_s 50: raise it" in line


def test_the_preview_legend_covers_no_panel(tmp_path, monkeypatch):
    from hilsim.telemetry import plot_common

    figures = []
    save = plot_common.save

    def keep(fig, path, dpi):
        figures.append(fig)
        return save(fig, path, dpi)

    monkeypatch.setattr(plot_common, "save", keep)
    assert main(["tracks", str(rig_file(tmp_path)), "--out", str(tmp_path / "p.png")]) == 0
    (fig,) = figures
    fig.canvas.draw()
    legend = next(ax.get_legend() for ax in fig.axes if ax.get_legend() is not None)
    box = legend.get_window_extent()
    assert not any(box.overlaps(ax.get_window_extent()) for ax in fig.axes)


def test_the_audio_jaw_speed_warning_says_what_to_change(tmp_path, capsys):
    rig = Path(__file__).resolve().parents[2] / "configs" / "talking_skull.toml"
    assert main(["tracks", str(rig), "--out", str(tmp_path / "p.png")]) == 0
    line = next(x for x in capsys.readouterr().err.splitlines() if "target speed" in x)
    assert "jaw: target speed" in line
    assert line.endswith(
        "raise max_speed_deg_s (within the servo's), lengthen attack_ms, or accept it "
        "(the safety filter holds the joint to its limit)"
    )
