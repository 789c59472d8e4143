"""The show's side of the browser panel: a state feed and a command inbox on a local socket.

The panel's web server (``hilsim panel``, :mod:`hilsim.panel`) runs in a process of its own,
so browsers, floods and slow clients never share this process's time. What stays here is one
thread, :class:`PanelFeed`, on a Unix socket that only this user can open (a 0700 directory),
whose path is written to ``<run_dir>/panel.json``:

* **out**, newline-separated JSON: ``hello`` once (the rig, joints and limits, cues, exit
  policy), ``state`` ``rate_hz`` times a second (every joint's target, commanded and present
  position in degrees, each servo's read status, which joints are live, the run's facts), and
  ``end`` once the show has ended (exit code, reason, exit policy);
* **in**, one JSON object a line: ``{"op": "cue", "name"}``, ``{"op": "joint", "joint", "deg"}``,
  ``{"op": "release", "joint": name | null}``, ``{"op": "stop", "who"}``. Each goes through
  :class:`~hilsim.show.api.Show` (``cue``, ``set_joint``, ``release``, ``stop``): a value
  reaches a servo only through its spring and the safety filter. A refused one gets a
  ``reply`` line; a malformed one is dropped and counted.

The loop does no work for the feed: the thread copies the loop's own arrays (a snapshot may mix
two ticks; it is a display). It runs SCHED_OTHER (never the loop's SCHED_FIFO), not niced: a
STOP arrives this way. A client that stops reading loses states (counted ``slow``), never
blocks the thread. Measured cost: ``docs/performance.md``.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import selectors
import socket
import tempfile
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hilsim.show.end import ShowResult

if TYPE_CHECKING:
    from hilsim.show.api import Show
    from hilsim.show.loop import HilLoop

__all__ = ["FEED_FILE", "PanelFeed"]

FEED_FILE = "panel.json"  # in the run directory: where the socket is, whose it is
MAX_LINE = 4096  # a command line longer than this is dropped (counted ``oversized``)
MAX_OUT = 256 * 1024  # bytes queued to a client that does not read: then states are skipped
MAX_CLIENTS = 4


def _deg(values: list[float]) -> list[float | None]:
    """Radians -> degrees rounded for display; NaN (no reading) -> None (JSON has no NaN)."""
    return [round(math.degrees(v), 3) if v == v else None for v in values]


class _Client:
    __slots__ = ("inbuf", "outbuf", "sock")

    def __init__(self, sock: socket.socket) -> None:
        self.sock, self.inbuf, self.outbuf = sock, b"", b""


class PanelFeed:
    """The feed thread for ``show`` (open, so its run directory exists). :meth:`start` binds
    the socket and writes ``panel.json``; :meth:`close` sends what is queued and ends it.

    ``counts``: commands applied, refused, malformed, oversized; states skipped for slow
    clients; clients turned away at the cap."""

    def __init__(self, show: Show, *, run_dir: Path | None = None, rate_hz: float = 25.0) -> None:
        if not (math.isfinite(rate_hz) and 1.0 <= rate_hz <= 200.0):
            raise ValueError(f"rate_hz = {rate_hz!r}: states a second, 1..200")
        self.show, self.period_s = show, 1.0 / rate_hz
        #: the show's run directory (before the show is open: the one it will use)
        self.run_dir = run_dir if run_dir is not None else show.run_dir
        self.counts = dict.fromkeys(
            ("commands", "refused", "malformed", "oversized", "slow", "turned_away", "internal"), 0
        )
        self._dir: Path | None = None
        self.socket_path: Path | None = None
        self._listener: socket.socket | None = None
        self._clients: dict[int, _Client] = {}
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None
        self._hello = b""
        self._end_sent = False
        self._n = 0
        self._sel = selectors.DefaultSelector()
        #: when the first stop command was handed to the show (``time.perf_counter``)
        self.stop_at: float | None = None

    # ------------------------------------------------------------------ life cycle
    def start(self, *, write_info: bool = True) -> Path:
        """Bind, start the thread, write ``<run_dir>/panel.json`` (``write_info``; else call
        :meth:`write_info` once the show is open: a run directory must be empty until then).
        Returns the socket path."""
        if self.run_dir is None:
            raise RuntimeError("open the show first, or name its run directory")
        self._dir = Path(tempfile.mkdtemp(prefix="hilsim-panel-"))  # 0700: this user only
        self.socket_path = self._dir / "feed.sock"
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        listener.bind(str(self.socket_path))
        listener.listen(MAX_CLIENTS)
        listener.setblocking(False)
        self._listener = listener
        self._hello = self._line(self._hello_msg())
        self._thread = threading.Thread(target=self._run, name="panel-feed", daemon=True)
        self._thread.start()
        if write_info:
            self.write_info()
        return self.socket_path

    def write_info(self) -> None:
        """``<run_dir>/panel.json``: the socket and this process, for ``hilsim panel``."""
        assert self.run_dir is not None and self.socket_path is not None
        info = {"socket": str(self.socket_path), "pid": os.getpid(), "rig": self.show.rig.name}
        (self.run_dir / FEED_FILE).write_text(json.dumps(info) + "\n", encoding="utf-8")

    def close(self, timeout_s: float = 1.0) -> None:
        """Send the end (if the show has one) and what is queued, then stop. Safe twice."""
        self._closing.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        if self._listener is not None:
            self._listener.close()
        for client in self._clients.values():
            client.sock.close()
        self._clients.clear()
        if self.socket_path is not None and self._dir is not None:
            with contextlib.suppress(OSError):
                self.socket_path.unlink()
                self._dir.rmdir()
        if self.run_dir is not None:
            with contextlib.suppress(OSError):
                (self.run_dir / FEED_FILE).unlink()

    # ------------------------------------------------------------------ messages
    @staticmethod
    def _line(msg: dict[str, Any]) -> bytes:
        return (json.dumps(msg, separators=(",", ":"), allow_nan=False) + "\n").encode()

    def _hello_msg(self) -> dict[str, Any]:
        show, rig = self.show, self.show.rig
        director = show.parts.director
        cues: list[str] = []
        if director is not None and director.runtime is not None:
            cues = sorted(director.runtime.spec.cues)
        return {
            "type": "hello",
            "rig": rig.name,
            "joints": [
                {
                    "name": j.name,
                    "min": round(math.degrees(j.min_rad), 3),
                    "max": round(math.degrees(j.max_rad), 3),
                    "servo": j.servo_id,
                }
                for j in rig.joints
            ],
            "rate_hz": rig.loop.rate_hz,
            "exit_policy": str(rig.safety.exit_policy),
            "cues": cues,
            "live": director is not None,
            "run_dir": str(self.run_dir),
            "virtual": show.virtual_time,
            "pid": os.getpid(),
        }

    def _state_msg(self, loop: HilLoop) -> dict[str, Any]:
        rec = loop.rec
        msg: dict[str, Any] = {
            "type": "state",
            "tick": int(rec.tick),
            "t": round(float(rec.t_sched), 4),
            "target": _deg(loop.u.tolist()),
            "cmd": _deg(loop.cmd.tolist()),
            "present": _deg(loop.present.tolist()),
            "status": loop.reading.status.tolist(),
        }
        director = loop.director
        if director is not None:
            msg["live"] = [tr.live is not None for tr in director.tracks]
        self._n += 1
        if self._n % 5 == 1:  # the run's facts, five times a second
            k = int(rec.tick)
            recent = loop.recent_lateness_us  # lateness of the last ticks (us)
            recent = recent[: min(k, len(recent))]
            stop = loop.stop
            # each servo's temperature, voltage, load (or current) and their ages (s)
            msg["condition"] = loop.watch.condition.views(loop.clock.now())
            msg["facts"] = {
                "overruns": loop.overruns,
                "comm_errors": loop.watch.comm_errors,
                "host_stalls": loop.stalls.count,
                "lateness_p99_us": (round(float(np.percentile(recent, 99)), 1) if k else None),
                "playing": None if director is None else director.now_playing,
                "stopping": stop.command
                if stop.command is not None
                else (None if stop.signum is None else f"signal {stop.signum}"),
            }
        return msg

    @staticmethod
    def _end_msg(result: ShowResult) -> dict[str, Any]:
        return {
            "type": "end",
            "exit_code": result.exit_code,
            "reason": result.reason,
            "exit_policy": result.exit_policy,
            "ticks": result.ticks,
        }

    # ------------------------------------------------------------------ commands
    def _apply(self, raw: bytes) -> dict[str, Any] | None:
        """One command line -> None (applied) or a reply saying why not."""
        try:
            cmd = json.loads(raw)
            op = cmd["op"]
        except (ValueError, TypeError, KeyError):
            self.counts["malformed"] += 1
            return None
        show = self.show
        try:
            if op == "cue":
                show.cue(str(cmd["name"]))
            elif op == "joint":
                deg = cmd["deg"]
                if isinstance(deg, bool) or not isinstance(deg, int | float):
                    raise ValueError("deg: a number of degrees")
                show.set_joint(str(cmd["joint"]), float(deg))
            elif op == "release":
                joint = cmd.get("joint")
                show.release(None if joint is None else str(joint))
            elif op == "stop":
                show.stop(what=str(cmd.get("who") or "the panel's STOP")[:80])
                if self.stop_at is None:
                    self.stop_at = time.perf_counter()
            else:
                self.counts["malformed"] += 1
                return None
        except (KeyError, ValueError, TypeError, RuntimeError) as exc:
            self.counts["refused"] += 1
            text = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
            return {"type": "reply", "op": str(op)[:20], "ok": False, "error": str(text)[:200]}
        self.counts["commands"] += 1
        return None

    # ------------------------------------------------------------------ the thread
    def _run(self) -> None:
        # A thread inherits its creator's policy: never SCHED_FIFO beside the loop. Not niced
        # either: a STOP comes this way, and a nice 19 thread waits for the CPU under load.
        with contextlib.suppress(AttributeError, OSError):
            if os.sched_getscheduler(0) != os.SCHED_OTHER:
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        assert self._listener is not None
        self._sel.register(self._listener, selectors.EVENT_READ, None)
        try:
            self._serve()
        finally:
            self._sel.close()

    def _serve(self) -> None:
        next_state = time.monotonic()
        while True:
            closing = self._closing.is_set()
            result = self.show.result
            if result is not None and not self._end_sent:
                self._broadcast(self._line(self._end_msg(result)), always=True)
                self._end_sent = True
            elif closing:
                self._flush_all()
                return
            now = time.monotonic()
            if now >= next_state:
                next_state = max(next_state + self.period_s, now)
                loop = self.show.loop
                if loop is not None and result is None and self._clients:
                    try:
                        line = self._line(self._state_msg(loop))
                    except Exception:  # a bug here must not end the feed (nor the show)
                        self.counts["internal"] += 1
                    else:
                        self._broadcast(line)
            timeout = max(0.0, min(next_state - time.monotonic(), 0.05))
            for key, mask in self._sel.select(timeout):
                if key.data is None:
                    self._accept()
                elif mask & selectors.EVENT_READ:
                    self._read(key.data)
                elif mask & selectors.EVENT_WRITE:
                    self._send(key.data)

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            sock, _ = self._listener.accept()
        except OSError:
            return
        if len(self._clients) >= MAX_CLIENTS:
            self.counts["turned_away"] += 1
            sock.close()
            return
        sock.setblocking(False)
        client = _Client(sock)
        self._clients[sock.fileno()] = client
        self._sel.register(sock, selectors.EVENT_READ, client)
        client.outbuf = self._hello
        self._send(client)

    def _drop(self, client: _Client) -> None:
        with contextlib.suppress(KeyError, ValueError):
            self._sel.unregister(client.sock)
        self._clients.pop(client.sock.fileno(), None)
        client.sock.close()

    def _read(self, client: _Client) -> None:
        try:
            data = client.sock.recv(65536)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self._drop(client)
            return
        buf = client.inbuf + data
        *lines, rest = buf.split(b"\n")
        if len(rest) > MAX_LINE:
            self.counts["oversized"] += 1
            rest = b""
        client.inbuf = rest
        for line in lines:
            if len(line) > MAX_LINE:
                self.counts["oversized"] += 1
            elif line.strip():
                reply = self._apply(line)
                if reply is not None:
                    self._queue(client, self._line(reply), always=True)

    def _queue(self, client: _Client, line: bytes, *, always: bool = False) -> None:
        if len(client.outbuf) > MAX_OUT and not always:
            self.counts["slow"] += 1  # it does not read: this state is skipped for it
            return
        client.outbuf += line
        self._send(client)

    def _broadcast(self, line: bytes, *, always: bool = False) -> None:
        for client in list(self._clients.values()):
            self._queue(client, line, always=always)

    def _send(self, client: _Client) -> None:
        try:
            n = client.sock.send(client.outbuf)
        except BlockingIOError:
            n = 0
        except OSError:
            self._drop(client)
            return
        client.outbuf = client.outbuf[n:]
        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if client.outbuf else 0)
        with contextlib.suppress(KeyError, ValueError):
            self._sel.modify(client.sock, events, client)

    def _flush_all(self) -> None:
        for client in list(self._clients.values()):
            with contextlib.suppress(OSError):
                client.sock.setblocking(True)
                client.sock.settimeout(0.2)
                client.sock.sendall(client.outbuf)
            client.outbuf = b""
