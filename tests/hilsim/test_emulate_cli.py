"""``hilsim emulate``'s printed follow-up: a command that fits the bus it serves."""

from __future__ import annotations

import shlex

import pytest

from hilsim.cli import build_parser
from hilsim.cli._args import parse_baud
from hilsim.cli.emulate import usage_lines


def _lines(*flags: str) -> list[str]:
    args = build_parser().parse_args(["emulate", *flags])
    args.baud = parse_baud(args.baud)
    return usage_lines("/dev/pts/9", args).splitlines()


def test_the_demo_is_suggested_for_the_demo_bus():
    assert "  e.g. hilsim run configs/demo.toml --port /dev/pts/9" in _lines()


@pytest.mark.parametrize(
    "flags",
    [
        ("--ids", "1-3", "--model", "XL430-W250", "--baud", "57600", "--rdt-us", "500"),
        ("--ids", "1-3"),
        ("--model", "XL430-W250"),
        ("--baud", "57600"),
        ("--rdt-us", "500"),
    ],
)
def test_another_bus_is_told_a_scan_of_itself_not_the_demo(flags):
    lines = _lines(*flags)
    assert not any("hilsim run configs/demo.toml" in x for x in lines)
    scan = next(x for x in lines if "hilsim scan" in x)
    argv = shlex.split(scan.split("e.g. ", 1)[1].split("   (")[0])
    got = build_parser().parse_args(argv[1:])  # the command parses as given
    want = build_parser().parse_args(["emulate", *flags])
    assert got.port == "/dev/pts/9"
    assert [parse_baud(b) for b in got.baud] == [parse_baud(want.baud)]
    assert got.ids == getattr(want, "ids", "1-4")
    rig = next(x for x in lines if "a rig of your own" in x)
    assert f'model = "{getattr(want, "model", "XM430-W350")}"' in rig
    assert f"baud = {parse_baud(want.baud)}" in rig
