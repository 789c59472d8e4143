"""The Bottango live driver's transport: a pseudo-terminal or a TCP connection, and the thread
that reads it (:class:`BottangoLink`). The protocol itself is :mod:`hilsim.live.bottango_live`.

* **pty** (Bottango's USB serial driver): ``os.openpty()``, the slave side set raw (no echo,
  no newline translation) and then closed, so hilsim sees when Bottango closes the port (a
  read then fails with EIO): that ends the connection (the next ``hRQ`` is answered again, as
  a board reset by the port opening would). Its path (``/dev/pts/N``) is what :meth:`start`
  returns, and ``link`` a symlink to it.
* **tcp** (Bottango's network driver): the app listens (127.0.0.1:59225 by default) and the
  driver connects to it, so hilsim connects out and retries every ``retry_s`` until the app is
  there, and again after the app closes the connection. hilsim listens on nothing.

The thread stamps each line with ``now()`` (the loop's show time), hands it to the engine's
``feed_line`` (bounded work under the engine's lock) and writes the answer back. It reads at
most ``max_lines_per_s`` lines a second (a token bucket on the monotonic clock, as
:class:`~hilsim.live.netguard.UdpReceiver` does): past that it stops reading and the writer
waits (a stream pushes back; Bottango sends one line and waits for ``OK`` anyway). A line
longer than ``max_line`` is handed over cut at ``max_line + 1`` bytes (the engine drops it and
answers as the firmware does) and the rest up to its newline is skipped. The thread runs at
SCHED_OTHER and nice 19 (Linux) so it never takes a CPU from the loop; the loop only ever
calls ``poll``. :meth:`close` is idempotent and joins the thread within ``timeout_s``·5.
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import socket
import threading
import time
import tty
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from hilsim.live.bottango_config import BottangoConfig
from hilsim.live.netguard import TokenBucket

if TYPE_CHECKING:
    from hilsim.live.bottango_live import BottangoLive

READ_SIZE = 4096


class BottangoLink:
    """``engine``: a :class:`~hilsim.live.bottango_live.BottangoLive` (``feed_line``,
    ``disconnected``); ``now()``: the loop's show time."""

    def __init__(
        self,
        engine: BottangoLive,
        config: BottangoConfig,
        now: Callable[[], float],
        *,
        timeout_s: float = 0.2,
        retry_s: float = 1.0,
    ) -> None:
        self.engine, self.config, self.now = engine, config, now
        self.timeout_s, self.retry_s = timeout_s, retry_s
        self.path: str | None = None  # the pty's slave path
        self.connected = False
        self._fd: int | None = None
        self._sock: socket.socket | None = None
        self._linked = False
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None
        self._buf = bytearray()
        self._skipping = False
        burst = max(1, min(100, int(config.max_lines_per_s)))
        self._budget = TokenBucket(config.max_lines_per_s, burst, time.monotonic())
        self._refill_s = max(1e-3, burst / 2 / config.max_lines_per_s)

    # ------------------------------------------------------------------ life cycle
    def start(self) -> str:
        """Open the transport and start the thread; returns a line saying where to connect."""
        cfg = self.config
        if cfg.transport == "pty":
            master, slave = os.openpty()
            try:
                tty.setraw(slave)
                self.path = os.ttyname(slave)
            finally:
                os.close(slave)
            os.set_blocking(master, False)
            self._fd = master
            try:
                self._make_link()
            except BaseException:
                self.close()
                raise
            run, note = self._run_pty, f"Bottango live (USB serial driver) on {self.path}"
            if self._linked:
                note += f" (link {cfg.link})"
        else:
            run = self._run_tcp
            note = f"Bottango live (network driver): connecting to {cfg.host}:{cfg.port}"
        self._thread = threading.Thread(target=run, name="bottango-link", daemon=True)
        self._thread.start()
        return note

    def _make_link(self) -> None:
        link = self.config.link
        if not link:
            return
        if os.path.islink(link):
            os.unlink(link)  # a stale link from an earlier run
        elif os.path.lexists(link):
            raise ValueError(f"inputs.bottango.link: {link} exists and is not a symlink")
        assert self.path is not None  # start() opened the pty first
        try:
            os.symlink(self.path, link)
        except OSError as exc:
            msg = f"inputs.bottango.link: cannot create {link}: {exc.strerror}"
            raise ValueError(msg) from None
        self._linked = True

    def close(self) -> None:
        """Stop the thread (joined within timeout_s·5), close the pty or socket, remove the
        link. Idempotent."""
        self._closing.set()
        th, self._thread = self._thread, None
        if th is not None and th is not threading.current_thread():
            th.join(self.timeout_s * 5)
        fd, self._fd = self._fd, None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)
        sock, self._sock = self._sock, None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.close()
        if self._linked:
            self._linked = False
            link = self.config.link or ""
            with contextlib.suppress(OSError):
                if os.path.islink(link) and os.readlink(link) == self.path:
                    os.unlink(link)

    # ------------------------------------------------------------------ the threads
    def _run_pty(self) -> None:
        _background()
        closing, fd = self._closing, self._fd
        if fd is None:
            return
        while not closing.is_set():
            try:
                ready, _, _ = select.select([fd], [], [], self.timeout_s)
                if not ready:
                    continue
                data = os.read(fd, READ_SIZE)
            except BlockingIOError:
                continue
            except OSError as exc:
                if exc.errno != errno.EIO or closing.is_set():
                    return
                self._lost()  # no one has the port open: wait for the next one
                closing.wait(min(0.05, self.timeout_s))
                continue
            self.connected = True
            if not self._take(data, lambda out: self._write_fd(fd, out)):
                return

    def _run_tcp(self) -> None:
        _background()
        cfg, closing = self.config, self._closing
        while not closing.is_set():
            try:
                sock = socket.create_connection((cfg.host, cfg.port), timeout=self.timeout_s)
            except OSError:
                closing.wait(self.retry_s)
                continue
            self._sock, self.connected = sock, True
            self._buf.clear()
            self._skipping = False
            try:
                while not closing.is_set():
                    try:
                        data = sock.recv(READ_SIZE)
                    except TimeoutError:
                        continue
                    if not data or not self._take(data, sock.sendall):
                        break
            except OSError:
                pass
            self._lost()
            with contextlib.suppress(OSError):
                sock.close()
            self._sock = None
            closing.wait(self.retry_s)

    def _lost(self) -> None:
        if self.connected:
            self.connected = False
            self._buf.clear()
            self._skipping = False
            with contextlib.suppress(Exception):
                self.engine.disconnected(self.now())

    def _take(self, data: bytes, send: Callable[[bytes], Any]) -> bool:
        """Split ``data`` into lines and answer each; False when the thread should end."""
        limit = self.config.max_line + 2  # a line, an optional \r, its \n
        buf = self._buf
        buf += data
        while True:
            nl = buf.find(b"\n")
            if self._skipping:
                if nl < 0:
                    buf.clear()
                    return True
                del buf[: nl + 1]
                self._skipping = False
                continue
            if nl < 0:
                if len(buf) <= limit:
                    return True
                line = bytes(buf[: self.config.max_line + 1])
                buf.clear()
                self._skipping = True
            else:
                line = bytes(buf[:nl])
                del buf[: nl + 1]
            while not self._budget.take(time.monotonic()):
                if self._closing.wait(self._refill_s):
                    return False
            try:
                out = self.engine.feed_line(self.now(), line)
            except Exception:  # feed_line never raises; a broken clock must not end us
                continue
            if out:
                send(b"".join(out))

    def _write_fd(self, fd: int, data: bytes) -> None:
        view = memoryview(data)
        while view and not self._closing.is_set():
            try:
                n = os.write(fd, view)
            except BlockingIOError:
                select.select([], [fd], [], self.timeout_s)
                continue
            except OSError:
                return  # the port was closed under us: the answer is lost with it
            view = view[n:]


def _background() -> None:
    """This thread at SCHED_OTHER and nice 19 (as netguard's receiver; Linux, best effort)."""
    with contextlib.suppress(AttributeError, OSError):
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    with contextlib.suppress(AttributeError, OSError):
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)
