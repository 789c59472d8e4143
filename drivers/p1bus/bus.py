"""The Protocol 1.0-framed backend of :class:`~drivers.servo_bus.ServoBus`: Feetech STS/SCS
and Dynamixel AX/MX (Protocol 1.0 firmware), one family or several of one protocol per bus.

Each tick: one Sync Write (0x83) of Goal Position to every servo, then the best read the
family has (:class:`~drivers.p1bus.table.ReadMethod`): Feetech STS one Sync Read (0x82) and
Dynamixel MX one Bulk Read (0x92), each answered by a status packet per servo, each checked
on its own; AX and SCS servos have neither, so a few single Reads per tick, in rotation
(:meth:`P1ServoBus.plan` fits them to the tick; the servos not asked this tick read
:attr:`~drivers.servo_bus.ReadStatus.UNREAD`). A missing, cut or damaged reply is STALE
(NaN), an instruction/range/checksum error bit ERROR (NaN), a hardware bit (voltage,
overheating, overload ...) ALERT with its position. After a failed chain the next request
waits for the rest of it to pass (:meth:`~drivers.dynamixel.port.PortHandler.hold_until_quiet`).

No Bus Watchdog: :meth:`arm_watchdog` arms nothing (:attr:`has_watchdog` is False) and the
start-up check says so. The start-up check is :mod:`drivers.p1bus.startup`; torque, health
and the exit policy :mod:`drivers.p1bus.health`.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable, Sequence
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from drivers.clock import Clock
from drivers.dynamixel.errors import Mismatch, StartupMismatch
from drivers.fill import Packed
from drivers.p1bus import health
from drivers.p1bus.link import P1Link, decode
from drivers.p1bus.startup import P1Expectation, P1ServoState, P1StartupReport, check_servo
from drivers.p1bus.table import Family, ReadMethod, bus_read_method, family_of
from drivers.protocol1 import packet, wire_time
from drivers.protocol1.encoding import to_sign_magnitude
from drivers.servo_bus import (
    ExitPolicy,
    ExitReport,
    HealthPart,
    PresentReading,
    ReadStatus,
    ServoBus,
    ServoHealth,
)

_OK, _STALE, _ERROR, _ALERT, _UNREAD = (int(s) for s in ReadStatus)
#: Present Position bytes read per servo each tick
_POS_BYTES = 2
#: the share of a tick single reads in rotation may take (the rest: Sync Write, the host)
ROTATION_SHARE_OF_TICK = 0.6


class P1ServoBus(ServoBus):
    """Servos of the Protocol 1.0-framed families on one port. Build with :meth:`open`;
    positions are rad in the servo frame (the family's centre tick is 0 rad)."""

    has_watchdog = False
    condition_with_health = True  # its health read covers load, voltage and temperature

    def __init__(
        self, link: P1Link, ids: Sequence[int], models: Sequence[str], retries: int
    ) -> None:
        fams = [family_of(m) for m in models]
        unknown = [m for m, f in zip(models, fams, strict=True) if f is None]
        if unknown or len(models) != len(ids):
            raise ValueError(f"not Protocol 1.0 models: {unknown or models}")
        self.fams: list[Family] = [f for f in fams if f is not None]
        if len({f.protocol for f in self.fams}) > 1:
            raise ValueError("one protocol per bus: Feetech and Dynamixel servos mixed")
        super().__init__(ids, link.clock)
        self.by_id = dict(zip(self.ids, self.fams, strict=True))
        self.link, self.retries = link, int(retries)
        self.method = bus_read_method(set(self.fams))
        first = self.fams[0]
        self._goal_addr = first.goal_position.addr
        self._present = first.present_position
        self._tpr = [f.ticks_per_rad for f in self.fams]
        self._center = [f.center_tick for f in self.fams]
        self._lo = [0] * self.n
        self._hi = [f.max_tick for f in self.fams]
        self._rdt_s = [link.return_delay_s] * self.n
        self.per_tick = self.n if self.method is not ReadMethod.ROTATION else 1
        self._next = 0  # rotation: the next servo to read
        self.watchdog_period_s: float | None = None  # asked for, never armed (there is none)
        self.corrupt_sample: bytes | None = None
        ids_ = list(self.ids)
        if self.method is ReadMethod.SYNC:
            self._request = packet.sync_read(self._present.addr, _POS_BYTES, ids_)
        elif self.method is ReadMethod.BULK:
            addr = self._present.addr
            self._request = packet.bulk_read([(i, addr, _POS_BYTES) for i in ids_])
        self._views = (Packed(), Packed(), Packed())  # a reading's arrays (drivers.fill)
        self._single = [packet.read(i, self._present.addr, _POS_BYTES) for i in ids_]
        # the tick's Sync Write, built once: per tick only the goals and the checksum change
        # (the words in each servo's byte order: its family's, as encode() writes them)
        self._goal_frame = bytearray(
            packet.sync_write(self._goal_addr, _POS_BYTES, {i: bytes(_POS_BYTES) for i in ids_})
        )
        self._goal_pack = struct.Struct("<" + "BH" * self.n).pack_into
        self._goal_args: list[int] = [v for i in ids_ for v in (i, 0)]
        self._swap = [f.big_endian for f in self.fams]
        self._goal_sign = [f.goal_position.sign_bit for f in self.fams]
        # Present Position per servo: byte order, sign bit, the error bits that void a reply
        pr = self._present
        self._present_codec: list[tuple[Literal["little", "big"], int | None, int]] = [
            ("big" if f.big_endian else "little", pr.sign_bit, ~f.hardware_bits) for f in self.fams
        ]

    @classmethod
    def open(
        cls,
        port: str,
        *,
        baud: int,
        ids: Sequence[int],
        models: Sequence[str],
        latency_timer_ms: float | None = None,
        clock: Clock | None = None,
        retries: int = 2,
    ) -> P1ServoBus:
        """Open ``port`` for servos ``ids`` of ``models`` (one per ID); nothing is written."""
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        link = P1Link.open(port, baud=baud, clock=clock, latency_timer_ms=latency_timer_ms)
        assert isinstance(link, P1Link)  # (Link.open builds the class it is called on)
        try:
            return cls(link, ids, models, retries)
        except BaseException:
            link.close()
            raise

    def __repr__(self) -> str:
        return f"P1ServoBus({self.link.name!r}, baud={self.link.baud}, ids={self.ids})"

    @property
    def read_mode(self) -> ReadMethod:
        """How the tick reads: sync read, bulk read or single reads in rotation."""
        return self.method

    @property
    def families(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(f.name for f in self.fams))

    # -- the rotation ------------------------------------------------------------
    def read_s(self) -> float:
        """Expected seconds of one single Read of a position (request, reply, Return Delay,
        turnaround, the adapter's latency): what a rotation step costs."""
        byte_s = self.link.port.tx_time_per_byte * 1e-3
        wire = (packet.OVERHEAD + 2 + packet.OVERHEAD + _POS_BYTES) * byte_s
        return wire + max(self._rdt_s) + 100e-6 + self.link.latency_timer_ms * 1e-3

    def write_s(self) -> float:
        """Expected seconds of the tick's Sync Write (no reply)."""
        byte_s = self.link.port.tx_time_per_byte * 1e-3
        return (packet.OVERHEAD + 2 + self.n * (1 + _POS_BYTES)) * byte_s

    def plan(self, period_s: float) -> int:
        """Fit the rotation's single reads to a tick of ``period_s``: as many per tick as
        :data:`ROTATION_SHARE_OF_TICK` of it holds (at least one). Returns reads per tick."""
        if self.method is ReadMethod.ROTATION:
            room = ROTATION_SHARE_OF_TICK * period_s - self.write_s()
            self.per_tick = max(1, min(self.n, int(room / self.read_s())))
        return self.per_tick

    def model_cycle_s(self, return_delay_s: float | None = None, baud: int | None = None) -> float:
        """The wire model's time of one tick (:mod:`drivers.protocol1.wire_time`): the Sync
        Write, this tick's reads, each reply's Return Delay Time (the longest on the bus, or
        ``return_delay_s``) and turnaround, the adapter latency once per read transaction; at
        the link's baud, or ``baud``."""
        method = {
            ReadMethod.SYNC: wire_time.ReadMethod.SYNC_READ,
            ReadMethod.BULK: wire_time.ReadMethod.BULK_READ,
            ReadMethod.ROTATION: wire_time.ReadMethod.SINGLE,
        }[self.method]
        return wire_time.cycle_time_s(
            self.n,
            self.link.baud if baud is None else baud,
            method,
            return_delay_s=max(self._rdt_s) if return_delay_s is None else return_delay_s,
            latency_s=self.link.latency_timer_ms * 1e-3,
            reads=self.per_tick,
        )

    @property
    def return_delay_s(self) -> float:
        """The longest Return Delay Time on the bus (s): as read by :meth:`check`, else the
        factory's."""
        return max(self._rdt_s)

    def read_rate_hz(self, tick_hz: float) -> float:
        """How often each servo's position is read at ``tick_hz`` ticks a second."""
        return tick_hz * self.per_tick / self.n

    # -- per tick ----------------------------------------------------------------
    def _write_goals(self, goals: NDArray[np.float64]) -> None:
        # one pass: tick, range check, the word in the servo's order (the tick's path)
        args, frame = self._goal_args, self._goal_frame
        i, bad = 1, False
        for g, tpr, c, lo, hi, sign, swap in zip(
            goals.tolist(),
            self._tpr,
            self._center,
            self._lo,
            self._hi,
            self._goal_sign,
            self._swap,
            strict=True,
        ):
            tk = round(g * tpr) + c
            if not lo <= tk <= hi:
                bad = True
                continue
            raw = (tk if tk >= 0 or sign is None else to_sign_magnitude(tk, sign)) & 0xFFFF
            args[i] = (raw >> 8 | (raw & 0xFF) << 8) if swap else raw
            i += 2
        if bad:
            self._refuse_goals(goals)
        self._goal_pack(frame, 7, *args)  # after FF FF FE LEN 83 addr len
        frame[-1] = ~sum(memoryview(frame)[2:-1]) & 0xFF
        self.link.transact(bytes(frame), (), 0, "Sync Write")

    def _refuse_goals(self, goals: NDArray[np.float64]) -> None:
        """ValueError naming every goal outside what its servo accepts."""
        ticks = [
            round(g * t) + c
            for g, t, c in zip(goals.tolist(), self._tpr, self._center, strict=True)
        ]
        raise ValueError(
            "goal outside what the servo accepts; nothing sent: "
            + ", ".join(
                f"servo {s}: tick {t} not in {lo}..{hi}"
                for s, t, lo, hi in zip(self.ids, ticks, self._lo, self._hi, strict=True)
                if not lo <= t <= hi
            )
        )

    def _read_present(self, out: PresentReading) -> None:
        n = self.n
        pos = [math.nan] * n
        status = [_STALE] * n
        errors = [0] * n
        out.t = self._clock.now()
        failed = 0
        if self.method is ReadMethod.ROTATION:
            status = [_UNREAD] * n
            for _ in range(self.per_tick):
                k = self._next
                self._next = (k + 1) % n
                replies = self.link.transact(self._single[k], (self.ids[k],), _POS_BYTES, "Read")
                status[k] = _STALE
                self._take(k, replies.got.get(self.ids[k]), pos, status, errors)
                if replies.corrupt:
                    self.corrupt_sample = replies.corrupt[-1] or self.corrupt_sample
                if status[k] == _STALE:
                    failed = 1
                    self.link.port.hold_until_quiet(
                        self._clock.now() + self.link.chain_s(1, _POS_BYTES)
                    )
        else:
            replies = self.link.transact(self._request, self.ids, _POS_BYTES, str(self.method))
            got, size = replies.got, self._present.size
            # _take's work for each servo, inline: the tick's path
            for k, (sid, (order, sign, bad), centre, tpr) in enumerate(
                zip(self.ids, self._present_codec, self._center, self._tpr, strict=True)
            ):
                reply = got.get(sid)
                if reply is None:
                    continue
                err, params = reply
                errors[k] = err
                if err & bad:
                    status[k] = _ERROR
                    continue
                tick = int.from_bytes(params[:size], order)
                if sign is not None:
                    tick = (
                        -(tick & ((1 << sign) - 1))
                        if tick >> sign & 1
                        else tick & ((1 << sign) - 1)
                    )
                pos[k] = (tick - centre) / tpr
                status[k] = _ALERT if err else _OK
            if replies.corrupt:
                self.corrupt_sample = replies.corrupt[-1] or self.corrupt_sample
            failed = status.count(_STALE)
            if failed:  # the rest of the chain may still be on the wire: wait it out
                now = self._clock.now()
                rest = self.link.chain_s(n, _POS_BYTES) + self.link.latency_timer_ms * 1e-3
                self.link.port.hold_until_quiet(now + rest)
        pv, sv, ev = self._views  # the reading's arrays, viewed once (drivers.fill)
        if pv.arr is not out.positions or sv.arr is not out.status or ev.arr is not out.errors:
            pv, sv, ev = self._views = (
                Packed(out.positions, n),
                Packed(out.status, n),
                Packed(out.errors, n),
            )
        pv.put(*pos)
        sv.put(*status)
        ev.put(*errors)
        out.t_done = self._clock.now()

    def _take(
        self,
        k: int,
        reply: tuple[int, bytes] | None,
        pos: list[float],
        status: list[int],
        errors: list[int],
    ) -> None:
        if reply is None:
            return
        err, params = reply
        fam = self.fams[k]
        errors[k] = err
        if err & ~fam.hardware_bits:
            status[k] = _ERROR
            return
        tick = decode(fam, self._present, params, self._present.addr)
        pos[k] = (tick - self._center[k]) / self._tpr[k]
        status[k] = _ALERT if err else _OK

    # -- start-up ----------------------------------------------------------------
    def check(self, expectations: Iterable[P1Expectation]) -> P1StartupReport:
        """Every servo against its :class:`~drivers.p1bus.startup.P1Expectation`, in its
        family's terms; read-only. Raises :class:`StartupMismatch` with one table of every
        difference. Loads each servo's goal range and Return Delay Time into the bus."""
        self._check_open()
        exps = {e.id: e for e in expectations}
        if set(exps) != set(self.ids):
            raise ValueError(f"expectations must cover exactly servos {self.ids}")
        self.link.recover()
        rows: list[Mismatch] = []
        states: list[P1ServoState] = []
        notes: list[str] = []
        for k, sid in enumerate(self.ids):
            found = check_servo(self.link, self.fams[k], exps[sid], 1 + self.retries)
            rows += found.rows
            notes += found.notes
            if found.goal_range is not None:
                self._lo[k], self._hi[k] = found.goal_range
            if found.return_delay_s is not None:
                self._rdt_s[k] = found.return_delay_s
            if found.state is not None:
                states.append(found.state)
        self.link.return_delay_s = max(self._rdt_s)
        if rows:
            raise StartupMismatch(rows, port=self.link.name)
        notes.append(
            f"{', '.join(self.families)}: no Bus Watchdog: a host stall is measured and said "
            "(the servos hold their last goal meanwhile)"
        )
        if self.method is ReadMethod.ROTATION:
            notes.append(
                f"{', '.join(self.families)}: no Sync Read: positions are read "
                f"{self.per_tick} servo(s) per tick, in rotation"
            )
        states_t: tuple[P1ServoState, ...] = tuple(states)
        return P1StartupReport(self.link.name, self.link.baud, self.method, states_t, tuple(notes))

    def clear_watchdog_trips(self) -> tuple[int, ...]:
        """There is no Bus Watchdog to have tripped."""
        return ()

    # -- state changes -----------------------------------------------------------
    def _set_torque(self, on: bool, ids: tuple[int, ...]) -> None:
        health.write_all(self.link, self.by_id, ids, "torque_enable", int(on), 1 + self.retries)

    def _arm_watchdog(self, period_s: float) -> None:
        self.watchdog_period_s = period_s  # nothing to arm: the host watches its own stalls

    def _disarm_watchdog(self) -> None:
        self.watchdog_period_s = None

    def _read_health(self, servo_id: int, part: HealthPart) -> ServoHealth:
        return health.read_health(self.link, self.by_id[servo_id], servo_id, part)

    def _health_read_s(self) -> float:
        byte_s = self.link.port.tx_time_per_byte * 1e-3
        size = max(health.health_block(f)[1] for f in self.fams)
        return (
            (2 * packet.OVERHEAD + 2 + size) * byte_s
            + max(self._rdt_s)
            + 100e-6
            + self.link.latency_timer_ms * 1e-3
        )

    def _recover_watchdog(self, servo_id: int, goal_rad: float) -> None:
        raise ValueError(f"servo {servo_id}: no Bus Watchdog on {self.by_id[servo_id].name}")

    def _apply_exit_policy(self, policy: ExitPolicy, retries: int) -> ExitReport:
        return health.apply_exit_policy(self.link, self.by_id, self.ids, policy, 1 + retries)

    @property
    def host_stall_s(self) -> float:
        return float(getattr(self.link.port, "host_stall_s", 0.0))

    @property
    def device_wait_s(self) -> float:
        return float(getattr(self.link.port, "device_wait_s", 0.0))

    def _close(self) -> None:
        self.link.close()
