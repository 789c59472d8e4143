"""Keyboard triggers: keys typed on a pty (the fake terminal) arrive as ``key:<k>``; the
terminal's mode is given back on close (and by the reader itself if the terminal goes away);
stdin that is not a terminal turns the input off with a note. Behaviour only: every wait is a
blocking wait with a safety-net timeout, nothing is timed."""

from __future__ import annotations

import os
import termios
import threading

import pytest

from hilsim.live.inbox import Inbox
from hilsim.live.keyboard import KeyboardConfig, KeyboardInput, parse_keys

pytestmark = pytest.mark.skipif(os.name != "posix", reason="a POSIX terminal")


class SignalInbox(Inbox):
    """An inbox that tells the test each time a key is handed over."""

    def __init__(self) -> None:
        super().__init__(64)
        self.arrived = threading.Semaphore(0)

    def put(self, t, message) -> None:
        super().put(t, message)
        self.arrived.release()


@pytest.fixture
def pty():
    fds = list(os.openpty())  # [master, slave]; a test that closes one sets it to -1
    yield fds
    for fd in fds:
        if fd >= 0:
            os.close(fd)


def started(slave: int, clock: float = 1.5) -> tuple[KeyboardInput, SignalInbox]:
    kb = KeyboardInput(KeyboardConfig(), fd=slave)
    kb.inbox = inbox = SignalInbox()
    note = kb.start(lambda: clock)
    assert kb.enabled and "key:<k>" in note
    return kb, inbox


def wait_keys(inbox: SignalInbox, n: int) -> None:
    for _ in range(n):
        assert inbox.arrived.acquire(timeout=10.0), "the reader thread handed nothing over"


def test_keys_typed_on_the_terminal_arrive_as_trigger_keys(pty) -> None:
    master, slave = pty
    kb, inbox = started(slave)
    try:
        os.write(master, b"s")
        wait_keys(inbox, 1)
        os.write(master, b"q \x1b[A")
        wait_keys(inbox, 3)
        assert kb.poll(1.0) == []  # stamped 1.5: not due yet
        assert kb.poll(1.5) == ["key:s", "key:q", "key:space", "key:up"]
        assert kb.poll(2.0) == []
    finally:
        kb.close()


def test_cbreak_while_running_and_the_mode_restored_on_close(pty) -> None:
    _master, slave = pty
    before = termios.tcgetattr(slave)
    assert before[3] & termios.ICANON and before[3] & termios.ECHO
    kb, _ = started(slave)
    during = termios.tcgetattr(slave)
    assert not during[3] & termios.ICANON and not during[3] & termios.ECHO
    assert during[3] & termios.ISIG  # Ctrl-C still stops the run
    kb.close()
    assert termios.tcgetattr(slave) == before
    assert not kb.enabled
    kb.close()  # twice: nothing happens
    assert termios.tcgetattr(slave) == before


def test_the_mode_is_restored_when_the_run_fails_with_an_exception(pty) -> None:
    _master, slave = pty
    before = termios.tcgetattr(slave)
    kb = None
    with pytest.raises(RuntimeError, match="the show failed"):
        try:
            kb, _ = started(slave)
            raise RuntimeError("the show failed")
        finally:  # what the director's close_inputs does on every exit path
            if kb is not None:
                kb.close()
    assert termios.tcgetattr(slave) == before


def test_the_reader_restores_the_mode_itself_when_it_fails(pty) -> None:
    master, slave = pty
    before = termios.tcgetattr(slave)
    kb = KeyboardInput(KeyboardConfig(), fd=slave)

    def broken_clock() -> float:
        raise RuntimeError("clock broke")

    kb.start(broken_clock)
    thread = kb._thread
    os.write(master, b"s")
    thread.join(timeout=10.0)
    assert not thread.is_alive()
    assert termios.tcgetattr(slave) == before  # given back by the reader, before close
    assert kb.summary()["error"] == "RuntimeError: clock broke"
    kb.close()
    assert termios.tcgetattr(slave) == before


def test_the_reader_ends_when_the_terminal_hangs_up(pty) -> None:
    master, slave = pty
    kb, _ = started(slave)
    thread = kb._thread
    os.close(master)  # the terminal hangs up: the reader sees EOF or an error and ends
    pty[0] = -1
    thread.join(timeout=10.0)
    assert not thread.is_alive()
    kb.close()  # and closing after that is quiet


def test_a_stdin_that_is_not_a_terminal_turns_the_input_off_with_a_note() -> None:
    r, w = os.pipe()
    try:
        kb = KeyboardInput(KeyboardConfig(), fd=r)
        note = kb.start(lambda: 0.0)
        assert note == "keyboard triggers off: stdin is not a terminal"
        assert not kb.enabled and kb._thread is None
        os.write(w, b"s")
        assert kb.poll(10.0) == []
        kb.close()
    finally:
        os.close(r)
        os.close(w)


def test_disabled_in_the_show_file_does_nothing(pty) -> None:
    _, slave = pty
    before = termios.tcgetattr(slave)
    kb = KeyboardInput(KeyboardConfig(enabled=False), fd=slave)
    assert kb.start(lambda: 0.0) is None
    assert termios.tcgetattr(slave) == before
    kb.close()


def test_a_full_inbox_drops_the_oldest_keys(pty) -> None:
    _master, slave = pty
    kb = KeyboardInput(KeyboardConfig(), fd=slave, capacity=2)
    kb.start(lambda: 0.0)
    try:
        for key in ("a", "b", "c"):
            kb.inbox.put(0.0, f"key:{key}")  # as the reader would, faster than the loop
        assert kb.poll(0.0) == ["key:b", "key:c"]
        assert kb.summary()["dropped"] == 1
    finally:
        kb.close()


def test_parse_keys_names_and_ignores() -> None:
    assert parse_keys("aA1 \r\n\t\x7f") == [
        "key:a", "key:A", "key:1", "key:space", "key:enter", "key:enter", "key:tab",
        "key:backspace",
    ]  # fmt: skip
    assert parse_keys("\x1b[A\x1b[B\x1bOC\x1b[D") == ["key:up", "key:down", "key:right", "key:left"]
    assert parse_keys("\x1b") == ["key:esc"]
    assert parse_keys("\x1b[1;5C\x1b[15~x") == ["key:x"]  # modified arrows, F5: nothing
    assert parse_keys("\x03\x04\x00") == []  # control keys are not triggers
    assert parse_keys("q") == ["key:q"]  # q is a key like any other
    assert parse_keys("é") == ["key:é"]


def test_config_from_table() -> None:
    where = "show.toml: inputs.keyboard"
    assert KeyboardConfig.from_table({}, where) == KeyboardConfig(enabled=True)
    assert KeyboardConfig.from_table({"enabled": False}, where).enabled is False
    with pytest.raises(ValueError, match=r"^show.toml: inputs.keyboard.enabled: must be true"):
        KeyboardConfig.from_table({"enabled": "yes"}, where)
    with pytest.raises(ValueError, match=r"inputs.keyboard.keys: unknown key; allowed: enabled"):
        KeyboardConfig.from_table({"keys": {"s": "scare"}}, where)
    with pytest.raises(ValueError, match="must be a table"):
        KeyboardConfig.from_table([], where)
