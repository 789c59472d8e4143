"""``hilsim scan`` on the emulator."""

from __future__ import annotations

from hilsim.cli import main


def test_scan_finds_every_servo(capsys):
    assert (
        main(
            [
                "scan",
                "--port",
                "dxlsim://?ids=1-3&model=XL330-M288&clock=virtual",
                "--baud",
                "57600",
            ]
        )
        == 0
    )
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 3
    assert lines[0].startswith("ID   1 @   57600 bit/s: XL330-M288 (model 1200")


def test_scan_says_when_nobody_answers(capsys):
    # The servos sit at 57600 (the port's first rate); at 1 Mbps nobody answers.
    code = main(
        [
            "scan",
            "--port",
            "dxlsim://?ids=5&baud=57600&clock=virtual",
            "--baud",
            "1000000",
            "--ids",
            "1-10",
        ]
    )
    assert code == 1
    assert "no servo answered" in capsys.readouterr().err


def test_scan_rejects_bad_ids(capsys):
    assert main(["scan", "--port", "dxlsim://?ids=1", "--ids", "1-999"]) == 2
    assert "0..252" in capsys.readouterr().err


def test_scan_takes_the_helps_baud_notation(capsys):
    # The help lists "57600 115200 1M ..."; 57.6k and 1M are what people type.
    code = main(["scan", "--port", "dxlsim://?ids=1-2&baud=57600&clock=virtual", "--baud", "57.6k",
                 "--baud", "1M", "--ids", "1-3"])  # fmt: skip
    assert code == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line[:22] for line in lines] == ["ID   1 @   57600 bit/s", "ID   2 @   57600 bit/s"]


def test_scan_refuses_an_unsupported_baud_in_one_line(capsys):
    assert main(["scan", "--port", "dxlsim://?ids=1", "--baud", "250000"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err
    assert err.startswith("hilsim scan: --baud '250000': the servos do not run at that rate")
