"""Every rig shipped in configs/ runs on the set-up the README recommends (emulated here): four
servos of the models the rig names (XM430-W350 where it names none of them for an ID) at 1 Mbps,
Return Delay Time 0, a U2D2 with its latency timer at 1 ms. Every joint names its model, and
no speed limit asks more than that model's no-load speed."""

from __future__ import annotations

from pathlib import Path

import pytest

from hilsim.cli import main
from hilsim.rig import load_rigs
from hilsim.telemetry.reader import read_run

REPO = Path(__file__).resolve().parents[2]
U2D2 = "dxlsim://?ids=1-4&model=XM430-W350&rdt_us=0&latency_ms=1"
#: rigs for a bigger bus than the four-servo figure: their own set-up, on the emulator
OWN_BUS = {
    "scale16.toml": "dxlsim://?ids=1-16&model=XM430-W350&rdt_us=0&baud=4000000",
    # the other servo families: their own emulated servos (README, Servo families)
    "so101_arm.toml": "dxlsim://?ids=1-6&model=STS3215&rdt_us=0&latency_ms=1",
    "ax12_figure.toml": "dxlsim://?ids=1-6&model=AX-12A&rdt_us=0&latency_ms=1",
}


#: rigs with several [buses.<name>]: each bus on the emulated bus its table names (one process
#: per bus; --port is for a rig's one [bus])
SEVERAL_BUSES = {"two_buses.toml": ("left", "right")}


def _with_models(rig: Path, url: str) -> str:
    """``url`` with each servo of the rig at the model its joint names."""
    models = ",".join(f"{j.servo_id}:{j.model}" for r in load_rigs(rig) for j in r.joints)
    return url.replace("model=XM430-W350", f"model=XM430-W350,{models}")


@pytest.mark.parametrize("rig", sorted((REPO / "configs").glob("*.toml")), ids=lambda p: p.name)
def test_shipped_rig_names_each_model_and_asks_no_more_speed_than_it_has(rig, caplog):
    text = rig.read_text()
    assert text.count("[[joints]]") == len(
        [line for line in text.splitlines() if line.startswith("model = ")]
    ), f"{rig.name}: every joint names its servo's model"
    with caplog.at_level("WARNING", logger="hilsim.rig"):
        load_rigs(rig)
    assert not [r.message for r in caplog.records if "no-load speed" in r.message]


@pytest.mark.parametrize("rig", sorted((REPO / "configs").glob("*.toml")), ids=lambda p: p.name)
def test_shipped_rig_runs_on_the_recommended_setup(rig, tmp_path, capsys):
    out = tmp_path / "run"
    buses = SEVERAL_BUSES.get(rig.name)
    port = [] if buses else ["--port", _with_models(rig, OWN_BUS.get(rig.name, U2D2))]
    code = main(
        ["run", str(rig), *port, "--virtual-time", "--no-plots", "--duration", "2",
         "--out", str(out)]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == 0, err
    for run_dir in [out / bus for bus in buses] if buses else [out]:
        run = read_run(run_dir)
        assert run.summary["exit_policy_confirmed"] is True
        assert run.summary["overruns"] == 0
        loop = run.summary["loop"]  # the tick has room to check the servos (or its read does)
        assert loop["health_reads"] > 0 or loop["health_every_tick"]
