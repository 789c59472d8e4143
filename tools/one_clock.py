"""Many figures, one clock: an FPP MultiSync master, and the offset between figures following it.

    python tools/one_clock.py measure [--figures 2] [--seconds 60] [--rate 4] [--port 32320]
    python tools/one_clock.py master [--seconds 60] [--rate 4] [--to 239.70.80.80] [--port 32320]
    python tools/one_clock.py offset RUN_A RUN_B [...]
    python tools/one_clock.py measure --via sacn [--figures 2] [--seconds 60] [--port 5568]

``master`` plays an FPP master from FPP's documented packets (``FPPD``, type 1: Open, Start,
Sync at ``--rate`` Hz with the seconds elapsed as a float32, Stop) for one sequence, for
``--seconds``, to the MultiSync multicast group on loopback (``--to``/``--iface`` for another
destination). ``measure`` starts ``--figures`` ``hilsim run`` processes on this host, each its
own rig on its own emulated bus and real clock, all following the master through multicast
(``[inputs.multisync] multicast = true``: each joins 239.70.80.80, and the kernel hands every
datagram to every joined socket), plays the master, and reports ``offset`` of their runs.

``offset`` reads each run's telemetry: the joint follows a linear ramp (``SLOPE`` deg/s), so
its target is the show time the figure commands; ``summary.json``'s ``loop.clock_t0`` plus a
row's ``t_actual`` is the host's CLOCK_MONOTONIC at that tick (shared by every process on one
host). For each tick of each other figure, the first figure's show time at that same host
instant (interpolated between its ticks) is subtracted: the median, p99 and max of that
difference are the figures' offset, set against one tick at 250 Hz (4 ms). The same with
``t_sched`` (the instant each tick was due, so without the ticks' lateness) shows how well the
clocks agree. State the load (``uptime``) beside any figure: this is a real-clock measurement.

``--via sacn``: the master streams E1.31 instead (packets built by the ``sacn`` package, 40
frames a second multicast to universe 1's group, a 16-bit channel whose value counts the
frames) and each figure takes the joint live from ``[inputs.sacn]``; the offset is, per
frame, the difference between the host instants the two figures first command it.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hilsim.live.multisync import MULTISYNC_GROUP, MULTISYNC_PORT, build_multisync  # noqa: E402
from hilsim.telemetry.reader import read_run  # noqa: E402

SEQUENCE = "oneclock.fseq"
START_DEG, SLOPE = -60.0, 1.5  # the ramp: target = START_DEG + SLOPE * show time (deg, deg/s)
TICK_S = 0.004  # one tick at 250 Hz

RIG = """# one figure of the one-clock measurement (tools/one_clock.py)
name = "{name}"
[bus]
port = "dxlsim://?ids=1&model=XM430-W350&rdt_us=0&latency_ms=1"
[loop]
rate_hz = 250
[safety]
soft_start_s = 0.2
[[joints]]
name = "ramp"
servo_id = 1
min_deg = -90
max_deg = 90
max_speed_deg_s = 240
max_accel_deg_s2 = 4000
spring = {{ frequency_hz = 4.0, damping_ratio = 1.0, response = 0.0 }}
target = {target}
"""
#: the rig's own target: a ramp whose angle is the show time (MultiSync), or a hold at the
#: bottom of the sACN range, which no frame's value maps to
RAMP = "{{ type = 'keyframes', keys = [[0, {start}], [{end_s}, {end_deg}]] }}"
HOLD = "{ type = 'hold', value_deg = -90 }"
SHOW = """[inputs.multisync]
sequence = "{sequence}"
port = {port}
multicast = true
on_stop = "stop"
"""


# ------------------------------------------------------------------------------ the master
def master_socket(iface: str) -> socket.socket:
    """A UDP socket that sends multicast out of ``iface`` and loops it back to this host."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(iface))
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
    return s


def play_master(
    dest: tuple[str, int], seconds: float, rate_hz: float, sequence: str, iface: str
) -> int:
    """Open, Start, Sync every 1/rate_hz s, Stop after ``seconds``; returns the packets sent.
    The master's time is this host's monotonic clock since the Start."""
    sock = master_socket(iface)
    sent = 0

    def send(action: str, at: float) -> None:
        nonlocal sent
        sock.sendto(build_multisync(action, at, sequence, frame=int(at / 0.025)), dest)
        sent += 1

    try:
        send("open", 0.0)
        time.sleep(0.2)
        t0 = time.perf_counter()
        send("start", 0.0)
        k = 1
        while k / rate_hz < seconds:
            due = t0 + k / rate_hz
            time.sleep(max(0.0, due - time.perf_counter()))
            send("sync", time.perf_counter() - t0)
            k += 1
        send("stop", time.perf_counter() - t0)
    finally:
        sock.close()
    return sent


SACN_SHOW = """[inputs.sacn]
port = {port}
multicast = true
[inputs.sacn.joints.ramp]
universe = 1
channel = 1
bits = 16
degrees = [-90, 0, 90]
"""
SACN_FPS = 40.0


def play_sacn(port: int, seconds: float, iface: str) -> int:
    """E1.31 data for universe 1 at SACN_FPS to its multicast group, built by the ``sacn``
    package: frame k carries the value k + 1 (coarse, fine) on channels 1-2."""
    from sacn.messages.data_packet import DataPacket

    sock, cid = master_socket(iface), tuple(range(16))
    sent = 0
    try:
        t0 = time.perf_counter()
        while sent / SACN_FPS < seconds:
            time.sleep(max(0.0, t0 + sent / SACN_FPS - time.perf_counter()))
            v = sent + 1
            packet = DataPacket(cid, "one_clock", 1, (v >> 8, v & 0xFF), 100, sent % 256)
            sock.sendto(bytes(packet.getBytes()), ("239.255.0.1", port))
            sent += 1
    finally:
        sock.close()
    return sent


def frame_times(run: Path) -> dict[str, np.ndarray]:
    """A ``--via sacn`` run: each frame (value) and the host instants (actual, scheduled) of
    the first tick that commanded it."""
    r = read_run(run)
    clock_t0 = float(json.loads((run / "summary.json").read_text())["loop"]["clock_t0"])
    deg = np.degrees(r.joint("target")[:, 0])
    value = np.rint(1 + (deg + 90.0) * 32767 / 90.0).astype(np.int64)  # below the split
    frames, first = np.unique(value, return_index=True)
    keep = frames > 1
    return {"frame": frames[keep], "host": clock_t0 + r.columns["t_actual"][first][keep],
            "sched": clock_t0 + r.columns["t_sched"][first][keep]}  # fmt: skip


def report_frames(runs: list[Path]) -> int:
    first = frame_times(runs[0])
    for run in runs[1:]:
        other = frame_times(run)
        common, ia, ib = np.intersect1d(first["frame"], other["frame"], return_indices=True)
        for key, what in (("host", "first commanded (t_actual)"), ("sched", "tick due")):
            d = (other[key][ib] - first[key][ia]) * 1e3
            ad = np.abs(d)
            print(f"{run.name} - {runs[0].name}, per sACN frame, {what}: {common.size} frames; "
                  f"median {np.median(d):+.3f} ms, |offset| p99 {np.percentile(ad, 99):.3f} ms, "
                  f"max {ad.max():.3f} ms (one tick at 250 Hz: {TICK_S * 1e3:g} ms)")  # fmt: skip
    return 0


# ------------------------------------------------------------------------------ the offset
def show_times(run: Path) -> dict[str, np.ndarray]:
    """A run's ticks while the master played: host times (actual, scheduled) and show time."""
    r = read_run(run)
    clock_t0 = float(json.loads((run / "summary.json").read_text())["loop"]["clock_t0"])
    show = (np.degrees(r.joint("target")[:, 0]) - START_DEG) / SLOPE
    t_act, t_sched = r.columns["t_actual"], r.columns["t_sched"]
    moving = np.flatnonzero(np.diff(show) != 0)  # after the Stop it holds: cut at the last move
    last = moving[-1] if moving.size else -1
    # before the Start the show time holds at 0; the first 0.5 s is skipped
    playing = (show > 0.5) & (np.arange(show.size) <= last)
    return {
        "host": clock_t0 + t_act[playing],
        "sched": clock_t0 + t_sched[playing],
        "show": show[playing],
    }


def offsets(a: dict[str, np.ndarray], b: dict[str, np.ndarray], key: str) -> np.ndarray:
    """``b``'s show time minus ``a``'s at each of ``b``'s ticks (host instants ``key``), where
    both played (``a``'s show time interpolated between its ticks)."""
    inside = (b[key] >= a[key][0]) & (b[key] <= a[key][-1])
    return b["show"][inside] - np.interp(b[key][inside], a[key], a["show"])


def report(runs: list[Path]) -> int:
    if len(runs) < 2:
        print("offset: name two runs or more", file=sys.stderr)
        return 2
    first = show_times(runs[0])
    worst = 0.0
    for run in runs[1:]:
        other = show_times(run)
        for key, what in (("host", "at the same host instant"), ("sched", "clocks (t_sched)")):
            d = offsets(first, other, key) * 1e3
            if d.size == 0:
                print(f"{run.name} vs {runs[0].name}: no common playing time", file=sys.stderr)
                return 1
            ad = np.abs(d)
            span = float(np.ptp(other[key]))
            print(f"{run.name} - {runs[0].name}, {what}: {d.size} ticks over "
                  f"{span:.1f} s; show-time offset median {np.median(d):+.3f} ms, "
                  f"|offset| p99 {np.percentile(ad, 99):.3f} ms, max {ad.max():.3f} ms "
                  f"(one tick at 250 Hz: {TICK_S * 1e3:g} ms; "
                  f"{int(np.sum(ad > TICK_S * 1e3))} ticks beyond it)")  # fmt: skip
            if key == "host":
                worst = max(worst, float(ad.max()))
    print(f"worst |offset| {worst:.3f} ms: {'within' if worst <= TICK_S * 1e3 else 'OVER'} "
          f"one tick")  # fmt: skip
    return 0


# ------------------------------------------------------------------------------ measure
def measure(args: argparse.Namespace) -> int:
    work = Path(args.work or tempfile.mkdtemp(prefix="one_clock-"))
    work.mkdir(parents=True, exist_ok=True)
    end_s = args.seconds + 30.0
    procs, ready, runs = [], [], []
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for i in range(args.figures):
        name = f"figure{i + 1}"
        end_deg = START_DEG + SLOPE * end_s
        ramp = RAMP.format(start=START_DEG, end_s=end_s, end_deg=end_deg)
        rig = RIG.format(name=name, target=HOLD if args.via == "sacn" else ramp)
        (work / f"{name}.toml").write_text(rig)
        show = SACN_SHOW if args.via == "sacn" else SHOW
        (work / f"{name}_show.toml").write_text(show.format(sequence=SEQUENCE, port=args.port))
        out = work / name
        runs.append(out)
        cmd = [sys.executable, "-m", "hilsim", "run", str(work / f"{name}.toml"),
               "--show", str(work / f"{name}_show.toml"), "--out", str(out), "--no-plots",
               "--duration", str(args.seconds + (8 if args.via == "sacn" else 20))]  # fmt: skip
        print("$", " ".join(cmd))
        p = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             text=True, cwd=str(work))  # fmt: skip
        flag = threading.Event()
        threading.Thread(target=_echo, args=(p, name, flag), daemon=True).start()
        procs.append(p)
        ready.append(flag)
    try:
        for flag in ready:
            if not flag.wait(60.0):
                print("a figure did not start listening within 60 s", file=sys.stderr)
                return 1
        time.sleep(2.0)  # tick 0 and the warm-up
        if args.via == "sacn":
            print(f"master: sACN universe 1 at {SACN_FPS:g} fps for {args.seconds:g} s")
            sent = play_sacn(args.port, args.seconds, args.iface)
        else:
            dest = (args.to or MULTISYNC_GROUP, args.port)
            print(f"master: {SEQUENCE} to {dest[0]}:{dest[1]} for {args.seconds:g} s, "
                  f"Sync at {args.rate:g} Hz")  # fmt: skip
            sent = play_master(dest, args.seconds, args.rate, SEQUENCE, args.iface)
        print(f"master: {sent} packets sent")
        for p in procs:
            p.wait(timeout=60.0)
    finally:
        for p in procs:
            if p.poll() is None:
                p.terminate()
    print("load:", os.getloadavg())
    return report_frames(runs) if args.via == "sacn" else report(runs)


def _echo(p: subprocess.Popen[str], name: str, listening: threading.Event) -> None:
    assert p.stdout is not None
    for line in p.stdout:
        print(f"[{name}] {line.rstrip()}")
        if "FPP MultiSync on" in line or "sACN on" in line:
            listening.set()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    sub = ap.add_subparsers(dest="what", required=True)
    for name in ("measure", "master"):
        p = sub.add_parser(name)
        p.add_argument("--seconds", type=float, default=60.0, help="how long the master plays")
        p.add_argument("--rate", type=float, default=4.0, help="Sync packets a second (FPP: 2-4)")
        p.add_argument("--port", type=int, default=None, help="default 32320 (sACN: 5568)")
        p.add_argument("--to", default=None, help=f"destination (default {MULTISYNC_GROUP})")
        p.add_argument("--iface", default="127.0.0.1", help="the interface multicast leaves by")
        p.add_argument("--sequence", default=SEQUENCE)
    sub.choices["measure"].add_argument("--figures", type=int, default=2)
    via = {"choices": ("multisync", "sacn"), "default": "multisync", "help": "the master's"}
    sub.choices["measure"].add_argument("--via", **via)
    sub.choices["measure"].add_argument("--work", default=None, help="directory for the runs")
    p = sub.add_parser("offset")
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--via", **via)
    args = ap.parse_args(argv)
    if args.what == "offset":
        return report_frames(args.runs) if args.via == "sacn" else report(args.runs)
    if args.port is None:
        args.port = 5568 if getattr(args, "via", "") == "sacn" else MULTISYNC_PORT
    if args.what == "master":
        dest = (args.to or MULTISYNC_GROUP, args.port)
        sent = play_master(dest, args.seconds, args.rate, args.sequence, args.iface)
        print(f"master: {sent} packets to {dest[0]}:{dest[1]}")
        return 0
    return measure(args)


if __name__ == "__main__":
    raise SystemExit(main())
