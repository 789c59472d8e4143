"""The ports the bench opens: emulated buses as ``dxlsim://`` URLs, on the clock it chooses.

The bench measures what this host achieves, so a ``dxlsim://?...`` URL that does not say
``clock=`` is opened on the real clock. The URL's grammar and defaults are
:class:`drivers.dxlsim.url.DxlsimUrl`'s; the driver's :func:`open_bus` opens whatever
port it is given.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from drivers.dxlsim.url import DxlsimUrl
from drivers.dynamixel import bench_session
from drivers.dynamixel.bench_session import BenchBus


def emulator_url(
    ids: Iterable[int], baud: int, *, rdt_us: float = 0.0, clock: str = "real", **keys: Any
) -> str:
    """``dxlsim://`` URL of an emulated bus with these servos (all on ``baud``), answering
    after ``rdt_us`` (default 0, as a tuned bus). ``keys`` are other :class:`DxlsimUrl`
    fields (``turnaround_us``, ``latency_ms``, ``firmware``, ...)."""
    named = ("ids", "baud", "rdt_us", "clock", *keys)  # printed even at their defaults
    return str(DxlsimUrl(ids=tuple(ids), baud=baud, rdt_us=rdt_us, clock=clock, **keys, keys=named))


def prepare_url(url: str, *, clock: str = "real", trace: bool = False) -> str:
    """For a ``dxlsim://?...`` URL: add ``clock=`` when missing and ``trace=1`` when asked.
    Other ports (and named emulated buses) pass through unchanged."""
    if not url.lower().startswith("dxlsim:"):
        return url
    try:
        parsed = DxlsimUrl.parse(url)
    except ValueError:
        return url  # opening it says what is wrong
    if parsed.name:
        return url
    if "clock" not in parsed.keys:
        parsed = parsed.replace(clock=clock)
    if trace:
        parsed = parsed.replace(trace=True)
    return str(parsed)


def open_bus(
    url: str, baud: int, *, clock: str = "real", trace: bool = False, stamped: bool = False
) -> BenchBus:
    """Open ``url`` at ``baud`` (:func:`drivers.dynamixel.bench_session.open_bus`) after
    :func:`prepare_url`; ``stamped`` records write times."""
    return bench_session.open_bus(prepare_url(url, clock=clock, trace=trace), baud, stamped=stamped)
