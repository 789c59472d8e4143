"""How a show is asked to stop: a signal, a stop command of the show, or ``Show.stop()``.

The loop looks at the flag once per tick (and during the start-up) and leaves through the
exit policy. Setting it is one attribute store, safe from a signal handler or another
thread; the first request wins.

:data:`STOP_SIGNALS` are the signals ``hilsim run`` turns into that request: each ends the show
as SIGTERM does (exit policy, ``summary.json``, a ``signal`` event), exit code 128 + its number.
"""

from __future__ import annotations

import signal
from dataclasses import dataclass

__all__ = ["STOP_SIGNALS", "StopFlag", "signal_name"]

#: Ctrl-C; ``kill`` or ``systemctl stop``; a terminal or SSH session gone (SIGHUP); the
#: quit key (SIGQUIT): each stops a show through its exit policy, never mid-tick
STOP_SIGNALS: tuple[signal.Signals, ...] = (
    signal.SIGINT,
    signal.SIGTERM,
    signal.SIGHUP,
    signal.SIGQUIT,
)


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
