"""``hilsim emulate`` in a child process for the pty tests: the path it prints first, then a
SIGTERM (and a kill if it does not stop) when the test is done."""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
from collections.abc import Iterator

import pytest


@contextlib.contextmanager
def emulated_pty(*args: str, timeout_s: float = 20.0) -> Iterator[tuple[subprocess.Popen, str]]:
    """``hilsim emulate ARGS``; yields (the process, its pty path). A process that does not
    print a path fails the test with what it said."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "hilsim", "emulate", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and proc.stderr is not None
    path = proc.stdout.readline().strip()
    if not path.startswith("/dev/"):
        proc.kill()
        pytest.fail(f"hilsim emulate printed {path!r}; stderr: {proc.stderr.read()}")
    try:
        yield proc, path
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                raise
        proc.stdout.close()
        proc.stderr.close()
