"""The figures a running show hands to ``on_status`` twice a second: the terminal's status
line (``hilsim.cli._report.StatusLine``) and the heartbeat (:mod:`hilsim.show.heartbeat`)
read them. Built on the loop's thread between ticks, from what the loop already keeps."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import numpy.ma  # np.percentile imports it at its first call: here, not in a tick

from hilsim._types import JsonDict

if TYPE_CHECKING:
    from hilsim.show.loop import HilLoop


def status_figures(loop: HilLoop, k: int, t_sim: float, t_end: float) -> JsonDict:
    """What the show is doing at tick ``k`` (show time ``t_sim``; ``t_end`` the clock's now)."""
    director = loop.director
    return {
        "tick": k,
        "t": t_sim,
        "duration": loop.duration_s,
        "comm_errors": loop.watch.comm_errors,
        "overruns": loop.overruns,
        "host_stalls": loop.stalls.count,
        "lateness_p99_us": float(np.percentile(loop.recent_lateness_us[: min(k, 512)], 99)),
        "cue": None if director is None else director.now_playing,
        "read": loop.reading.status.tolist(),  # each servo's last (ReadStatus)
        "present_rad": loop.present.tolist(),
        "limp": list(loop.watch.limp),
        "condition": loop.watch.condition.views(t_end),  # temperature, voltage, load
        "layers": None if director is None else director.layers,
    }
