"""summary.json has exactly the keys docs/summary.md documents, each once."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from hilsim.cli import main
from hilsim.telemetry.format import SUMMARY_SCHEMA_VERSION
from hilsim.telemetry.stats import comm_errors

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "summary.md"
#: objects whose inner keys are data (joint names, stages, percentiles), not schema
DATA_OBJECTS = {
    "lateness_us",
    "stage_us",
    "stale_reads",
    "error_reads",
    "alert_reads",
    "servo_ids",
    "safety_limits",
    "safety_ticks",
    "loop.host_stalls",
    "loop.servo_condition",
    "live",
}
#: sections only some runs have (documented, absent from the demo's summary)
OPTIONAL = {"live"}


def documented_keys() -> list[str]:
    return re.findall(r"^\| `([\w.]+)` \|", DOC.read_text(encoding="utf-8"), re.M)


def summary_keys(summary: dict, prefix: str = "") -> list[str]:
    keys = []
    for key, value in summary.items():
        keys.append(prefix + key)
        if isinstance(value, dict) and prefix + key not in DATA_OBJECTS:
            keys += summary_keys(value, prefix + key + ".")
    return keys


@pytest.fixture(scope="module")
def demo_summary(tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("schema") / "run"
    demo = str(REPO / "configs" / "demo.toml")
    argv = ["run", demo, "--virtual-time", "--duration", "1", "--out", str(out), "--no-plots"]
    assert main(argv) == 0
    return json.loads((out / "summary.json").read_text(encoding="utf-8"))


def test_every_key_is_documented_once_and_every_documented_key_is_there(demo_summary):
    doc = documented_keys()
    assert len(doc) == len(set(doc)), "a key documented twice"
    parents = {k.rsplit(".", 1)[0] for k in doc if "." in k}
    assert sorted(summary_keys(demo_summary)) == sorted((set(doc) | parents) - OPTIONAL)


def test_a_live_show_has_the_live_section(tmp_path):
    """A show with OSC: the documented ``live`` section, with the keys its prose names."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # a free port
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    show = tmp_path / "show.toml"
    show.write_text(f"[inputs.osc]\nport = {port}\n[record]\n")
    out = tmp_path / "run"
    demo = str(REPO / "configs" / "demo.toml")
    argv = ["run", demo, "--show", str(show), "--virtual-time", "--duration", "0.2",
            "--out", str(out), "--no-plots"]  # fmt: skip
    assert main(argv) == 0
    live = json.loads((out / "summary.json").read_text(encoding="utf-8"))["live"]
    doc = DOC.read_text(encoding="utf-8").split("## A live show")[1]
    for key in live:
        assert f"`{key}`" in doc, key
    assert {"show", "events", "cues", "stops", "live_values", "osc_drops", "takes"} <= set(live)


def test_the_version_is_the_documented_one(demo_summary):
    assert demo_summary["schema_version"] == SUMMARY_SCHEMA_VERSION == 1
    assert "schema version 1" in DOC.read_text(encoding="utf-8").splitlines()[0]


def test_no_fact_in_two_books(demo_summary):
    """The keys version 1 removed stay removed: counts that re-counted another key."""
    for gone in ("comm_errors", "comm_errors_total"):
        assert gone not in demo_summary
    for gone in ("overruns", "exit_policy", "exit_policy_confirmed", "safety"):
        assert gone not in demo_summary["loop"]
    assert comm_errors(demo_summary) == 0


def test_the_summary_has_each_servos_max_temperature_and_min_voltage(demo_summary):
    """The demo's emulated XM430s: about room temperature, on a 12 V supply."""
    cond = demo_summary["loop"]["servo_condition"]
    assert sorted(cond) == sorted(demo_summary["servo_ids"])
    for joint, figures in cond.items():
        assert 10.0 <= figures["max_temperature_c"] <= 45.0, joint
        assert figures["min_voltage_v"] == 12.0, joint
