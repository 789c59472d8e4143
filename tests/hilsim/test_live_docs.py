"""docs/live.md's input examples are shows hilsim loads: every key they name exists, with the
value shown (an unknown key or a bad value is refused by the show file's reader)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from hilsim.live.showfile import load_show
from hilsim.rig import load_rig

REPO = Path(__file__).resolve().parents[2]
LIVE_MD = (REPO / "docs" / "live.md").read_text(encoding="utf-8")
SECTIONS = ("inputs.", "teach")
RIG = """
name = "docs"
[bus]
port = "dxlsim://?ids=1-2&rdt_us=0&latency_ms=1"
[[joints]]
name = "head_pan"
servo_id = 1
min_deg = -60
max_deg = 60
spring = { frequency_hz = 4.0, damping_ratio = 1.0, response = 0.0 }
target = { type = "hold", value_deg = 0 }
[[joints]]
name = "jaw"
servo_id = 2
min_deg = 0
max_deg = 30
spring = { frequency_hz = 4.0, damping_ratio = 1.0, response = 0.0 }
target = { type = "hold", value_deg = 0 }
"""


def _examples() -> list[str]:
    blocks = re.findall(r"```toml\n(.*?)```", LIVE_MD, flags=re.S)
    return [b for b in blocks if any(b.lstrip().startswith(f"[{s}") for s in SECTIONS)]


def test_the_inputs_each_have_an_example():
    heads = {b.lstrip().split("]", 1)[0][1:] for b in _examples()}
    assert {"inputs.sacn", "inputs.multisync", "inputs.osc"} <= heads  # Art-Net: sACN's keys
    assert {"inputs.midi", "inputs.mtc", "inputs.gamepad", "inputs.bottango", "teach"} <= heads


@pytest.mark.parametrize("block", _examples(), ids=lambda b: b.lstrip().split("]", 1)[0][1:])
def test_each_example_loads_as_written(tmp_path, block):
    (tmp_path / "rig.toml").write_text(RIG)
    blocks = [block]
    if block.lstrip().startswith("[inputs.sacn]"):  # "[inputs.artnet] takes the same keys"
        artnet = block.replace("inputs.sacn", "inputs.artnet").replace("port = 5568", "port = 6454")
        artnet = re.sub(r"\nmulticast = true[^\n]*", "", artnet)
        artnet = artnet.replace("# broadcast = true", "broadcast = true")
        blocks.append(artnet)
    if block.lstrip().startswith("[inputs.ltc]"):  # the file it names, as the docs make it
        import wave

        with wave.open(str(tmp_path / "show_ltc.wav"), "wb") as w:
            w.setnchannels(1), w.setsampwidth(2), w.setframerate(48000)
            w.writeframes(b"\0\0" * 4800)
    for i, text in enumerate(blocks):
        (tmp_path / f"show{i}.toml").write_text(text)
        spec = load_show(tmp_path / f"show{i}.toml", load_rig(tmp_path / "rig.toml"),
                         lambda *a: None)  # fmt: skip
        assert spec is not None
