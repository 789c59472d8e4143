"""The panel's cost to the loop (issue 28; not a test): the demo show in real time on the
emulator, in one run of this tool, in three ways taken in turn ``--rounds`` times:

* ``plain``: ``hilsim.Show`` alone (what ``hilsim run`` does without ``--panel``);
* ``controls``: ``Show(controls=True)``: the director ``--panel`` adds (cues, live joints);
* ``panel``: that, its feed thread, a ``hilsim panel`` process and ``--browsers`` headless
  Chromium pages (Debian's ``chromium``, through Playwright) showing it.

Per way: the tick's lateness (wake-up after its deadline) and the loop's own work per tick
(the safety filter, springs, targets, telemetry: ``t_safety_us + t_sim_us + t_telemetry_us``;
the bus stage is left out, it is the in-process emulator's time), p50 / p99 in µs, overruns;
and for ``panel`` the CPU of the feed thread (in the show's process) and of the panel process,
as a share of one core. Give the load beside the figures: the machine is shared.

    python tools/bench_panel.py [--seconds 10] [--rounds 2] [--browsers 2]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import hilsim  # noqa: E402
from hilsim.show.feed import PanelFeed  # noqa: E402

CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync"]  # fmt: skip


def _pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, round(q / 100 * (len(s) - 1)))]


def _ticks(run_dir: Path) -> tuple[list[float], list[float], int]:
    late, work, overruns = [], [], 0
    with (run_dir / "telemetry.csv").open() as f:
        for row in csv.DictReader(f):
            late.append(float(row["lateness_us"]))
            work.append(
                float(row["t_safety_us"]) + float(row["t_sim_us"]) + float(row["t_telemetry_us"])
            )
            overruns += row["overrun"] in ("1", "True", "true")
    return late, work, overruns


def _cpu_s(stat: Path) -> float:
    fields = stat.read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _one(way: str, out: Path, seconds: float, browsers: int) -> dict[str, float]:
    show = hilsim.Show(REPO / "configs/demo.toml", duration=seconds, out=out,
                       controls=way != "plain")  # fmt: skip
    facts: dict[str, float] = {}
    with show, contextlib.ExitStack() as stack:
        if way == "panel":
            feed = PanelFeed(show)
            feed.start()
            stack.callback(feed.close)
            proc = subprocess.Popen(
                [sys.executable, "-m", "hilsim", "panel", str(out), "--bind", "127.0.0.1:0"],
                stdout=subprocess.PIPE, cwd=REPO, env=dict(os.environ, PYTHONPATH=str(REPO)),
            )  # fmt: skip
            stack.callback(proc.wait)
            stack.callback(proc.terminate)
            assert proc.stdout is not None
            url = proc.stdout.readline().decode().strip().removeprefix("panel: ")
            from playwright.sync_api import sync_playwright

            pw = stack.enter_context(sync_playwright())
            exe = shutil.which("chromium")
            browser = pw.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
            stack.callback(browser.close)
            for _ in range(browsers):
                page = browser.new_page()
                page.goto(url)
                page.wait_for_selector("#joint-tail canvas")
            panel_stat = Path(f"/proc/{proc.pid}/stat")
            panel0 = _cpu_s(panel_stat)
        tid: list[int] = []
        runner = threading.Thread(target=lambda: (tid.append(threading.get_native_id()),
                                                  show.run()))  # fmt: skip
        wall0 = time.monotonic()
        runner.start()
        if way == "panel":
            feed_thread = feed._thread
            assert feed_thread is not None and feed_thread.native_id is not None
            feed_stat = Path(f"/proc/self/task/{feed_thread.native_id}/stat")
            feed0 = _cpu_s(feed_stat)
        runner.join()
        wall = time.monotonic() - wall0
        result = show.result
        if result is not None and result.exit_code != 0:
            print(f"  ({way}: exit {result.exit_code}: {result.reason})", flush=True)
        if way == "panel":
            facts["feed_cpu_pct"] = 100 * (_cpu_s(feed_stat) - feed0) / wall
            facts["panel_cpu_pct"] = 100 * (_cpu_s(panel_stat) - panel0) / wall
    late, work, overruns = _ticks(out)
    facts.update(
        ticks=len(late), overruns=overruns,
        late_p50=statistics.median(late), late_p99=_pct(late, 99),
        work_p50=statistics.median(work), work_p99=_pct(work, 99),
    )  # fmt: skip
    return facts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--browsers", type=int, default=2)
    args = ap.parse_args()
    print(f"load before: {Path('/proc/loadavg').read_text().strip()}")
    results: dict[str, list[dict[str, float]]] = {"plain": [], "controls": [], "panel": []}
    with tempfile.TemporaryDirectory(prefix="bench-panel-") as tmp:
        for r in range(args.rounds):
            for way in results:
                facts = _one(way, Path(tmp) / f"{way}-{r}", args.seconds, args.browsers)
                results[way].append(facts)
                print(f"round {r + 1} {way:8s} " + "  ".join(
                    f"{k} {v:.1f}" for k, v in facts.items()), flush=True)  # fmt: skip
    print(f"load after: {Path('/proc/loadavg').read_text().strip()}")
    print("\nway       lateness p50/p99 us   loop work p50/p99 us   overruns   feed/panel CPU %")
    for way, rows in results.items():

        def mean(key: str, rows: list[dict[str, float]] = rows) -> float:
            return statistics.fmean(r.get(key, float("nan")) for r in rows)

        cpu = (f"{mean('feed_cpu_pct'):.1f} / {mean('panel_cpu_pct'):.1f}"
               if way == "panel" else "-")  # fmt: skip
        print(f"{way:9s} {mean('late_p50'):8.0f} / {mean('late_p99'):7.0f}"
              f"      {mean('work_p50'):7.1f} / {mean('work_p99'):7.1f}"
              f"     {mean('overruns'):6.0f}     {cpu}")  # fmt: skip


if __name__ == "__main__":
    main()
