"""The gamepad with a fake joystick: the show file's section, axes -> degrees (deadzone, an axis
takes its joint once it moves), button presses -> triggers, unplugged -> input_lost and the
joints hold, the reading thread, and the optional extra. pygame itself is tried only when it is
installed (it is not a test dependency)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import pytest

from hilsim.live.gamepad import (
    AxisMap,
    GamepadConfig,
    GamepadInput,
    GamepadUnavailableError,
)

WHERE = "show.toml: inputs.gamepad"
NAMES = ("head_pan", "jaw", "eyes")


class FakeJoystick:
    """What the reading thread sees: axes, buttons, plugged in or not."""

    def __init__(self, n_axes: int = 4, n_buttons: int = 4) -> None:
        self.axes = [0.0] * n_axes
        self.buttons = [False] * n_buttons
        self.present = True
        self.reads = threading.Semaphore(0)
        self.closed = False

    def read(self, index):
        self.reads.release()
        if not self.present:
            return None
        return list(self.axes), list(self.buttons)

    def close(self):
        self.closed = True


def config(**kw) -> GamepadConfig:
    table = {
        "axis": [
            {"axis": 0, "joint": "head_pan", "degrees": [-30, 30]},
            {"axis": 2, "joint": "jaw", "degrees": [20, 0]},
        ],
        "button": [{"button": 0, "trigger": "key:s"}, {"button": 3, "trigger": "midi:note:60"}],
        **kw,
    }
    return GamepadConfig.from_table(table, WHERE, NAMES)


def pad(**kw) -> tuple[GamepadInput, FakeJoystick]:
    joy = FakeJoystick()
    gp = GamepadInput(config(**kw), joystick_factory=lambda: joy)
    gp.open_source()
    return gp, joy


# -- the show file ---------------------------------------------------------------------------


def test_from_table_reads_the_section() -> None:
    c = config(index=1, deadzone=0.1, lost_after_s=2)
    assert c.index == 1 and c.deadzone == 0.1 and c.lost_after_s == 2.0
    assert c.axes == (AxisMap(0, "head_pan", -30.0, 30.0), AxisMap(2, "jaw", 20.0, 0.0))
    assert [(b.button, b.trigger) for b in c.buttons] == [(0, "key:s"), (3, "midi:note:60:ch1")]
    d = GamepadConfig.from_table({"button": [{"button": 1, "trigger": "key:x"}]}, WHERE)
    assert (d.index, d.deadzone, d.lost_after_s, d.axes) == (0, 0.05, 0.5, ())


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"axes": []}, r"inputs.gamepad.axes: unknown key; allowed: index"),
        ({}, r"inputs.gamepad: maps nothing"),
        ({"index": -1, "axis": []}, r"inputs.gamepad.index: must be an integer 0-255"),
        ({"deadzone": 1.0}, r"inputs.gamepad.deadzone: must be a number 0 <= x < 1"),
        ({"lost_after_s": 0}, r"inputs.gamepad.lost_after_s: must be a number of seconds > 0"),
        ({"axis": {"axis": 0}}, r"inputs.gamepad.axis: must be an array of tables"),
        ({"axis": [{"axis": 0, "joint": "neck", "degrees": [0, 1]}]},
         r"inputs.gamepad.axis\[0\].joint: no joint 'neck'; the rig has head_pan, jaw, eyes"),
        ({"axis": [{"axis": 0, "joint": "jaw", "degrees": [5]}]},
         r"inputs.gamepad.axis\[0\].degrees: must be \[min, max\]"),
        ({"axis": [{"axis": 0, "joint": "jaw", "degrees": [5, 5]}]},
         r"inputs.gamepad.axis\[0\].degrees: both ends are 5"),
        ({"axis": [{"axis": True, "joint": "jaw", "degrees": [0, 5]}]},
         r"inputs.gamepad.axis\[0\].axis: must be an integer"),
        ({"axis": [{"joint": "jaw", "degrees": [0, 5]}]}, r"inputs.gamepad.axis\[0\].axis: missing"),
        ({"axis": [{"axis": 0, "joint": "jaw", "degrees": [0, 5]},
                   {"axis": 1, "joint": "jaw", "degrees": [0, 5]}]},
         r"inputs.gamepad.axis\[1\].joint: 'jaw' is mapped twice"),
        ({"button": [{"button": 0}]}, r"inputs.gamepad.button\[0\]: needs button and trigger"),
        ({"button": [{"button": 0, "trigger": ""}]}, r"inputs.gamepad.button\[0\].trigger"),
        ({"button": [{"button": 0, "trigger": "scare"}]},
         r"inputs.gamepad.button\[0\].trigger: 'scare': unknown trigger"),
        ({"button": [{"button": 0, "trigger": "every:5"}]},
         r"inputs.gamepad.button\[0\].trigger: 'every:5' is a timer"),
        ({"button": [{"button": 0, "trigger": "x", "hold": 1}]},
         r"inputs.gamepad.button\[0\].hold: unknown key"),
    ],
)  # fmt: skip
def test_from_table_errors_are_one_line(table, message) -> None:
    with pytest.raises(ValueError, match=message) as err:
        GamepadConfig.from_table(table, WHERE, NAMES)
    assert str(err.value).startswith(WHERE) and "\n" not in str(err.value)


# -- axes, buttons ---------------------------------------------------------------------------


def test_axis_mapping_is_linear_with_the_deadzone_cut_out() -> None:
    a = AxisMap(0, "head_pan", -30.0, 30.0)
    assert [a.degrees(v, 0.1) for v in (-1.0, -0.1, 0.05, 0.1, 0.55, 1.0, 3.0)] == pytest.approx(
        [-30.0, 0.0, 0.0, 0.0, 15.0, 30.0, 30.0]
    )
    assert AxisMap(0, "jaw", 20.0, 0.0).degrees(-1.0, 0.0) == 20.0  # reversed


def test_an_axis_takes_its_joint_only_once_it_moves() -> None:
    gp, joy = pad()
    gp.sample(0.00)  # at rest: the show's clips keep the joints
    joy.axes[0] = 0.04  # within the deadzone of its first reading: still nothing
    gp.sample(0.01)
    p = gp.poll(0.01)
    assert dict(p.values) == {"head_pan": None, "jaw": None} and p.events == []
    joy.axes[0] = 0.525  # moved: head_pan is live from here on
    gp.sample(0.02)
    assert gp.poll(0.02).values["head_pan"] == pytest.approx(15.0)
    joy.axes[0] = 0.0  # back to the centre: the centre of the range, not "no value"
    gp.sample(0.03)
    p = gp.poll(0.03)
    assert p.values["head_pan"] == 0.0 and p.values["jaw"] is None


def test_a_trigger_axis_resting_at_minus_one_does_not_count_as_a_move() -> None:
    gp, joy = pad()
    joy.axes[2] = -1.0
    gp.sample(0.0)
    gp.sample(0.01)
    assert gp.poll(0.01).values["jaw"] is None
    joy.axes[2] = 1.0  # squeezed fully: jaw to its +1 end (0 deg, the range is reversed)
    gp.sample(0.02)
    assert gp.poll(0.02).values["jaw"] == 0.0


def test_a_button_press_fires_its_trigger_once_even_between_two_polls() -> None:
    gp, joy = pad()
    gp.sample(0.00)
    joy.buttons[0] = True
    gp.sample(0.01)
    joy.buttons[0] = False  # released before the loop polled
    gp.sample(0.02)
    assert gp.poll(0.02).triggers == ["key:s"]
    joy.buttons[3] = True
    for k in range(3, 8):  # held: one press
        gp.sample(k / 100)
    assert gp.poll(0.08).triggers == ["midi:note:60:ch1"]
    joy.buttons[3] = False
    gp.sample(0.09)
    joy.buttons[3] = joy.buttons[0] = True
    gp.sample(0.10)
    assert gp.poll(0.10).triggers == ["key:s", "midi:note:60:ch1"]
    assert gp.summary()["presses"] == 4


def test_readings_wait_for_their_time() -> None:
    gp, joy = pad()
    joy.buttons[0] = True
    gp.sample(0.5)
    assert gp.poll(0.4).triggers == []
    assert gp.poll(0.5).triggers == ["key:s"]


def test_unplugged_is_one_input_lost_and_the_joints_hold_then_it_comes_back() -> None:
    gp, joy = pad()
    gp.sample(0.0)
    joy.axes[0] = 1.0
    gp.sample(0.01)
    assert gp.poll(0.01).values["head_pan"] == 30.0
    joy.present = False
    for k in range(2, 50):  # the thread keeps looking
        gp.sample(k / 100)
    p = gp.poll(0.49)
    (ev,) = p.events
    assert ev.kind == "input_lost" and ev.t == 0.02 and ev.source == "gamepad"
    assert "unplugged" in ev.detail["message"] and ev.detail["held_deg"] == {"head_pan": 30.0}
    assert p.lost and p.values["head_pan"] == 30.0  # held
    p = gp.poll(2.0)  # long silence while lost: no second event
    assert p.events == [] and p.lost
    joy.present = True
    joy.axes[0] = -1.0
    gp.sample(2.01)
    p = gp.poll(2.01)
    assert [e.kind for e in p.events] == ["input_resumed"]
    assert not p.lost and p.values["head_pan"] == -30.0


def test_no_reading_for_lost_after_s_is_input_lost_too() -> None:
    gp, _joy = pad(lost_after_s=0.25)
    gp.sample(0.0)
    assert gp.poll(0.25).events == []
    (ev,) = gp.poll(0.26).events  # the reader stalled: nothing came for 0.26 s
    assert ev.kind == "input_lost" and "no reading" in ev.detail["message"]
    assert gp.poll(0.5).events == []
    gp.sample(0.6)
    assert [e.kind for e in gp.poll(0.6).events] == ["input_resumed"]


def test_a_pad_with_fewer_axes_than_mapped_says_so_once() -> None:
    joy = FakeJoystick(n_axes=2, n_buttons=1)
    gp = GamepadInput(config(), joystick_factory=lambda: joy)
    gp.open_source()
    gp.sample(0.0)
    gp.sample(0.01)
    (ev,) = gp.poll(0.01).events
    assert ev.kind == "input_config"
    assert "axis 2, button 3 never move anything" in ev.detail["message"]


def test_a_source_that_raises_is_an_unplugged_pad() -> None:
    gp, joy = pad()

    def broken(index):
        raise RuntimeError("driver error")

    joy.read = broken
    gp.sample(0.0)
    assert [e.kind for e in gp.poll(0.0).events] == ["input_lost"]


# -- the thread ------------------------------------------------------------------------------


def test_the_thread_reads_the_pad_and_close_stops_it_and_closes_the_source() -> None:
    joy = FakeJoystick()
    joy.axes[0] = 0.3
    made = []

    def factory():
        made.append(threading.current_thread().name)
        return joy

    gp = GamepadInput(config(), joystick_factory=factory)
    note = gp.start(lambda: 1.0)
    assert (
        note
        == "gamepad 0: axis 0 -> head_pan, axis 2 -> jaw, button 0 -> key:s, button 3 -> midi:note:60:ch1"
    )
    try:
        assert joy.reads.acquire(timeout=10.0)  # the first reading (the rest position)
        joy.axes[0] = 1.0
        joy.buttons[0] = True
        for _ in range(3):  # a read after the change has begun: the change was handed over
            assert joy.reads.acquire(timeout=10.0)
    finally:
        gp.close()
    assert made == ["hilsim-gamepad"]  # the source is made in the reading thread
    assert joy.closed
    p = gp.poll(1.0)
    assert p.values["head_pan"] == 30.0 and p.triggers == ["key:s"]


def test_a_joystick_library_that_cannot_start_is_one_oserror_line() -> None:
    def factory():
        raise RuntimeError("SDL could not initialize")

    gp = GamepadInput(config(), joystick_factory=factory)
    with pytest.raises(OSError, match="cannot start the gamepad: RuntimeError: SDL could not"):
        gp.start(lambda: 0.0)


# -- pygame ----------------------------------------------------------------------------------


def test_without_pygame_the_show_is_refused_with_the_extra(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "pygame", None)
    with pytest.raises(GamepadUnavailableError, match=r"pip install 'hilsim\[gamepad\]'") as err:
        GamepadInput(config())
    assert isinstance(err.value, ValueError)


def test_pygame_source_runs_headless_when_pygame_is_installed() -> None:
    """In a child process (SDL's state is process-wide): no window, no banner, no pad."""
    pytest.importorskip("pygame")
    code = (
        "from hilsim.live.gamepad import PygameSource\n"
        "s = PygameSource()\n"
        "print(s.read(0))\n"
        "s.close()\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "SDL_VIDEODRIVER"}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env=env
    )
    assert out.returncode == 0, out.stderr
    last = out.stdout.strip().splitlines()[-1]
    assert last == "None" or last.startswith("(")  # no pad here, or (axes, buttons) of one
    assert "Hello from the pygame community" not in out.stdout
