"""Bottango live driver: framing and hash, handshake, curves against the export reader, stop,
bad lines, fuzz, the show-file table, and the pty and TCP transports (behaviour only)."""

from __future__ import annotations

import math
import os
import select
import socket
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hilsim.live.bottango_live import BottangoLive, EffectorMap, from_table
from hilsim.targets.formats.bottango import read_export
from hilsim.targets.formats.common import UnitMap

OK, HASH_FAIL = b"OK\n", b"HASH_FAIL\n"
REG = "rSVPin,0,1000,2000,3000,1500"
SC1 = "sC,0,0,2000,4096,513,0,7110,-763,814"
SC2 = "sC,0,2000,1000,7110,331,-354,2277,-331,931"
JAW = {"0": EffectorMap("jaw", 1000, 2000, 0, 40)}
WHERE = "show.toml: inputs.bottango"


def h(cmd: str) -> bytes:
    """A command as Bottango sends it: ``,h<sum of the character codes>`` and a newline."""
    return f"{cmd},h{sum(cmd.encode())}\n".encode()


def live(*cmds: str, t: float = 0.0, **kw) -> BottangoLive:
    eng = BottangoLive(JAW, **kw)
    for c in cmds:
        eng.feed_line(t, h(c))
    return eng


@pytest.fixture
def export_track(tmp_path):
    """The same two curves as a generated-code export, read by the export reader."""
    p = tmp_path / "GeneratedCodeAnimations.cpp"
    p.write_text(
        f'const char SETUP_DATA_0[] PROGMEM = "{REG}\\n";\n'
        f'const char ANIM_0_DATA0[] PROGMEM = "{SC1}\\n{SC2}\\n";\n'
        "const uint16_t ANIM_0_CONFIG[] PROGMEM = { 0, 0, 0, 10, 0, 1, 0, 0 };\n"
    )
    track = read_export(p).track(0, "0", signal=UnitMap((1000, 2000), (0, 40), "us"))
    return lambda t: math.degrees(track.sample(t)[0])


# ------------------------------------------------------------------------------ framing, hash
def test_hash_accepted_and_rejected_moves_nothing():
    eng = BottangoLive(JAW)
    assert eng.feed_line(0.0, b"xUC,4,h368")[-1] == OK  # 120+85+67+44+52 = 368
    assert eng.feed_line(0.0, b"xUC,4,h369\n") == [HASH_FAIL]
    eng = live(REG, "tSYN,0", SC1)
    before = eng.poll(1.0).values
    for bad in (b"xUC,0,h369", b"sCI,0,0,h1", b"xE", b"STOP,h0", b"xE,h", b"xE,h12x", b""):
        assert eng.feed_line(1.0, bad) == [HASH_FAIL], bad
    p = eng.poll(1.0)
    assert p.values == before and not p.stop
    assert eng.summary()["drops"]["hash"] == 7


def test_handshake_exact_and_once():
    eng = BottangoLive(JAW)
    assert eng.feed_line(0.0, h("hRQ,144")) == [b"btngoHSK,0.8.0c1,144\n", OK]
    assert eng.feed_line(0.1, h("hRQ,145")) == []  # the serial driver ignores a second one
    eng.disconnected(0.2)  # the port was closed: a new connection's handshake is answered
    assert eng.feed_line(0.3, h("hRQ,146")) == [b"btngoHSK,0.8.0c1,146\n", OK]
    custom = BottangoLive(JAW, driver_version="9.9.9")
    assert custom.feed_line(0.0, h("hRQ,7"))[0] == b"btngoHSK,9.9.9,7\n"
    net = BottangoLive(JAW, network=True)
    for code in ("1", "2"):  # the network driver answers every one, live input accepted
        assert net.feed_line(0.0, h(f"hRQ,{code}")) == [f"btngoHSK,CUSTOM9,{code},1\n".encode(), OK]
    kinds = [(e.kind, e.detail.get("reason")) for e in eng.poll(0.3).events]
    assert kinds == [("bottango_connected", None), ("bottango_disconnected", None),
                     ("bottango_connected", None), ("input_dropped", "duplicate_handshake")]  # fmt: skip


def test_handshake_deregisters_and_modules_answer():
    eng = live(REG, "hRQ,1")
    assert eng.poll(0.0).values == {}
    assert eng.feed_line(0.0, h("hMOD")) == [OK, b"MOD,CMD_SRC,0\n"]
    assert eng.feed_line(0.0, h("OK")) == [OK, b"MOD,CMD_CFG,512,16,0,32\n"]
    assert eng.feed_line(0.0, h("OK")) == [OK, b"MOD,EoM\n"]
    assert eng.feed_line(0.0, h("OK")) == [OK]


# ------------------------------------------------------------------------------ curves
def test_curve_matches_the_export_reader(export_track):
    eng = live(REG, "tSYN,0", SC1, SC2)
    assert eng.poll(0.0).values["jaw"] == pytest.approx(20.0, abs=1e-9)  # start 1500 µs
    assert eng.poll(1.0).values["jaw"] == pytest.approx(29.97, abs=0.02)
    for t in (0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 2.25, 2.7, 3.0, 4.0):
        assert eng.poll(t).values["jaw"] == pytest.approx(export_track(t), abs=1e-9), t


def test_time_sync_and_registration_range(export_track):
    # no signal range in the map: the registration's 1000..2000 maps to 0..40
    eng = BottangoLive({"0": EffectorMap("jaw", None, None, 0, 40)})
    for c in (REG, "tSYN,5000"):
        eng.feed_line(2.0, h(c))  # the driver's clock reads 5000 ms at show time 2 s
    eng.feed_line(2.5, h("sC,0,-5000,2000,4096,513,0,7110,-763,814"))  # starts at 0 ms
    eng.feed_line(2.5, h("sC,0,1000,2000,4096,513,0,7110,-763,814"))  # 6000 ms = t 3 s
    assert eng.poll(4.0).values["jaw"] == pytest.approx(export_track(1.0), abs=1e-9)
    for c in ("xUC,0", "upE,0,2000,1000,3000", "sCI,0,8192"):  # reversed bounds, then a jump
        assert eng.feed_line(4.0, h(c)) == [OK]
    assert eng.poll(4.1).values["jaw"] == pytest.approx(40.0)  # movement 1 -> degrees[1]
    fixed = live(REG, "upE,0,2000,1000,3000", "sCI,0,8192")  # a signal map: µs -> degrees
    assert fixed.poll(0.1).values["jaw"] == pytest.approx(0.0)  # y 8192 -> 1000 µs -> 0°


def test_hold_between_curves_clear_and_deregister():
    eng = live(REG, "tSYN,0", SC1, "sC,0,5000,1000,0,0,0,8192,0,0")
    end = eng.poll(2.0).values["jaw"]
    assert eng.poll(3.5).values["jaw"] == end  # between curves: the last end held
    assert eng.poll(6.0).values["jaw"] == pytest.approx(40.0)
    eng = live(REG, "tSYN,0", SC1)
    mid = eng.poll(1.0).values["jaw"]
    assert eng.feed_line(1.0, h("xUC,0")) == [OK]
    assert eng.poll(5.0).values["jaw"] == mid  # cleared mid-curve: held where it was
    assert eng.feed_line(5.0, h("sC,9,0,10,0,0,0,0,0,0")) == [
        *[b"\n", b"errNoEffectorOnPin: 9\n"] * 2,
        OK,
    ]
    assert eng.feed_line(5.0, h(REG))[:2] == [b"\n", b"errServoCollision: 0\n"]
    assert eng.feed_line(5.0, h("xUE,0")) == [OK]
    assert eng.poll(6.0).values == {}  # the director holds the joint's last value


def test_stop_once_and_reboot_answer():
    eng = live(REG, "hRQ,1", REG)
    assert eng.feed_line(1.0, h("STOP")) == [b"\n", b"BOOT\n"]
    p = eng.poll(1.0)
    assert p.stop and p.stop_reason == "Bottango STOP" and p.values == {}
    assert "stop" in [e.kind for e in p.events]
    assert not eng.poll(1.1).stop
    assert eng.feed_line(1.2, h("hRQ,2"))[0] == b"btngoHSK,0.8.0c1,2\n"  # rebooted
    net = BottangoLive(JAW, network=True)
    assert net.feed_line(0.0, h("STOP")) == [OK] and net.poll(0.0).stop


def test_bad_lines_counted_answered_and_logged_rate_limited():
    eng = live(REG, "tSYN,0", SC1)
    assert eng.feed_line(0.0, h("zZz,1,2")) == [OK]  # unknown: the firmware says OK
    assert eng.feed_line(0.0, h("sCO,0,0,1")) == [OK]  # known, moves no joint
    assert eng.feed_line(0.0, b"x" * 600) == [b"\n", b"errCmdTooLong: 600\n", OK]
    assert eng.feed_line(0.0, h("sC,0,1")) == [OK]  # too few fields: nothing set
    assert eng.feed_line(0.0, h(",".join(["xE"] * 16)))[-2:] == [b"errTooManyParams 15\n", OK]
    for i in range(1000):
        assert eng.feed_line(i / 2000, b"\xffbad\x00" if i % 2 else b"xE\x00,h1") == [HASH_FAIL]
    first = [e for e in eng.poll(0.5).events if e.kind == "input_dropped"]
    assert {e.detail["reason"] for e in first} == {"unknown", "oversized", "value", "malformed"}
    eng.feed_line(0.6, b"\x80")
    assert not [e for e in eng.poll(0.9).events if e.kind == "input_dropped"]  # within 1 s
    again = [e for e in eng.poll(1.6).events if e.kind == "input_dropped"]
    assert [(e.detail["reason"], e.detail["new"]) for e in again] == [("malformed", 1)]
    assert eng.poll(1.0).values["jaw"] == pytest.approx(29.97, abs=0.02)  # still moving


@settings(max_examples=800, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.binary(max_size=600), max_size=8))
def test_fuzz_raw_bytes(lines):
    eng = live(REG, "tSYN,0", SC1)
    for i, line in enumerate(lines):
        out = eng.feed_line(i * 0.01, line)
        assert isinstance(out, list) and all(
            isinstance(b, bytes) and b.endswith(b"\n") for b in out
        )
    p = eng.poll(1.0)
    assert all(math.isfinite(v) for v in p.values.values())


_NAMES = ["sC", "sCI", "rSVPin", "rMTR", "rECC", "rSVI2C", "upE", "xUC", "xUE", "xC", "xE",
          "tSYN", "hRQ", "hMOD", "OK", "STOP", "sCO", "q"]  # fmt: skip
_FIELD = st.one_of(st.integers(-(10**12), 10**12).map(str), st.text("0123456789-+.eh ", max_size=6))


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from(_NAMES), st.lists(_FIELD, max_size=10)), max_size=12))
def test_fuzz_hashed_commands(cmds):
    eng = live(REG, "tSYN,0", SC1)
    for i, (name, fields) in enumerate(cmds):
        out = eng.feed_line(i * 0.1, h(",".join([name, "0", *fields])))
        assert all(isinstance(b, bytes) and b.endswith(b"\n") for b in out)
        assert out != [HASH_FAIL]
    for t in (0.0, 1.0, 100.0):
        assert all(math.isfinite(v) for v in eng.poll(t).values.values())


# ------------------------------------------------------------------------------ [inputs.bottango]
def test_from_table_reads_and_refuses():
    eff = {"effectors": {"0": {"joint": "jaw", "signal": [1000, 2000], "degrees": [0, 40]}}}
    cfg = from_table({**eff, "link": "/tmp/x"}, WHERE, ["jaw", "neck"])
    assert cfg.transport == "pty" and cfg.link == "/tmp/x"
    assert cfg.effectors["0"] == EffectorMap("jaw", 1000.0, 2000.0, 0.0, 40.0)
    tcp = from_table({**eff, "transport": "tcp", "host": "10.0.0.5", "allow": ["10.0.0.0/24"]},
                     WHERE, ["jaw"])  # fmt: skip
    assert (tcp.host, tcp.port, BottangoLive.from_config(tcp).version) == (
        "10.0.0.5",
        59225,
        "CUSTOM9",
    )
    bad = {
        "transport = 'serial'": ({"transport": "serial"}, ".transport"),
        "unknown key": ({"baud": 9600}, ".baud"),
        "no effectors": ({"effectors": {}}, ".effectors"),
        "joint": ({"effectors": {"0": {"joint": "tail", "degrees": [0, 1]}}}, '"0".joint'),
        "degrees": ({"effectors": {"0": {"joint": "jaw", "degrees": [0]}}}, '"0".degrees'),
        "signal": (
            {"effectors": {"0": {"joint": "jaw", "degrees": [0, 1], "signal": [5, 5]}}},
            '"0".signal',
        ),
        "remote host": ({"transport": "tcp", "host": "192.168.1.9"}, ".host"),
        "port": ({"transport": "tcp", "port": 0}, ".port"),
        "link on tcp": ({"transport": "tcp", "link": "/tmp/x"}, ".link"),
        "host on pty": ({"host": "127.0.0.1"}, ".host"),
        "bad allow": ({"transport": "tcp", "allow": ["nope"]}, ".allow"),
    }
    for name, (table, key) in bad.items():
        with pytest.raises(ValueError) as err:
            from_table({**eff, **table}, WHERE, ["jaw"])
        msg = str(err.value)
        assert msg.startswith(WHERE) and key in msg and "\n" not in msg, (name, msg)


# ------------------------------------------------------------------------------ transports
def _read_lines(fd_read, n: int, timeout_s: float = 5.0) -> list[bytes]:
    """n complete lines, waiting on select (never sleeping) up to timeout_s in all."""
    buf, end = b"", time.monotonic() + timeout_s
    while buf.count(b"\n") < n:
        left = end - time.monotonic()
        assert left > 0, f"timed out; got {buf!r}"
        more = fd_read(left)
        assert more, f"closed; got {buf!r}"
        buf += more
    return buf.splitlines(keepends=True)


def test_pty_handshake_and_curve(tmp_path, export_track):
    link = tmp_path / "bottango"
    table = {"link": str(link), "effectors": {"0": {"joint": "jaw", "degrees": [0, 40],
                                                    "signal": [1000, 2000]}}}  # fmt: skip
    eng = BottangoLive.from_config(from_table(table, WHERE, ["jaw"]))
    note = eng.start(lambda: 0.0)
    try:
        assert str(link) in note and os.path.islink(link)
        fd = os.open(link, os.O_RDWR | os.O_NOCTTY)

        def read(left: float) -> bytes:
            return os.read(fd, 4096) if select.select([fd], [], [], left)[0] else b""

        try:
            os.write(fd, h("hRQ,144"))
            assert _read_lines(read, 2) == [b"btngoHSK,0.8.0c1,144\n", OK]
            os.write(fd, b"x" * 2000 + b"\n")  # too long: dropped, answered, the link goes on
            blank, err, ok = _read_lines(read, 3)
            assert (blank, ok) == (b"\n", OK) and err.startswith(b"errCmdTooLong: ")
            os.write(fd, h(REG) + h("tSYN,0") + h(SC1) + b"xUC,0,h1\n")
            assert _read_lines(read, 4) == [OK, OK, OK, HASH_FAIL]
        finally:
            os.close(fd)
        assert eng.poll(1.0).values["jaw"] == pytest.approx(export_track(1.0), abs=1e-9)
    finally:
        eng.close()
        eng.close()  # idempotent
    assert not os.path.lexists(link)


def test_pty_link_refuses_a_file(tmp_path):
    f = tmp_path / "taken"
    f.write_text("mine")
    cfg = from_table({"link": str(f), "effectors": {"0": {"joint": "jaw", "degrees": [0, 1]}}},
                     WHERE, ["jaw"])  # fmt: skip
    with pytest.raises(ValueError, match="not a symlink"):
        BottangoLive.from_config(cfg).start(lambda: 0.0)
    assert f.read_text() == "mine"


def test_tcp_connects_to_the_app_and_drives(export_track):
    app = socket.socket()  # plays the Bottango app: it listens, the driver connects
    app.bind(("127.0.0.1", 0))
    app.listen(1)
    app.settimeout(5.0)
    table = {"transport": "tcp", "port": app.getsockname()[1],
             "effectors": {"0": {"joint": "jaw", "degrees": [0, 40], "signal": [1000, 2000]}}}  # fmt: skip
    eng = BottangoLive.from_config(from_table(table, WHERE, ["jaw"]))
    try:
        assert "127.0.0.1" in eng.start(lambda: 0.0)
        conn, peer = app.accept()
        assert peer[0] == "127.0.0.1"

        def read(left: float) -> bytes:
            conn.settimeout(left)
            return conn.recv(4096)

        with conn:
            conn.sendall(h("hRQ,144"))
            assert _read_lines(read, 2) == [b"btngoHSK,CUSTOM9,144,1\n", OK]
            conn.sendall(f"{REG}\ntSYN,0\n".encode() + h(SC1) + b"xUC,0,h1\n")
            assert _read_lines(read, 4) == [OK, OK, OK, HASH_FAIL]
        assert eng.poll(1.0).values["jaw"] == pytest.approx(export_track(1.0), abs=1e-9)
    finally:
        eng.close()
        app.close()
