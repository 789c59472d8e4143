"""Clocks for tests of the loop's real-clock paths on the emulator's virtual clock."""

from __future__ import annotations

from drivers.clock import VirtualClock


class NotVirtual:
    """The loop's view of the emulator's clock as a real one (so its real-clock steps run:
    the real-time checks, the warm-up); the bus keeps the virtual clock underneath, so
    nothing sleeps."""

    virtual = False

    def __init__(self, clock: VirtualClock) -> None:
        self._clock = clock

    def now(self) -> float:
        return self._clock.now()

    def wait_until(self, t: float, idle=None) -> float:
        return self._clock.wait_until(t)
