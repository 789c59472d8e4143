"""Find the servos on a port: which IDs answer at which baud, with model and firmware.

Per baud one broadcast Ping (every servo answers in one round: fast); if nobody answers,
unicast Pings over the candidate IDs (slow on hardware: one packet timeout per silent
ID, ~4 ms with a 1 ms latency timer, ~34 ms with 16 ms). On ``dxlsim://`` with the
virtual clock the whole scan takes milliseconds.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from drivers.clock import Clock
from drivers.dynamixel.errors import CommError, ServoError
from drivers.dynamixel.link import Link
from drivers.protocol2.control_table import model_name

DEFAULT_BAUDS: tuple[int, ...] = (57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)


@dataclass(frozen=True, order=True)
class Found:
    """One servo that answered: ``baud`` in bit/s."""

    baud: int
    id: int
    model_number: int
    model_name: str
    firmware: int

    def __str__(self) -> str:
        return (
            f"ID {self.id:3d} @ {self.baud:>7d} bit/s: {self.model_name} "
            f"(model {self.model_number}, firmware {self.firmware})"
        )


def scan(
    port: str,
    bauds: Sequence[int] = DEFAULT_BAUDS,
    ids: Iterable[int] | None = None,
    *,
    clock: Clock | None = None,
    latency_timer_ms: float | None = None,
    unicast_fallback: bool = True,
    progress: Callable[[int, str, list[Found]], None] | None = None,
) -> list[Found]:
    """Every servo answering on ``port`` at each of ``bauds``, sorted by (baud, id).

    ``ids``: the IDs to report (and to unicast-ping in the fallback); default 0..252.
    ``unicast_fallback``: when a broadcast Ping finds nobody at a baud, ping each ID.
    ``progress(baud, step, found)``: told ``"unicast"`` before a baud's unicast Pings (the
    slow part: one timeout per silent ID) and ``"done"`` with what that baud found.
    Raises :class:`~drivers.dynamixel.errors.PortGone` if the adapter vanishes.
    """
    wanted = list(range(253)) if ids is None else sorted(set(ids))
    if not bauds:
        raise ValueError("give at least one baud rate")
    found: list[Found] = []
    link = Link.open(port, baud=bauds[0], clock=clock, latency_timer_ms=latency_timer_ms)
    try:
        for baud in bauds:
            link.set_baud(baud)
            answers = link.broadcast_ping()
            if not answers and unicast_fallback:
                if progress is not None:
                    progress(baud, "unicast", [])
                answers = _unicast(link, wanted)
            here = sorted(
                Found(baud, sid, model, model_name(model), fw)
                for sid, (model, fw) in answers.items()
                if sid in wanted
            )
            found += here
            if progress is not None:
                progress(baud, "done", here)
    finally:
        link.close()
    return sorted(found)


def _unicast(link: Link, ids: Iterable[int]) -> dict[int, tuple[int, int]]:
    answers = {}
    for sid in ids:
        try:
            answers[sid] = link.ping(sid)
        except (CommError, ServoError):
            continue
    return answers
