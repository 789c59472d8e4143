"""Sound in a venue: a real-time show with sounds on a machine without a sound device runs
silent after one warning; ``[sounds] required = true`` refuses in one line; ``device`` picks
the output; ``hilsim sounds`` lists the outputs.

"No device" is tried twice, in a real ``hilsim run`` process: as this machine is (no
sounddevice, or no PortAudio, or no device), and with a stand-in ``sounddevice`` module
whose PortAudio finds no device (what a machine with the extra but no sound card says)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import types
import wave
from pathlib import Path

import pytest

import hilsim
from hilsim.cli import main

REPO = Path(__file__).resolve().parents[2]

RIG = """
name = "skull"
[bus]
port = "dxlsim://?ids=1&rdt_us=0&latency_ms=1"
[loop]
rate_hz = 100
[[joints]]
name = "jaw"
servo_id = 1
min_deg = 0
max_deg = 30
spring = { frequency_hz = 6.0, damping_ratio = 0.9, response = 0.0 }
target = { type = "hold", value_deg = 0 }
"""

SHOW = """
[clips.talk]
jaw = { type = "keyframes", keys = [[0, 0], [0.2, 10], [0.4, 0]] }
[sounds]
talk = "hello.wav"
[[timeline]]
at_s = 0
clip = "talk"
"""

#: a sounddevice whose PortAudio sees no device (what the extra says on a machine without one)
NO_DEVICE = """
class PortAudioError(Exception):
    pass


def query_devices():
    return []


class default:
    device = (-1, -1)


class OutputStream:
    def __init__(self, **kw):
        raise PortAudioError("Error querying device -1")
"""


def files(tmp_path: Path, show: str = SHOW) -> tuple[Path, Path]:
    with wave.open(str(tmp_path / "hello.wav"), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(8000)
        w.writeframes(b"\x00\x10" * 4000)
    (tmp_path / "rig.toml").write_text(RIG)
    (tmp_path / "show.toml").write_text(show)
    return tmp_path / "rig.toml", tmp_path / "show.toml"


def machine_has_a_sound_device() -> bool:
    try:
        import sounddevice  # type: ignore[import-not-found,unused-ignore]

        return any(d["max_output_channels"] > 0 for d in sounddevice.query_devices())
    except Exception:
        return False


def hilsim_run(tmp_path: Path, show: Path, fake: bool) -> subprocess.CompletedProcess[str]:
    """``hilsim run`` in its own process, on the real clock, for 0.5 s of show."""
    paths = [str(REPO)]
    if fake:
        (tmp_path / "fake").mkdir(exist_ok=True)
        (tmp_path / "fake" / "sounddevice.py").write_text(NO_DEVICE)
        paths.insert(0, str(tmp_path / "fake"))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}
    argv = [sys.executable, "-m", "hilsim", "run", str(tmp_path / "rig.toml"), "--show",
            str(show), "--duration", "0.5", "--no-plots", "--out", str(tmp_path / "run")]  # fmt: skip
    return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=120, check=False)


@pytest.mark.parametrize("fake", [False, True], ids=["this-machine", "portaudio-no-device"])
def test_a_real_time_show_with_sounds_and_no_device_runs_silent_after_one_warning(tmp_path, fake):
    if not fake and machine_has_a_sound_device():
        pytest.skip("this machine has a sound device")
    _, show = files(tmp_path)
    done = hilsim_run(tmp_path, show, fake)
    assert done.returncode == 0, done.stderr
    warnings = [line for line in done.stderr.splitlines() if "warning" in line]
    assert len(warnings) == 1, done.stderr
    assert warnings[0].startswith("hilsim run: warning: no sound: ")
    assert warnings[0].endswith("the show runs silent (audio_error in events.jsonl)")
    if fake:
        assert (
            "cannot open the audio output default device: Error querying device -1" in (warnings[0])
        )
    events = [json.loads(line) for line in (tmp_path / "run" / "events.jsonl").open()]
    errors = [e for e in events if e["kind"] == "audio_error"]
    assert len(errors) == 1 and errors[0]["tick"] == 0
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["live"]["audio"]["errors"] == 1


@pytest.mark.parametrize("fake", [False, True], ids=["this-machine", "portaudio-no-device"])
def test_a_show_that_requires_its_sound_is_refused_in_one_line(tmp_path, fake):
    if not fake and machine_has_a_sound_device():
        pytest.skip("this machine has a sound device")
    _, show = files(tmp_path, SHOW.replace("[sounds]", "[sounds]\nrequired = true"))
    done = hilsim_run(tmp_path, show, fake)
    assert done.returncode == 2
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"hilsim run: {show}: ")
    assert lines[0].endswith(
        "([sounds] required = true: the show does not start without its sound)"
    )
    assert not (tmp_path / "run").exists()  # nothing moved, nothing left


def test_the_device_key_reaches_the_output_stream(tmp_path, monkeypatch):
    opened = []

    class Stream:
        latency, time, active = 0.01, 0.0, True

        def __init__(self, **kw):
            opened.append(kw)

        def start(self):
            pass

        def abort(self):
            pass

        def close(self):
            pass

    monkeypatch.setitem(sys.modules, "sounddevice", types.SimpleNamespace(OutputStream=Stream))
    rig, show = files(tmp_path, SHOW.replace("[sounds]", '[sounds]\ndevice = "USB Audio"'))
    notes: list[str] = []
    with hilsim.Show(rig, show=show, duration=0.1, out=tmp_path / "run", on_note=notes.append):
        pass  # entering opens the inputs, the sound output among them
    assert opened[0]["device"] == "USB Audio"
    assert any(n.startswith("audio out: USB Audio, 8000 Hz") for n in notes)


@pytest.mark.parametrize(
    ("line", "words"),
    [
        ("device = true", "sounds.device: an output device's name or index (hilsim sounds"),
        ("device = -1", "sounds.device: an output device's name or index"),
        ('required = "yes"', "sounds.required: true or false, got 'yes'"),
    ],
)
def test_a_bad_sound_setting_is_one_line(tmp_path, line, words):
    rig, show = files(tmp_path, SHOW.replace("[sounds]", f"[sounds]\n{line}"))
    with pytest.raises(hilsim.RigError, match=words.replace("(", r"\(").replace(".", r"\.")):
        hilsim.Show(rig, show=show, virtual_time=True)


def sd_with(devices: list[dict], default: tuple[int, int]) -> types.SimpleNamespace:
    return types.SimpleNamespace(
        query_devices=lambda: devices, default=types.SimpleNamespace(device=default)
    )


def test_hilsim_sounds_lists_the_outputs_and_marks_the_default(monkeypatch, capsys):
    devices = [
        {"name": "Mic", "max_output_channels": 0, "default_samplerate": 48000.0},
        {"name": "bcm2835 Headphones", "max_output_channels": 2, "default_samplerate": 44100.0},
        {"name": "USB Audio", "max_output_channels": 2, "default_samplerate": 48000.0},
    ]
    monkeypatch.setitem(sys.modules, "sounddevice", sd_with(devices, (0, 2)))
    assert main(["sounds"]) == 0
    out = capsys.readouterr()
    assert out.out.splitlines() == [
        "  1  bcm2835 Headphones  2 ch, 44100 Hz",
        "  2  USB Audio  2 ch, 48000 Hz  (default)",
    ]
    assert '[sounds] device = "<name>" or <index>' in out.err


def test_hilsim_sounds_without_a_device_or_the_extra_is_one_line(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "sounddevice", sd_with([], (-1, -1)))
    assert main(["sounds", "--list"]) == 1
    assert capsys.readouterr().err.startswith("hilsim sounds: no sound output device found")
    monkeypatch.setitem(sys.modules, "sounddevice", None)
    assert main(["sounds"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == ["hilsim sounds: sounds need the optional package sounddevice: pip install "
                   "'hilsim[live]'"]  # fmt: skip
