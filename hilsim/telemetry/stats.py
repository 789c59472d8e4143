"""Run statistics: per-tick numbers accumulated on the loop thread, turned into the run summary.

:class:`RunStats` is fed by :class:`hilsim.telemetry.TelemetryWriter` (or directly, without a
writer); :func:`summarize` builds the JSON-ready summary (``summary.json``) from whole-run arrays,
with percentiles (:data:`PERCENTILES`) of lateness and per-stage times.

Safety interventions are counted in one place, the summary's ``safety_limits``: kind -> joint ->
count, where the kinds are the safety filter's counters (:data:`hilsim.safety.filter.COUNTER_KINDS`:
``position`` the desired position was beyond a limit and was clamped, ``speed``, ``accel``,
``brake`` the step was shortened by that limit, ``nonfinite`` the desired value was NaN/inf,
``outside`` the command itself was outside the limits, walking back in after a start outside
them), counted in ticks; one tick may count under several kinds. Beside it, ``safety_ticks`` gives
``{"filtered": ticks the filter ran, "held": ticks it held every joint on a non-finite input}``.
The loop hands the filter's counters over once, at the end (:meth:`RunStats.set_safety_counts`);
then every kind lists every joint, **0 included**, so a missing joint never reads as "not counted".
If no counts ever arrived (the run died before the loop could hand them over) ``safety_limits``
and ``safety_ticks`` are ``null``: unknown, not zero.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from drivers.servo_bus import ReadStatus
from hilsim.telemetry.format import STAGES, SUMMARY_SCHEMA_VERSION, TickRecord, check_joint_names

#: percentiles reported in the summary, as (key, q)
PERCENTILES: tuple[tuple[str, float], ...] = (("p50", 50.0), ("p99", 99.0), ("p99.9", 99.9))


def _percentiles(values: np.ndarray) -> dict[str, float | None]:
    """p50/p99/p99.9/max/mean of the finite values (numpy's linear interpolation); None if none."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {**{k: None for k, _ in PERCENTILES}, "max": None, "mean": None}
    qs = np.percentile(v, [q for _, q in PERCENTILES])
    out: dict[str, float | None] = {k: float(x) for (k, _), x in zip(PERCENTILES, qs, strict=True)}
    out["max"] = float(v.max())
    out["mean"] = float(v.mean())
    return out


def summarize(
    *,
    joint_names: Sequence[str],
    t_actual: npt.ArrayLike,
    lateness_us: npt.ArrayLike,
    overrun: npt.ArrayLike,
    stage_us: Mapping[str, npt.ArrayLike],
    status: npt.ArrayLike,
    servo_ids: Sequence[Any] | None = None,
    safety_limits: Mapping[str, Mapping[str, int]] | None = None,
    safety_ticks: Mapping[str, int] | None = None,
    faults: Sequence[Mapping[str, Any]] = (),
    exit_code: int | None = None,
    exit_reason: str | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """Build the summary dict (JSON-ready) from whole-run arrays.

    ``t_actual`` (s), ``lateness_us``, ``overrun`` and each ``stage_us[stage]`` (µs) are shaped
    ``(ticks,)``; ``status`` is ``(ticks, n_joints)`` of :class:`ReadStatus` codes.

    Keys: ``ticks``; ``duration_s`` (first to last tick start) and ``rate_hz`` (achieved:
    (ticks - 1) / duration); ``lateness_us`` and ``stage_us[stage]`` as p50/p99/p99.9/max/mean
    (numpy's linear interpolation over finite values; None when there are none); ``overruns``
    and ``overruns_failed_read`` (those on a tick whose read left a servo unread);
    ``stale_reads``/``error_reads``/``alert_reads`` per joint (their sum is the run's
    communication errors); ``servo_ids`` (joint -> servo ID); ``safety_limits`` (kind -> joint
    -> count) and ``safety_ticks`` (as given; None, JSON null, when not given: see the module
    docstring); ``faults``; ``exit_code``, ``exit_reason``; then ``extra`` verbatim. The keys
    and their meaning are documented in ``docs/summary.md`` (``schema_version``).
    """
    names = list(joint_names)
    if servo_ids is not None and len(servo_ids) != len(names):
        raise ValueError(f"{len(servo_ids)} servo ids for {len(names)} joints")
    lat = np.asarray(lateness_us, dtype=np.float64).reshape(-1)
    ticks = int(lat.size)
    st = np.asarray(status).reshape(ticks, len(names))
    t = np.asarray(t_actual, dtype=np.float64).reshape(-1)
    span = float(t[-1] - t[0]) if ticks else 0.0
    late = np.nan_to_num(np.asarray(overrun, dtype=np.float64).reshape(-1)) != 0

    def per_joint(code: ReadStatus) -> list[int]:
        return [int(c) for c in (st == code).sum(axis=0)]

    return {
        "schema_version": SUMMARY_SCHEMA_VERSION,
        "ticks": ticks,
        "duration_s": span,
        "rate_hz": (ticks - 1) / span if span > 0 else None,
        "lateness_us": _percentiles(lat),
        "overruns": int(np.count_nonzero(late)),
        "overruns_failed_read": int(np.count_nonzero(late & (st == ReadStatus.STALE).any(axis=1))),
        "stage_us": {s: _percentiles(np.asarray(v, dtype=np.float64)) for s, v in stage_us.items()},
        "stale_reads": dict(zip(names, per_joint(ReadStatus.STALE), strict=True)),
        "error_reads": dict(zip(names, per_joint(ReadStatus.ERROR), strict=True)),
        "alert_reads": dict(zip(names, per_joint(ReadStatus.ALERT), strict=True)),
        "servo_ids": None
        if servo_ids is None
        else {
            j: (int(s) if isinstance(s, int | np.integer) else str(s))
            for j, s in zip(names, servo_ids, strict=True)
        },
        "safety_limits": None
        if safety_limits is None
        else {k: {str(j): int(n) for j, n in v.items()} for k, v in safety_limits.items()},
        "safety_ticks": None
        if safety_ticks is None
        else {str(k): int(n) for k, n in safety_ticks.items()},
        "faults": [dict(f) for f in faults],
        "exit_code": exit_code,
        "exit_reason": exit_reason,
        **extra,
    }


def comm_errors(summary: Mapping[str, Any], servo: int | None = None) -> int:
    """Communication errors from a summary: reads that were not OK (stale, error or alert), of
    every joint or of one ``servo`` (by ID); 0 for a summary without read counts."""
    joints = None
    if servo is not None:
        joints = {j for j, sid in (summary.get("servo_ids") or {}).items() if sid == servo}
    return sum(
        int(n)
        for key in ("stale_reads", "error_reads", "alert_reads")
        for j, n in (summary.get(key) or {}).items()
        if joints is None or j in joints
    )


_PACK_ROW = struct.Struct("7d").pack_into  # one row of RunStats._COLS
_PACK_LATE = struct.Struct("5d").pack_into  # its overrun and stage times (from column 2)
_ROW_BYTES = 7 * 8


class RunStats:
    """Accumulates what the summary needs, cheaply, on the loop thread; percentiles at the end.

    Per tick, :meth:`add` stores the tick's start time, lateness, overrun flag, the four stage
    times and the read status into preallocated chunks of ``chunk_ticks`` rows (when one fills a
    new one is allocated, never copied: no tick pays for a large copy). Faults are noted when
    they happen (:meth:`fault`); the safety filter's counters arrive once, at the end
    (:meth:`set_safety_counts`): it is their one owner. :meth:`summary`
    computes everything with numpy (:func:`summarize`). A :class:`TelemetryWriter` owns one and
    feeds it; use one directly only without a writer.
    """

    #: columns of the per-tick float chunk
    _COLS = ("t_actual", "lateness_us", "overrun", *(f"t_{s}_us" for s in STAGES))

    def __init__(
        self,
        joint_names: Sequence[str],
        *,
        servo_ids: Sequence[Any] | None = None,
        chunk_ticks: int = 1 << 16,
    ) -> None:
        self.joint_names = check_joint_names(joint_names)
        if servo_ids is not None and len(servo_ids) != len(self.joint_names):
            raise ValueError(f"{len(servo_ids)} servo ids for {len(self.joint_names)} joints")
        self.servo_ids = None if servo_ids is None else tuple(servo_ids)
        self._n = len(self.joint_names)
        self._chunk_ticks = int(chunk_ticks)
        self._done: list[tuple[np.ndarray, np.ndarray]] = []
        self._new_chunk()
        #: a status array and a memoryview of it (None: not a uint8 array of n)
        self._status_seen: tuple[object, memoryview | None] = (None, None)
        self._last_tick: int | None = None
        self.safety_limits: dict[str, dict[str, int]] | None = None
        self.safety_ticks: dict[str, int] | None = None
        self.faults: list[dict[str, Any]] = []

    def _new_chunk(self) -> None:
        self._f = np.full((self._chunk_ticks, len(self._COLS)), np.nan)
        self._s = np.zeros((self._chunk_ticks, self._n), dtype=np.int8)
        self._i = 0
        # add() packs each tick into the chunks' memory (drivers.fill: no numpy call per tick)
        self._f_bytes = self._f.data.cast("B")  # memoryview(a), typed (see telemetry.ring)
        self._s_bytes = self._s.data.cast("B")

    def add(self, rec: TickRecord) -> None:
        """Store one tick: its start time, lateness, overrun, stage times and read status."""
        i = self._i
        if i == self._chunk_ticks:
            self._done.append((self._f, self._s))
            self._new_chunk()
            i = 0
        _PACK_ROW(
            self._f_bytes,
            i * _ROW_BYTES,
            rec.t_actual,
            rec.lateness_us,
            rec.overrun,
            rec.t_sim_us,
            rec.t_safety_us,
            rec.t_bus_us,
            rec.t_telemetry_us,
        )
        status, n = rec.status, self._n
        seen = self._status_seen
        if seen[0] is not status:  # a status array's bytes, viewed once
            view = None
            if type(status) is np.ndarray and status.dtype == np.uint8 and status.shape == (n,):
                view = status.data  # memoryview(status)
            seen = self._status_seen = (status, view)
        if seen[1] is not None:
            self._s_bytes[i * n : (i + 1) * n] = seen[1]  # 0..3: the same bytes as int8
        else:
            self._s[i] = status
        self._i = i + 1
        self._last_tick = rec.tick

    def amend(self, rec: TickRecord) -> None:
        """Take the late values (stage times, overrun) of the last tick added, ``rec.tick``."""
        if self._i == 0 or rec.tick != self._last_tick:
            raise ValueError(f"can only amend the last tick ({self._last_tick}), not {rec.tick}")
        _PACK_LATE(
            self._f_bytes,
            (self._i - 1) * _ROW_BYTES + 16,
            rec.overrun,
            rec.t_sim_us,
            rec.t_safety_us,
            rec.t_bus_us,
            rec.t_telemetry_us,
        )

    def set_safety_counts(
        self,
        counts: Mapping[str, Mapping[str, int]],
        *,
        ticks: int,
        held_ticks: int = 0,
    ) -> None:
        """Take the safety filter's counters for the summary (once, at the end of the run).

        Args:
            counts: kind -> joint name -> ticks, e.g. ``SafetyFilter.counters.by_kind()`` (kinds
                position, speed, accel, brake, nonfinite, outside).
            ticks: how many ticks the filter ran (``SafetyCounters.ticks``).
            held_ticks: ticks it held every joint on a non-finite input (``.fault_ticks``).

        Replaces what earlier calls of either method counted; every joint of this run is listed
        under every kind given, 0 when the counts do not name it. Raises ValueError for a
        negative count or a joint name this run does not have.
        """
        known = set(self.joint_names)
        table: dict[str, dict[str, int]] = {}
        for kind, per_joint in counts.items():
            row = dict.fromkeys(self.joint_names, 0)
            for joint, n in per_joint.items():
                if str(joint) not in known:
                    raise ValueError(f"safety counts for an unknown joint {joint!r} ({kind})")
                if int(n) < 0:
                    raise ValueError(f"negative safety count {n!r} for {joint} ({kind})")
                row[str(joint)] = int(n)
            table[str(kind)] = row
        if int(ticks) < 0 or int(held_ticks) < 0:
            raise ValueError(f"tick counts must be >= 0, got {ticks!r} and {held_ticks!r}")
        self.safety_limits = table
        self.safety_ticks = {"filtered": int(ticks), "held": int(held_ticks)}

    def fault(
        self, kind: str, message: str, tick: int | None, t: float | None, **fields: Any
    ) -> None:
        """Remember a fault for the summary's ``faults`` list."""
        self.faults.append({"kind": kind, "message": message, "tick": tick, "t": t, **fields})

    @property
    def ticks(self) -> int:
        return len(self._done) * self._chunk_ticks + self._i

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(ticks, 7)`` float array (columns ``_COLS``) and ``(ticks, n)`` int8 status, copied
        together from the chunks."""
        fs = [f for f, _ in self._done] + [self._f[: self._i]]
        ss = [s for _, s in self._done] + [self._s[: self._i]]
        return np.concatenate(fs), np.concatenate(ss)

    def summary(self, **extra: Any) -> dict[str, Any]:
        """The run summary (:func:`summarize`); ``extra`` (``exit_code``, ``exit_reason``, ...)
        is passed on."""
        f, s = self.arrays()
        return summarize(
            joint_names=self.joint_names,
            t_actual=f[:, 0],
            lateness_us=f[:, 1],
            overrun=f[:, 2],
            stage_us={stage: f[:, 3 + k] for k, stage in enumerate(STAGES)},
            status=s,
            servo_ids=self.servo_ids,
            safety_limits=self.safety_limits,
            safety_ticks=self.safety_ticks,
            faults=self.faults,
            **extra,
        )
