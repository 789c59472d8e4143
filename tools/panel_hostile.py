"""The panel's hostile clients against a real-clock demo, then a plain demo: lateness side by side.

    python tools/panel_hostile.py [--rounds 3]

Each round runs ``hilsim run configs/demo.toml --panel`` and drives the hostile clients of
``tests/hilsim/test_panel.py`` (bad tokens, a foreign Origin, 20 connections against a cap of
8, 10,000 malformed messages, then STOP), then a plain 4 s demo; it prints each run's
lateness p99 / max, overruns and host stalls from its summary.json (docs/performance.md).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import select
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.hilsim.test_panel import _hostile  # noqa: E402


def _line(name: str, run: Path) -> str:
    s = json.loads((run / "summary.json").read_text())
    lat, stalls = s["lateness_us"], s["loop"]["host_stalls"]["count"]
    return (
        f"{name:14s} {s['ticks']:5d} ticks  p99 {lat['p99']:7.0f} us  max {lat['max']:7.0f} us  "
        f"overruns {s['overruns']:3d}  host stalls {stalls:3d}  exit {s['exit_code']}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    base_cmd = [sys.executable, "-m", "hilsim", "run", "configs/demo.toml", "--no-plots"]
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.rounds):
            out = Path(tmp) / f"panel{k}"
            cmd = [*base_cmd, "--panel", "--panel-bind", "127.0.0.1:0", "--duration", "120"]
            proc = subprocess.Popen(
                [*cmd, "--out", str(out)], cwd=REPO, stderr=subprocess.PIPE, text=True
            )
            assert proc.stderr is not None
            select.select([proc.stderr], [], [], 60)
            url = proc.stderr.readline().strip().removeprefix("panel: ")
            base, token = url.split("/?token=")
            seen = asyncio.run(_hostile(base, token))
            proc.communicate(timeout=60)
            print(_line("panel+hostile", out), " counted", seen["counts"], flush=True)
            plain = Path(tmp) / f"plain{k}"
            subprocess.run(
                [*base_cmd, "--duration", "4", "--out", str(plain)],
                cwd=REPO,
                capture_output=True,
                check=False,
            )
            print(_line("plain", plain), flush=True)


if __name__ == "__main__":
    main()
