"""The show file and every file it (and the rig) names, kept with the run (issue 31, item 4):
small ones copied, big ones hashed, one manifest (show_files.json) that says which."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import hilsim
from hilsim.show import show_files
from hilsim.show.show_files import record_show_files
from hilsim.telemetry.reader import read_run
from tests.hilsim.test_rig import BASE

SHOW = """
[clips.wave]
pan = { type = "csv", file = "anim/wave.csv", column = "pan" }
[sounds]
wave = "snd/wave.wav"
big = { file = "snd/big.wav", offset_ms = 20 }
[cues.wave]
trigger = "key:w"
clip = "wave"
"""


def _show_dir(tmp_path: Path) -> Path:
    d = tmp_path / "show"
    (d / "anim").mkdir(parents=True)
    (d / "snd").mkdir()
    (d / "anim" / "wave.csv").write_text("time_s,pan\n0,0\n0.5,10\n1,0\n")
    (d / "snd" / "wave.wav").write_bytes(b"RIFF" + bytes(200))
    (d / "snd" / "big.wav").write_bytes(b"RIFF" + bytes(5000))
    (d / "show.toml").write_text(SHOW)
    return d


def test_small_files_are_copied_big_ones_hashed_and_the_manifest_says_which(
    tmp_path: Path, monkeypatch
) -> None:
    monkeypatch.setattr(show_files, "COPY_MAX_BYTES", 1000)
    d = _show_dir(tmp_path)
    run = tmp_path / "run"
    run.mkdir()
    rig = tmp_path / "rig.toml"
    rig.write_text(BASE)
    manifest, problem = record_show_files(run, rig, BASE, d / "show.toml")
    assert problem is None and manifest is not None
    on_disk = json.loads((run / "show_files.json").read_text())
    assert on_disk == manifest
    by_path = {f["path"]: f for f in manifest["files"]}
    assert by_path[str(rig.resolve())]["copy"] == "rig.toml"
    show = by_path[str((d / "show.toml").resolve())]
    assert show["role"] == "show" and (run / show["copy"]).read_text() == SHOW
    csv = by_path[str((d / "anim" / "wave.csv").resolve())]
    assert csv["named_by"] == "show.toml: clips.wave.pan.file"
    assert (run / csv["copy"]).read_bytes() == (d / "anim" / "wave.csv").read_bytes()
    small = by_path[str((d / "snd" / "wave.wav").resolve())]
    assert small["named_by"] == "show.toml: sounds.wave" and small["copy"] is not None
    big = by_path[str((d / "snd" / "big.wav").resolve())]
    assert big["named_by"] == "show.toml: sounds.big.file"
    assert big["copy"] is None and "hashed only" in big["why_not_copied"]
    assert big["size"] == 5004
    assert big["sha256"] == hashlib.sha256((d / "snd" / "big.wav").read_bytes()).hexdigest()


def test_a_show_keeps_its_files_with_the_run(tmp_path: Path) -> None:
    d = _show_dir(tmp_path)
    (d / "show.toml").write_text(SHOW.split("[sounds]")[0] + SHOW.split("offset_ms = 20 }\n")[1])
    rig = tmp_path / "rig.toml"
    rig.write_text(
        BASE.replace('"dxlsim://?ids=1-2"', '"dxlsim://?ids=1-2&rdt_us=0&latency_ms=1"').replace(
            "rate_hz = 500", "rate_hz = 250"
        )
    )
    out = tmp_path / "run"
    with hilsim.Show(rig, virtual_time=True, duration=0.2, show=d / "show.toml", out=out) as s:
        result = s.run()
    assert result.exit_code == 0
    manifest = json.loads((out / "show_files.json").read_text())
    assert [f["role"] for f in manifest["files"]] == ["rig", "show", "named"]
    assert (out / manifest["files"][2]["copy"]).read_text().startswith("time_s,pan")
    assert read_run(out).events[0]["kind"] == "start"  # the manifest is the record: no event


def test_a_manifest_that_cannot_be_written_is_a_warning_not_a_stop(tmp_path: Path) -> None:
    d = _show_dir(tmp_path)
    not_a_dir = tmp_path / "file"
    not_a_dir.write_text("")
    manifest, problem = record_show_files(not_a_dir, None, None, d / "show.toml")
    assert manifest is None and problem is not None and "show_files.json not written" in problem
