"""How a show is asked to stop: a signal, a stop command of the show, or ``Show.stop()``.

The loop looks at the flag once per tick (and during the start-up) and leaves through the
exit policy. Setting it is one attribute store, safe from a signal handler or another
thread; the first request wins.
"""

from __future__ import annotations

import signal
from dataclasses import dataclass

__all__ = ["StopFlag", "signal_name"]


@dataclass
class StopFlag:
    """Set from a signal handler, or by a stop command from the show's control (OSC
    ``/hilsim/stop``, Bottango's ``STOP``: :mod:`hilsim.live.director`); the loop looks at it
    once per tick (and during start-up). The first request wins."""

    signum: int | None = None
    #: what sent the stop command (e.g. "OSC /hilsim/stop"), None: none was sent
    command: str | None = None

    def request(self, signum: int) -> None:
        if self.signum is None and self.command is None:
            self.signum = signum

    def request_command(self, what: str) -> None:
        if self.signum is None and self.command is None:
            self.command = what


def signal_name(signum: int) -> str:
    """``SIGTERM`` for 15; ``signal 99`` for a number that names none."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"
