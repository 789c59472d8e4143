"""The panel without a browser: `hilsim run --panel` end to end, hostile clients, a client
that stops reading, the feed's commands, and Show.release (the stand-in)."""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import os
import select
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

import hilsim
from hilsim.exit_codes import ExitCode
from hilsim.live.controls import Controls
from tests.hilsim.panel_helpers import REPO

websockets = pytest.importorskip(
    "websockets", reason="the panel extra: pip install 'hilsim[panel]'"
)
from websockets.asyncio.client import connect  # noqa: E402

from hilsim.panel.runs import list_runs, run_file  # noqa: E402
from hilsim.panel.server import PanelConfig, PanelServer  # noqa: E402


def _get(url: str, method: str = "GET", headers: dict[str, str] | None = None) -> int:
    req = urllib.request.Request(url, method=method, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=10) as resp:
            return int(resp.status)
    except urllib.error.HTTPError as exc:
        return int(exc.code)


def test_release_hands_a_live_joint_back_and_refuses_an_unknown_one() -> None:
    c = Controls(["a", "b"])
    c.set_joint("a", 10.0)
    c.release("a")
    p = c.poll(0.0)
    assert p.values == {} and p.releases == ["a"]  # the value asked before is dropped too
    c.release()
    assert c.poll(0.0).releases == [None]  # None: every joint
    assert c.poll(0.0).releases == []
    with pytest.raises(KeyError):
        c.release("nope")


def test_a_panel_show_ends_with_its_animation_and_a_released_joint_goes_back(tmp_path) -> None:
    show = hilsim.Show(REPO / "configs/demo.toml", virtual_time=True, controls=True,
                       out=tmp_path / "run")  # fmt: skip
    plain = hilsim.Show(REPO / "configs/demo.toml", virtual_time=True)
    assert show.parts.targets.duration == plain.parts.targets.duration is not None
    director = show.parts.director
    assert director is not None
    track = director.tracks[0]
    show.set_joint("head_pan", 30.0)
    director.tick(0, 0.0, [0.0] * 4)
    assert track.sample(0.0)[0] == pytest.approx(0.5235987755982988)  # live: 30 deg
    show.release("head_pan")
    director.tick(1, 0.004, [0.0] * 4)
    assert track.live is None and track.sample(1.0) == track.inner.sample(1.0)  # the show's
    with show:
        result = show.run()
    assert result.exit_code == ExitCode.OK
    assert result.ticks == plain.parts.targets.duration * show.rig.loop.rate_hz + 1


def test_past_runs_list_their_plots_and_serve_nothing_else(tmp_path: Path) -> None:
    run = tmp_path / "demo-1"
    (run / "plots").mkdir(parents=True)
    (run / "summary.json").write_text('{"exit_code": 0, "exit_reason": "end of show"}')
    (run / "plots" / "joints.png").write_bytes(b"png")
    (run / "plots" / "notes.txt").write_text("not a plot")
    (tmp_path / "elsewhere.png").write_bytes(b"png")
    (run / "plots" / "link.png").symlink_to(tmp_path / "elsewhere.png")
    (tmp_path / "not-a-run").mkdir()
    rows = list_runs(tmp_path, lambda summary, ticks: "healthy?")
    assert [r["name"] for r in rows] == ["demo-1"]
    assert rows[0]["plots"] == ["plots/joints.png"] and rows[0]["verdict"] == "healthy?"
    assert run_file(tmp_path, "demo-1", "plots/joints.png") == (run / "plots/joints.png").resolve()
    for name, file in [("demo-1", "plots/notes.txt"), ("demo-1", "plots/link.png"),
                       ("demo-1", "../elsewhere.png"), ("..", "elsewhere.png"),
                       ("demo-1", "plots/../summary.json"), ("demo-1", "summary.json")]:  # fmt: skip
        assert run_file(tmp_path, name, file) is None, (name, file)


async def _hostile(base: str, token: str) -> dict[str, object]:
    """Every hostile client of the issue, then one good client's STOP."""
    ws_url = base.replace("http://", "ws://") + "/ws?token="
    seen: dict[str, object] = {}
    for bad in ("", "wrong"):
        with pytest.raises(websockets.InvalidStatus) as info:
            async with connect(ws_url + bad, origin=base):
                pass
        assert info.value.response.status_code == 403
    with pytest.raises(websockets.InvalidStatus):
        async with connect(ws_url + token, origin="http://evil.example"):
            pass
    # a flood of connections: the cap (8) holds, the rest are turned away
    flood = []
    for _ in range(20):
        try:
            flood.append(await connect(ws_url + token, origin=base))
        except websockets.InvalidStatus as exc:
            assert exc.response.status_code == 503
    seen["flood_accepted"] = len(flood)
    for ws in flood:
        await ws.close()
    await asyncio.sleep(0.5)
    async with connect(ws_url + token, origin=base, max_size=None) as ws:
        for i in range(10_000):  # malformed: not JSON, wrong types, unknown ops, huge values
            await ws.send(["{", '{"op": "joint", "joint": "jaw", "deg": "x"}',
                           '{"op": "dance"}', "[]", '{"op": "joint", "joint": "jaw"}'][i % 5])  # fmt: skip
        states = 0
        t_end = time.monotonic() + 2.0
        while time.monotonic() < t_end:  # the show goes on: states keep coming
            msg = json.loads(await asyncio.wait_for(ws.recv(), 5))
            states += msg["type"] == "state"
            if msg["type"] == "panel":
                seen["counts"] = msg["counts"]
        seen["states_after_flood"] = states
        await asyncio.sleep(1.2)  # the bucket refills: the STOP is not a flood
        await ws.send(json.dumps({"op": "stop"}))
        async for raw in ws:
            msg = json.loads(raw)
            if msg["type"] == "end":
                seen["end"] = msg
                break
    return seen


def test_hilsim_run_panel_prints_its_url_first_survives_hostile_clients_and_stops_5(
    tmp_path: Path,
) -> None:
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    cmd = [sys.executable, "-m", "hilsim", "run", "configs/demo.toml", "--panel",
           "--panel-bind", "127.0.0.1:0", "--duration", "120", "--out", str(out), "--no-plots"]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stderr is not None
        assert select.select([proc.stderr], [], [], 60)[0]
        first = proc.stderr.readline().strip()
        assert first.startswith("panel: http://127.0.0.1:"), first  # the URL first
        url = first.removeprefix("panel: ")
        base, token = url.split("/?token=")
        assert _get(base + "/") == 403  # no token
        assert _get(f"{base}/?token=nope") == 403
        assert _get(f"{base}/?token={token}", method="POST") == 405  # no state change but GET
        assert _get(f"{base}/?token={token}", headers={"Host": "evil.example:80"}) == 403
        assert _get(f"{base}/?token={token}") == 200
        seen = asyncio.run(_hostile(base, token))
        rest = proc.communicate(timeout=60)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == ExitCode.STOPPED, rest
    assert seen["flood_accepted"] == 8
    assert seen["states_after_flood"] > 20  # >= 20 states a second, after 10 k bad messages
    end = seen["end"]
    assert isinstance(end, dict) and end["exit_code"] == 5
    summary = json.loads((out / "summary.json").read_text())
    assert summary["live"]["live_values"] == 0  # nothing moved that was not asked
    assert summary["exit_reason"].startswith("stopped by the panel's STOP")
    counts = seen["counts"]
    assert isinstance(counts, dict)
    assert counts["malformed"] + counts["flood"] == 10_000  # every bad message counted
    assert counts["token"] >= 3 and counts["origin"] >= 2 and counts["clients"] == 12
    assert "hilsim panel: closed:" in rest and "malformed" in rest
    assert not (out / "panel.json").exists()  # the show is over: nothing to attach to
    kept = json.loads((out / "panel_counts.json").read_text())["counts"]  # in the record too
    assert kept["malformed"] + kept["flood"] == 10_000


class _FakeFeed:
    """A Unix socket that says hello and then sends big states as fast as it may."""

    def __init__(self, path: Path) -> None:
        self.sock = socket.socket(socket.AF_UNIX)
        self.sock.bind(str(path))
        self.sock.listen(1)
        self.stop = threading.Event()
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self) -> None:
        conn, _ = self.sock.accept()
        hello = {"type": "hello", "rig": "x", "joints": [{"name": "j", "min": -1, "max": 1,
                 "servo": 1}], "rate_hz": 100, "exit_policy": "hold", "cues": [], "live": True}  # fmt: skip
        conn.sendall((json.dumps(hello) + "\n").encode())
        k = 0
        while not self.stop.is_set():
            k += 1
            state = {"type": "state", "tick": k, "t": k / 100, "target": [0.0], "cmd": [0.0],
                     "present": [0.0], "status": [0], "pad": "x" * 4000}  # fmt: skip
            conn.sendall((json.dumps(state) + "\n").encode())
            time.sleep(0.005)
        conn.close()


def test_a_browser_that_stops_reading_is_closed_and_the_others_go_on(tmp_path: Path) -> None:
    feed = _FakeFeed(tmp_path / "feed.sock")
    config = PanelConfig(port=0, send_timeout_s=1.0, write_limit=4096)
    server = PanelServer(config, feed=tmp_path / "feed.sock", runs=None)
    loop = asyncio.new_event_loop()
    ready = threading.Event()
    thread = threading.Thread(
        target=lambda: loop.run_until_complete(server.run(lambda _url: ready.set())), daemon=True
    )
    thread.start()
    assert ready.wait(20)
    assert server.address is not None
    host, port = server.address
    # the slow one: a WebSocket handshake by hand, then never a byte read
    slow = socket.socket()
    slow.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    slow.connect((host, port))
    key = base64.b64encode(os.urandom(16)).decode()
    slow.sendall(
        f"GET /ws?token={config.token} HTTP/1.1\r\nHost: {host}:{port}\r\n"
        f"Origin: http://{host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode()
    )

    async def good() -> int:
        n = 0
        async with connect(f"ws://{host}:{port}/ws?token={config.token}",
                           origin=f"http://{host}:{port}", max_size=None) as ws:  # fmt: skip
            t_end = time.monotonic() + 15
            while time.monotonic() < t_end and server.counts["slow"] == 0:
                n += json.loads(await asyncio.wait_for(ws.recv(), 5))["type"] == "state"
            for _ in range(20):  # and after it was closed
                n += json.loads(await asyncio.wait_for(ws.recv(), 5))["type"] == "state"
        return n

    try:
        states = asyncio.run(good())
        assert server.counts["slow"] == 1
        assert states > 20
    finally:
        feed.stop.set()
        loop.call_soon_threadsafe(server.stopped.set)
        thread.join(10)
        with contextlib.suppress(OSError):
            slow.close()
