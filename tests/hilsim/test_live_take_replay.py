"""A take made live is checked offline: a Bottango live session over the pty, recorded with
``[record]``, replays through ``hilsim tracks`` as the targets the live show had. The take's
files are what the rig already reads: ``raw.csv`` and ``keys.csv`` as ``type = "csv"``
targets, ``take.toml`` as a clip."""

from __future__ import annotations

import json
import os
import select
import termios
import tty

import numpy as np
import pytest

from hilsim.cli import main
from tests.hilsim.test_live_run import PERIOD, RIG, deg, hashed, show

CURVES = ("sC,0,0,1000,4096,300,0,7110,-300,0", "sC,0,1300,400,7110,0,0,1000,0,0")


def _session(tmp_path):
    """The Bottango app's side at tick 10: handshake, registration, time sync, two curves
    (1.0 s, then a 0.3 s hold and 0.4 s back), each line answered before the next."""
    link = tmp_path / "bottango"
    text = f"""
[inputs.bottango]
transport = "pty"
link = "{link}"
[inputs.bottango.effectors."0"]
joint = "jaw"
signal = [1000, 2000]
degrees = [0, 20]
[record]
joints = ["jaw"]
tolerance_deg = 0.5
"""
    fds = []

    def talk(fd: int, line: bytes) -> None:
        os.write(fd, line)
        got = b""
        while not got.endswith(b"OK\n"):
            assert select.select([fd], [], [], 5.0)[0], f"no answer to {line!r}"  # a safety net
            got += os.read(fd, 256)

    def inject(k, _director):
        if k == 10:
            fd = os.open(link, os.O_RDWR | os.O_NOCTTY)
            tty.setraw(fd, termios.TCSANOW)
            fds.append(fd)
            for cmd in ("hRQ,144", "rSVPin,0,1000,2000,3000,1500", "tSYN,0", *CURVES):
                talk(fd, hashed(cmd))

    try:
        return show(tmp_path, text, duration=2.4, inject=inject, open_inputs=True)
    finally:
        for fd in fds:
            os.close(fd)


def _tracks(tmp_path, name: str, jaw_target: str, extra: str, times: np.ndarray, capsys):
    rig = tmp_path / f"{name}.toml"
    text = RIG.replace(
        'target = { type = "keyframes", keys = [[0, 0], [10, 20]], easing = "linear" }',
        f"target = {jaw_target}",
    )
    rig.write_text(text + extra)
    at = ",".join(repr(float(t)) for t in times)
    assert main(["tracks", str(rig), "--at", at, "--json"]) == 0
    return np.array(json.loads(capsys.readouterr().out)["jaw"])


def test_a_bottango_live_take_replays_offline_as_it_was_live(tmp_path, capsys):
    r = _session(tmp_path)
    assert r.result.exit_code == 0
    written = r.result.summary["live"]["takes"]["live"]
    take = r.out / "take"
    assert written["raw_csv"] == str(take / "raw.csv")
    live = deg(r.run, "target", 1)  # the jaw's target, tick by tick, as the show ran it
    ticks = np.arange(len(live)) * PERIOD
    raw_t = np.loadtxt(take / "raw.csv", delimiter=",", skiprows=1)[:, 0]
    on = (ticks >= raw_t[0] - 1e-9) & (ticks <= raw_t[-1] + 1e-9)  # while Bottango held it
    assert on.sum() > 400 and written["raw_samples"]["jaw"] > 200
    at, want = ticks[on][::3], live[on][::3]
    # raw.csv: every value the session set, at the tick it set it: the live targets exactly.
    # (Joined linearly between two samples, so across a hold it is not the live target.)
    k = np.rint(raw_t / PERIOD).astype(int)[::3]
    raw = _tracks(tmp_path, "raw", f'{{ type = "csv", file = "{take / "raw.csv"}" }}', "",
                  ticks[k], capsys)  # fmt: skip
    np.testing.assert_allclose(raw, live[k], rtol=0, atol=1e-9)
    # raw.csv held row to row: the live target at every tick, holds kept
    held = _tracks(tmp_path, "held",
                   f'{{ type = "csv", file = "{take / "raw.csv"}", interpolation = "hold" }}', "",
                   at, capsys)  # fmt: skip
    np.testing.assert_allclose(held, want, rtol=0, atol=1e-9)
    # keys.csv: the linear keys, within the take's tolerance of the live target at every tick
    keys = _tracks(tmp_path, "keys", f'{{ type = "csv", file = "{take / "keys.csv"}" }}', "", at,
                   capsys)  # fmt: skip
    assert np.max(np.abs(keys - want)) <= 0.5
    assert written["keys"]["jaw"] < written["raw_samples"]["jaw"] / 5
    # take.toml: the [clips.take] table pasted into the rig and played from show time 0
    clip = (take / "take.toml").read_text() + '[[play]]\nat_s = 0\nclip = "take"\n'
    played = _tracks(tmp_path, "clip", '{ type = "hold", value_deg = 0 }', clip, at, capsys)
    np.testing.assert_allclose(played, keys, rtol=0, atol=1e-9)
    assert played[-1] == pytest.approx(live[on][-1], abs=0.5)
