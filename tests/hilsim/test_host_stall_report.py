"""Host stalls under the event threshold: counted, and said to be, never silently missing."""

from __future__ import annotations

from pathlib import Path

import pytest

from hilsim.cli._report import print_stats
from hilsim.show.monitors import STALL_ALLOWANCE_S, STALL_EVENT_INTERVAL_S, STALL_EVENT_S

REPO = Path(__file__).resolve().parents[2]


def _summary(count: int, max_ms: float) -> dict:
    stalls = {"count": count, "total_ms": count * max_ms, "max_ms": max_ms}
    return {"lateness_us": {"p50": 0, "p99": 15, "max": 4917}, "loop": {"host_stalls": stalls}}


@pytest.mark.parametrize(
    ("count", "max_ms", "said"),
    [
        (5, 7.0, "host stalls 5 (max 7 ms, each under 10 ms: no event)"),
        (5, 12.0, "host stalls 5 (max 12 ms)"),
        (0, 0.0, "host stalls 0 (max 0 ms)"),
    ],
)
def test_the_end_line_says_when_no_stall_made_an_event(capsys, count, max_ms, said):
    print_stats(_summary(count, max_ms))
    assert said in capsys.readouterr().err


def test_the_readme_states_what_is_counted_and_what_is_an_event():
    text = " ".join((REPO / "README.md").read_text(encoding="utf-8").split())
    bullet = text.split("**A host stall is not a servo failure.**", 1)[1].split("- **", 1)[0]
    assert f"every stall over {STALL_ALLOWANCE_S * 1e3:g} ms" in bullet
    assert f"{STALL_EVENT_S * 1e3:g} ms or more also in a `host_stall` event" in bullet
    assert STALL_EVENT_INTERVAL_S == 1.0 and "at most one a second" in bullet
