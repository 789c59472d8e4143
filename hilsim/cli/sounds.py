"""``hilsim sounds [--list]``: the sound output devices a show file's ``[sounds] device`` can name.

One line per output device PortAudio sees: its index, its name, its output channels and
default rate, and ``(default)`` beside the default output. ``device = 3`` or ``device = "USB
Audio"`` (a part of the name, as sounddevice matches it) picks one; without ``device`` a show
plays on the default. Needs ``pip install 'hilsim[live]'`` and PortAudio
(``apt install libportaudio2``). Exit codes: 0 devices listed, 1 no output device found, 2
sounddevice or PortAudio missing (one line naming what to install).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from hilsim.exit_codes import ExitCode

HELP = "list the sound output devices a show's [sounds] device can name"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--list", action="store_true", help="list the output devices (what it does by default)"
    )


def output_devices(sd: Any) -> list[tuple[int, str, int, float, bool]]:
    """(index, name, output channels, default rate, is the default) of each output device."""
    default = sd.default.device
    default_out = default[1] if isinstance(default, list | tuple) else default
    out = []
    for i, dev in enumerate(sd.query_devices()):
        channels = int(dev.get("max_output_channels", 0))
        if channels > 0:
            rate = float(dev.get("default_samplerate", 0.0))
            out.append((i, str(dev.get("name", "?")), channels, rate, i == default_out))
    return out


def run(args: argparse.Namespace) -> int:
    from hilsim.live.audio_out import AudioUnavailableError, require_sounddevice

    try:
        sd = require_sounddevice()
        devices = output_devices(sd)
    except AudioUnavailableError as exc:
        print(f"hilsim sounds: {exc}", file=sys.stderr)
        return int(ExitCode.USAGE)
    except Exception as exc:  # PortAudio failing to list: said in one line
        print(f"hilsim sounds: cannot list the devices: {exc}", file=sys.stderr)
        return int(ExitCode.NOTHING_FOUND)
    if not devices:
        print(
            "hilsim sounds: no sound output device found: a show with sounds runs silent "
            "(one warning), or is refused with [sounds] required = true",
            file=sys.stderr,
        )
        return int(ExitCode.NOTHING_FOUND)
    for index, name, channels, rate, is_default in devices:
        mark = "  (default)" if is_default else ""
        print(f"{index:3d}  {name}  {channels} ch, {rate:.0f} Hz{mark}")
    print('hilsim sounds: in a show file: [sounds] device = "<name>" or <index>', file=sys.stderr)
    return int(ExitCode.OK)
