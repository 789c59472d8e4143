"""``hilsim scan`` on the emulator."""

from __future__ import annotations

from hilsim.cli import main


def test_scan_finds_every_servo(capsys):
    assert main(["scan", "--port", "dxlsim://?ids=1-3&model=XL330-M288", "--baud", "57600"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 3
    assert lines[0].startswith("ID   1 @   57600 bit/s: XL330-M288 (model 1200")


def test_scan_says_when_nobody_answers(capsys):
    # The servos sit at 57600 (the port's first rate); at 1 Mbps nobody answers.
    code = main(
        ["scan", "--port", "dxlsim://?ids=5&baud=57600", "--baud", "1000000", "--ids", "1-10"]
    )
    assert code == 1
    assert "no servo answered" in capsys.readouterr().err


def test_scan_rejects_bad_ids(capsys):
    assert main(["scan", "--port", "dxlsim://?ids=1", "--ids", "1-999"]) == 2
    assert "0..252" in capsys.readouterr().err
