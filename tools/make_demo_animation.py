"""Write configs/demo_animation.csv: 20 s of a small figure's show, in degrees, every 50 ms.

Deterministic (no randomness beyond a fixed seed), so rerunning it reproduces the file byte for
byte. The figure looks left, then right, talks, nods and wags its tail; it starts and ends at rest
in its zero pose, and stays well inside the demo rig's limits (configs/demo.toml) and speed limits
(under 100 deg/s for the head, about 210 deg/s at most for the jaw and tail).

    python tools/make_demo_animation.py [OUTPUT]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

DT_S = 0.05
DURATION_S = 20.0
JOINTS = ("head_pan", "head_tilt", "jaw", "tail")


def eased(t: np.ndarray, keys: list[tuple[float, float]]) -> np.ndarray:
    """Pose-to-pose motion: hold each key, move between keys with smoothstep (rest at every key)."""
    times = np.array([k[0] for k in keys])
    values = np.array([k[1] for k in keys])
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(keys) - 2)
    u = np.clip((t - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0)
    return values[i] + (values[i + 1] - values[i]) * u * u * (3.0 - 2.0 * u)


def window(t: np.ndarray, start: float, end: float, ramp: float) -> np.ndarray:
    """1 inside [start, end], 0 outside, smoothstep ramps of ``ramp`` seconds inside the edges."""
    up = np.clip((t - start) / ramp, 0.0, 1.0)
    down = np.clip((end - t) / ramp, 0.0, 1.0)
    return up * up * (3 - 2 * up) * down * down * (3 - 2 * down)


def talk(t: np.ndarray, bursts: list[tuple[float, float]], rng: np.random.Generator) -> np.ndarray:
    """Jaw openings: one sin² pulse per syllable (0.25–0.4 s, 8–20 deg), in bursts of speech."""
    jaw = np.zeros_like(t)
    for start, end in bursts:
        s = start
        while True:
            length = rng.uniform(0.25, 0.4)
            if s + length > end:
                break
            x = (t - s) / length
            inside = (x >= 0.0) & (x <= 1.0)
            jaw[inside] += rng.uniform(8.0, 20.0) * np.sin(np.pi * x[inside]) ** 2
            s += length + rng.uniform(0.0, 0.12)  # a short gap between some syllables
    return jaw


def make(rng_seed: int = 7) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    t = np.round(np.arange(0.0, DURATION_S + DT_S / 2, DT_S), 6)
    rng = np.random.default_rng(rng_seed)
    pan = eased(
        t,
        [(0.0, 0.0), (1.0, 0.0), (2.5, -35.0), (4.0, -35.0), (5.5, 35.0), (7.0, 35.0), (8.0, 0.0),
         (14.0, 0.0), (14.5, 15.0), (15.5, 15.0), (16.0, 0.0), (20.0, 0.0)],
    )  # fmt: skip
    tilt = eased(
        t,
        [(0.0, 0.0), (2.5, -5.0), (4.0, -5.0), (5.5, 3.0), (8.0, 0.0), (9.0, 0.0),
         (9.35, -18.0), (9.7, 4.0), (10.05, -15.0), (10.4, 3.0), (10.75, -10.0), (11.1, 0.0),
         (16.0, 0.0), (16.8, 10.0), (18.0, 10.0), (19.0, 0.0), (20.0, 0.0)],
    )  # fmt: skip
    jaw = talk(t, [(2.0, 4.5), (11.5, 14.5), (17.0, 18.5)], rng)
    idle = 6.0 * np.sin(2 * np.pi * 0.25 * t) * window(t, 0.0, DURATION_S, 1.0)
    wag = 25.0 * np.sin(2 * np.pi * 1.2 * (t - 7.5)) * window(t, 7.5, 12.5, 0.8)
    tail = idle + wag
    return t, {"head_pan": pan, "head_tilt": tilt, "jaw": jaw, "tail": tail}


def main(argv: list[str] | None = None) -> int:
    root = Path(__file__).resolve().parent.parent
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", nargs="?", type=Path, default=root / "configs/demo_animation.csv")
    args = parser.parse_args(argv)
    t, cols = make()
    lines = ["time_s," + ",".join(JOINTS)]
    for i, ti in enumerate(t):
        cells = [f"{ti:.2f}"] + [
            f"{cols[name][i]:.3f}".replace("-0.000", "0.000") for name in JOINTS
        ]
        lines.append(",".join(cells))
    args.output.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"wrote {args.output} ({len(t)} rows, {t[-1]:g} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
