"""The Dynamixel backend of :class:`~drivers.servo_bus.ServoBus`, over dynamixel-sdk.

:class:`DynamixelBus` - the loop's bus: one Sync Write of Goal Position per tick, one
Fast Sync Read (or plain Sync Read) of Present Position per tick with a status for
every servo, start-up :meth:`~DynamixelBus.check`, watchdog, torque and exit policy.
Non-tick transactions go through a :class:`~drivers.dynamixel.link.Link`; the per-tick
path calls the SDK's packet handler directly.

Per-servo status on every read. The SDK's ``GroupSyncRead`` drops each servo's ERR byte
and ``getData`` returns 0 for missing data, and its Fast Sync Read reports one result for
the whole packet, so the bus sends the request with ``syncReadTx`` and parses the replies
itself: plain Sync Read takes each status packet with ``rxPacket`` and files it under the
ID it carries (a corrupt one costs only that servo); Fast Sync Read takes the one packet
and, when the SDK finds it corrupt or short, checks every block's own CRC (the running
CRC, re-seeded from the previous block's transmitted CRC, so one bad block does not
condemn the rest) and keeps the blocks that verify.

In a Sync Read chain a silent servo silences those after it (each waits for the previous
status packet). So after a read with a STALE servo, the first STALE servo moves to the
back of the read order: one dead servo costs one tick of collateral STALE, not all ticks.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import TypeVar

import numpy as np

from drivers.clock import Clock
from drivers.dynamixel import control_table as ct
from drivers.dynamixel.control_table import Item, OperatingMode
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
from drivers.servo_bus import ExitPolicy, ExitReport, PresentReading, ReadStatus, ServoBus

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
                    if i + 1 < len(order):  # the chain broke here: ask it last next time
                        self._set_order(order[:i] + order[i + 1 :] + [k])
                    break

    def _receive_plain(self, out: PresentReading) -> None:
        """Take up to n status packets; file each under the ID it carries."""
        pos, status, errors = out.positions, out.status, out.errors
        index, ph, port = self._index, self._ph, self._port
        missing = self.n
        for _ in range(2 * self.n):
            packet, result = ph.rxPacket(port, False)
            if result == _OK:
                k = index.get(packet[4])
                if k is None or status[k] != _STALE:
                    continue  # a stranger, or a second reply from the same servo
                err = packet[8]
                errors[k] = err
                if err & ct.ERROR_NUMBER_MASK:
                    status[k] = _ALERT if err & ct.ALERT_BIT else _ERROR
                elif (packet[5] | packet[6] << 8) >= 8:  # LEN = INST ERR data(4) CRC(2)
                    v = packet[9] | packet[10] << 8 | packet[11] << 16 | packet[12] << 24
                    pos[k] = ((v - 0x1_0000_0000 if v & 0x8000_0000 else v) - CENTER_TICK) * (
                        RAD_PER_TICK
                    )
                    status[k] = _ALERT if err & ct.ALERT_BIT else _GOOD
                else:
                    continue  # no data and no error: not a reading
                missing -= 1
                if not missing:
                    return
            elif result == _TIMEOUT:
                return
            # corrupt: that reply is lost; the next may be fine

    def _parse_fast(self, packet: list[int], verified: bool, out: PresentReading) -> None:
        """Blocks ``ERR ID pos(4) CRC(2)`` from offset 8. ``verified``: the SDK checked the
        packet CRC (which covers every block); else each block's CRC is checked alone."""
        if packet[:5] != [0xFF, 0xFF, 0xFD, 0x00, 0xFE]:
            return
        pos, status, errors, index = out.positions, out.status, out.errors, self._index
        crc = self._ph.updateCRC
        end = len(packet)
        seed = None if verified else crc(0, packet, 8)
        for o in range(8, 8 + 8 * self.n, 8):
            if o + 8 > end:
                return
            if not verified:
                if o > 8:  # the sender's running CRC went on over the previous CRC bytes
                    seed = crc(packet[o - 2] | packet[o - 1] << 8, packet[o - 2 : o], 2)
                if crc(seed, packet[o : o + 6], 6) != packet[o + 6] | packet[o + 7] << 8:
                    continue
            k = index.get(packet[o + 1])
            if k is None:
                continue
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
        """Packet timeouts for the reads: the SDK's (wire + 2·latency + 2 ms) plus the
        servos' Return Delay Times, which the SDK leaves out (n of them in a plain chain,
        one in a fast reply)."""
        base = self._port.tx_time_per_byte * 15 * self.n + 2.0 * self.link.latency_timer_ms + 2.0
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

    def _check_one(
        self, k: int, exp: Expectation, rows: list[Mismatch], notes: list[str]
    ) -> ServoState | None:
        sid, link, attempts = exp.id, self.link, 1 + self.retries

        def add(item: str, expected: str, found: str, fix: str = "") -> None:
            rows.append(Mismatch(sid, item, expected, found, fix))

        try:
            model, fw = _retry(attempts, lambda: link.ping(sid))
        except CommTimeout:
            add(
                "answers Ping",
                "yes",
                "no (timeout)",
                f"check ID, power, wiring and baud ({link.baud})",
            )
            return None
        except CorruptPacket:
            add("answers Ping", "yes", "corrupt replies", "two servos with this ID?")
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
        try:
            block = _retry(attempts, lambda: link.read(sid, 0, block_item.size))
        except CommTimeout:
            add(
                "Status Return Level",
                "2",
                "0? (answers Ping, not Read)",
                "write 2 to addr 68 (Status Return Level)",
            )
            return None
        except (CorruptPacket, ServoError) as exc:
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
        :func:`~drivers.dynamixel.control_table.describe_hardware_error`."""
        self._check_open()
        return self.link.read_item(servo_id, ct.HARDWARE_ERROR_STATUS)

    # -- exit ----------------------------------------------------------------------
    def _apply_exit_policy(self, policy: ExitPolicy, retries: int) -> ExitReport:
        """``hold``: torque must be on; a tripped watchdog is cleared, Goal Position :=
        Present Position, then the watchdog armed (the last :meth:`arm_watchdog` period,
        else 0.1 s); each read back. ``relax``: Torque Enable := 0, read back. A servo
        whose step fails ``1 + retries`` times is skipped and named; the adapter gone
        stops at once. Raises :class:`ExitNotConfirmed` unless every servo is confirmed."""
        confirmed: list[int] = []
        failed: list[tuple[int, str]] = []
        attempts = 1 + retries
        try:
            self.link.recover()
            for sid in self.ids:
                try:
                    if policy is ExitPolicy.HOLD:
                        self._hold_one(sid, attempts)
                    else:
                        self._confirm(sid, ct.TORQUE_ENABLE, 0, attempts)
                    confirmed.append(sid)
                except _UnconfirmedError as exc:
                    failed.append((sid, str(exc)))
        except PortGone as exc:
            done = {s for s, _ in failed} | set(confirmed)
            failed += [(s, f"adapter gone: {exc}") for s in self.ids if s not in done]
            raise ExitNotConfirmed(ExitReport(policy, tuple(confirmed), tuple(failed))) from exc
        report = ExitReport(policy, tuple(confirmed), tuple(failed))
        if failed:
            raise ExitNotConfirmed(report)
        return report

    def _hold_one(self, sid: int, attempts: int) -> None:
        if not self._read(sid, ct.TORQUE_ENABLE, attempts):
            raise _UnconfirmedError("torque is off: cannot hold (the servo is limp)")
        if self._read(sid, ct.BUS_WATCHDOG, attempts) == ct.WATCHDOG_TRIPPED:
            self._confirm(sid, ct.BUS_WATCHDOG, 0, attempts)
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
