"""Test-suite settings: a deterministic hypothesis profile for CI.

With the environment variable ``CI`` set (CI runs with ``CI=true``), the ``hilsim-ci`` profile is
loaded; otherwise hypothesis keeps its default profile (random examples, the ``.hypothesis/``
example database), unless ``HYPOTHESIS_PROFILE`` names another registered profile.

``hilsim-ci`` makes every CI run draw the same examples:

* ``derandomize=True``: examples come from a seed derived from each test itself, not from a
  random seed, so a run is repeatable and a failure reproduces on any machine.
* no example database: ``derandomize=True`` implies ``database=None`` (hypothesis refuses the
  two together), so ``.hypothesis/`` is neither read nor written. One failing example can no
  longer be saved there and replayed on every later run, turning a rare failure into a
  permanent one in that checkout.
* ``deadline=None`` and the ``too_slow`` health check off: both depend on wall-clock time, which
  a loaded CI host does not give reliably.
* ``print_blob=True``: a failure prints the blob to reproduce it with ``@reproduce_failure``.
"""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile(
    "hilsim-ci",
    derandomize=True,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)

_in_ci = os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")
_profile = os.environ.get("HYPOTHESIS_PROFILE") or ("hilsim-ci" if _in_ci else None)
if _profile:
    settings.load_profile(_profile)


@pytest.fixture(autouse=True)
def _no_real_time_scheduling(monkeypatch):
    """No test makes the test process SCHED_FIFO or pins it to a CPU for real. A rig that asks
    for it (configs/hardware_example.toml) run in-process as root would otherwise get it: a
    SCHED_FIFO process that busy-waits (the virtual clock never sleeps) starves the host, and
    several test runs at once froze a 2-core machine that way. The request is refused as an
    unprivileged user's would be (a warning); tests of the scheduling code patch their own."""
    import hilsim.show.realtime

    def refuse(*_args, **_kwargs):
        raise PermissionError(1, "Operation not permitted (the test suite never runs real time)")

    monkeypatch.setattr(hilsim.show.realtime.os, "sched_setscheduler", refuse)
    monkeypatch.setattr(hilsim.show.realtime.os, "sched_setaffinity", refuse)
