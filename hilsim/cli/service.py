"""``hilsim service print RIG [--show SHOW]``: a systemd unit that runs the show at boot.

The unit (``docs/service.md``) runs this Python's ``hilsim run`` on the rig, with absolute
paths: the rig and show files, the runs root (``--runs-dir``: each run's directory is made
there) and the heartbeat (``--status-file`` in a runtime directory, kept after the service
stops so a monitor reads how it ended). Normal stops are successes (``SuccessExitStatus``),
only faults restart it, real-time priority is granted when the rig asks for it, and its
lines go to the journal. It is printed, never installed: the commands to install it are in
its first lines.
"""

from __future__ import annotations

import argparse
import getpass
import os
import re
import sys
from pathlib import Path

from hilsim.exit_codes import ExitCode

HELP = "print a systemd unit that runs a rig's show at boot (docs/service.md)"

#: normal stops: a stop command, and the signals that stop a show through its exit policy
NORMAL_STOPS = (
    ExitCode.STOPPED,
    ExitCode.SIGHUP,
    ExitCode.SIGINT,
    ExitCode.SIGQUIT,
    ExitCode.SIGTERM,
)
#: never restarted: a rig or servos that do not fit (2: a restart refuses again), an exit
#: policy not confirmed (4: a person should look at the figure), and every normal stop
NO_RESTART = (ExitCode.USAGE, ExitCode.UNSAFE_EXIT, *NORMAL_STOPS)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("action", choices=["print"], help="print: write the unit on stdout")
    p.add_argument("config", help="rig file (TOML)")
    p.add_argument("--show", metavar="SHOW", help="the show file the service runs")
    p.add_argument(
        "--runs-dir",
        metavar="DIR",
        help="where each run's directory is made (default: the rig's telemetry.out_dir, from "
        "the working directory)",
    )
    p.add_argument(
        "--workdir", metavar="DIR", help="the service's working directory (default: this one)"
    )
    p.add_argument("--user", help="the user it runs as (default: you)")
    p.add_argument("--name", help="the unit's name (default: hilsim-<rig name>)")


def _say(message: str) -> None:
    print(f"hilsim service: {message}", file=sys.stderr)


def _arg(text: str) -> str:
    """One ExecStart word: ``%`` doubled (a specifier otherwise), quoted when it must be."""
    text = text.replace("%", "%%")
    if re.fullmatch(r"[A-Za-z0-9_@%+=:,./-]+", text):
        return text
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _hilsim_command() -> list[str]:
    """This environment's ``hilsim``: its console script beside the interpreter (a venv's
    bin/), else the interpreter with ``-m hilsim``. Not resolved: a venv's python is a link."""
    python = Path(sys.executable).absolute()
    script = python.parent / "hilsim"
    if script.is_file() and os.access(script, os.X_OK):
        return [str(script)]
    return [str(python), "-m", "hilsim"]


def run(args: argparse.Namespace) -> int:
    from hilsim.rig import RigError, load_rigs
    from hilsim.show.api import Show

    try:
        rigs = load_rigs(args.config)
        if args.show is not None and len(rigs) > 1:
            _say("--show drives one bus for now: this rig has several buses")
            return int(ExitCode.USAGE)
        if args.show is not None:  # the rig and show as hilsim run reads them (nothing opened)
            Show(rigs[0], show=args.show)
    except (RigError, ValueError) as exc:
        _say(str(exc))
        return int(ExitCode.USAGE)
    rig = rigs[0]
    workdir = Path(args.workdir or os.getcwd()).expanduser().absolute()
    runs = Path(args.runs_dir or rig.telemetry.out_dir).expanduser()
    runs = runs if runs.is_absolute() else workdir / runs
    name = args.name or "hilsim-" + re.sub(r"[^A-Za-z0-9_.-]", "-", rig.name)
    user = args.user or os.environ.get("SUDO_USER") or getpass.getuser()
    print(
        unit_text(
            rig_path=Path(args.config).absolute(),
            show_path=None if args.show is None else Path(args.show).absolute(),
            name=name,
            user=user,
            workdir=workdir,
            runs=runs,
            several_buses=len(rigs) > 1,
            realtime_priority=rig.loop.realtime_priority,
            hardware=any(not r.bus.port.lower().startswith("dxlsim://") for r in rigs),
        ),
        end="",
    )
    return int(ExitCode.OK)


def unit_text(
    *,
    rig_path: Path,
    show_path: Path | None,
    name: str,
    user: str,
    workdir: Path,
    runs: Path,
    several_buses: bool,
    realtime_priority: int | None,
    hardware: bool,
) -> str:
    """The unit file's text (``docs/service.md`` explains each line)."""
    command = [*_hilsim_command(), "run", str(rig_path)]
    if show_path is not None:
        command += ["--show", str(show_path)]
    command += ["--runs-dir", str(runs), "--no-plots"]
    status = f"/run/{name}/status.json"
    command += ["--status-file", status]
    if several_buses:  # each bus writes its own
        status = f"/run/{name}/status-<bus>.json"
    codes = " ".join(str(int(c)) for c in NORMAL_STOPS)
    no_restart = " ".join(str(int(c)) for c in NO_RESTART)
    lines = [
        f"# {name}.service: generated by `hilsim service print` (docs/service.md)",
        f"# install: sudo cp THIS_FILE /etc/systemd/system/{name}.service",
        f"#          sudo systemctl daemon-reload && sudo systemctl enable --now {name}",
        f"# watch:   journalctl -u {name} -f; the heartbeat: {status}",
        "",
        "[Unit]",
        f"Description=hilsim show: {rig_path.name}",
        *(["Wants=network-online.target", "After=network-online.target"] if show_path else []),
        "# a figure that faults 5 times in 10 minutes is left stopped for a person to look at",
        "StartLimitIntervalSec=600",
        "StartLimitBurst=5",
        "",
        "[Service]",
        "Type=exec",
        f"User={user}",
        *(["# the serial port's group", "SupplementaryGroups=dialout"] if hardware else []),
        f"WorkingDirectory={workdir}",
        "# each run's record in its own directory under --runs-dir; plots drawn on demand",
        "# (hilsim plot RUN), not at the end of a long show",
        "ExecStart=" + " ".join(_arg(a) for a in command),
        "Environment=PYTHONUNBUFFERED=1",
        "# the status line (every 10 s in a log) and every message, in the journal",
        "StandardOutput=journal",
        "StandardError=journal",
        f"SyslogIdentifier={name}",
    ]
    lines += [
        "# the heartbeat on a RAM disk (no SD-card wear), kept after a stop: how it ended",
        f"RuntimeDirectory={name}",
        "RuntimeDirectoryPreserve=yes",
    ]
    if realtime_priority is not None:
        lines += [
            f"# loop.realtime_priority = {realtime_priority}: SCHED_FIFO for the loop",
            "AmbientCapabilities=CAP_SYS_NICE",
            f"LimitRTPRIO={realtime_priority}",
        ]
    else:
        lines += ["# no loop.realtime_priority in the rig: no real-time priority asked for"]
    lines += [
        "# normal stops: a stop command (5), SIGHUP/SIGINT/SIGQUIT/SIGTERM (129/130/131/143)",
        f"SuccessExitStatus={codes}",
        "# restart after a fault (3) or a crash (1); never after a refusal (2: it would",
        "# refuse again), an unconfirmed exit policy (4) or a normal stop",
        "Restart=on-failure",
        "RestartSec=5",
        f"RestartPreventExitStatus={no_restart}",
        "# systemctl stop: SIGTERM to hilsim alone (it stops every bus's process itself),",
        "# time for the exit policy and the summary. Its other processes are never killed",
        "# by systemd: each stops itself, through its exit policy, when hilsim ends, and a",
        "# Feetech/Protocol 1.0 bus's guardian must outlive a crash to turn torque off",
        "KillMode=process",
        "TimeoutStopSec=30",
        "",
        "[Install]",
        "WantedBy=multi-user.target",
    ]
    return "\n".join(lines) + "\n"
