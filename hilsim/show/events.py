"""What a show writes to ``events.jsonl`` besides its start and its end, rate-limited.

The loop says what happened; :class:`ShowLog` decides how often it is worth a line: a host
stall at most once per :data:`~hilsim.show.monitors.STALL_EVENT_INTERVAL_S` (the rest counted into
the next line), the safety filter's clamps and a corrupt reply once a second of show at most.
Writing an event never raises: it may run while a failure is being handled.
"""

from __future__ import annotations

import contextlib
import math
import time
from typing import Any

from drivers.servo_bus import ServoBus
from hilsim.safety.filter import SafetyFilter
from hilsim.show.monitors import STALL_EVENT_INTERVAL_S
from hilsim.telemetry import TelemetryWriter


class ShowLog:
    def __init__(self, telemetry: TelemetryWriter, safety: SafetyFilter, bus: ServoBus) -> None:
        self.telemetry, self.safety, self.bus = telemetry, safety, bus
        self._stall_event_t = -math.inf
        self._stalls_unreported = 0
        self._limits_seen: dict[str, dict[str, int]] = {}

    def event(self, kind: str, message: str, **fields: Any) -> None:
        """An events.jsonl line; never raises (it may run while handling a failure)."""
        with contextlib.suppress(Exception):  # a broken writer must not stop the exit path
            self.telemetry.event(kind, message, **fields)

    def host_stall(self, stall: float, k: int, t_sim: float) -> None:
        """One ``host_stall`` event per STALL_EVENT_INTERVAL_S at most; the rest counted in."""
        now = time.monotonic()
        self._stalls_unreported += 1
        if now - self._stall_event_t < STALL_EVENT_INTERVAL_S:
            return
        more = self._stalls_unreported - 1
        self.event(
            "host_stall",
            f"the host stalled {stall * 1e3:.0f} ms at tick {k} (t = {t_sim:.2f} s): the "
            "process was not running; not counted against any servo"
            + (f" ({more} shorter stalls since the last report)" if more else ""),
            tick=k,
            t=t_sim,
            stall_ms=round(stall * 1e3, 3),
            unreported=more,
        )
        self._stall_event_t = now
        self._stalls_unreported = 0

    def safety_limits(self, k: int, t_sim: float) -> None:
        """One ``safety_limit`` event naming each joint and limit that acted since the last
        one (a second of show at most): rate-limited, never a line per tick."""
        counts = self.safety.counters.by_kind()
        seen = self._limits_seen
        acted = []
        for kind, per_joint in counts.items():
            for joint, n in per_joint.items():
                new = n - seen.get(kind, {}).get(joint, 0)
                if new:
                    acted.append(f"{joint} {kind} x{new}")
        self._limits_seen = counts
        if acted:
            self.event(
                "safety_limit",
                "limits acted in the last second: " + ", ".join(acted),
                tick=k,
                t=t_sim,
            )

    def corrupt_reply(self, k: int, t_sim: float) -> None:
        """The latest corrupt reply the driver kept, as received (then forgotten)."""
        bus = self.bus
        if bus.corrupt_sample is not None:
            self.event(
                "corrupt_reply",
                "a corrupt reply (bytes as received; the latest of the last second)",
                tick=k,
                t=t_sim,
                raw=bus.corrupt_sample.hex(" "),
            )
            bus.corrupt_sample = None
