"""``hilsim panel [RUN_DIR]``: the browser control panel of a show running on this machine.

It attaches to the show whose run directory is given (default: the newest under ``runs/``
with a live ``panel.json``), or, with none running, serves the past runs alone. It prints
``panel: http://ADDR:PORT/?token=...`` first; open that URL. ``hilsim run RIG --panel`` starts
this same server as its child. The page, the guards and how to open it from a phone:
``docs/panel.md``. Exit codes: 0 closed by Ctrl-C or SIGTERM; 2 a bad option, a port in use,
or the ``panel`` extra missing.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
import threading
from pathlib import Path

from hilsim.exit_codes import ExitCode

HELP = "the browser control panel of a show running on this machine (and its past runs)"
DEFAULT_BIND = "127.0.0.1:8080"
TOKEN_ENV = "HILSIM_PANEL_TOKEN"  # the parent's token for its child (argv is public)
EXTRA_HINT = "the panel needs its extra: pip install 'hilsim[panel]'"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "run_dir",
        nargs="?",
        help="the show's run directory (default: the newest running one under --runs)",
    )
    add_panel_options(p, "--bind")
    p.add_argument(
        "--runs",
        metavar="DIR",
        default="runs",
        help="the directory of run directories, for the past runs (default runs/)",
    )
    p.add_argument("--feed", help=argparse.SUPPRESS)  # hilsim run --panel: the feed's socket
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)


def add_panel_options(p: argparse.ArgumentParser, bind_flag: str) -> None:
    """``--bind``/``--panel-bind ADDR:PORT`` and ``--allow``/``--panel-allow LIST``."""
    allow_flag = "--allow" if bind_flag == "--bind" else "--panel-allow"
    p.add_argument(
        bind_flag,
        metavar="ADDR:PORT",
        dest="panel_bind",
        default=None,
        help=f"where the panel listens (default {DEFAULT_BIND}; another address than "
        f"127.0.0.1 needs {allow_flag}); PORT 0: any free port",
    )
    p.add_argument(
        allow_flag,
        metavar="LIST",
        dest="panel_allow",
        default="",
        help="client addresses or networks allowed (e.g. 192.168.1.20,10.0.0.0/24)",
    )


def parse_bind(text: str | None, flag: str = "--panel-bind") -> tuple[str, int]:
    """``ADDR:PORT`` -> (addr, port); ValueError with one line."""
    text = text or DEFAULT_BIND
    host, sep, port = text.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or int(port) > 65535:
        raise ValueError(f"{flag} {text!r}: ADDR:PORT, e.g. 127.0.0.1:8080")
    return host, int(port)


def check_options(
    bind: str | None, allow_text: str, flags: tuple[str, str] = ("--panel-bind", "--panel-allow")
) -> tuple[str, int, tuple[str, ...]]:
    """The panel's address and allow-list, checked as the server will; ValueError, one line."""
    from hilsim.live.netguard import GuardConfig, NetGuardError

    host, port = parse_bind(bind, flags[0])
    allow = tuple(a.strip() for a in allow_text.split(",") if a.strip())
    try:
        GuardConfig(interface=host, allow=allow)
    except NetGuardError as exc:
        if "opens the input" in str(exc):
            raise ValueError(
                f"{flags[0]} {host}: the panel would be open to the network: name the clients "
                f"allowed ({flags[1]} 192.168.1.23,10.0.0.0/24), or listen on 127.0.0.1"
            ) from None
        raise ValueError(f"{flags[1]}: {exc}") from None
    return host, port, allow


def _say(message: str) -> None:
    print(f"hilsim panel: {message}", file=sys.stderr, flush=True)


def _find_show(runs: Path) -> Path | None:
    """The newest run directory under ``runs`` whose panel.json names a live process."""
    found = []
    for info in runs.glob("*/panel.json"):
        try:
            pid = int(json.loads(info.read_text(encoding="utf-8"))["pid"])
            os.kill(pid, 0)
        except (OSError, ValueError, KeyError, TypeError):
            continue
        found.append(info.parent)
    return max(found, key=lambda d: d.stat().st_mtime) if found else None


def run(args: argparse.Namespace) -> int:
    try:
        from hilsim.panel.server import PanelConfig, PanelServer, new_token
    except ImportError:
        _say(EXTRA_HINT)
        return int(ExitCode.USAGE)
    from hilsim.cli._report import verdict
    from hilsim.live.netguard import NetGuardError

    try:
        flags = ("--panel-bind", "--panel-allow") if args.child else ("--bind", "--allow")
        host, port, allow = check_options(args.panel_bind, args.panel_allow, flags)
        token = os.environ.pop(TOKEN_ENV, None) if args.child else None
        config = PanelConfig(host=host, port=port, allow=allow, token=token or new_token())
    except (ValueError, NetGuardError) as exc:
        _say(str(exc))
        return int(ExitCode.USAGE)
    runs, run_dir, feed = Path(args.runs), None, None
    if args.feed:
        feed, run_dir = Path(args.feed), Path(args.run_dir) if args.run_dir else None
    else:
        run_dir = Path(args.run_dir) if args.run_dir else _find_show(runs)
        if run_dir is not None:
            try:
                feed = Path(json.loads((run_dir / "panel.json").read_text())["socket"])
            except (OSError, ValueError, KeyError, TypeError):
                _say(f"{run_dir}: no show with a panel runs there (no panel.json): past runs only")
                run_dir = None
        else:
            _say(f"no show with a panel is running under {runs}/: past runs only")
    if run_dir is not None:
        runs = run_dir.parent
    server = PanelServer(config, feed=feed, runs=runs, run_dir=run_dir, verdict=verdict)
    return _serve(server, args.child)


def _serve(server: object, child: bool) -> int:
    import asyncio  # here: `hilsim run` imports this module for its panel options

    from hilsim.panel.server import PanelServer

    assert isinstance(server, PanelServer)
    loop = asyncio.new_event_loop()

    def closing(*_: object) -> None:
        loop.call_soon_threadsafe(server.stopped.set)

    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, closing)
    if child:  # the parent's pipe closing (it ended, or died) closes the panel

        def watch() -> None:
            with contextlib.suppress(OSError, ValueError):
                while sys.stdin.readline():
                    pass
            closing()

        threading.Thread(target=watch, daemon=True).start()
    try:
        loop.run_until_complete(server.run(lambda url: print(f"panel: {url}", flush=True)))
    except OSError as exc:
        _say(f"cannot listen on {server.config.host}:{server.config.port}: {exc.strerror or exc}")
        return int(ExitCode.USAGE)
    finally:
        loop.close()
    if child and server.run_dir is not None:  # the run's record keeps what it refused
        with contextlib.suppress(OSError):
            counts = {"clients_max": server.config.max_clients, "counts": server.counts}
            (server.run_dir / "panel_counts.json").write_text(json.dumps(counts) + "\n")
    refused = {k: v for k, v in server.counts.items() if v and k not in ("requests", "commands")}
    said = ", ".join(f"{k} {v}" for k, v in refused.items()) or "nothing"
    _say(
        f"closed: {server.counts['requests']} requests, {server.counts['commands']} commands; "
        f"refused or dropped: {said}"
    )
    return int(ExitCode.OK)
