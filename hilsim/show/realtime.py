"""Asking the OS for real-time treatment: SCHED_FIFO, a CPU of its own, a short GIL switch,
precise timers.

Each is a request: refused (no privilege, no such CPU), the show runs anyway and a warning
says how to grant it. Precise timers (Linux's per-thread timer slack at 1 ns instead of
50 µs, :func:`drivers.clock.precise_timers`) need no privilege and are asked for silently:
the loop's sleep then ends within the OS's wake-up latency of the time it asked for, so the
clock's spin window (``loop.spin_us``) can be short.
"""

from __future__ import annotations

import contextlib
import os
import warnings
from collections.abc import Iterator

from drivers.clock import precise_timers

#: GIL switch interval while a show runs on the real clock: when the loop wakes from its
#: sleep it may wait for the GIL up to the interpreter's switch interval (5 ms by default)
#: while the telemetry writer thread holds it; this asks the holder to let go within 100 µs.
REALTIME_SWITCH_INTERVAL_S = 100e-6

#: a process's scheduling policy, priority and CPU set (what :func:`_restore` puts back)
_SchedState = tuple[int, os.sched_param, set[int]]


def try_realtime(priority: int | None, cpu: int | None) -> str:
    """Ask for SCHED_FIFO and CPU affinity; warn (never fail) when not permitted.

    Returns the scheduling class in force, e.g. ``"SCHED_FIFO:50"`` or ``"SCHED_OTHER"``.
    """
    if cpu is not None:
        try:
            os.sched_setaffinity(0, {cpu})
        except (OSError, AttributeError, ValueError) as exc:
            warnings.warn(f"could not pin the loop to CPU {cpu}: {exc}", stacklevel=2)
    sched = "SCHED_OTHER"
    if priority is not None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            sched = f"SCHED_FIFO:{priority}"
        except (OSError, AttributeError) as exc:
            warnings.warn(
                f"SCHED_FIFO priority {priority} not permitted ({exc}); running as SCHED_OTHER. "
                "Grant it with: sudo setcap cap_sys_nice+ep $(readlink -f $(which python3)) "
                "or run under a user with an rtprio limit (/etc/security/limits.conf); as a "
                "service, the unit `hilsim service print` writes grants it.",
                stacklevel=2,
            )
    return sched


def _snapshot() -> _SchedState | None:
    """This process's scheduling policy, priority and CPU set, or None where the OS has none."""
    try:
        return os.sched_getscheduler(0), os.sched_getparam(0), os.sched_getaffinity(0)
    except (OSError, AttributeError):
        return None


def _restore(state: _SchedState | None) -> None:
    if state is None:
        return
    policy, param, cpus = state
    try:
        if (os.sched_getscheduler(0), os.sched_getparam(0)) != (policy, param):
            os.sched_setscheduler(0, policy, param)
        if os.sched_getaffinity(0) != cpus:
            os.sched_setaffinity(0, cpus)
    except (OSError, AttributeError, ValueError) as exc:
        warnings.warn(f"could not restore the scheduling class and CPUs: {exc}", stacklevel=3)


@contextlib.contextmanager
def realtime(priority: int | None, cpu: int | None) -> Iterator[str]:
    """:func:`try_realtime` and precise timers for the ``with`` block, then the process's
    scheduling class and CPUs and this thread's timer slack as they were: a show run inside a
    longer-lived process (a test suite, a program that embeds hilsim) must not leave it
    SCHED_FIFO or pinned — a SCHED_FIFO process that busy-waits (the virtual clock never
    sleeps) starves everything else on the host."""
    state = _snapshot()
    try:
        with precise_timers():  # this thread's timer slack, as it was afterwards
            yield try_realtime(priority, cpu)
    finally:
        _restore(state)
