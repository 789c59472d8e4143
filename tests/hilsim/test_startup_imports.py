"""Start-up (issue 12): the path from ``hilsim run`` to the first tick loads only what the
show needs. Never matplotlib (the plots come after the show), nor the other subcommands'
modules (the emulator's pty server, the bench, the integrator study). Subprocesses, so this
process's imports do not count; nothing is timed (``tools/bench_startup.py`` times it).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
NOT_BEFORE_THE_SHOW = ("matplotlib", "hilsim.cli.emulate", "hilsim.bench", "hilsim.studies")
#: what a show without a panel never needs: the package metadata (``hilsim --version``) and
#: the panel server's event loop
NOT_IN_A_PLAIN_RUN = ("importlib.metadata", "asyncio")


def loaded(code: str, *args: str) -> dict[str, bool]:
    """Run ``code`` in a fresh interpreter with ``args`` (``sys.argv[1:]``; the first is
    the JSON list of module names to look for); it prints a JSON dict as its last line."""
    proc = subprocess.run(  # stderr not piped: a plotting process it starts may outlive it
        [sys.executable, "-c", code, *args], cwd=REPO, stdout=subprocess.PIPE, text=True
    )
    assert proc.returncode == 0, proc.returncode
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_importing_hilsim_run_and_its_parser_loads_neither_matplotlib_nor_the_sdk():
    code = (
        "import json, sys, hilsim.cli.run, hilsim.cli\n"
        "hilsim.cli.build_parser('run')\n"
        "print(json.dumps({m: m in sys.modules for m in json.loads(sys.argv[1])}))"
    )
    names = ["matplotlib", "dynamixel_sdk", "drivers.dxlsim", *NOT_BEFORE_THE_SHOW]
    seen = loaded(code, json.dumps(names))
    assert not any(seen.values()), seen


def test_the_first_tick_of_the_demo_comes_without_matplotlib(tmp_path):
    """``hilsim run configs/demo.toml --virtual-time`` (plots on: the run that may start a
    plotting process meanwhile), stopped at its first tick: what this process has loaded."""
    code = (
        "import json, os, sys\n"
        "import hilsim.show.loop as loop\n"
        "def first_tick(self, *args):\n"
        "    seen = {m: m in sys.modules for m in json.loads(sys.argv[1])}\n"
        "    print(json.dumps(seen), flush=True)\n"
        "    os._exit(0)\n"
        "loop.HilLoop._tick = first_tick\n"
        "from hilsim.cli import main\n"
        "main(['run', 'configs/demo.toml', '--virtual-time', '--out', sys.argv[2]])\n"
        "print(json.dumps({'no first tick': True}))"
    )
    names = ["dynamixel_sdk", *NOT_BEFORE_THE_SHOW, *NOT_IN_A_PLAIN_RUN]
    seen = loaded(code, json.dumps(names), str(tmp_path / "run"))
    assert seen.pop("dynamixel_sdk", False), seen  # it did reach the first tick
    assert not any(seen.values()), seen


def test_importing_hilsim_leaves_the_version_lookup_until_asked():
    code = (
        "import json, sys, hilsim\n"
        "before = 'importlib.metadata' in sys.modules\n"
        "print(json.dumps({'before': before, 'version': hilsim.__version__}))"
    )
    seen = loaded(code)
    assert seen["before"] is False
    assert seen["version"]  # still there when asked for


def test_hilsim_version_prints_the_version_on_stdout(capsys):
    import pytest

    from hilsim import __version__
    from hilsim.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out == f"hilsim {__version__}\n"


def test_the_plotting_process_starts_before_the_show_is_imported(tmp_path):
    """``hilsim run --virtual-time`` (plots on) starts its plotting process before it imports
    the show, the rig and the emulator: matplotlib's import runs beside theirs."""
    code = (
        "import json, os, sys\n"
        "import hilsim.telemetry.plots as plots\n"
        "def prestart():\n"
        "    seen = {m: m in sys.modules for m in json.loads(sys.argv[1])}\n"
        "    print(json.dumps(seen), flush=True)\n"
        "    os._exit(0)\n"
        "plots.prestart = prestart\n"
        "from hilsim.cli import main\n"
        "main(['run', 'configs/demo.toml', '--virtual-time', '--out', sys.argv[2]])\n"
        "print(json.dumps({'no prestart': True}))"
    )
    names = ["hilsim.show", "hilsim.rig", "hilsim.live", "drivers.dxlsim", "dynamixel_sdk"]
    seen = loaded(code, json.dumps(names), str(tmp_path / "run"))
    assert seen == dict.fromkeys(names, False)


def test_the_status_twice_a_second_imports_nothing_in_the_loop():
    """An import inside the loop is a stall in a real show: the status the loop builds twice
    a second takes a percentile, and numpy's imports numpy.ma at its first call (~17 ms on
    a slow host). Importing the loop loads it beforehand."""
    code = (
        "import json, sys\n"
        "import numpy as np\n"
        "import hilsim.show.loop\n"
        "before = set(sys.modules)\n"
        "from hilsim.show import status\n"
        "status.np.percentile(np.zeros(3), 99)\n"
        "print(json.dumps({'new': sorted(set(sys.modules) - before)}))"
    )
    assert loaded(code, "[]") == {"new": []}
