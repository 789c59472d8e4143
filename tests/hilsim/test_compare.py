"""``hilsim compare`` end to end, quickly, and the import hygiene of the package."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hilsim.cli import SUBCOMMANDS, compare, main
from hilsim.studies.compare_plots import FIGURES

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, str]:
    root = tmp_path_factory.mktemp("compare")
    out, json_path = root / "out", root / "numbers" / "compare.json"
    import contextlib
    import io

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        assert main(["compare", "--out", str(out), "--json", str(json_path), "--quick"]) == 0
    return out, json_path, buffer.getvalue()


def test_compare_is_a_registered_subcommand() -> None:
    assert SUBCOMMANDS["compare"] == "hilsim.cli.compare"
    for attr in ("HELP", "add_arguments", "run"):
        assert hasattr(compare, attr)


def test_compare_writes_the_report_the_json_and_every_figure(quick_run) -> None:
    out, _, _ = quick_run
    for name in FIGURES:
        assert (out / name).read_bytes()[:8] == PNG_MAGIC, name
    report = (out / "report.md").read_text(encoding="utf-8")
    for name in FIGURES:
        assert f"]({name})" in report
    assert "](../numbers/compare.json)" in report
    assert "matches the paper's to 6 decimals in every row" in report


def test_compare_numbers(quick_run) -> None:
    _, json_path, _ = quick_run
    numbers = json.loads(json_path.read_text(encoding="utf-8"))
    assert numbers["quick"] is True
    assert numbers["exponential"]["euler"] == pytest.approx(1.1)
    assert round(numbers["exponential"]["rk4"], 5) == 1.10517
    assert numbers["undamped"]["matches_paper"] and numbers["undamped"]["n_points"] == 1000
    assert round(numbers["damped"]["omega_d"], 4) == 3.8649
    for method, order in {"euler": 1, "semi_implicit_euler": 1, "midpoint": 2, "rk4": 4}.items():
        assert numbers["damped"]["order"][method] == pytest.approx(order, abs=0.1)
    assert numbers["damped"]["max_error"]["rk4"] <= 1.2e-7
    assert numbers["stability"]["imag_axis"]["rk4"] == pytest.approx(2.8284, abs=1e-3)
    assert numbers["energy"]["at_10s"]["rk4"] == pytest.approx(-1.40e-8, rel=0.02)
    assert len(numbers["paper_slips"]) == 5


def test_compare_prints_a_summary(quick_run) -> None:
    *_, printed = quick_run
    assert "reproduced to 6 decimals" in printed
    assert "ω_d = 3.8649 rad/s" in printed
    assert "rk4" in printed and "report.md" in printed


@pytest.mark.parametrize("module", ["hilsim", "hilsim.studies.compare", "hilsim.cli.compare"])
def test_importing_does_not_import_matplotlib_or_the_sdk(module: str) -> None:
    code = (
        f"import sys, {module}; "
        "loaded = [m for m in ('matplotlib', 'dynamixel_sdk') if m in sys.modules]; "
        "print(loaded); sys.exit(1 if loaded else 0)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stdout + done.stderr


def test_public_api() -> None:
    import hilsim

    for name in ("Spring", "simulate", "check_stability", "make_integrator", "INTEGRATORS"):
        assert name in hilsim.__all__ and hasattr(hilsim, name)
    assert hilsim.__version__
