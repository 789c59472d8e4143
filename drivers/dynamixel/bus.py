"""The Dynamixel backend of :class:`~drivers.servo_bus.ServoBus`, over dynamixel-sdk.

:class:`DynamixelBus` - the loop's bus: one Sync Write of Goal Position per tick, one
Fast Sync Read (or plain Sync Read) of Present Position per tick with a status for
every servo, start-up :meth:`~DynamixelBus.check`, watchdog, torque and exit policy.
Non-tick transactions go through a :class:`~drivers.dynamixel.link.Link` (the per-servo
start-up check is :func:`~drivers.dynamixel.startup.check_servo`; health, watchdog recovery
and the exit policy are in :mod:`drivers.dynamixel.health`). The per-tick packets are
built, sent and received by :mod:`drivers.dynamixel.tick_packets`: the SDK's bytes and its
calls on the port, without its per-call costs. Read timeouts count bytes with
:mod:`drivers.protocol2.wire_time`.

Per-servo status on every read. The SDK's ``GroupSyncRead`` drops each servo's ERR byte and
``getData`` returns 0 for missing data, and its Fast Sync Read reports one result for the
whole packet, so the bus parses the replies itself: plain Sync Read takes the status packets
in chain order (a corrupt one costs only its own place; a reply from an unexpected ID ends
the read); Fast Sync Read takes the one packet and keeps each block only while every earlier
block was kept, the block carries the ID asked at its position, and the running CRC over it
matches (:func:`~drivers.dynamixel.fast_reply.parse_blocks`). After a silent servo the next
request waits out the rest of that chain and discards it, and the order of the next read
changes (:mod:`drivers.dynamixel.read_order`: a silent servo silences those after it, and a
Fast block later than the wait could fill its own servo's place in a later reply); plain
reads after it ask another length for a while, so a late status packet (its LEN says the
length it answers) is passed over.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from functools import partial
from operator import le

import numpy as np
from numpy.typing import ArrayLike, NDArray

from drivers.clock import Clock
from drivers.dynamixel import health, tick_block
from drivers.dynamixel.errors import (
    DynamixelError,
    Mismatch,
    StartupMismatch,
)
from drivers.dynamixel.fast_reply import STALE
from drivers.dynamixel.link import Link
from drivers.dynamixel.read_order import ReadOrder
from drivers.dynamixel.sdk_result import OK, SERIAL_ERRORS, port_gone, raise_for
from drivers.dynamixel.startup import (
    Expectation,
    ReadMode,
    ServoState,
    StartupReport,
    all_support_fast,
    check_servo,
    retry,
)
from drivers.dynamixel.tick_packets import (
    GoalFrame,
    finite_goals,
    goal_range_error,
    receive_fast_reply,
    receive_plain_replies,
    send_goals,
    sync_read_request,
    transmit,
)
from drivers.dynamixel.units import (
    CENTER_TICK,
    TICKS_PER_RAD,
    rad_to_ticks,
)
from drivers.fill import Packed
from drivers.protocol2 import control_table as ct
from drivers.protocol2 import wire_time
from drivers.servo_bus import (
    ExitPolicy,
    ExitReport,
    HealthPart,
    HealthProblem,
    PresentReading,
    ServoBus,
    ServoHealth,
)

#: Servo processing time allowed per reply on top of its Return Delay Time (AX ~20 µs,
#: MX ~50 µs; X series unpublished). A timeout's allowance, so above the wire-time model's
#: estimate (:data:`drivers.protocol2.wire_time.DEFAULT_TURNAROUND_S`).
TURNAROUND_ALLOWANCE_S = 50e-6
#: Return Delay Time assumed until :meth:`DynamixelBus.check` has read the real one.
FACTORY_RETURN_DELAY_S = 500e-6
#: Bytes of Present Position in a reply (the wire-time model's data bytes).
_DATA_BYTES = ct.PRESENT_POSITION.size


# ----------------------------------------------------------------------- the bus
class DynamixelBus(ServoBus):
    """Dynamixel X-series servos (Protocol 2.0) on one port, through dynamixel-sdk.

    Build with :meth:`open`. Positions are rad in the servo frame (tick 2048 = 0 rad,
    4096 ticks per turn). ``retries`` is how often non-tick transactions (check, torque,
    watchdog) are repeated on a wire failure; per-tick calls never retry.
    """

    def __init__(self, link: Link, ids: Sequence[int], read_mode: ReadMode, retries: int) -> None:
        super().__init__(ids, link.clock)
        self.link = link
        self.retries = int(retries)
        self._requested = read_mode
        self._fast = read_mode is ReadMode.FAST
        self._ph, self._port = link.ph, link.port
        n = self.n
        self._index = {sid: k for k, sid in enumerate(self.ids)}
        self._orders = ReadOrder(n)
        link.unanswered = self._unanswered  # a show's other reads' late replies, too
        self._set_order()
        self._goal_frame = GoalFrame(self.ids, ct.GOAL_POSITION.addr)  # the tick's Sync Write
        # accepted Goal Position ticks (Position mode until check)
        self._lo: NDArray[np.float64] = np.zeros(n)
        self._hi: NDArray[np.float64] = np.full(n, 4095.0)
        self._lo_l, self._hi_l = self._lo.tolist(), self._hi.tolist()  # the same, as lists
        # read_present's books: the last read all OK; stats.consecutive_bad maybe not all 0
        self._all_ok, self._bad_counted = False, True
        self._views: tuple[Packed, ...] = (Packed(), Packed(), Packed())  # a reading's arrays
        self._rdt_s = np.full(n, FACTORY_RETURN_DELAY_S)
        self._watchdog_units: int | None = None
        self._models: dict[int, str] = {}  # servo ID -> model name, from check()
        # the tick block (tick_block.py): Indirect Data 1's address once use_tick_block set
        # it up, the bytes each servo's reply carries, what each servo's state should be
        self._block_at: int | None = None
        self._block_planned = False
        self._size = _DATA_BYTES
        self._torque_on = [False] * n
        self._health_ok = [tick_block.expected(False, None)] * n  # tick_health_ok
        #: the bytes of the latest corrupt reply to a tick's read (None until one comes); the
        #: loop samples it into events.jsonl so a noisy line can be diagnosed afterwards
        self.corrupt_sample: bytes | None = None
        self._update_timeouts()

    @classmethod
    def open(
        cls,
        port: str,
        *,
        baud: int,
        ids: Sequence[int],
        read_mode: ReadMode | str = ReadMode.AUTO,
        latency_timer_ms: float | None = None,
        clock: Clock | None = None,
        retries: int = 2,
    ) -> DynamixelBus:
        """Open ``port`` (``/dev/ttyUSB0``, a pty, ``dxlsim://...``) for servos ``ids``.

        ``read_mode`` ``"auto"`` pings every servo now and reads fast only if all answer
        with Fast Sync Read firmware. ``latency_timer_ms``, ``clock``: see
        :meth:`~drivers.dynamixel.link.Link.open`. Nothing is written to the servos.
        """
        mode = ReadMode(read_mode)
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        link = Link.open(port, baud=baud, clock=clock, latency_timer_ms=latency_timer_ms)
        try:
            bus = cls(link, ids, mode, retries)
            if mode is ReadMode.AUTO:
                bus._fast = all_support_fast(bus.link, bus.ids, 1 + bus.retries)
        except BaseException:
            link.close()
            raise
        return bus

    def __repr__(self) -> str:
        return (
            f"DynamixelBus({self.link.name!r}, baud={self.link.baud}, ids={self.ids}, "
            f"read_mode={self.read_mode.value!r})"
        )

    @property
    def read_mode(self) -> ReadMode:
        """What :meth:`read_present` uses now: FAST or PLAIN."""
        return ReadMode.FAST if self._fast else ReadMode.PLAIN

    @property
    def read_order(self) -> tuple[int, ...]:
        """Servo IDs in the order the next Sync Read lists them."""
        return tuple(self._read_param)

    # -- per tick ------------------------------------------------------------------
    # write_goals and read_present are ServoBus's, with the same checks, errors and books;
    # the tick's own case (an (n,) float64 array of finite goals, a reading for these IDs)
    # is checked on Python floats instead of a dozen numpy calls. Anything else goes
    # through ServoBus's methods, which raise as they always have.
    def write_goals(self, positions_rad: ArrayLike) -> None:
        goals = finite_goals(positions_rad, self._n)
        if goals is None or self._closed:
            super().write_goals(positions_rad)
        else:
            self._send_goals(goals)
            self.stats.writes += 1

    def read_present(self, out: PresentReading | None = None) -> PresentReading:
        if out is None or self._closed or (out.ids is not self._ids and out.ids != self._ids):
            return super().read_present(out)
        self._read_present(out)
        st = self.stats
        st.reads += 1
        if not self._all_ok:
            status = out.status
            st._not_ok[status, self._cols] += 1
            st.consecutive_bad += 1
            st.consecutive_bad *= status != 0
            self._bad_counted = True
        elif self._bad_counted:  # consecutive_bad is all 0 until a read is not OK
            st.consecutive_bad.fill(0)
            self._bad_counted = False
        return out

    def _write_goals(self, goals: NDArray[np.float64]) -> None:
        self._send_goals(goals.tolist())

    def _send_goals(self, goals: list[float]) -> None:
        # round() rounds halves to even, as np.rint: the ticks the numpy path computed
        ticks = [round(g * TICKS_PER_RAD) + CENTER_TICK for g in goals]
        if not (all(map(le, self._lo_l, ticks)) and all(map(le, ticks, self._hi_l))):
            raise goal_range_error(self.ids, goals, self._lo, self._hi)
        try:
            result = send_goals(self._port, self._ph, self._goal_frame, ticks)
        except SERIAL_ERRORS as exc:
            raise port_gone(exc, self.link.name, "Sync Write") from exc
        if result != OK:
            raise_for(result, 0, None, "Sync Write of Goal Position")

    def _read_present(self, out: PresentReading) -> None:
        clock = self._clock
        out.t = clock.now()
        n = self._n
        pos, status, errors = [math.nan] * n, [STALE] * n, [0] * n
        port, ph = self._port, self._ph
        fast = self._fast
        untold: tuple[int, ...]
        late: frozenset[int]
        size, untold, late = self._size, (), frozenset()
        seen = status  # the replies as they came (the order follows them)
        block = self._block_at is not None and fast
        if block:
            self.tick_health = state = [-1] * n
        if not fast and self._orders.busy_lengths:  # a late packet may come: another length
            size, untold = self._orders.plain_length(out.t)
            late = self._orders.late_ids(self.ids)
        request = self._request(fast, size)
        try:
            if request is None:
                addr = ct.PRESENT_POSITION.addr if self._block_at is None else self._block_at
                result = ph.syncReadTx(port, addr, size, self._read_param, n, fast)
            else:  # syncReadTx's txPacket; its own packet timeout is replaced just below
                result = transmit(port, request)
            if result == OK:
                want, order, sample = self._read_param, self._orders.order, self._sample
                if block:  # the tick block: each servo's state besides its position
                    self._receive_block(out.t, pos, status, errors, state)
                elif fast:
                    port.setPacketTimeoutMillis(self._fast_timeout_ms)
                    receive_fast_reply(port, want, order, pos, status, errors, sample)
                    if self._orders.suspect:  # a late block may be in flight (read_order),
                        self._orders.distrust(out.t, pos, status, errors)  # from its start
                else:
                    more = (size - _DATA_BYTES) * n * port.tx_time_per_byte  # ms
                    port.setPacketTimeoutMillis(self._plain_timeout_ms + more)
                    receive_plain_replies(
                        ph, port, want, order, pos, status, errors, sample, size, late
                    )
                    if untold:  # these servos' packets of this length may be late ones
                        seen = self._orders.take_back(untold, pos, status, errors)
        except SERIAL_ERRORS as exc:
            if isinstance(exc, DynamixelError):
                raise
            raise port_gone(exc, self.link.name, "Sync Read") from exc
        finally:
            pv, sv, ev = self._views  # the reading's arrays, viewed once (drivers.fill)
            if pv.arr is not out.positions or sv.arr is not out.status or ev.arr is not out.errors:
                pv, sv, ev = self._views = tuple(
                    Packed(a, n) for a in (out.positions, out.status, out.errors)
                )
            pv.put(*pos)
            sv.put(*status)
            ev.put(*errors)
            self._all_ok = not any(status)
        if result != OK:
            raise_for(result, 0, None, "Sync Read of Present Position")
        out.t_done = clock.now()
        if STALE in status:
            now = out.t_done + self.link.latency_timer_ms * 1e-3
            if not fast:  # a servo not read may send its packet late: ask another length
                self._orders.plain_unread(size, [k for k in range(n) if status[k] == STALE], now)
            if STALE in seen:  # the next order; the rest of the chain may still come:
                order = self._orders.order  # the next transmit waits it out, discards it
                i = self._orders.after(seen, now, fast)
                delays = self._rdt_s + TURNAROUND_ALLOWANCE_S  # those from place i on
                rest = wire_time.chain_rest_s(
                    fast, delays[order[i:]].tolist(), i == 0, port.tx_time_per_byte * 1e-3, size
                )
                port.hold_until_quiet(out.t_done + rest + self.link.latency_timer_ms * 1e-3)
                if self._orders.order != order:  # (requests rebuilt only when it changed)
                    self._set_order()

    def _receive_block(
        self,
        t: float,
        pos: list[float],
        status: list[int],
        errors: list[int],
        state: list[int],
    ) -> None:
        """The reply to a Fast Sync Read of the tick block, as the Fast read below; a state
        taken back (read_order) goes with its block."""
        port, orders = self._port, self._orders
        port.setPacketTimeoutMillis(self._fast_timeout_ms)
        tick_block.receive_block_reply(
            port, self._read_param, orders.order, pos, status, errors, state, self._sample
        )
        if orders.suspect:
            kept = [k for k in range(self._n) if status[k] != STALE]
            orders.distrust(t, pos, status, errors)
            for k in kept:
                if status[k] == STALE:
                    state[k] = -1

    def _set_order(self, order: Sequence[int] | None = None) -> None:
        if order is not None:  # (tests set one)
            self._orders.order = list(order)
        order = self._orders.order
        self._read_param = [self.ids[k] for k in order]
        self._requests: dict[tuple[bool, int], bytes | None] = {}  # built when first asked

    def _request(self, fast: bool, size: int) -> bytes | None:
        """The (Fast) Sync Read of ``size`` bytes from Present Position, in this order."""
        key = (fast, size)
        if key not in self._requests:
            ids, addr = self._read_param, ct.PRESENT_POSITION.addr
            if fast and self._block_at is not None:
                addr = self._block_at
            self._requests[key] = sync_read_request(addr, size, ids, fast)
        return self._requests[key]

    def _unanswered(self, servo_id: int, size: int) -> None:
        if not self._fast and servo_id in self._index:
            now = self._clock.now() + self.link.latency_timer_ms * 1e-3
            self._orders.plain_unread(size, (self._index[servo_id],), now)

    def _sample(self, packet: bytes) -> None:
        self.corrupt_sample = packet

    def _update_timeouts(self) -> None:
        """Packet timeouts for the reads: the SDK's (wire + 2·latency + 2 ms), the device
        margin of a port that is not a known USB adapter (a pty: its replies come from a
        process that may wait for a CPU; see ``PortHandler.timeout_margin_ms``), plus the
        servos' Return Delay Times, which the SDK leaves out (n of them in a plain chain,
        one in a fast reply). A longer timeout costs time only when a servo is silent."""
        port = self._port
        base = (
            port.tx_time_per_byte * wire_time.status_bytes(self._size) * self.n
            + 2.0 * self.link.latency_timer_ms
            + 2.0
            + port.timeout_margin_ms
        )
        delays = self._rdt_s + TURNAROUND_ALLOWANCE_S
        self._rdt_max_s = float(self._rdt_s.max())  # (a health read's time: every tick at 1 kHz)
        self._plain_timeout_ms = base + 1e3 * float(delays.sum())
        self._fast_timeout_ms = base + 1e3 * float(delays.max())

    # -- start-up ------------------------------------------------------------------
    def check(self, expectations: Iterable[Expectation]) -> StartupReport:
        """Compare every servo with its :class:`Expectation`; read-only.

        Checked per servo: answers Ping; model; Fast Sync Read firmware (read_mode
        ``"fast"``); Operating Mode; the expected position range within Min/Max Position
        Limit (Position mode) or the multi-turn range; Return Delay Time; Status Return
        Level 2 (1 leaves writes unanswered, their errors unseen; 0 shows as "answers
        Ping, not Read"); Hardware Error Status 0; Bus Watchdog not tripped; torque
        (reported, a mismatch only if not ``allow_torque_on``). Raises
        :class:`StartupMismatch` with one table of every difference. Also loads each
        servo's accepted goal range and Return Delay Time into the bus (``write_goals``
        validation, read timeouts) and settles ``read_mode`` ``"auto"``.
        """
        self._check_open()
        exps = {e.id: e for e in expectations}
        missing = [sid for sid in self.ids if sid not in exps]
        extra = sorted(set(exps) - set(self.ids))
        if missing or extra:
            raise ValueError(
                f"expectations must cover exactly servos {self.ids}: "
                f"missing {missing}, not on this bus {extra}"
            )
        self.link.recover()
        rows: list[Mismatch] = []
        states: list[ServoState] = []
        notes: list[str] = []
        attempts, fast_required = 1 + self.retries, self._requested is ReadMode.FAST
        for k, sid in enumerate(self.ids):
            found = check_servo(
                self.link, exps[sid], attempts=attempts, fast_required=fast_required
            )
            rows += found.rows
            notes += found.notes
            if found.goal_range is not None:
                self._lo[k], self._hi[k] = found.goal_range
                self._lo_l, self._hi_l = self._lo.tolist(), self._hi.tolist()
            if found.return_delay_s is not None:
                self._rdt_s[k] = found.return_delay_s
            if found.state is not None:
                states.append(found.state)
                self._models[sid] = found.state.model_name
        fast_ok = len(states) == self.n and all(s.fast_read for s in states)
        if self._requested is ReadMode.AUTO:
            self._fast = fast_ok
            if not fast_ok and len(states) == self.n:
                slow = [s.id for s in states if not s.fast_read]
                notes.append(f"plain Sync Read: no Fast Sync Read firmware on servo(s) {slow}")
        self._update_timeouts()
        if rows:
            raise StartupMismatch(rows, port=self.link.name)
        return StartupReport(
            self.link.name, self.link.baud, self.read_mode, tuple(states), tuple(notes)
        )

    # -- the tick block -------------------------------------------------------------
    def tick_block_possible(self) -> bool:
        """Whether :meth:`use_tick_block` can work: Fast Sync Read, and Indirect Data 1 at
        one address on every servo (known after :meth:`check`)."""
        models = [self._models.get(sid) for sid in self.ids]
        if not self._fast or None in models:
            return False
        return tick_block.block_addr([m for m in models if m is not None]) is not None

    def use_tick_block(self) -> None:
        """Have the tick's Fast Sync Read carry each servo's Torque Enable and Bus Watchdog
        with its position (:mod:`drivers.dynamixel.tick_block`) from the first torque on:
        the reads before it (the start's, which the hold-at-start goals come from) read
        positions alone, and nothing is written before those goals. ValueError when the
        bus cannot (:meth:`tick_block_possible`)."""
        self._check_open()
        if not self.tick_block_possible():
            raise ValueError("the tick block needs Fast Sync Read and one indirect layout")
        self._block_planned = True

    def _set_up_tick_block(self) -> None:
        """Every servo's Indirect Addresses read back and, where they are not the block's,
        written and read back again; then the tick's read is the block's. Raises
        :class:`DynamixelError` when a servo does not answer or confirm (the tick's read is
        then as it was)."""
        attempts = 1 + self.retries
        self.link.recover()
        for sid in self.ids:
            try:
                retry(
                    attempts, partial(tick_block.restore, self.link, sid), settle=self.link.settle
                )
            except ValueError as exc:
                raise DynamixelError(f"servo {sid}: tick block not set: {exc}") from None
        self._block_at = tick_block.block_addr([self._models[sid] for sid in self.ids])
        self._size = tick_block.SIZE
        self._set_order()  # the requests read the block from now on
        self._update_timeouts()

    @property
    def tick_health_ok(self) -> list[int]:
        """Each servo's state as the show set it (torque, the armed watchdog): a servo whose
        :attr:`tick_health` differs is judged by :meth:`tick_health_of`."""
        return self._health_ok

    def _expect(self) -> None:
        units = self._watchdog_units
        self._health_ok = [tick_block.expected(on, units) for on in self._torque_on]

    def tick_health_of(self, k: int) -> ServoHealth:
        """Servo ``k``'s (bus order) health as this tick's read found it (no transaction
        unless a problem needs its temperature and voltage to be named)."""
        sid = self.ids[k]
        state = -1 if self.tick_health is None else self.tick_health[k]
        if state < 0:
            return ServoHealth(sid, None, None, None, None)
        torque, wd, marker = tick_block.unpack(state)
        if marker != tick_block.MARKER:
            return ServoHealth(
                sid,
                torque == 1,
                None,
                None,
                None,
                HealthProblem.RESET,
                f"its Indirect Addresses are back at their defaults (the tick's read carries "
                f"no position: Status Return Level reads {marker}, not {tick_block.MARKER}): "
                "the servo restarted (brownout or reboot) and its RAM is back to defaults"
                + health.condition(self.link, sid),
            )
        return health.judge(self.link, sid, torque == 1, None, wd, self._watchdog_units)

    # -- state changes -------------------------------------------------------------
    def _set_torque(self, on: bool, ids: tuple[int, ...]) -> None:
        if on and self._block_planned and self._block_at is None:
            self._set_up_tick_block()
        for sid in ids:  # what the tick block should find (set before: a failure is loud)
            self._torque_on[self._index[sid]] = on
        self._expect()
        health.write_all(self.link, ids, ct.TORQUE_ENABLE, int(on), 1 + self.retries, "torque")

    def _arm_watchdog(self, period_s: float) -> None:
        units = round(period_s / ct.WATCHDOG_UNIT_S)
        if not 1 <= units <= ct.WATCHDOG_MAX_UNITS:
            raise ValueError(
                f"watchdog period {period_s} s is outside 0.02..2.54 s (20 ms units, 1..127)"
            )
        health.write_all(
            self.link, self.ids, ct.BUS_WATCHDOG, units, 1 + self.retries, "arm watchdog"
        )
        self._watchdog_units = units
        self._expect()

    def _disarm_watchdog(self) -> None:
        health.write_all(
            self.link, self.ids, ct.BUS_WATCHDOG, 0, 1 + self.retries, "disarm watchdog"
        )
        self._watchdog_units = None
        self._expect()

    def hardware_error_status(self, servo_id: int) -> int:
        """Hardware Error Status (addr 70) of one servo; see
        :func:`~drivers.protocol2.control_table.describe_hardware_error`."""
        self._check_open()
        return self.link.read_item(servo_id, ct.HARDWARE_ERROR_STATUS)

    def clear_watchdog_trips(self) -> tuple[int, ...]:
        """Before a show: disarm every servo's Bus Watchdog and return the IDs whose
        watchdog had tripped (a previous run's ``hold`` exit leaves it armed, and it trips
        once that host is gone). Servos that do not answer are skipped (the start-up check
        names them); the caller reports the trips, nothing is cleared silently."""
        self._check_open()
        tripped = health.clear_watchdog_trips(self.link, self.ids, 1 + self.retries)
        self._watchdog_units = None
        self._expect()
        return tripped

    # -- health (spread over ticks by the loop) -----------------------------------
    def _read_health(self, servo_id: int, part: HealthPart) -> ServoHealth:
        model = self._models.get(servo_id)
        return health.read_health(self.link, servo_id, part, self._watchdog_units, model)

    def _health_read_s(self) -> float:
        return self._read_s(ct.HEALTH_BLOCK.size)

    def _condition_read_s(self) -> float:
        return self._read_s(ct.CONDITION_BLOCK.size)

    def _read_s(self, size: int) -> float:
        """Expected bus time (s) of one Read of ``size`` bytes from the slowest servo."""
        n_bytes = wire_time.read_bytes(size)  # Read instruction + status
        return (
            self._port.tx_time_per_byte * 1e-3 * n_bytes
            + self._rdt_max_s
            + TURNAROUND_ALLOWANCE_S
            + self.link.latency_timer_ms * 1e-3
        )

    @property
    def host_stall_s(self) -> float:
        return float(getattr(self._port, "host_stall_s", 0.0))

    @property
    def device_wait_s(self) -> float:
        return float(getattr(self._port, "device_wait_s", 0.0))

    def _recover_watchdog(self, servo_id: int, goal_rad: float) -> None:
        attempts = 1 + self.retries
        k = self._index[servo_id]
        tick = int(rad_to_ticks(goal_rad))
        if not self._lo[k] <= tick <= self._hi[k]:
            raise ValueError(
                f"servo {servo_id}: goal tick {tick} outside [{int(self._lo[k])}, "
                f"{int(self._hi[k])}]"
            )
        health.recover_watchdog(self.link, servo_id, tick, self._watchdog_units, attempts)
        if self._block_at is not None:  # the tick's read must carry its health again
            try:
                retry(attempts, partial(tick_block.restore, self.link, servo_id))
            except ValueError as exc:
                raise DynamixelError(f"servo {servo_id}: tick block not restored: {exc}") from None

    # -- exit ----------------------------------------------------------------------
    def _apply_exit_policy(self, policy: ExitPolicy, retries: int) -> ExitReport:
        """See :func:`drivers.dynamixel.health.apply_exit_policy` (``1 + retries``
        attempts per step; ``hold`` arms the last :meth:`arm_watchdog` period)."""
        return health.apply_exit_policy(
            self.link, self.ids, policy, 1 + retries, self._watchdog_units
        )

    def _close(self) -> None:
        self.link.close()
