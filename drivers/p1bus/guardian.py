"""The guardian: the exit policy applied if the show's process dies, on buses with no Bus Watchdog.

An X-series servo stops on its own when its host goes quiet (Bus Watchdog). Feetech STS/SCS
and Dynamixel AX/MX servos have none: if the show's process is killed (SIGKILL, the OOM
killer, a crash in a C extension) they hold their last goal with torque on, for ever. So a
show on such a port starts this small process first, before torque goes on
(:meth:`Guardian.start`). Its contract:

* It shares the port's open file (the descriptor is inherited: the same line settings and
  lock) and holds the read end of a pipe whose write end only the show's process holds
  (never inherited; closed in any child the show forks).
* While the show lives it blocks in ``read`` on that pipe: it never writes to the bus and
  costs the show nothing per tick. A show that ends in any way of its own (its exit policy
  applied) writes :data:`RELEASE` and closes the pipe: the guardian exits, writing nothing.
* End of file without it means the process died without its exit policy. The guardian lets
  the line go quiet, then applies the rig's policy itself: ``relax``: Sync Write of Torque
  Enable := 0 to the rig's servos (each family's address), read back from each servo, sent
  again up to three times; ``hold``: nothing to do (the servos hold their last goal). It
  writes ``guardian.json`` and one ``events.jsonl`` line into the run directory and one line
  on stderr, then exits.
* It ignores SIGINT and SIGTERM and runs in a session of its own: a Ctrl-C or a service stop
  is the show's to handle (the show then releases it).

What it cannot cover: the computer itself stopping (power cut, kernel panic), or the guardian
killed together with the show (``kill -9`` of the process group; a systemd unit that SIGKILLs
its whole cgroup when the main process dies, as ``KillMode=mixed`` does: the unit ``hilsim
service print`` writes uses ``KillMode=process``). ``docs/servos.md`` says it for users.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import subprocess
import sys
import termios
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from drivers.p1bus.table import family_of
from drivers.protocol1 import packet

#: what a show that ended by itself writes before closing the pipe
RELEASE = b"R"
#: the guardian's record in the run directory
RECORD_FILE = "guardian.json"
#: silence let pass before the guardian speaks: the dead show's last packet and any reply
#: chain off the wire, the servos' half-received packet dropped (1.5 ms on Dynamixel)
QUIET_S = 0.05
#: a read-back's reply wait: Return Delay up to 508 µs, two USB latency timers of 16 ms
READ_TIMEOUT_S = 0.05
ATTEMPTS = 3


class Guardian:
    """The show's side: the guardian's process and the pipe's write end."""

    def __init__(self, proc: subprocess.Popen[bytes], write_fd: int) -> None:
        self.proc, self._fd = proc, write_fd
        os.register_at_fork(after_in_child=self._close_in_child)

    @property
    def pid(self) -> int:
        return self.proc.pid

    @classmethod
    def start(
        cls,
        port_fd: int,
        *,
        port: str,
        ids: Sequence[int],
        models: Sequence[str],
        policy: str,
        run_dir: str | os.PathLike[str] | None,
    ) -> Guardian:
        """Start a guardian on the open port ``port_fd`` for servos ``ids`` of ``models``,
        exit policy ``policy`` (``"hold"`` or ``"relax"``), recording into ``run_dir``.
        Raises OSError if the process cannot be started."""
        read_fd, write_fd = os.pipe()  # neither inheritable (PEP 446); pass_fds passes one
        spec = {
            "pipe_fd": read_fd,
            "port_fd": port_fd,
            "port": port,
            "ids": list(ids),
            "models": list(models),
            "policy": str(policy),
            "run_dir": None if run_dir is None else os.fspath(run_dir),
            "show_pid": os.getpid(),
        }
        root = str(Path(__file__).resolve().parents[2])  # the drivers package's home
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
        try:
            proc = subprocess.Popen(
                [sys.executable, "-m", "drivers.p1bus.guardian", json.dumps(spec)],
                pass_fds=(read_fd, port_fd),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                start_new_session=True,  # a Ctrl-C to the terminal is the show's
                env=env,
            )
        except BaseException:
            os.close(write_fd)
            raise
        finally:
            os.close(read_fd)
        return cls(proc, write_fd)

    def release(self, wait_s: float = 5.0) -> None:
        """The show ended by itself: the guardian exits without a word. Safe to call twice."""
        fd, self._fd = self._fd, -1
        if fd < 0:
            return
        with contextlib.suppress(OSError):
            os.write(fd, RELEASE)
        os.close(fd)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(wait_s)  # (it exits at once; the port is then ours alone)

    def _close_in_child(self) -> None:
        """A child forked by the show must not keep the pipe open past the show."""
        if self._fd >= 0:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = -1


# ---------------------------------------------------------------------- the guardian's process


def main(argv: Sequence[str] | None = None) -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    spec: dict[str, Any] = json.loads((sys.argv[1:] if argv is None else argv)[0])
    pipe_fd = int(spec["pipe_fd"])
    while True:
        try:
            got = os.read(pipe_fd, 1)
            break
        except InterruptedError:  # (Python retries; kept for clarity)
            continue
    if got == RELEASE:
        return 0
    report = act(int(spec["port_fd"]), spec)
    record(spec, report)
    return 0


def act(port_fd: int, spec: dict[str, Any]) -> dict[str, Any]:
    """Apply the exit policy on the bus: what was done and read back, for the record."""
    ids = [int(i) for i in spec["ids"]]
    policy = spec["policy"]
    report: dict[str, Any] = {
        "event": "show_process_died",
        "show_pid": spec["show_pid"],
        "guardian_pid": os.getpid(),
        "port": spec["port"],
        "policy": policy,
        "wall": time.time(),
        "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    if policy != "relax":
        report["action"] = "none: exit policy hold (the servos hold their last goal, torque on)"
        report["message"] = (
            f"the show's process {spec['show_pid']} ended without its exit policy; exit "
            "policy hold: nothing to do, the servos hold their last goal with torque on"
        )
        return report
    fams = {sid: family_of(m) for sid, m in zip(ids, spec["models"], strict=True)}
    by_addr: dict[int, list[int]] = {}
    for sid, fam in fams.items():
        assert fam is not None
        by_addr.setdefault(fam.torque_enable.addr, []).append(sid)
    time.sleep(QUIET_S)
    with contextlib.suppress(termios.error, OSError):
        termios.tcflush(port_fd, termios.TCIOFLUSH)
    torque: dict[int, int | None] = dict.fromkeys(ids)
    attempts = 0
    error = ""
    try:
        for attempts in range(1, ATTEMPTS + 1):  # noqa: B007 - the count goes in the record
            for addr, group in by_addr.items():
                _write(port_fd, packet.sync_write(addr, 1, {sid: b"\x00" for sid in group}))
            for sid in ids:
                if torque[sid] != 0:
                    fam = fams[sid]
                    assert fam is not None
                    torque[sid] = _read_byte(port_fd, sid, fam.torque_enable.addr)
            if all(v == 0 for v in torque.values()):
                break
    except OSError as exc:  # the adapter gone with the show
        error = f"{exc.strerror or exc}"
    confirmed = [sid for sid in ids if torque[sid] == 0]
    unconfirmed = [sid for sid in ids if torque[sid] != 0]
    report.update(
        action=f"Sync Write Torque Enable := 0 to servos {_ids(ids)} ({attempts} time(s))",
        torque_read_back={str(k): v for k, v in torque.items()},
        confirmed=confirmed,
        unconfirmed=unconfirmed,
    )
    if error:
        report["error"] = error
    said = (
        f"read back 0 on all {len(ids)}"
        if not unconfirmed
        else (
            f"NOT confirmed on servo(s) {_ids(unconfirmed)}"
            + (f" ({error})" if error else " (no reply, or torque still on)")
        )
    )
    report["message"] = (
        f"the show's process {spec['show_pid']} ended without its exit policy; exit policy "
        f"relax applied by the guardian: torque off on servos {_ids(ids)}, {said}"
    )
    return report


def record(spec: dict[str, Any], report: dict[str, Any]) -> None:
    """``guardian.json`` and an ``events.jsonl`` line in the run directory; a line on stderr."""
    where = ""
    run_dir = spec.get("run_dir")
    if run_dir and Path(run_dir).is_dir():
        path = Path(run_dir) / RECORD_FILE
        try:
            path.write_text(json.dumps(report, indent=2) + "\n")
            where = f" ({path})"
            event = {
                "tick": None,
                "t": None,
                "wall": report["wall"],
                "kind": "guardian",
                "message": report["message"],
                "policy": report["policy"],
                "confirmed": report.get("confirmed"),
                "unconfirmed": report.get("unconfirmed"),
            }
            with open(Path(run_dir) / "events.jsonl", "a", encoding="utf-8") as f:
                f.write(json.dumps(event) + "\n")
        except OSError as exc:
            where = f" (cannot write {path}: {exc.strerror or exc})"
    with contextlib.suppress(OSError):
        sys.stderr.write(f"hilsim guardian: {report['message']}{where}\n")
        sys.stderr.flush()


def _ids(ids: Sequence[int]) -> str:
    return ", ".join(map(str, ids))


def _write(fd: int, data: bytes) -> None:
    view = memoryview(data)
    deadline = time.monotonic() + 1.0
    while view:
        try:
            n = os.write(fd, view)
        except BlockingIOError:
            n = 0
        view = view[n:]
        if view:
            if time.monotonic() > deadline:
                raise TimeoutError("the port takes no more bytes")
            select.select((), (fd,), (), 0.05)


def _read_byte(fd: int, servo_id: int, addr: int) -> int | None:
    """One READ of one byte; its value, or None (no reply, a damaged one, an error bit
    other than the servo's own condition is still a reply: the value counts)."""
    with contextlib.suppress(termios.error, OSError):
        termios.tcflush(fd, termios.TCIFLUSH)
    _write(fd, packet.read(servo_id, addr, 1))
    parser = packet.StreamParser()
    deadline = time.monotonic() + READ_TIMEOUT_S
    while (left := deadline - time.monotonic()) > 0:
        ready, _, _ = select.select((fd,), (), (), left)
        if not ready:
            break
        try:
            data = os.read(fd, 64)
        except BlockingIOError:
            continue
        if not data:
            break
        for _, (_, fid, ok, _, params) in parser.feed_decoded(data):
            if ok and fid == servo_id and len(params) == 1:
                return params[0]
    return None


if __name__ == "__main__":
    sys.exit(main())
