"""A gamepad's sticks -> joint degrees, its buttons -> trigger keys, polled once per tick.

The show file's ``[inputs.gamepad]`` maps axes to joints (``degrees`` at -1 and +1) and buttons
to trigger strings. Needs pygame (``pip install 'hilsim[gamepad]'``); without it the show file
is refused at load with that line. No window opens: SDL runs with the ``dummy`` video driver
unless ``SDL_VIDEODRIVER`` is set.

* A thread reads the mapped axes and buttons ~100 times a second into a bounded
  :class:`~hilsim.live.inbox.Inbox`, stamped with show time.
* :meth:`GamepadInput.poll` (the loop) takes, without waiting, the latest degrees per joint and
  each button's rising edge as a trigger: a press shorter than a tick is still seen.
* An axis maps linearly, its deadzone cut out without a step. It takes its joint only once it
  has moved: a pad on the desk does not override the show's clips.
* Unplugged, or silent for ``lost_after_s``: one ``input_lost`` event and the joints hold; its
  return is ``input_resumed``.

:meth:`GamepadInput.close` stops the thread and shuts SDL's joystick down. Every key with an
example: ``docs/live.md`` (Gamepad).
"""

from __future__ import annotations

import contextlib
import importlib.util
import math
import os
import threading
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from hilsim.live.inbox import DEFAULT_CAPACITY, MAX_LIVE_DEG, Inbox, LiveEvent
from hilsim.live.midi import LiveExtraError
from hilsim.live.triggers import INPUT_KINDS, parse_trigger

GAMEPAD_HINT = "pip install 'hilsim[gamepad]'"
#: readings per second the thread takes
RATE_HZ = 100.0
_LOST = "lost"  # the thread's message: the pad is gone


class GamepadUnavailableError(LiveExtraError, ValueError):
    """pygame is not installed (one line naming the extra); a ValueError for show loaders."""


@dataclass(frozen=True)
class AxisMap:
    """One axis (-1..+1) -> one joint's ``min_deg`` .. ``max_deg``."""

    axis: int
    joint: str
    min_deg: float
    max_deg: float

    def degrees(self, v: float, deadzone: float) -> float:
        """The joint angle for the axis value ``v``, the deadzone cut out."""
        v = max(-1.0, min(1.0, v))
        m = abs(v)
        v = 0.0 if m <= deadzone else math.copysign((m - deadzone) / (1.0 - deadzone), v)
        return self.min_deg + (v + 1.0) * 0.5 * (self.max_deg - self.min_deg)


@dataclass(frozen=True)
class ButtonMap:
    """One button -> one trigger key, given on each press."""

    button: int
    trigger: str


@dataclass(frozen=True)
class GamepadConfig:
    """``[inputs.gamepad]`` (its keys: ``docs/live.md``, Gamepad)."""

    axes: tuple[AxisMap, ...] = ()
    buttons: tuple[ButtonMap, ...] = ()
    index: int = 0
    deadzone: float = 0.05
    lost_after_s: float = 0.5
    #: an axis not moved this long hands its joint back to the show (None: held)
    release_after_s: float | None = None

    @classmethod
    def from_table(
        cls, table: Mapping[str, Any], where: str, names: Collection[str] | None = None
    ) -> GamepadConfig:
        """Read ``[inputs.gamepad]``; ``names``: the rig's joints. Raises ValueError
        ``"<where>.<key>: ..."`` (one line)."""
        if not isinstance(table, Mapping):
            raise ValueError(f"{where}: must be a table, got {type(table).__name__}")
        allowed = ("index", "deadzone", "lost_after_s", "release_after_s", "axis", "button")
        for key in table:
            if key not in allowed:
                raise ValueError(f"{where}.{key}: unknown key; allowed: {', '.join(allowed)}")
        index = _int(table.get("index", 0), f"{where}.index")
        dz = table.get("deadzone", 0.05)
        if not (_num(dz) and 0 <= dz < 1):
            raise ValueError(f"{where}.deadzone: must be a number 0 <= x < 1, got {dz!r}")
        lost = table.get("lost_after_s", 0.5)
        if not (_num(lost) and lost > 0):
            raise ValueError(f"{where}.lost_after_s: must be a number of seconds > 0, got {lost!r}")
        release = table.get("release_after_s")
        if release is not None and not (_num(release) and release > 0):
            raise ValueError(
                f"{where}.release_after_s: must be a number of seconds > 0, got {release!r}"
            )
        axes = tuple(_axis(t, f"{where}.axis[{i}]", names) for i, t in _items(table, "axis", where))
        seen: set[str] = set()
        for i, a in enumerate(axes):
            if a.joint in seen:
                raise ValueError(f"{where}.axis[{i}].joint: {a.joint!r} is mapped twice")
            seen.add(a.joint)
        buttons = tuple(
            _button(t, f"{where}.button[{i}]") for i, t in _items(table, "button", where)
        )
        if not axes and not buttons:
            raise ValueError(
                f"{where}: maps nothing: add [[inputs.gamepad.axis]] or [[inputs.gamepad.button]]"
            )
        return cls(
            axes, buttons, index, float(dz), float(lost),
            None if release is None else float(release),
        )  # fmt: skip


def _num(x: object) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _int(x: object, where: str) -> int:
    if not isinstance(x, int) or isinstance(x, bool) or not 0 <= x <= 255:
        raise ValueError(f"{where}: must be an integer 0-255, got {x!r}")
    return x


def _items(table: Mapping[str, Any], key: str, where: str) -> list[tuple[int, Mapping[str, Any]]]:
    items = table.get(key, [])
    if not isinstance(items, list) or not all(isinstance(t, Mapping) for t in items):
        raise ValueError(f"{where}.{key}: must be an array of tables ([[...{key}]])")
    return list(enumerate(items))


def _axis(t: Mapping[str, Any], where: str, names: Collection[str] | None) -> AxisMap:
    for key in t:
        if key not in ("axis", "joint", "degrees"):
            raise ValueError(f"{where}.{key}: unknown key; allowed: axis, joint, degrees")
    for key in ("axis", "joint", "degrees"):
        if key not in t:
            raise ValueError(f"{where}.{key}: missing")
    joint = t["joint"]
    if not isinstance(joint, str) or not joint:
        raise ValueError(f"{where}.joint: must be a joint's name, got {joint!r}")
    if names is not None and joint not in names:
        raise ValueError(f"{where}.joint: no joint {joint!r}; the rig has {', '.join(names)}")
    deg = t["degrees"]
    if not (
        isinstance(deg, list)
        and len(deg) == 2
        and all(_num(x) and abs(x) <= MAX_LIVE_DEG for x in deg)
    ):
        raise ValueError(
            f"{where}.degrees: must be [min, max] in degrees within ±{MAX_LIVE_DEG:g}, got {deg!r}"
        )
    if deg[0] == deg[1]:
        raise ValueError(f"{where}.degrees: both ends are {deg[0]!r}")
    return AxisMap(_int(t["axis"], f"{where}.axis"), joint, float(deg[0]), float(deg[1]))


def _button(t: Mapping[str, Any], where: str) -> ButtonMap:
    for key in t:
        if key not in ("button", "trigger"):
            raise ValueError(f"{where}.{key}: unknown key; allowed: button, trigger")
    if "button" not in t or "trigger" not in t:
        raise ValueError(f"{where}: needs button and trigger")
    try:
        trig = parse_trigger(t["trigger"])
    except ValueError as exc:
        raise ValueError(f"{where}.trigger: {exc}") from None
    if trig.kind not in INPUT_KINDS:
        raise ValueError(f"{where}.trigger: {trig.key!r} is a timer; a button gives 'key:<k>', "
                         "'osc:/address' or 'midi:...'")  # fmt: skip
    return ButtonMap(_int(t["button"], f"{where}.button"), trig.key)


class JoystickSource(Protocol):
    """What the thread reads (pygame's, or a test's fake); every call from the thread."""

    def read(self, index: int) -> tuple[Sequence[float], Sequence[bool]] | None:
        """(axes, buttons) of joystick ``index`` now, or None when it is not there."""
        ...

    def close(self) -> None: ...


class PygameSource:
    """Joystick ``index`` through pygame 2 (SDL), no window; made in the reading thread."""

    def __init__(self) -> None:
        os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # the event pump needs video
        os.environ.setdefault("SDL_JOYSTICK_ALLOW_BACKGROUND_EVENTS", "1")
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")  # no banner on stdout
        import pygame

        self.pg = pygame
        pygame.display.init()
        pygame.joystick.init()
        self.joy: Any = None
        self.name = ""

    def read(self, index: int) -> tuple[Sequence[float], Sequence[bool]] | None:
        pg = self.pg
        try:
            for ev in pg.event.get():
                joy = self.joy
                if (
                    ev.type == pg.JOYDEVICEREMOVED
                    and joy is not None
                    and getattr(ev, "instance_id", None) == joy.get_instance_id()
                ):
                    self.joy = None
            if self.joy is None:
                if pg.joystick.get_count() <= index:
                    return None
                self.joy = pg.joystick.Joystick(index)
                self.name = self.joy.get_name()
            joy = self.joy
            axes = [joy.get_axis(i) for i in range(joy.get_numaxes())]
            buttons = [bool(joy.get_button(i)) for i in range(joy.get_numbuttons())]
        except pg.error:  # unplugged between the check and the read
            self.joy = None
            return None
        return axes, buttons

    def close(self) -> None:
        self.pg.joystick.quit()
        self.pg.display.quit()


@dataclass
class GamepadPoll:
    """What one ``poll(t)`` found: ``values`` joint -> degrees (``None`` until its axis first
    moves; the input's own dict: read it, do not keep it), ``triggers`` pressed, ``events``,
    ``lost`` (hold the joints)."""

    values: Mapping[str, float | None]
    triggers: list[str] = field(default_factory=list)
    events: list[LiveEvent] = field(default_factory=list)
    lost: bool = False


class GamepadInput:
    """A gamepad -> joint degrees and trigger keys (see the module docstring).

    Args:
        config: the show file's ``[inputs.gamepad]``.
        joystick_factory: makes the :class:`JoystickSource`, called in the reading thread;
            ``None``: pygame's (raises GamepadUnavailableError now when pygame is missing).
        capacity: readings held for the loop.
    """

    def __init__(
        self,
        config: GamepadConfig,
        joystick_factory: Callable[[], JoystickSource] | None = None,
        *,
        capacity: int = DEFAULT_CAPACITY,
        source: str = "gamepad",
    ) -> None:
        if joystick_factory is None:
            if importlib.util.find_spec("pygame") is None:
                raise GamepadUnavailableError(
                    f"the gamepad needs the optional package pygame: {GAMEPAD_HINT}"
                )
            joystick_factory = PygameSource
        self.config, self.source = config, source
        self.factory = joystick_factory
        self.inbox = Inbox(capacity)
        self.values: dict[str, float | None] = {a.joint: None for a in config.axes}
        self.lost = False
        self.readings = 0  #: readings taken by the thread, in all
        self.presses = 0  #: button presses handed to the show
        self._src: JoystickSource | None = None
        self._rest: list[float | None] = [None] * len(config.axes)  # the first reading
        self._engaged = [False] * len(config.axes)
        self._pressed = [False] * len(config.buttons)
        self._absent = False
        self._warned = False
        self._last_t: float | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ the reading side
    def start(self, now: Callable[[], float]) -> str | None:
        """Start the reading thread (before the show). Raises OSError (one line) when the
        joystick library cannot start."""
        ready = threading.Event()
        failed: list[str] = []

        def run() -> None:
            try:
                self.open_source()
                self.sample(now())  # the first reading: is the pad there?
            except Exception as exc:
                failed.append(f"{type(exc).__name__}: {exc}")
                return
            finally:
                ready.set()
            period = 1.0 / RATE_HZ
            try:
                while not self._stop.is_set():
                    self.sample(now())
                    self._stop.wait(period)
            finally:
                src, self._src = self._src, None
                if src is not None:
                    with contextlib.suppress(Exception):
                        src.close()

        self._thread = threading.Thread(target=run, name="hilsim-gamepad", daemon=True)
        self._thread.start()
        if not ready.wait(10.0) or failed:
            self.close()
            why = failed[0] if failed else "no answer in 10 s"
            raise OSError(f"cannot start the gamepad: {why}")
        maps = [f"axis {a.axis} -> {a.joint}" for a in self.config.axes]
        maps += [f"button {b.button} -> {b.trigger}" for b in self.config.buttons]
        missing = " (not found yet: its joints wait for it)" if self._absent else ""
        return f"gamepad {self.config.index}{missing}: {', '.join(maps)}"

    def open_source(self) -> None:
        """Make the joystick source (in the reading thread; tests call it, then sample)."""
        self._src = self.factory()

    def sample(self, t: float) -> None:
        """One reading, stamped ``t`` (show time): the thread's step (tests call it)."""
        src = self._src
        if src is None:
            return
        try:
            got = src.read(self.config.index)
        except Exception:  # a driver error is an unplugged pad, never the thread's end
            got = None
        if got is None:
            if not self._absent:
                self._absent = True
                self.inbox.put(t, (_LOST, None))
            return
        self._absent = False
        self.readings += 1
        axes, buttons = got
        dz = self.config.deadzone
        degs: list[tuple[str, float]] = []
        missing = []
        for i, a in enumerate(self.config.axes):
            if a.axis >= len(axes):
                missing.append(f"axis {a.axis}")
                continue
            v = float(axes[a.axis])
            if not math.isfinite(v):
                continue
            rest = self._rest[i]
            if rest is None:
                self._rest[i] = rest = v
            if not self._engaged[i] and abs(v - rest) > dz:
                self._engaged[i] = True
            if self._engaged[i]:
                degs.append((a.joint, a.degrees(v, dz)))
        pressed: list[str] = []
        for i, b in enumerate(self.config.buttons):
            if b.button >= len(buttons):
                missing.append(f"button {b.button}")
                continue
            down = bool(buttons[b.button])
            if down and not self._pressed[i]:
                pressed.append(b.trigger)
            self._pressed[i] = down
        note = None
        if missing and not self._warned:
            self._warned = True
            note = (
                f"the gamepad has {len(axes)} axes and {len(buttons)} buttons: "
                f"{', '.join(missing)} never move anything"
            )
        self.inbox.put(t, (degs, pressed, note))

    # ------------------------------------------------------------------ the loop's side
    def poll(self, t: float) -> GamepadPoll:
        """The readings due at ``t`` (show time, s) applied; bounded work, never waits."""
        out = GamepadPoll(self.values)
        if self._last_t is None:
            self._last_t = t  # the lost timer starts at the first poll
        drops = self.inbox.take_drops()
        if drops:
            out.events.append(LiveEvent(t, "inbox_overflow", self.source,
                                        {"message": f"gamepad: {drops} readings dropped",
                                         "dropped": drops}))  # fmt: skip
        for tm, msg in self.inbox.take_due(t):
            self._last_t = tm
            if msg[0] == _LOST:
                if not self.lost:
                    self._lose(tm, "unplugged (or not found)", out.events)
                continue
            degs, pressed, note = msg
            if self.lost:
                self.lost = False
                out.events.append(LiveEvent(tm, "input_resumed", self.source,
                                            {"message": "gamepad back",
                                             "joints": list(self.values)}))  # fmt: skip
            if note:
                out.events.append(LiveEvent(tm, "input_config", self.source, {"message": note}))
            for joint, deg in degs:
                self.values[joint] = deg
            out.triggers += pressed
            self.presses += len(pressed)
        if not self.lost and t - self._last_t > self.config.lost_after_s:
            self._lose(t, f"no reading for {t - self._last_t:.3f} s", out.events)
        out.lost = self.lost
        return out

    def _lose(self, t: float, why: str, events: list[LiveEvent]) -> None:
        self.lost = True
        held = {j: v for j, v in self.values.items() if v is not None}
        events.append(
            LiveEvent(
                t,
                "input_lost",
                self.source,
                {
                    "message": f"gamepad {self.config.index} lost: {why}; joints hold",
                    "joints": list(self.values),
                    "held_deg": held,
                    "lost_after_s": self.config.lost_after_s,
                },
            )
        )

    def close(self) -> None:
        """Stop the thread (it closes the joystick library). Never raises; idempotent."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2.0)

    def summary(self) -> dict[str, Any]:
        return {"readings": self.readings, "presses": self.presses, "lost": self.lost,
                "dropped": self.inbox.dropped}  # fmt: skip
