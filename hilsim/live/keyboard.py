"""Keys typed in the terminal running ``hilsim run`` fire a show's ``key:<k>`` triggers.

In a show file::

    [inputs.keyboard]            # enabled = true is the default; enabled = false turns it off

    [cues.scare]
    trigger = "key:s"            # pressing s fires the cue

Each key pressed gives one trigger key: a printable character as itself (``key:s``, ``key:S``
and ``key:1`` differ), and ``key:space``, ``key:enter``, ``key:tab``, ``key:backspace``,
``key:esc``, ``key:up``, ``key:down``, ``key:left``, ``key:right``. Other control keys and
escape sequences are ignored. No key is special here: Ctrl-C still stops the run (the terminal
keeps its signal keys), and ``q`` is a trigger like any other.

**How.** :meth:`KeyboardInput.start` puts the terminal in cbreak mode (keys arrive one by one,
not echoed, signals kept) and starts a thread that waits on stdin with ``select`` and hands each
key, stamped with show time, to a bounded :class:`~hilsim.live.inbox.Inbox` (64 keys; a full
inbox drops the oldest). The loop's :meth:`KeyboardInput.poll` takes what is due without
waiting. Needs no optional package (POSIX termios; on Windows it is off with a note).

**Off, with a note**, when stdin is not a terminal (a pipe, a service, CI) or when
``hilsim run`` is in the background (changing the terminal's mode there would stop the process).

**The terminal is always given back**: :meth:`KeyboardInput.close` restores the mode saved at
start (the director closes its inputs on every exit path, Ctrl-C and an exception included);
an ``atexit`` hook does it too if the process ends otherwise, and the thread does it itself if
stdin closes or fails. A stall of the loop does not lose keys (up to 64); they fire at the
next tick, stamped with the time they were typed.
"""

from __future__ import annotations

import atexit
import codecs
import contextlib
import os
import select
import sys
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from hilsim.live.inbox import Inbox

#: keys held for the loop at most (a full inbox drops the oldest)
CAPACITY = 64
#: named keys: the character -> the name after ``key:``
NAMED = {" ": "space", "\r": "enter", "\n": "enter", "\t": "tab", "\x7f": "backspace",
         "\x08": "backspace"}  # fmt: skip
#: arrow keys: the final byte of ``ESC [ x`` / ``ESC O x``
ARROWS = {"A": "up", "B": "down", "C": "right", "D": "left"}


@dataclass(frozen=True)
class KeyboardConfig:
    """``[inputs.keyboard]``: ``enabled`` (default true)."""

    enabled: bool = True

    @classmethod
    def from_table(cls, table: Mapping[str, Any], where: str) -> KeyboardConfig:
        """Read ``[inputs.keyboard]``; raises ValueError ``"<where>.<key>: ..."`` (one line)."""
        if not isinstance(table, Mapping):
            raise ValueError(f"{where}: must be a table, got {type(table).__name__}")
        for key in table:
            if key != "enabled":
                raise ValueError(
                    f"{where}.{key}: unknown key; allowed: enabled (a cue names its key itself: "
                    'trigger = "key:s")'
                )
        enabled = table.get("enabled", True)
        if not isinstance(enabled, bool):
            raise ValueError(f"{where}.enabled: must be true or false, got {enabled!r}")
        return cls(enabled=enabled)


def parse_keys(text: str) -> list[str]:
    """The trigger keys in ``text`` as one read in cbreak mode gives them (a terminal sends an
    escape sequence in one write; a lone ESC is the Esc key, an unknown sequence nothing)."""
    keys: list[str] = []
    i, n = 0, len(text)
    while i < n:
        ch = text[i]
        i += 1
        if ch == "\x1b":
            if i < n and text[i] in "[O":
                j = i + 1
                while j < n and not ("@" <= text[j] <= "~"):
                    j += 1  # parameters, up to the final byte
                if j < n and j == i + 1 and text[j] in ARROWS:
                    keys.append(f"key:{ARROWS[text[j]]}")
                i = j + 1
            else:
                keys.append("key:esc")
        elif ch in NAMED:
            keys.append(f"key:{NAMED[ch]}")
        elif ch.isprintable():
            keys.append(f"key:{ch}")
    return keys


class KeyboardInput:
    """Keys typed in a terminal -> trigger keys (see the module docstring).

    Args:
        config: the show file's ``[inputs.keyboard]``.
        fd: the terminal's file descriptor; ``None``: stdin's.
        capacity: keys held for the loop at most.
    """

    def __init__(
        self, config: KeyboardConfig, *, fd: int | None = None, capacity: int = CAPACITY
    ) -> None:
        self.config = config
        self.inbox = Inbox(capacity)
        self.enabled = False  #: True while the thread reads the terminal
        self.note = ""
        self.typed = 0  #: keys handed to the loop, in all
        self.error: str | None = None  #: why the reader stopped early, if it did
        self._fd = fd
        self._saved: list[Any] | None = None  # termios.tcgetattr's (flags, speeds, chars)
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._wake: tuple[int, int] | None = None
        self._stop = threading.Event()

    def start(self, now: Callable[[], float]) -> str | None:
        """Take the terminal (cbreak) and start reading it; ``now()`` stamps each key with
        show time. Returns a note for the operator (why it is off, or which keys work)."""
        if not self.config.enabled:
            return None
        why = self._cannot_start()
        if why:
            self.note = f"keyboard triggers off: {why}"
            return self.note
        import termios
        import tty

        fd = self._fd
        assert fd is not None
        self._saved = termios.tcgetattr(fd)
        atexit.register(self._restore)
        try:
            tty.setcbreak(fd, termios.TCSANOW)
            self._wake = os.pipe()
            self._thread = threading.Thread(
                target=self._read, args=(fd, now), name="hilsim-keyboard", daemon=True
            )
            self._thread.start()
        except BaseException:
            self.close()
            raise
        self.enabled = True
        self.note = 'keyboard: keys typed here fire "key:<k>" triggers (Ctrl-C stops)'
        return self.note

    def _cannot_start(self) -> str:
        if os.name != "posix":
            return "needs a POSIX terminal"
        if self._fd is None:
            try:
                self._fd = sys.stdin.fileno()
            except (AttributeError, OSError, ValueError):
                return "stdin is not a terminal"
        if not os.isatty(self._fd):
            return "stdin is not a terminal"
        try:
            foreground = os.tcgetpgrp(self._fd) == os.getpgrp()
        except OSError:  # not our controlling terminal (a pty we were handed): no job control
            foreground = True
        if not foreground:
            return "hilsim run is in the background"
        return ""

    def _read(self, fd: int, now: Callable[[], float]) -> None:
        """The thread: wait on the terminal (and the wake-up pipe), hand keys over."""
        assert self._wake is not None
        wake = self._wake[0]
        decoder = codecs.getincrementaldecoder("utf-8")(errors="replace")
        try:
            while not self._stop.is_set():
                ready, _, _ = select.select([fd, wake], [], [])
                if wake in ready or self._stop.is_set():
                    return
                data = os.read(fd, 256)
                if not data:  # the terminal closed
                    return
                keys = parse_keys(decoder.decode(data))
                t = now()
                for key in keys:
                    self.inbox.put(t, key)
        except OSError:  # the terminal went away
            return
        except Exception as exc:  # never a traceback from a thread; the summary says it
            self.error = f"{type(exc).__name__}: {exc}"
        finally:
            self._restore()

    def poll(self, t: float) -> list[str]:
        """The trigger keys typed up to show time ``t``, in order; never waits."""
        keys = [key for _, key in self.inbox.take_due(t)]
        self.typed += len(keys)
        return keys

    def close(self) -> None:
        """Stop reading and give the terminal its mode back. Never raises; idempotent."""
        self._stop.set()
        wake, self._wake = self._wake, None
        if wake is not None:
            with contextlib.suppress(OSError):
                os.write(wake[1], b"x")
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=1.0)
        self._restore()
        if wake is not None:
            for end in wake:
                with contextlib.suppress(OSError):
                    os.close(end)
        self.enabled = False

    def _restore(self) -> None:
        """Give the terminal back the mode saved at start (once)."""
        with self._lock:
            saved, self._saved = self._saved, None
        if saved is None:
            return
        assert self._fd is not None  # start() saved the mode of this terminal
        import termios

        with contextlib.suppress(OSError, termios.error):
            termios.tcsetattr(self._fd, termios.TCSADRAIN, saved)
        with contextlib.suppress(Exception):
            atexit.unregister(self._restore)

    def summary(self) -> dict[str, Any]:
        return {"enabled": self.enabled, "typed": self.typed, "dropped": self.inbox.dropped,
                "note": self.note, "error": self.error}  # fmt: skip
