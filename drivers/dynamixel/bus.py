"""The Dynamixel backend of :class:`~drivers.servo_bus.ServoBus`, over dynamixel-sdk.

:class:`DynamixelBus` - the loop's bus: one Sync Write of Goal Position per tick, one
Fast Sync Read (or plain Sync Read) of Present Position per tick with a status for
every servo, start-up :meth:`~DynamixelBus.check`, watchdog, torque and exit policy.
Non-tick transactions go through a :class:`~drivers.dynamixel.link.Link` (the per-servo
start-up check is :func:`~drivers.dynamixel.startup.check_servo`; health, watchdog recovery
and the exit policy are in :mod:`drivers.dynamixel.health`); the per-tick path calls the
SDK's packet handler directly and parses Fast Sync Read replies with
:func:`~drivers.dynamixel.fast_reply.parse_fast_reply`. Read timeouts count bytes with
:mod:`drivers.protocol2.wire_time`.

Per-servo status on every read. The SDK's ``GroupSyncRead`` drops each servo's ERR byte
and ``getData`` returns 0 for missing data, and its Fast Sync Read reports one result for
the whole packet, so the bus sends the request with ``syncReadTx`` and parses the replies
itself: plain Sync Read takes the status packets in chain order with ``rxPacket`` (a
corrupt one costs only its own place; a reply from an unexpected ID ends the read); Fast
Sync Read takes the one packet and keeps each block only while every earlier block was
kept, the block carries the ID asked at its position, and the running CRC over it matches:
a late reply spliced into this one can never give a previous transaction's value as this
tick's. After a read with a silent servo the next request waits until the rest of that
chain would be over, and discards it.

In a Sync Read chain a silent servo silences those after it (each waits for the previous
status packet). So after a read with a STALE servo, the first STALE servo moves to the
back of the read order: one dead servo costs one tick of collateral STALE, not all ticks.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from drivers.clock import Clock
from drivers.dynamixel import health
from drivers.dynamixel.errors import (
    CommError,
    DynamixelError,
    Mismatch,
    ServoError,
    StartupMismatch,
)
from drivers.dynamixel.fast_reply import ALERT, ERROR, GOOD, STALE, parse_fast_reply
from drivers.dynamixel.link import Link
from drivers.dynamixel.sdk_result import CORRUPT, OK, SERIAL_ERRORS, TIMEOUT, port_gone, raise_for
from drivers.dynamixel.startup import (
    Expectation,
    ReadMode,
    ServoState,
    StartupReport,
    check_servo,
    retry,
)
from drivers.dynamixel.units import (
    CENTER_TICK,
    RAD_PER_TICK,
    TICKS_PER_RAD,
    decode_position,
    rad_to_ticks,
)
from drivers.protocol2 import control_table as ct
from drivers.protocol2 import wire_time
from drivers.servo_bus import (
    ExitPolicy,
    ExitReport,
    HealthPart,
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
        self._set_order(list(range(n)))
        # write_goals buffers: ticks (float work, int32) and the Sync Write parameters
        self._tickf = np.empty(n)
        self._ticks = np.empty(n, dtype="<i4")
        self._wparam = np.zeros((n, 5), dtype=np.uint8)
        self._wparam[:, 0] = self.ids
        self._ticks_u8 = self._ticks.view(np.uint8).reshape(n, 4)
        self._lo = np.zeros(n)  # accepted Goal Position ticks (Position mode until check)
        self._hi = np.full(n, 4095.0)
        self._rdt_s = np.full(n, FACTORY_RETURN_DELAY_S)
        self._watchdog_units: int | None = None
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
                bus._fast = bus._all_support_fast()
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
    def _write_goals(self, goals: np.ndarray) -> None:
        t = self._tickf
        np.multiply(goals, TICKS_PER_RAD, out=t)
        np.rint(t, out=t)
        t += CENTER_TICK
        if not ((t >= self._lo) & (t <= self._hi)).all():
            bad = [
                f"servo {sid}: {g:+.4f} rad = tick {int(x)} outside [{int(lo)}, {int(hi)}]"
                for sid, g, x, lo, hi in zip(self.ids, goals, t, self._lo, self._hi, strict=True)
                if not lo <= x <= hi
            ]
            raise ValueError("goal out of range, nothing sent: " + "; ".join(bad))
        self._ticks[:] = t
        self._wparam[:, 1:] = self._ticks_u8
        try:
            result = self._ph.syncWriteTxOnly(
                self._port, ct.GOAL_POSITION.addr, 4, self._wparam.tobytes(), 5 * self.n
            )
        except SERIAL_ERRORS as exc:
            raise port_gone(exc, self.link.name, "Sync Write") from exc
        if result != OK:
            raise_for(result, 0, None, "Sync Write of Goal Position")

    def _read_present(self, out: PresentReading) -> None:
        clock = self.clock
        out.t = clock.now()
        out.positions.fill(np.nan)
        out.status.fill(STALE)
        out.errors.fill(0)
        port, ph = self._port, self._ph
        fast = self._fast
        try:
            result = ph.syncReadTx(
                port, ct.PRESENT_POSITION.addr, 4, self._read_param, self.n, fast
            )
            if result == OK:
                if fast:
                    port.setPacketTimeoutMillis(self._fast_timeout_ms)
                    packet, rx = ph.rxPacket(port, True)
                    if rx == CORRUPT and packet:
                        self.corrupt_sample = bytes(packet)
                    if rx == OK or (rx == CORRUPT and packet):
                        parse_fast_reply(packet, self._read_param, self._order, out)
                else:
                    port.setPacketTimeoutMillis(self._plain_timeout_ms)
                    self._receive_plain(out)
        except SERIAL_ERRORS as exc:
            if isinstance(exc, DynamixelError):
                raise
            raise port_gone(exc, self.link.name, "Sync Read") from exc
        if result != OK:
            raise_for(result, 0, None, "Sync Read of Present Position")
        out.t_done = clock.now()
        status = out.status
        if status.any():
            order = self._order
            for i, k in enumerate(order):
                if status[k] == STALE:
                    # The rest of the chain may still be on its way (a slow servo): the
                    # next transmit waits it out and discards it, so it is never read as
                    # the next transaction's reply.
                    port.hold_until_quiet(out.t_done + self._chain_rest_s(i))
                    if i + 1 < len(order):  # the chain broke here: ask it last next time
                        self._set_order(order[:i] + order[i + 1 :] + [k])
                    break

    def _chain_rest_s(self, i: int) -> float:
        """Longest the replies of this Sync Read's servos from chain position ``i`` on can
        still take from now, if the one at ``i`` started late: their wire time, Return
        Delay Times and turnaround (one of each in a Fast Sync Read, every one in a plain
        chain), and the adapter's latency. 1.5 ms for four fast servos at 1 Mbps, 1 ms
        latency. Not the device margin: only a failed read pays this, every time."""
        order, byte_s = self._order, self._port.tx_time_per_byte * 1e-3
        rest = len(order) - i
        delays = self._rdt_s + TURNAROUND_ALLOWANCE_S
        if self._fast:  # (header if it is still to come) + ERR ID pos(4) CRC(2) each
            head = wire_time.FAST_REPLY_HEADER_BYTES if i == 0 else 0
            wire = (wire_time.fast_block_bytes(_DATA_BYTES) * rest + head) * byte_s
            wait = float(delays[order[i]])
        else:  # one 15-byte status packet each, each after its own delay
            wire = wire_time.status_bytes(_DATA_BYTES) * rest * byte_s
            wait = float(sum(delays[k] for k in order[i:]))
        return wire + wait + self.link.latency_timer_ms * 1e-3

    def _receive_plain(self, out: PresentReading) -> None:
        """Take the chain's status packets in the order asked (``_read_param``: each servo
        answers after the one before it). A packet is a reading only if it carries the ID
        asked at its place. A corrupt one takes its place (that servo only loses this
        tick); a valid one from another ID - a late reply to an earlier request, whose
        chain had another order, a stranger, a second reply - ends the read, since what
        follows it cannot be placed."""
        pos, status, errors = out.positions, out.status, out.errors
        want, order, ph, port = self._read_param, self._order, self._ph, self._port
        p, n = 0, self.n
        while p < n:
            packet, result = ph.rxPacket(port, False)
            if result == OK:
                if packet[4] != want[p]:
                    return
                k = order[p]
                p += 1
                err = packet[8]
                errors[k] = err
                if err & ct.ERROR_NUMBER_MASK:
                    status[k] = ALERT if err & ct.ALERT_BIT else ERROR
                elif (packet[5] | packet[6] << 8) == 8:  # LEN = INST ERR data(4) CRC(2)
                    v = packet[9] | packet[10] << 8 | packet[11] << 16 | packet[12] << 24
                    pos[k] = (decode_position(v) - CENTER_TICK) * RAD_PER_TICK
                    status[k] = ALERT if err & ct.ALERT_BIT else GOOD
                # else no data and no error, or a reply to another request: not a reading
            elif result == TIMEOUT:
                return
            else:  # corrupt: this place's reply is lost; the next may be fine
                self.corrupt_sample = bytes(packet)
                p += 1

    def _set_order(self, order: list[int]) -> None:
        self._order = order
        self._read_param = [self.ids[k] for k in order]

    def _update_timeouts(self) -> None:
        """Packet timeouts for the reads: the SDK's (wire + 2·latency + 2 ms), the device
        margin of a port that is not a known USB adapter (a pty: its replies come from a
        process that may wait for a CPU; see ``PortHandler.timeout_margin_ms``), plus the
        servos' Return Delay Times, which the SDK leaves out (n of them in a plain chain,
        one in a fast reply). A longer timeout costs time only when a servo is silent."""
        port = self._port
        base = (
            port.tx_time_per_byte * wire_time.status_bytes(_DATA_BYTES) * self.n
            + 2.0 * self.link.latency_timer_ms
            + 2.0
            + port.timeout_margin_ms
        )
        delays = self._rdt_s + TURNAROUND_ALLOWANCE_S
        self._plain_timeout_ms = base + 1e3 * float(delays.sum())
        self._fast_timeout_ms = base + 1e3 * float(delays.max())

    # -- start-up ------------------------------------------------------------------
    def _all_support_fast(self) -> bool:
        for sid in self.ids:
            try:
                model, fw = retry(1 + self.retries, lambda sid=sid: self.link.ping(sid))
            except (CommError, ServoError):
                return False
            if not ct.supports_fast_read(model, fw):
                return False
        return True

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
            if found.return_delay_s is not None:
                self._rdt_s[k] = found.return_delay_s
            if found.state is not None:
                states.append(found.state)
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

    # -- state changes -------------------------------------------------------------
    def _set_torque(self, on: bool) -> None:
        health.write_all(self.link, self.ids, ct.TORQUE_ENABLE, int(on), 1 + self.retries, "torque")

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

    def _disarm_watchdog(self) -> None:
        health.write_all(
            self.link, self.ids, ct.BUS_WATCHDOG, 0, 1 + self.retries, "disarm watchdog"
        )
        self._watchdog_units = None

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
        return tripped

    # -- health (spread over ticks by the loop) -----------------------------------
    def _read_health(self, servo_id: int, part: HealthPart) -> ServoHealth:
        return health.read_health(self.link, servo_id, part, self._watchdog_units)

    def _health_read_s(self) -> float:
        n_bytes = wire_time.read_bytes(ct.HEALTH_BLOCK.size)  # Read instruction + status
        return (
            self._port.tx_time_per_byte * 1e-3 * n_bytes
            + float(self._rdt_s.max())
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

    # -- exit ----------------------------------------------------------------------
    def _apply_exit_policy(self, policy: ExitPolicy, retries: int) -> ExitReport:
        """See :func:`drivers.dynamixel.health.apply_exit_policy` (``1 + retries``
        attempts per step; ``hold`` arms the last :meth:`arm_watchdog` period)."""
        return health.apply_exit_policy(
            self.link, self.ids, policy, 1 + retries, self._watchdog_units
        )

    def _close(self) -> None:
        self.link.close()
