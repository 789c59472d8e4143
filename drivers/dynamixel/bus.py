"""The Dynamixel backend of :class:`~drivers.servo_bus.ServoBus`, over dynamixel-sdk.

:class:`DynamixelBus` - the loop's bus: one Sync Write of Goal Position per tick, one
Fast Sync Read (or plain Sync Read) of Present Position per tick with a status for
every servo, start-up :meth:`~DynamixelBus.check`, watchdog, torque and exit policy.
Non-tick transactions go through a :class:`~drivers.dynamixel.link.Link`; the per-tick
path calls the SDK's packet handler directly.

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

from collections.abc import Callable, Iterable, Sequence
from typing import TypeVar

import numpy as np

from drivers.clock import Clock
from drivers.dynamixel.errors import (
    CommError,
    CommTimeout,
    CorruptPacket,
    DynamixelError,
    ExitNotConfirmed,
    Mismatch,
    PortGone,
    ServoError,
    StartupMismatch,
)
from drivers.dynamixel.link import _CORRUPT, _OK, _SERIAL_ERRORS, _TIMEOUT, Link, _gone, _raise_for
from drivers.dynamixel.startup import Expectation, ReadMode, ServoState, StartupReport
from drivers.dynamixel.units import (
    CENTER_TICK,
    RAD_PER_TICK,
    TICKS_PER_RAD,
    goal_tick_range,
    rad_to_ticks,
    ticks_to_rad,
)
from drivers.protocol2 import control_table as ct
from drivers.protocol2.control_table import Item, OperatingMode
from drivers.servo_bus import (
    ExitPolicy,
    ExitReport,
    HealthPart,
    HealthProblem,
    PresentReading,
    ReadStatus,
    ServoBus,
    ServoHealth,
)

T = TypeVar("T")

_STALE, _ERROR, _ALERT, _GOOD = (
    int(s) for s in (ReadStatus.STALE, ReadStatus.ERROR, ReadStatus.ALERT, ReadStatus.OK)
)
#: Servo processing time allowed per reply on top of its Return Delay Time (AX ~20 µs,
#: MX ~50 µs; X series unpublished).
TURNAROUND_ALLOWANCE_S = 50e-6
#: Return Delay Time assumed until :meth:`DynamixelBus.check` has read the real one.
FACTORY_RETURN_DELAY_S = 500e-6
#: Watchdog period a ``hold`` exit arms when :meth:`DynamixelBus.arm_watchdog` never ran.
DEFAULT_EXIT_WATCHDOG_S = 0.1


def _retry(attempts: int, fn: Callable[[], T]) -> T:
    """Call ``fn`` up to ``attempts`` times while it fails on the wire (CommError)."""
    for k in range(attempts):
        try:
            return fn()
        except CommError:
            if k + 1 == attempts:
                raise
    raise AssertionError("unreachable")


def _crc_table() -> list[int]:
    """Protocol 2.0 CRC-16 (polynomial 0x8005, MSB first) by high byte."""
    table = []
    for i in range(256):
        c = i << 8
        for _ in range(8):
            c = ((c << 1) ^ 0x8005) if c & 0x8000 else c << 1
        table.append(c & 0xFFFF)
    return table


#: For ``_parse_fast``, which runs every tick (the SDK's ``updateCRC`` rebuilds its table
#: on every call: 13 us for one 4-servo packet).
_CRC_TABLE = _crc_table()


class _UnconfirmedError(Exception):
    """One exit step could not be confirmed on one servo (internal)."""


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
        except _SERIAL_ERRORS as exc:
            raise _gone(exc, self.link.name, "Sync Write") from exc
        if result != _OK:
            _raise_for(result, 0, None, "Sync Write of Goal Position")

    def _read_present(self, out: PresentReading) -> None:
        clock = self.clock
        out.t = clock.now()
        out.positions.fill(np.nan)
        out.status.fill(_STALE)
        out.errors.fill(0)
        port, ph = self._port, self._ph
        fast = self._fast
        try:
            result = ph.syncReadTx(
                port, ct.PRESENT_POSITION.addr, 4, self._read_param, self.n, fast
            )
            if result == _OK:
                if fast:
                    port.setPacketTimeoutMillis(self._fast_timeout_ms)
                    packet, rx = ph.rxPacket(port, True)
                    if rx == _CORRUPT and packet:
                        self.corrupt_sample = bytes(packet)
                    if rx == _OK or (rx == _CORRUPT and packet):
                        self._parse_fast(packet, rx == _OK, out)
                else:
                    port.setPacketTimeoutMillis(self._plain_timeout_ms)
                    self._receive_plain(out)
        except _SERIAL_ERRORS as exc:
            if isinstance(exc, DynamixelError):
                raise
            raise _gone(exc, self.link.name, "Sync Read") from exc
        if result != _OK:
            _raise_for(result, 0, None, "Sync Read of Present Position")
        out.t_done = clock.now()
        status = out.status
        if status.any():
            order = self._order
            for i, k in enumerate(order):
                if status[k] == _STALE:
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
            wire, wait = (8 * rest + (8 if i == 0 else 0)) * byte_s, float(delays[order[i]])
        else:  # one 15-byte status packet each, each after its own delay
            wire, wait = 15 * rest * byte_s, float(sum(delays[k] for k in order[i:]))
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
            if result == _OK:
                if packet[4] != want[p]:
                    return
                k = order[p]
                p += 1
                err = packet[8]
                errors[k] = err
                if err & ct.ERROR_NUMBER_MASK:
                    status[k] = _ALERT if err & ct.ALERT_BIT else _ERROR
                elif (packet[5] | packet[6] << 8) == 8:  # LEN = INST ERR data(4) CRC(2)
                    v = packet[9] | packet[10] << 8 | packet[11] << 16 | packet[12] << 24
                    pos[k] = ((v - 0x1_0000_0000 if v & 0x8000_0000 else v) - CENTER_TICK) * (
                        RAD_PER_TICK
                    )
                    status[k] = _ALERT if err & ct.ALERT_BIT else _GOOD
                # else no data and no error, or a reply to another request: not a reading
            elif result == _TIMEOUT:
                return
            else:  # corrupt: this place's reply is lost; the next may be fine
                self.corrupt_sample = bytes(packet)
                p += 1

    def _parse_fast(self, packet: list[int], verified: bool, out: PresentReading) -> None:
        """Blocks ``ERR ID pos(4) CRC(2)`` from offset 8, one per servo in request order.

        ``verified``: the SDK found the packet's last CRC right; else the packet is what
        arrived of a corrupt or short reply (any length, even under 8 bytes). Either way a
        block is a reading only if

        * every block before it was one (prefix rule: a bad block costs the servos after
          it this tick, as a silent one does; what follows a bad block may be another
          transaction's reply spliced in),
        * it carries the ID this Sync Read asked for at its position (``_read_param``: a
          late reply to an earlier request has another order after a failed read),
        * its CRC is the running CRC of the packet up to its data. Checked even when the
          SDK verified the packet: after two servos collide on one block, the servos
          after them compute their CRCs over what they heard, so the last CRC can hold
          over a garbled block.
        """
        end = len(packet)
        if (
            end < 16
            or packet[0] != 0xFF
            or packet[1] != 0xFF
            or packet[2] != 0xFD
            or packet[3] != 0x00
            or packet[4] != 0xFE
        ):
            return
        pos, status, errors, order = out.positions, out.status, out.errors, self._order
        table = _CRC_TABLE
        running = 0
        for b in packet[0:8]:
            running = ((running << 8) ^ table[((running >> 8) ^ b) & 0xFF]) & 0xFFFF
        for p, sid in enumerate(self._read_param):
            o = 8 + 8 * p
            if o + 8 > end or packet[o + 1] != sid:
                return
            for b in packet[o : o + 6]:
                running = ((running << 8) ^ table[((running >> 8) ^ b) & 0xFF]) & 0xFFFF
            lo, hi = packet[o + 6], packet[o + 7]
            if running != lo | hi << 8:
                return
            for b in (lo, hi):  # the next servo's CRC runs on over this one's
                running = ((running << 8) ^ table[((running >> 8) ^ b) & 0xFF]) & 0xFFFF
            k = order[p]
            err = packet[o]
            errors[k] = err
            if err & ct.ERROR_NUMBER_MASK:
                status[k] = _ALERT if err & ct.ALERT_BIT else _ERROR
                continue
            v = packet[o + 2] | packet[o + 3] << 8 | packet[o + 4] << 16 | packet[o + 5] << 24
            pos[k] = ((v - 0x1_0000_0000 if v & 0x8000_0000 else v) - CENTER_TICK) * RAD_PER_TICK
            status[k] = _ALERT if err & ct.ALERT_BIT else _GOOD

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
            port.tx_time_per_byte * 15 * self.n
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
                model, fw = _retry(1 + self.retries, lambda sid=sid: self.link.ping(sid))
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
        for k, sid in enumerate(self.ids):
            state = self._check_one(k, exps[sid], rows, notes)
            if state is not None:
                states.append(state)
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

    @staticmethod
    def _tries(attempts: int, fn: Callable[[], T], seen: list[CommError]) -> T:
        """:func:`_retry`, keeping every wire failure in ``seen``."""
        for k in range(attempts):
            try:
                return fn()
            except CommError as exc:
                seen.append(exc)
                if k + 1 == attempts:
                    raise
        raise AssertionError("unreachable")

    @staticmethod
    def _corrupt_hint(seen: list[CommError], baud: int) -> tuple[str, str]:
        """(found, fix) for a servo whose replies stayed corrupt. Two servos on one ID is
        suggested only when every try got a whole packet - valid header, this ID, every
        LEN byte - with a bad CRC (two replies merged on the wire); a reply cut short or
        arriving late (a busy host, a pty) says so instead."""
        garbled = sum(1 for e in seen if getattr(e, "complete", False))
        if garbled == len(seen):
            return (
                f"corrupt replies ({garbled} of {garbled} whole packets with a bad CRC)",
                "two servos with this ID? (connect them one at a time)",
            )
        return (
            f"corrupt replies ({len(seen) - garbled} of {len(seen)} cut short or late)",
            f"check wiring, termination and baud ({baud}); a busy host delays pty replies",
        )

    def _check_one(
        self, k: int, exp: Expectation, rows: list[Mismatch], notes: list[str]
    ) -> ServoState | None:
        sid, link, attempts = exp.id, self.link, 1 + self.retries

        def add(item: str, expected: str, found: str, fix: str = "") -> None:
            rows.append(Mismatch(sid, item, expected, found, fix))

        # Each step is tried 1 + retries times: a reply that comes late (after its
        # timeout) is discarded at the next transmit or read as that try's reply (the same
        # request's answer), so one late reply costs one try, never the check.
        seen: list[CommError] = []
        try:
            model, fw = self._tries(attempts, lambda: link.ping(sid), seen)
        except CommTimeout:
            add(
                "answers Ping",
                "yes",
                "no (timeout)",
                f"check ID, power, wiring and baud ({link.baud})",
            )
            return None
        except CorruptPacket:
            add("answers Ping", "yes", *self._corrupt_hint(seen, link.baud))
            return None
        except ServoError as exc:
            add("answers Ping", "yes", f"error reply: {exc.name}", "")
            return None
        name = ct.model_name(model)
        if exp.model is not None and model != ct.model_number(exp.model):
            add(
                "model",
                f"{exp.model} ({ct.model_number(exp.model)})",
                f"{name} ({model})",
                "fix the rig file or the servo",
            )
        fast = ct.supports_fast_read(model, fw)
        if self._requested is ReadMode.FAST and not fast:
            least = ct.fast_read_min_firmware(model)
            add(
                "firmware (Fast Sync Read)",
                f">= {least}" if least else "known model",
                str(fw),
                "update firmware (DYNAMIXEL Wizard 2.0) or read_mode='plain'",
            )
        block_item = ct.STARTUP_BLOCK
        seen = []
        try:
            block = self._tries(attempts, lambda: link.read(sid, 0, block_item.size), seen)
        except CommTimeout:
            add(
                "Status Return Level",
                "2",
                "0? (answers Ping, not Read)",
                "write 2 to addr 68 (Status Return Level)",
            )
            return None
        except CorruptPacket:
            add("read control table", "a reply", *self._corrupt_hint(seen, link.baud))
            return None
        except ServoError as exc:
            add("read control table", "a reply", str(exc), "")
            return None

        def get(item: Item) -> int:
            return item.decode(block)

        mode, rdt_us = get(ct.OPERATING_MODE), get(ct.RETURN_DELAY_TIME) * 2.0
        srl, hw, wd = (
            get(ct.STATUS_RETURN_LEVEL),
            get(ct.HARDWARE_ERROR_STATUS),
            get(ct.BUS_WATCHDOG),
        )
        torque = get(ct.TORQUE_ENABLE) == 1
        lo_lim, hi_lim = get(ct.MIN_POSITION_LIMIT), get(ct.MAX_POSITION_LIMIT)
        present = ticks_to_rad(get(ct.PRESENT_POSITION))
        if mode != exp.operating_mode:
            add(
                "Operating Mode",
                _mode_text(exp.operating_mode),
                _mode_text(mode),
                "write addr 11 (torque off)",
            )
        if mode in ct.POSITION_MODES:
            lo_t, hi_t = goal_tick_range(mode, lo_lim, hi_lim)
            self._lo[k], self._hi[k] = lo_t, hi_t
            if exp.position_range_rad is not None:
                want = rad_to_ticks(np.array(exp.position_range_rad))
                if want[0] < lo_t or want[1] > hi_t:
                    r = exp.position_range_rad
                    add(
                        "position range",
                        f"[{r[0]:+.3f}, {r[1]:+.3f}] rad = ticks [{want[0]}, {want[1]}]",
                        f"limits [{lo_t}, {hi_t}] ticks",
                        "widen Min/Max Position Limit (addr 52/48) or narrow the joint",
                    )
        self._rdt_s[k] = rdt_us * 1e-6
        if rdt_us > exp.return_delay_us_max:
            add(
                "Return Delay Time",
                f"<= {exp.return_delay_us_max:g} us",
                f"{rdt_us:g} us",
                f"write {int(exp.return_delay_us_max // 2)} to addr 9 (2 us units)",
            )
        if srl != ct.STATUS_RETURN_ALL:
            add("Status Return Level", "2", str(srl), "write 2 to addr 68")
        shutdown = get(ct.SHUTDOWN)
        if exp.shutdown_bits & ~shutdown:
            want = exp.shutdown_bits
            add(
                "Shutdown (torque cut on)",
                f"includes 0x{want:02X} ({ct.describe_hardware_error(want)})",
                f"0x{shutdown:02X} ({ct.describe_hardware_error(shutdown)})",
                f"write {shutdown | want} to addr 63 (torque off): the servo protects itself",
            )
        if hw:
            add(
                "Hardware Error Status",
                "0",
                f"0x{hw:02X} ({ct.describe_hardware_error(hw)})",
                "remove the cause, then Reboot the servo",
            )
        if wd == ct.WATCHDOG_TRIPPED:
            add(
                "Bus Watchdog",
                "not tripped",
                "tripped (-1)",
                "write 0 to addr 98 (bus.disarm_watchdog())",
            )
        if torque:
            if not exp.allow_torque_on:
                add("Torque Enable", "off", "on", "bus.set_torque(False)")
            else:
                notes.append(f"servo {sid}: torque already on, holding {present:+.4f} rad")
        return ServoState(
            sid, model, name, fw, fast, mode, torque, rdt_us, srl, hw, wd, (lo_lim, hi_lim), present
        )

    # -- state changes -------------------------------------------------------------
    def _each(self, what: str, fn: Callable[[int], None]) -> None:
        """Do ``fn(id)`` on every servo (with retries); raise the first failure after
        trying all, the others noted on it."""
        self.link.recover()
        failures: list[DynamixelError] = []
        for sid in self.ids:
            try:
                _retry(1 + self.retries, lambda sid=sid: fn(sid))
            except (CommError, ServoError) as exc:
                failures.append(exc)
        if failures:
            first = failures[0]
            if len(failures) > 1:
                first.add_note(f"{what} also failed on: " + "; ".join(map(str, failures[1:])))
            raise first

    def _set_torque(self, on: bool) -> None:
        self._each("torque", lambda sid: self.link.write_item(sid, ct.TORQUE_ENABLE, int(on)))

    def _arm_watchdog(self, period_s: float) -> None:
        units = round(period_s / ct.WATCHDOG_UNIT_S)
        if not 1 <= units <= ct.WATCHDOG_MAX_UNITS:
            raise ValueError(
                f"watchdog period {period_s} s is outside 0.02..2.54 s (20 ms units, 1..127)"
            )
        self._each("arm watchdog", lambda sid: self.link.write_item(sid, ct.BUS_WATCHDOG, units))
        self._watchdog_units = units

    def _disarm_watchdog(self) -> None:
        self._each("disarm watchdog", lambda sid: self.link.write_item(sid, ct.BUS_WATCHDOG, 0))
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
        self.link.recover()
        tripped = []
        for sid in self.ids:
            try:
                value = _retry(
                    1 + self.retries, lambda sid=sid: self.link.read_item(sid, ct.BUS_WATCHDOG)
                )
                if value != 0:
                    _retry(
                        1 + self.retries,
                        lambda sid=sid: self.link.write_item(sid, ct.BUS_WATCHDOG, 0),
                    )
            except (CommError, ServoError):
                continue
            if value == ct.WATCHDOG_TRIPPED:
                tripped.append(sid)
        self._watchdog_units = None
        return tuple(tripped)

    # -- health (spread over ticks by the loop) -----------------------------------
    def _read_health(self, servo_id: int, part: HealthPart) -> ServoHealth:
        torque = hw = wd = None
        if part is HealthPart.WATCHDOG:
            wd = self.link.read_item(servo_id, ct.BUS_WATCHDOG)
        else:
            item = ct.HEALTH_WATCHDOG_BLOCK if part is HealthPart.ALL else ct.HEALTH_BLOCK
            block = self.link.read(servo_id, item.addr, item.size)
            torque = ct.TORQUE_ENABLE.decode(block, item.addr) == 1
            hw = ct.HARDWARE_ERROR_STATUS.decode(block, item.addr)
            if part is HealthPart.ALL:
                wd = ct.BUS_WATCHDOG.decode(block, item.addr)
            elif not torque or hw:  # something is wrong: the watchdog names the cause
                wd = self.link.read_item(servo_id, ct.BUS_WATCHDOG)
        tripped = None if wd is None else wd == ct.WATCHDOG_TRIPPED
        armed = None if wd is None else wd > 0
        expected = self._watchdog_units
        problem, detail = None, ""
        if hw:
            problem = HealthProblem.HARDWARE_ERROR
            detail = (
                f"Hardware Error Status 0x{hw:02X} ({ct.describe_hardware_error(hw)})"
                f"{self._condition(servo_id)}; remove the cause, then reboot the servo"
            )
        elif torque is False and expected and wd == 0:
            problem = HealthProblem.RESET
            detail = (
                f"torque off and Bus Watchdog 0 although it was armed ({expected} x 20 ms): "
                "the servo restarted (brownout or reboot) and its RAM is back to defaults"
                f"{self._condition(servo_id)}"
            )
        elif tripped:
            problem = HealthProblem.WATCHDOG_TRIPPED
            detail = "Bus Watchdog reads -1: the servo stopped itself and refuses goals"
        elif torque is False:
            problem = HealthProblem.TORQUE_OFF
            detail = "Torque Enable reads 0: the servo is limp"
        return ServoHealth(servo_id, torque, hw, tripped, armed, problem, detail)

    def _condition(self, servo_id: int) -> str:
        """Temperature, input voltage and load of one servo, as text (best effort)."""
        block_item = ct.CONDITION_BLOCK
        try:
            block = self.link.read(servo_id, block_item.addr, block_item.size)
        except (CommError, ServoError):
            return ""
        start = block_item.addr
        return (
            f"; {ct.PRESENT_TEMPERATURE.decode(block, start)} °C, "
            f"{ct.PRESENT_INPUT_VOLTAGE.decode(block, start) / 10:.1f} V, "
            f"load {ct.PRESENT_LOAD.decode(block, start)}"
        )

    def _health_read_s(self) -> float:
        n_bytes = 14 + 11 + ct.HEALTH_BLOCK.size  # Read instruction + status with data
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
        self.link.recover()
        try:
            self._confirm(servo_id, ct.BUS_WATCHDOG, 0, attempts)
            self._confirm(servo_id, ct.GOAL_POSITION, tick, attempts)
            if self._watchdog_units:
                self._confirm(servo_id, ct.BUS_WATCHDOG, self._watchdog_units, attempts)
        except _UnconfirmedError as exc:
            raise DynamixelError(
                f"servo {servo_id}: cannot recover from the Bus Watchdog trip: {exc}"
            ) from None

    # -- exit ----------------------------------------------------------------------
    def _apply_exit_policy(self, policy: ExitPolicy, retries: int) -> ExitReport:
        """``hold``: torque must be on; a tripped watchdog is cleared, Goal Position :=
        Present Position, then the watchdog armed (the last :meth:`arm_watchdog` period,
        else 0.1 s); each read back. ``relax``: Torque Enable := 0, read back. A servo
        whose step fails ``1 + retries`` times is skipped and named; the adapter gone
        stops at once. Raises :class:`ExitNotConfirmed` unless every servo is confirmed."""
        confirmed: list[int] = []
        failed: list[tuple[int, str]] = []
        notes: list[str] = []
        attempts = 1 + retries
        try:
            self.link.recover()
            for sid in self.ids:
                try:
                    if policy is ExitPolicy.HOLD:
                        self._hold_one(sid, attempts, notes)
                    else:
                        self._confirm(sid, ct.TORQUE_ENABLE, 0, attempts)
                    confirmed.append(sid)
                except _UnconfirmedError as exc:
                    failed.append((sid, str(exc)))
        except PortGone as exc:
            done = {s for s, _ in failed} | set(confirmed)
            failed += [(s, f"adapter gone: {exc}") for s in self.ids if s not in done]
            report = ExitReport(policy, tuple(confirmed), tuple(failed), tuple(notes))
            raise ExitNotConfirmed(report) from exc
        report = ExitReport(policy, tuple(confirmed), tuple(failed), tuple(notes))
        if failed:
            raise ExitNotConfirmed(report)
        return report

    def _hold_one(self, sid: int, attempts: int, notes: list[str]) -> None:
        if not self._read(sid, ct.TORQUE_ENABLE, attempts):
            raise _UnconfirmedError("torque is off: cannot hold (the servo is limp)")
        if self._read(sid, ct.BUS_WATCHDOG, attempts) == ct.WATCHDOG_TRIPPED:
            # The servo had stopped itself (the host was silent longer than the watchdog
            # period); holding needs the trip cleared: say so, never silently.
            self._confirm(sid, ct.BUS_WATCHDOG, 0, attempts)
            notes.append(
                f"servo {sid}: its Bus Watchdog had tripped (it had stopped itself); "
                "cleared to hold it"
            )
        present = self._read(sid, ct.PRESENT_POSITION, attempts)
        self._confirm(sid, ct.GOAL_POSITION, present, attempts)
        units = self._watchdog_units or round(DEFAULT_EXIT_WATCHDOG_S / ct.WATCHDOG_UNIT_S)
        self._confirm(sid, ct.BUS_WATCHDOG, units, attempts)

    def _read(self, sid: int, item: Item, attempts: int) -> int:
        last: Exception | None = None
        for _ in range(attempts):
            try:
                return self.link.read_item(sid, item)
            except (CommError, ServoError) as exc:
                last = exc
        raise _UnconfirmedError(f"reading {item.name} failed {attempts}x: {last}")

    def _confirm(self, sid: int, item: Item, value: int, attempts: int) -> None:
        """Write ``item := value`` and read it back, up to ``attempts`` times."""
        last = ""
        for _ in range(attempts):
            try:
                self.link.write_item(sid, item, value)
                got = self.link.read_item(sid, item)
            except (CommError, ServoError) as exc:
                last = str(exc)
                continue
            if got == value:
                return
            last = f"wrote {value}, read back {got}"
        raise _UnconfirmedError(
            f"{item.name} := {value} not confirmed after {attempts} attempt(s): {last}"
        )

    def _close(self) -> None:
        self.link.close()


def _mode_text(mode: int) -> str:
    try:
        return f"{OperatingMode(mode).name.lower()} ({mode})"
    except ValueError:
        return f"unknown ({mode})"
