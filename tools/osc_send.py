"""Send one OSC message to a running show: ``python tools/osc_send.py ADDRESS [NUMBER ...]``.

    python tools/osc_send.py /hilsim/cue/scare
    python tools/osc_send.py /hilsim/joint/jaw 0.5
    python tools/osc_send.py /hilsim/release/jaw
    python tools/osc_send.py /hilsim/stop
    python tools/osc_send.py --host 127.0.0.1 --port 9000 /hilsim/joint/head_pan 0.25

Numbers are sent as 32-bit floats (OSC type ``f``). The standard library only, so it runs
anywhere hilsim does; any OSC sender (TouchOSC, QLab, a lighting desk, python-osc) does the same.
"""

from __future__ import annotations

import argparse
import socket
import struct


def pad(b: bytes) -> bytes:
    """An OSC string: the bytes, a NUL, padded to a multiple of 4."""
    return b + b"\0" * (4 - len(b) % 4)


def message(address: str, numbers: list[float]) -> bytes:
    tags = "," + "f" * len(numbers)
    return (
        pad(address.encode()) + pad(tags.encode()) + b"".join(struct.pack(">f", x) for x in numbers)
    )


def main() -> int:
    ap = argparse.ArgumentParser(description="send one OSC message (UDP) to a running show")
    ap.add_argument("address", help="e.g. /hilsim/joint/jaw, /hilsim/cue/scare, /hilsim/stop")
    ap.add_argument("numbers", nargs="*", type=float, help="arguments, sent as floats")
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=9000)
    args = ap.parse_args()
    if not args.address.startswith("/"):
        ap.error(f"an OSC address starts with '/', got {args.address!r}")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(message(args.address, args.numbers), (args.host, args.port))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
