"""Write sample blender-servo-animation exports into configs/animations/blender_servo/.

The three forms of one 100-frame, 30 fps scene, written the way the add-on (v2.x) lays them
out - ``r53.json``, ``r53.bin``, ``r53.h`` - by this project's own writer (no file of the add-on
is copied). Two servos:

* servo 0, µs (544-2400, the Arduino ``Servo`` library's range; rest 1472): 1472, 1477, ...,
  2106 at frame 15, 2326 at frame 30, 2089 at frame 37, 2045 at frame 38, back to 1472 by frame
  60 and still there to frame 99 (issue 13's worked numbers: with position_min 544,
  position_max 2400, rotation_range 180, neutral_angle 90, the servo angle is 151.487° at
  0.500 s; linear 147.705° at 1.25 s; held 149.838°);
* servo 10, PCA9685 ticks (150-600), whose ID byte and many position bytes are 0x0A (the frame
  end), so a reader that splits on 0x0A instead of reading 5-byte records gets it wrong.

"Skip unchanged positions" is on, as the add-on's default: a servo is left out of a frame whose
position did not change, so many frames are sparse or empty.

    python tools/samples_blender_servo.py [OUTPUT_DIR]
    python tools/samples_blender_servo.py --bench     # time the reader on a long export

Deterministic: rerunning it reproduces the files byte for byte. Tests import its functions.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

FPS = 30
N_FRAMES = 100
SCENE = "Skull"
#: (frame, position) keys of servo 0; positions between keys are linear, rounded to integers
SERVO0_KEYS = [(0, 1472), (1, 1477), (15, 2106), (30, 2326), (37, 2089), (38, 2045), (60, 1472)]
#: servo 10's keys: 266 = 0x010A and 522 = 0x020A put 0x0A inside records
SERVO10_KEYS = [(0, 266), (20, 266), (40, 522), (70, 522), (85, 266)]


def keyed(keys: list[tuple[int, int]], n: int = N_FRAMES) -> list[int]:
    """One integer position per frame, linear between keys, the last key held."""
    f, v = zip(*keys, strict=True)
    return [int(x) for x in np.rint(np.interp(np.arange(n), f, v))]


def sample_positions() -> dict[int, list[int]]:
    """Servo ID -> its position in every frame (before skipping unchanged ones)."""
    return {0: keyed(SERVO0_KEYS), 10: keyed(SERVO10_KEYS)}


def skip_unchanged(per_servo: dict[int, list[int]]) -> list[dict[int, int]]:
    """Frames as the add-on exports them with "skip unchanged positions" on."""
    n = len(next(iter(per_servo.values())))
    frames: list[dict[int, int]] = []
    last: dict[int, int] = {}
    for k in range(n):
        frame = {}
        for sid, values in per_servo.items():
            if last.get(sid) != values[k]:
                frame[sid] = last[sid] = values[k]
        frames.append(frame)
    return frames


def json_bytes(frames: list[dict[int, int]], fps: int = FPS, scene: str = SCENE) -> bytes:
    doc = {
        "description": "Blender Servo Animation Positions",
        "fps": fps,
        "frames": len(frames),
        "seconds": round(len(frames) / fps),
        "bones": len(frames[0]) if frames else 0,
        "file": "sample.blend",
        "scene": scene,
        "positions": [{str(sid): pos for sid, pos in f.items()} for f in frames],
    }
    return json.dumps(doc, indent=2).encode()


def bin_bytes(frames: list[dict[int, int]]) -> bytes:
    """``3C id hi lo 3E`` per position, ``0A`` after each frame."""
    out = bytearray()
    for frame in frames:
        for sid, pos in frame.items():
            out += bytes((0x3C, sid, pos >> 8, pos & 0xFF, 0x3E))
        out.append(0x0A)
    return bytes(out)


def h_bytes(
    frames: list[dict[int, int]], fps: int = FPS, scene: str = SCENE, namespace: bool = True
) -> bytes:
    """The same bytes as a C array, 12 to a line, with FPS, FRAMES and LENGTH."""
    data = bin_bytes(frames)
    rows = "".join(
        "    " + ", ".join(f"{b:#04x}" for b in data[i : i + 12]) + ",\n"
        for i in range(0, len(data), 12)
    )
    text = (
        "/*\n  Blender Servo Animation Positions\n\n"
        f"  FPS: {fps}\n  Frames: {len(frames)}\n  Seconds: {round(len(frames) / fps)}\n"
        f"  Bones: {len(frames[0]) if frames else 0}\n  Scene: {scene}\n"
        "  File: sample.blend\n*/\n\n"
        "#include <Arduino.h>\n"
    )
    if namespace:
        text += f"\nnamespace {scene} {{\n"
    text += (
        f"\nconst byte FPS = {fps};\nconst int FRAMES = {len(frames)};\n"
        f"const int LENGTH = {len(data)};\n\n"
        f"const byte PROGMEM ANIMATION_DATA[LENGTH] = {{\n{rows}}};\n"
    )
    if namespace:
        text += f"\n}} // namespace {scene}\n"
    return text.encode()


def write_samples(out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    frames = skip_unchanged(sample_positions())
    written = []
    for name, data in (
        ("r53.json", json_bytes(frames)),
        ("r53.bin", bin_bytes(frames)),
        ("r53.h", h_bytes(frames)),
    ):
        path = out_dir / name
        path.write_bytes(data)
        written.append(path)
    return written


def bench(repeat: int = 3) -> None:
    """Time the reader on a long export: 16 servos, 10 min at 60 fps (36,000 frames, every servo
    moving), all 16 tracks, each form from bytes in memory; min and median of ``repeat``."""
    import statistics
    import time

    from hilsim.targets.formats.blender_servo import BoneSettings, parse_blender_servo

    n = 60 * 600
    per = {
        sid: [int(x) for x in np.rint(1472 + 500 * np.sin(np.arange(n) / 60 * (0.3 + sid / 10)))]
        for sid in range(16)
    }
    frames = skip_unchanged(per)
    bones = [BoneSettings(sid, 544, 2400, 180, 90) for sid in range(16)]
    forms = {"json": json_bytes(frames, 60), "bin": bin_bytes(frames), "h": h_bytes(frames, 60)}
    for form, data in forms.items():
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            anim = parse_blender_servo(
                data, form, f"bench.{form}", fps=60 if form == "bin" else None
            )
            for bone in bones:
                anim.track_for(bone, angle="bone")
            times.append(time.perf_counter() - t0)
        print(
            f"blender {form:4s}: 16 servos x {n} frames ({len(data) / 1e6:.1f} MB), 16 tracks: "
            f"min {min(times) * 1e3:.0f} ms, median {statistics.median(times) * 1e3:.0f} ms"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parent.parent / "configs" / "animations" / "blender_servo"
    parser.add_argument("out_dir", nargs="?", type=Path, default=default)
    parser.add_argument("--bench", action="store_true", help="time the reader, write nothing")
    args = parser.parse_args()
    if args.bench:
        bench()
        return
    for path in write_samples(args.out_dir):
        print(f"{path} ({path.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
