"""The heartbeat: a small JSON file saying how a running show is doing, for a monitor.

``status.json`` (in the run directory, or where the show's ``status_file`` says) is rewritten
about every ``every_s`` seconds from the figures the loop offers twice a second (tick, show
time, rate, lateness p99, overruns, comm errors, host stalls, each servo's last read, what
plays), and once more at each change of state: ``starting``, ``running``, ``stopping`` (the
loop has stopped; the exit policy comes next), ``ended`` (with the exit code and reason, as
``summary.json`` says them) or ``refused`` (nothing moved). Its last write says how the run
ended. The layout and a staleness check are in ``docs/service.md``.

The loop only hands its dict over (a lock held for an append); a thread of its own turns it
into the file's fields and writes them, each time to a temporary file then ``os.replace``,
so a reader never sees half a file and a slow or full disk never holds up a tick. A write
that fails is one line (through ``say``), then the show goes on; one more line when writing
works again.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import threading
import time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from drivers.servo_bus import CONDITION_FIELDS, ReadStatus
from hilsim._types import JsonDict

__all__ = ["STATUS_FILE", "STATUS_SCHEMA_VERSION", "Heartbeat"]

#: its name in the run directory
STATUS_FILE = "status.json"
#: raised when a field changes meaning or goes away (fields may be added without it)
STATUS_SCHEMA_VERSION = 1
#: how long the end of a show waits for the last write (a stalled disk: the show has ended)
END_TIMEOUT_S = 2.0


def _now() -> tuple[str, float]:
    t = time.time()
    return datetime.fromtimestamp(t, UTC).isoformat(timespec="milliseconds"), t


def _condition(c: JsonDict | None) -> JsonDict:
    """One servo's figures from the loop's ``condition`` (every key, None where unknown)."""
    c = c or {}
    keys = [k for f in CONDITION_FIELDS for k in (f, f + "_age_s")]
    return {k: _finite(c.get(k)) for k in keys}


def _finite(x: Any) -> float | None:
    return float(x) if isinstance(x, int | float) and math.isfinite(x) else None


class Heartbeat:
    """Writes ``path`` for one show. ``fixed``: fields every write carries (rig, run
    directory, clock...); ``joints``: (joint name, servo ID) in bus order; ``say``: one line
    for a write that failed, and for writing that works again."""

    def __init__(
        self,
        path: Path,
        *,
        fixed: JsonDict,
        joints: Sequence[tuple[str, int]],
        every_s: float = 1.0,
        say: Callable[[str], None],
    ) -> None:
        if not (math.isfinite(every_s) and every_s > 0):
            raise ValueError(f"status_every_s must be a finite number > 0, got {every_s!r}")
        self.path, self.every_s, self._say = path, every_s, say
        self._joints = tuple(joints)
        started, _ = _now()
        self._doc: JsonDict = {
            "schema_version": STATUS_SCHEMA_VERSION,
            "state": "starting",
            "pid": os.getpid(),
            "started_at": started,
            "interval_s": every_s,
            **fixed,
            "rate_hz": None,
            **self._figures({}),  # every field from the first write: null until known
            "exit_code": None,
            "exit_reason": None,
        }
        self._cv = threading.Condition()
        #: changes for the writer, in order: (fields, the loop's raw figures or None); the
        #: writer alone touches ``_doc`` once started
        self._queue: list[tuple[JsonDict, JsonDict | None]] = []
        self._final = self._closed = False
        self._failing = False
        self._last: tuple[float, int] | None = None  # (perf_counter, tick) of the last offer
        self._thread: threading.Thread | None = None
        #: writes that succeeded / failed (for tests and the curious)
        self.writes = self.failures = 0

    # ------------------------------------------------------------------ the loop's side
    def start(self) -> None:
        """The show's record is open: ``starting`` now, then a thread writes each offer."""
        self._thread = threading.Thread(target=self._run, name="hilsim-heartbeat", daemon=True)
        self._thread.start()
        self._put({})

    def offer(self, st: JsonDict) -> None:
        """The loop's live figures (``HilLoop``'s ``on_status``); kept at most every
        ``every_s``. Never blocks on the disk."""
        now = time.perf_counter()
        last = self._last
        if last is not None and now - last[0] < 0.9 * self.every_s:
            return
        tick = st.get("tick", 0)
        rate = None if last is None or now <= last[0] else (tick - last[1]) / (now - last[0])
        self._last = (now, tick)
        self._put({"state": "running", "rate_hz": rate}, raw=st)

    def stopping(self, code: int, reason: str) -> None:
        """The loop has stopped (``on_stop``): the exit policy is next."""
        self._put({"state": "stopping", "exit_code": int(code), "exit_reason": reason})

    def end(self, outcome: JsonDict) -> None:
        """The show has ended: ``outcome`` has its exit code, reason, exit policy. Written,
        waited for (at most :data:`END_TIMEOUT_S`), and the thread ends."""
        self._put({"state": "ended", "rate_hz": None, **outcome}, final=True)
        if self._thread is not None:
            self._thread.join(END_TIMEOUT_S)
            if self._thread.is_alive():
                self._say(
                    f"warning: {self.path}: the last status was not written within "
                    f"{END_TIMEOUT_S:g} s (a stalled disk?)"
                )
                with self._cv:
                    self._closed = True

    def refused(self, reason: str) -> None:
        """The show was refused before anything moved (exit 2): one write, at once."""
        self._doc.update(state="refused", exit_code=2, exit_reason=reason, run_dir=None)
        self._write(dict(self._doc), final=True)

    # ------------------------------------------------------------------ the writer's side
    def _figures(self, st: JsonDict) -> JsonDict:
        reads = st.get("read") or ()
        present = st.get("present_rad") or ()
        limp = set(st.get("limp") or ())
        conditions = st.get("condition") or ()
        servos = []
        for i, (joint, sid) in enumerate(self._joints):
            code = reads[i] if i < len(reads) else None
            rad = _finite(present[i]) if i < len(present) else None
            servos.append(
                {
                    "id": sid,
                    "joint": joint,
                    "read": None if code is None else ReadStatus(int(code)).name.lower(),
                    "present_deg": None if rad is None else round(math.degrees(rad), 3),
                    "limp": i in limp,
                    # temperature_c, voltage_v, load_pct, current_a and each one's age (s):
                    # null where never read; a failed read leaves the last figure
                    **_condition(conditions[i] if i < len(conditions) else None),
                }
            )
        return {
            "tick": int(st.get("tick", 0)),
            "show_time_s": _finite(st.get("t")),
            "duration_s": _finite(st.get("duration")),
            "lateness_p99_us": _finite(st.get("lateness_p99_us")),
            "overruns": int(st.get("overruns", 0)),
            "comm_errors": int(st.get("comm_errors", 0)),
            "host_stalls": int(st.get("host_stalls", 0)),
            "playing": st.get("cue"),
            "servos": servos,
        }

    def _put(self, change: JsonDict, *, raw: JsonDict | None = None, final: bool = False) -> None:
        """Queue a change for the writer; a running offer replaces one still waiting (a
        stalled disk: only the newest figures are kept)."""
        with self._cv:
            if self._final or self._closed:
                return
            queue = self._queue
            if raw is not None and queue and queue[-1][1] is not None:
                queue[-1] = (change, raw)
            else:
                queue.append((change, raw))
            self._final = final
            self._cv.notify()

    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._queue and not self._closed:
                    self._cv.wait()
                if self._closed:
                    return
                changes, self._queue = self._queue, []
                final = self._final
            for change, raw in changes:  # the loop's figures turned into fields here, not there
                if raw is not None:
                    self._doc.update(self._figures(raw))
                self._doc.update(change)
            self._write(dict(self._doc), final=final)
            if final:
                return

    def _write(self, doc: JsonDict, *, final: bool) -> None:
        doc["written_at"], doc["written_at_unix"] = _now()
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        try:
            text = json.dumps(doc, indent=1, default=str, allow_nan=False) + "\n"
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with open(tmp, "w", encoding="utf-8") as f:
                f.write(text)
                if final:  # how the run ended survives a power cut
                    f.flush()
                    os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except Exception as exc:  # a full disk, a gone directory: never the show's end
            self.failures += 1
            with contextlib.suppress(OSError):
                tmp.unlink()
            if not self._failing:
                self._failing = True
                why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
                self._say(
                    f"warning: status file {self.path} not written ({why}); the show goes on, "
                    "trying again at each status"
                )
            return
        self.writes += 1
        if self._failing:
            self._failing = False
            self._say(f"status file {self.path} written again")
