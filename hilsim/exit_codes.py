"""The exit codes of ``hilsim`` commands, in one place.

=====  ==================================================================================
code   meaning
=====  ==================================================================================
0      the show completed; the exit policy was applied and confirmed on every servo
1      an unexpected error outside the show (a bug: the traceback is printed); for
       ``hilsim scan``, ``hilsim plot`` and ``hilsim sounds``: nothing found (no servo
       answered; no tick in the run or in the window asked for; no sound output device)
       (``NOTHING_FOUND``)
2      usage or configuration error: the rig file, a command-line value, or servos that do
       not match the rig or refuse to start (before torque went on). Nothing moved.
3      a fault stopped the show (a servo, the bus, the host, the telemetry disk, or an
       internal error in the loop), or the telemetry disk failed as the record was finished
       after it; the reason names it. The exit policy was applied.
4      the show was not stopped by a fault, but the exit policy could not be confirmed on
       some servo (named on stderr and in ``summary.json``): the figure may not be in a safe
       state. (After a fault, 3 stands and the unconfirmed servos are named the same way.)
5      stopped by a stop command from the show's control: OSC ``/hilsim/stop``, Bottango's
       ``STOP`` (``hilsim run --show``/``--live``); the exit policy was applied and confirmed
       (unconfirmed: 4)
129    stopped by SIGHUP (the terminal or SSH session went away); exit policy applied
130    stopped by SIGINT (Ctrl-C); exit policy applied (128 + the signal number)
131    stopped by SIGQUIT (Ctrl-\\); exit policy applied
143    stopped by SIGTERM (``kill``, ``systemctl stop``); exit policy applied
=====  ==================================================================================
"""

from __future__ import annotations

from enum import IntEnum


class ExitCode(IntEnum):
    OK = 0
    INTERNAL = 1
    NOTHING_FOUND = 1  # scan: no servo answered; plot: no tick to plot (same code, own meaning)
    USAGE = 2
    FAULT = 3
    UNSAFE_EXIT = 4
    STOPPED = 5
    SIGHUP = 129
    SIGINT = 130
    SIGQUIT = 131
    SIGTERM = 143


def for_signal(signum: int) -> int:
    """The exit code of a show stopped by signal ``signum``: 128 + signum."""
    return 128 + int(signum)
