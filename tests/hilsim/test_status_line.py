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
    loop's calls return at once and only the newest line waits to be written."""
    release = threading.Event()

    class Blocked(io.StringIO):
        def write(self, s: str) -> int:
            release.wait(10)
            return super().write(s)

    out, clock = Blocked(), Clock()
    line = StatusLine(250.0, out, tty=True, clock=clock)
    for k in range(1000):  # would block on the first write if the loop wrote itself
        clock.t = 0.5 * (k + 1)
        line({**ST, "t": clock.t})
    line.close(timeout_s=0.01)  # gives up waiting; the show's end is not held either
    release.set()
    line._thread.join(10)
    assert out.getvalue().count("\r") <= 2  # the first line and at most the newest
