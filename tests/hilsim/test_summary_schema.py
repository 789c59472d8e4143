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
}


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
    assert sorted(summary_keys(demo_summary)) == sorted(set(doc) | parents)


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
