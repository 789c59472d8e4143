"""Write small Bottango export samples, the same animations in all three forms, written by
hilsim from Bottango's published command format (not copied from any Bottango file):

    configs/animations/bottango/GeneratedCodeAnimations.cpp   generated code
    configs/animations/bottango/sd/anims/...                   SD-card files
    configs/animations/bottango/commands.json                  JSON (array of command strings)

Animation 0 ("Talk") is issue 13's acceptance curve on pin servo 0 (1000-2000 µs) plus an I2C
servo (address 64, pin 3 -> effector "643"); it plays when input 10 goes HIGH, no loop.
Animation 1 ("Idle") is the idle animation: an instant move, a slow sway and an on/off event
(skipped by the reader). The tests import :func:`write_code`, :func:`write_sd` and
:func:`write_json` to build their own fixtures.

    python tools/samples_bottango.py [OUT_DIR]
    python tools/samples_bottango.py --bench     # reader and track timing
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

OUT = Path(__file__).resolve().parent.parent / "configs" / "animations" / "bottango"


@dataclass
class Anim:
    name: str
    data: list[str]
    config: tuple[int, ...] = (0, 0, 0, 0, 0, 0, 0, 0)
    loop: list[str] = field(default_factory=list)


SETUP = [
    "rSVPin,0,1000,2000,3000,1500",
    "rSVI2C,64,3,2000,1000,3000,1500",
    "rECOnOff,lamp,0,12",
]
ANIMS = [
    Anim(
        "Talk",
        [
            "sC,0,0,2000,4096,513,0,7110,-763,814",
            "sC,643,0,1500,0,400,0,8192,-400,0",
            "sC,0,2000,1000,7110,331,-354,2277,-331,931",
            "sC,643,2500,500,8192,100,0,4096,-100,0",
        ],
        (0, 0, 0, 10, 0, 1, 0, 0),
    ),
    Anim(
        "Idle",
        ["sCI,0,4096", "sCO,lamp,0,1", "sC,0,500,3000,4096,1000,800,4096,-1000,800"],
        (0, 0, 1, 0, 1, 0, 0, 0),
        loop=["sC,0,0,200,4096,50,0,4096,-50,0"],
    ),
]


def _c_literals(text: str, width: int) -> str:
    """``text`` as adjacent C string literals of at most ``width`` characters each (split
    anywhere, also inside a command), one per line, escaped."""
    esc = text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
    units, i = [], 0
    while i < len(esc):
        n = 2 if esc[i] == "\\" else 1
        units.append(esc[i : i + n])
        i += n
    chunks, cur = [], ""
    for u in units:
        if len(cur) + len(u) > width:
            chunks.append(cur)
            cur = ""
        cur += u
    chunks.append(cur)
    return "\n\t\t".join(f'"{c}"' for c in chunks)


def code_text(setup: list[str], anims: list[Anim], split: int = 2, width: int = 48) -> str:
    """Generated-code form: each animation's data in ``split`` DATA arrays (cut inside a
    command on purpose), each array as several literals over several lines."""
    out = [
        "// GENERATED CODE (a hilsim sample in Bottango's export layout)",
        "// Animation Index Key:",
        *(f"// {i}: {a.name}" for i, a in enumerate(anims)),
        '#include "GeneratedCodeAnimations.h"',
        "namespace GeneratedCodeAnimations",
        "{",
        "\t// setup",
        f"\tconst char SETUP_DATA_0[] PROGMEM = {_c_literals(''.join(s + chr(10) for s in setup), width)};",  # noqa: E501
        "\tconst char* const SETUP_DATAARRAY[] PROGMEM = { SETUP_DATA_0 };",
    ]
    for i, a in enumerate(anims):
        stream = "".join(c + "\n" for c in a.data)
        cut = [round(len(stream) * k / split) for k in range(split + 1)]
        out += ["", f'\t// animation {i}, "{a.name}"']
        for k in range(split):
            lit = _c_literals(stream[cut[k] : cut[k + 1]], width)
            out.append(f"\tconst char ANIM_{i}_DATA{k}[] PROGMEM = {lit};")
        names = ", ".join(f"ANIM_{i}_DATA{k}" for k in range(split))
        out.append(f"\tconst char* const ANIM_{i}_DATAARRAY[] PROGMEM = {{ {names} }};")
        loop = _c_literals("".join(c + "\n" for c in a.loop), width)
        out.append(f"\tconst char ANIM_{i}_LOOP[] PROGMEM = {loop};")
        cfg = ", ".join(str(v) for v in a.config)
        out.append(f"\tconst uint16_t ANIM_{i}_CONFIG[] PROGMEM = {{ {cfg} }};")
    out += ["\t/* CommandStream* unused() { return nullptr; } */", "}", ""]
    return "\n".join(out)


def write_code(path: Path, setup: list[str] = SETUP, anims: list[Anim] = ANIMS, **kw) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(code_text(setup, anims, **kw), encoding="utf-8")
    return path


def write_sd(root: Path, setup: list[str] = SETUP, anims: list[Anim] = ANIMS) -> Path:
    """SD-card form under ``root/anims/`` (with comment lines and CRLF in the config)."""
    names = ("playOnStart", "loopOnStart", "idleAnim", "playOnPin", "loop", "playOnPinHigh",
             "buttonLadderMin", "buttonLadderMax")  # fmt: skip
    (root / "anims" / "setup").mkdir(parents=True, exist_ok=True)
    (root / "anims" / "setup" / "data.txt").write_text("".join(s + "\n" for s in setup))
    for i, a in enumerate(anims):
        d = root / "anims" / str(i)
        d.mkdir(parents=True, exist_ok=True)
        (d / "data.txt").write_text("".join(c + "\n" for c in a.data))
        (d / "loop.txt").write_text("".join(c + "\n" for c in a.loop))
        cfg = "".join(f"/ {n}\r\n{v}\r\n" for n, v in zip(names, a.config, strict=True))
        (d / "config.txt").write_bytes(f"/ animation {i}: {a.name}\r\n{cfg}".encode())
    return root


def write_json(
    path: Path, setup: list[str] = SETUP, anims: list[Anim] = ANIMS, flat: bool = False
) -> Path:
    """JSON form: an object with ``setup`` and ``animations`` (name, commands, loop,
    config); with ``flat``, the documented bare array of command strings (setup, then the
    first animation's commands: no name, loop or config)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if flat:
        doc: object = [*setup, *anims[0].data]
    else:
        doc = {
            "setup": setup,
            "animations": [
                {"name": a.name, "commands": a.data, "loop": a.loop, "config": list(a.config)}
                for a in anims
            ],
        }
    path.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return path


def bench(repeats: int = 5) -> None:
    """Time the reader and the track: parse a long export (issue 13 has no figure for it;
    this prints ours) and sample one effector's track as the tick does."""
    import tempfile

    from hilsim.targets.formats.bottango import read_export
    from hilsim.targets.formats.common import UnitMap

    # 10 effectors x 1 h of 1 s segments = 36,000 sC commands
    data, y = [], dict.fromkeys(range(10), 4096)
    for k in range(3600):
        for e in range(10):
            y1 = (y[e] + 1500 * (1 + (k + e) % 4)) % 8193
            data.append(f"sC,{e},{k * 1000},1000,{y[e]},300,200,{y1},-300,-200")
            y[e] = y1
    setup = [f"rSVPin,{e},1000,2000,3000,1500" for e in range(10)]
    with tempfile.TemporaryDirectory() as tmp:
        paths = {
            "code": write_code(
                Path(tmp) / "g.cpp", setup, [Anim("long", data)], split=8, width=400
            ),
            "sd": write_sd(Path(tmp) / "card", setup, [Anim("long", data)]),
            "json": write_json(Path(tmp) / "e.json", setup, [Anim("long", data)]),
        }
        for form, path in paths.items():
            best = min(_timed(lambda p=path: read_export(p)) for _ in range(repeats))
            print(f"read {form:4s}: {len(data)} sC commands in {best * 1e3:.0f} ms (best of 5)")
        track = read_export(paths["code"]).track(0, "3", signal=UnitMap((1000, 2000), (0, 40)))
    ts = [i * 0.004 for i in range(25_000)]  # 100 s at 250 Hz
    per = min(_timed(lambda: [track.sample(t) for t in ts]) for _ in range(repeats)) / len(ts)
    print(f"BezierTrack.sample: {per * 1e6:.2f} us per call (best of {repeats}, {len(ts)} calls)")
    from hilsim.targets.formats.common import SampledTrack

    ref = SampledTrack(
        [i * 0.1 for i in range(36_000)], [0.001 * i for i in range(36_000)], "linear"
    )
    per = min(_timed(lambda: [ref.sample(t) for t in ts]) for _ in range(repeats)) / len(ts)
    print(
        f"for reference, SampledTrack.sample (linear, 36000 samples): {per * 1e6:.2f} us per call"
    )


def _timed(fn) -> float:
    import time

    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main(out: Path = OUT) -> None:
    write_code(out / "GeneratedCodeAnimations.cpp")
    write_sd(out / "sd")
    write_json(out / "commands.json")
    print(f"wrote {out}/GeneratedCodeAnimations.cpp, sd/anims/, commands.json")


if __name__ == "__main__":
    if sys.argv[1:] == ["--bench"]:
        bench()
    else:
        main(Path(sys.argv[1]) if len(sys.argv) > 1 else OUT)
