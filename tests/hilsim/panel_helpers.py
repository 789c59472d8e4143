"""What the panel's tests share: a real-clock demo show on a traced emulated bus, its feed,
and a `hilsim panel` process attached to it."""

from __future__ import annotations

import contextlib
import os
import select
import subprocess
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import hilsim
from drivers.dxlsim import DxlBus
from drivers.dxlsim.url import bus_from_url, register_bus, unregister_bus
from hilsim.show.feed import PanelFeed

REPO = Path(__file__).resolve().parents[2]
DEMO_URL = "dxlsim://?ids=1-4&model=XM430-W350&rdt_us=0&latency_ms=1&clock=real&trace=1"


def demo_show_file(tmp_path: Path) -> Path:
    """The demo show (clips, idle, the scare cue) with no network input of its own."""
    text = (REPO / "configs/shows/demo_show.toml").read_text()
    text = text[: text.index("[inputs.osc]")]
    text = text.replace('trigger = ["osc:/hilsim/cue/scare", "key:s", "every:45"]', "trigger = []")
    path = tmp_path / "show.toml"
    path.write_text(text)
    return path


@dataclass
class LiveShow:
    show: hilsim.Show
    emu: DxlBus
    thread: threading.Thread
    feed: PanelFeed
    run_dir: Path


@contextlib.contextmanager
def live_demo(tmp_path: Path, name: str, *, duration: float = 60.0) -> Iterator[LiveShow]:
    """The demo figure's show in real time on a traced emulator, running in a thread, with
    its panel feed; stopped (exit policy) on the way out."""
    emu = bus_from_url(DEMO_URL)
    rig_text = (REPO / "configs/demo.toml").read_text()
    port_line = next(line for line in rig_text.splitlines() if line.startswith("port ="))
    rig = tmp_path / "demo.toml"
    text = rig_text.replace(port_line, f'port = "dxlsim://{name}"')
    text = text.replace('"demo_animation.csv"', f'"{REPO / "configs/demo_animation.csv"}"')
    # the machine running the tests is shared: a stall of a few hundred ms must not end the
    # show (the Bus Watchdog and the comm budget are the figure's business, not the panel's)
    text = text.replace("watchdog_ms = 100", "watchdog_ms = 1000")
    text = text.replace("comm_failure_budget_ms = 100", "comm_failure_budget_ms = 500")
    rig.write_text(text)
    register_bus(name, emu)
    run_dir = tmp_path / "runs" / "demo-1"
    run_dir.parent.mkdir()
    show = hilsim.Show(rig, show=demo_show_file(tmp_path), duration=duration, out=run_dir)
    try:
        with show:
            feed = PanelFeed(show)
            feed.start()
            thread = threading.Thread(target=show.run, daemon=True)
            thread.start()
            try:
                yield LiveShow(show, emu, thread, feed, run_dir)
            finally:
                show.stop()
                thread.join(30)
                feed.close()
    finally:
        unregister_bus(name)


@contextlib.contextmanager
def panel_process(run_dir: Path, *extra: str) -> Iterator[tuple[str, subprocess.Popen[bytes]]]:
    """`hilsim panel RUN_DIR --bind 127.0.0.1:0`: its URL and the process."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    cmd = [sys.executable, "-m", "hilsim", "panel", str(run_dir), "--bind", "127.0.0.1:0"]
    proc = subprocess.Popen(
        [*cmd, *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=REPO
    )
    try:
        assert proc.stdout is not None
        assert select.select([proc.stdout], [], [], 60)[0], "the panel did not start"
        line = proc.stdout.readline().decode().strip()
        assert line.startswith("panel: http://127.0.0.1:"), line
        yield line.removeprefix("panel: "), proc
    finally:
        if proc.poll() is None:
            proc.terminate()
        proc.wait(10)
