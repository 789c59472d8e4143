"""The live status line of a real-clock show (hilsim/cli/_report.py StatusLine): rewritten in
place on a terminal, one line every LOG_STATUS_S in a log, and never the loop's wait."""

from __future__ import annotations

import io
import threading

from hilsim.cli._report import LOG_STATUS_S, StatusLine

ST = {"tick": 500, "t": 2.0, "duration": 10.0, "comm_errors": 1, "overruns": 2}


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_in_a_log_a_line_every_few_seconds_each_whole():
    out, clock = io.StringIO(), Clock()
    line = StatusLine(250.0, out, tty=False, clock=clock)
    for k in range(100):  # the loop offers a line twice a second
        clock.t = 0.5 * (k + 1)
        line({**ST, "t": clock.t})
    line.close()
    lines = out.getvalue().splitlines()
    assert len(lines) == int(50 // LOG_STATUS_S)  # 50 s of show
    assert all(s.startswith("hilsim run: status: t ") and "\r" not in s for s in lines)
    assert "comm err 1  overruns 2" in lines[0] and "/10.0 s" in lines[0]


def test_on_a_terminal_the_line_is_rewritten_and_ended():
    out, clock = io.StringIO(), Clock()
    line = StatusLine(250.0, out, tty=True, clock=clock)
    clock.t = 2.0
    line(ST)
    line.close()
    text = out.getvalue()
    assert text.startswith("\r t 2.0/10.0 s  250/250 Hz") and text.endswith("\033[K\n")


def test_a_stream_that_blocks_never_holds_up_the_loop():
    """A terminal paused with Ctrl-S, a pipe nobody reads: the writer thread waits, the
    loop's calls return at once, and what still waits when the show ends is dropped (never
    written after the end-of-show lines)."""
    entered, release = threading.Event(), threading.Event()

    class Blocked(io.StringIO):
        def write(self, s: str) -> int:
            if not entered.is_set():  # the first write blocks until released
                entered.set()
                release.wait(10)
            return super().write(s)

    out, clock = Blocked(), Clock()
    line = StatusLine(250.0, out, tty=True, clock=clock)
    clock.t = 0.5
    line({**ST, "t": 0.5})
    assert entered.wait(10)  # the writer is stuck in its first write
    for k in range(1, 1000):  # the loop goes on: each call returns at once
        clock.t = 0.5 * (k + 1)
        line({**ST, "t": clock.t})
    line.close(timeout_s=0)  # gives up at once: the newest line is dropped, the line ended
    release.set()
    line._thread.join(10)
    text = out.getvalue()
    assert text.count("\r") == 1 and "t 0.5/10.0" in text and "\n" in text
