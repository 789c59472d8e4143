"""What reading the reply at the next tick's start would save over a pty: a measurement, not
a feature (issue 12, item 2; not a test).

Each tick of the demo sleeps twice: until its deadline, and, after its Sync Write and Fast
Sync Read request, until the reply is there. A pipelined loop would send the request and
read its reply at the start of the next tick, before that tick's Sync Write: one sleep a
tick, the reading one tick older. This runs ``tools/pty_breakdown.py``'s demo over a
``hilsim emulate`` pty with the driver patched that way (``--mode pipelined``) or as shipped
(``--mode shipped``), health reads off in both (the patched driver would need them to wait
for the pending reply), and prints the loop thread's CPU per part. The patch skips the read
order's rules (``drivers/dynamixel/read_order.py``) and the chain's wait after a miss: its
readings are not to be trusted, only its CPU figure.

    python tools/pipelined_probe.py --mode pipelined [--seconds 6]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "tools")]


def no_health_reads() -> None:
    import hilsim.show.servo_watch as sw

    sw.ServoWatch.maybe_read_health = lambda self, *a: None


def pipeline() -> None:
    """Patch :class:`~drivers.dynamixel.bus.DynamixelBus` (Fast Sync Read only): the Sync
    Write first takes the last request's reply; the read returns it and sends a new request
    without waiting."""
    import drivers.dynamixel.bus as bus_mod
    from drivers.dynamixel.fast_reply import STALE
    from drivers.dynamixel.tick_packets import receive_fast_reply, transmit

    cls = bus_mod.DynamixelBus
    send = cls._send_goals

    def collect(self) -> None:
        n = self._n
        pos, status, errors = [math.nan] * n, [STALE] * n, [0] * n
        if getattr(self, "_pending", False):
            self._port.setPacketTimeoutMillis(self._fast_timeout_ms)
            want, order = self._read_param, self._orders.order
            receive_fast_reply(self._port, want, order, pos, status, errors, self._sample)
            self._pending = False
        self._stash = (pos, status, errors)

    def send_goals(self, goals) -> None:
        collect(self)  # before the Sync Write, whose transmit clears the port
        send(self, goals)

    def read_present(self, out) -> None:
        out.t = self._clock.now()
        if getattr(self, "_pending", False):  # start-up reads: no Sync Write between them
            collect(self)
        n = self._n
        pos, status, errors = getattr(self, "_stash", None) or (
            [math.nan] * n,
            [STALE] * n,
            [0] * n,
        )
        out.positions[:], out.status[:], out.errors[:] = pos, status, errors
        self._all_ok = not any(status)
        transmit(self._port, self._request(True, 4))
        self._pending = True
        out.t_done = self._clock.now()

    cls._send_goals, cls._read_present = send_goals, read_present


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mode", choices=("shipped", "pipelined"), required=True)
    ap.add_argument("--seconds", default="6", help="show length (s)")
    args = ap.parse_args(argv)
    no_health_reads()
    if args.mode == "pipelined":
        pipeline()
    import pty_breakdown

    print(f"{args.mode}, health reads off:")
    return pty_breakdown.main(["--seconds", args.seconds])


if __name__ == "__main__":
    raise SystemExit(main())
