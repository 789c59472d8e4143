"""The panel's cost to the loop (issue 28; not a test): the demo show in real time on the
emulator, in one run of this tool, in three ways taken in turn ``--rounds`` times:

* ``plain``: ``hilsim.Show`` alone (what ``hilsim run`` does without ``--panel``);
* ``controls``: ``Show(controls=True)``: the director ``--panel`` adds (cues, live joints);
* ``panel-ws``: that, its feed thread, a ``hilsim panel`` process and ``--browsers``
  WebSocket clients reading every message (in a process of their own, no browser);
* ``panel``: that, its feed thread, a ``hilsim panel`` process and ``--browsers`` headless
  Chromium pages (Debian's ``chromium``, through Playwright) showing it.

First, in virtual time (the loop flat out, so the host's load matters less): the loop's own
work per tick for ``plain`` and ``controls`` (the median over ``--rounds`` runs of its p50 and
p99), ``Director.tick`` alone for ``controls``, and what one feed snapshot holds the
interpreter for (copying the loop's arrays and encoding the line).

Then on the real clock, per way: the tick's lateness (wake-up after its deadline) and the
loop's own work per tick (the safety filter, springs, targets, telemetry: ``t_safety_us +
t_sim_us + t_telemetry_us``; the bus stage is left out, it is the in-process emulator's
time), p50 / p99 in µs, overruns; and for ``panel`` the CPU of the feed thread (in the
show's process), of the panel process and of the browsers, as a share of one core. Give the
load beside the figures: the machine is shared.

    python tools/bench_panel.py [--seconds 10] [--rounds 2] [--browsers 2]

``--rounds 0``: the virtual-time part alone.
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


# ``panel-ws``: N WebSocket clients that read every message, in a process of their own
WS_READERS = """
import asyncio, sys
from websockets.asyncio.client import connect
url, n = sys.argv[1], int(sys.argv[2])
base, token = url.split("/?token=")
async def read():
    async with connect(base.replace("http", "ws") + "/ws?token=" + token, origin=base) as ws:
        async for _ in ws:
            pass
async def main():
    await asyncio.gather(*(read() for _ in range(n)))
asyncio.run(main())
"""


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


def _descendants_cpu_s(names: tuple[str, ...]) -> float:
    """CPU seconds of this process's descendants whose name starts with one of ``names``."""
    me, total = os.getpid(), 0.0
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
            comm = text[text.index("(") + 1 : text.rindex(")")]
            pid = int(stat.parent.name)
            while pid > 1:  # walk up to us
                ppid = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
                if ppid == me:
                    break
                pid = ppid
            else:
                continue
            if comm.startswith(names):
                total += _cpu_s(stat)
        except (OSError, ValueError):
            continue
    return total


def _one(way: str, out: Path, seconds: float, browsers: int) -> dict[str, float]:
    show = hilsim.Show(REPO / "configs/demo.toml", duration=seconds, out=out,
                       controls=way != "plain")  # fmt: skip
    facts: dict[str, float] = {}
    with show, contextlib.ExitStack() as stack:
        if way in ("panel", "panel-ws"):
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
        if way == "panel-ws":  # the same feed and server; the browsers' part in a process
            reader = subprocess.Popen([sys.executable, "-c", WS_READERS, url, str(browsers)],
                                      cwd=REPO)  # fmt: skip
            stack.callback(reader.wait)
            stack.callback(reader.terminate)
        if way == "panel":
            from playwright.sync_api import sync_playwright

            pw = stack.enter_context(sync_playwright())
            exe = shutil.which("chromium")
            browser = pw.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
            stack.callback(browser.close)
            for _ in range(browsers):
                page = browser.new_page()
                page.goto(url)
                page.wait_for_selector("#joint-tail canvas")
        if way in ("panel", "panel-ws"):  # the CPU from here on: the show's run alone
            panel_stat = Path(f"/proc/{proc.pid}/stat")
            panel0 = _cpu_s(panel_stat)
            chrome0 = _descendants_cpu_s(("chrom", "headless"))
        tid: list[int] = []
        runner = threading.Thread(target=lambda: (tid.append(threading.get_native_id()),
                                                  show.run()))  # fmt: skip
        wall0 = time.monotonic()
        runner.start()
        if way in ("panel", "panel-ws"):
            feed_thread = feed._thread
            assert feed_thread is not None and feed_thread.native_id is not None
            feed_stat = Path(f"/proc/self/task/{feed_thread.native_id}/stat")
            feed0 = _cpu_s(feed_stat)
        runner.join()
        wall = time.monotonic() - wall0
        result = show.result
        if result is not None and result.exit_code != 0:
            print(f"  ({way}: exit {result.exit_code}: {result.reason})", flush=True)
            facts["faulted"] = 1.0
        if way in ("panel", "panel-ws"):
            facts["feed_cpu_pct"] = 100 * (_cpu_s(feed_stat) - feed0) / wall
            facts["panel_cpu_pct"] = 100 * (_cpu_s(panel_stat) - panel0) / wall
            chrome = _descendants_cpu_s(("chrom", "headless")) - chrome0
            facts["browsers_cpu_pct"] = 100 * chrome / wall
    late, work, overruns = _ticks(out)
    facts.update(
        ticks=len(late), overruns=overruns,
        late_p50=statistics.median(late), late_p99=_pct(late, 99),
        work_p50=statistics.median(work), work_p99=_pct(work, 99),
    )  # fmt: skip
    return facts


def _virtual(way: str, out: Path) -> dict[str, float]:
    show = hilsim.Show(REPO / "configs/demo.toml", virtual_time=True, out=out,
                       controls=way != "plain")  # fmt: skip
    facts: dict[str, float] = {}
    times: list[float] = []
    director = show.parts.director
    if director is not None:
        real = director.tick

        def tick(k: int, t: float, present: list[float]) -> None:
            a = time.perf_counter()
            real(k, t, present)
            times.append(time.perf_counter() - a)

        director.tick = tick  # type: ignore[method-assign]
    with show:
        show.run()
        if way == "controls":
            loop = show.loop
            assert loop is not None
            feed = PanelFeed(show)
            snaps = []
            for _ in range(2000):
                a = time.perf_counter()
                feed._line(feed._state_msg(loop))
                snaps.append(time.perf_counter() - a)
            facts["snapshot_p50"] = statistics.median(snaps) * 1e6
            facts["snapshot_p99"] = _pct(snaps, 99) * 1e6
    _, work, _ = _ticks(out)
    facts["work_p50"], facts["work_p99"] = statistics.median(work), _pct(work, 99)
    if times:
        us = [x * 1e6 for x in times]
        facts["director_p50"], facts["director_p99"] = statistics.median(us), _pct(us, 99)
    return facts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--browsers", type=int, default=2)
    args = ap.parse_args()
    print(f"load before: {Path('/proc/loadavg').read_text().strip()}")
    with tempfile.TemporaryDirectory(prefix="bench-panel-") as tmp:
        virt: dict[str, list[dict[str, float]]] = {"plain": [], "controls": []}
        for r in range(max(3, args.rounds)):
            for way in virt:
                virt[way].append(_virtual(way, Path(tmp) / f"v-{way}-{r}"))
    print("virtual time, the demo's 20 s (5,001 ticks), median of the runs, us:")
    for way, rows in virt.items():
        line = "  ".join(f"{k} {statistics.median(r[k] for r in rows):.1f}" for k in rows[0])
        print(f"  {way:8s} {line}")
    print(f"load: {Path('/proc/loadavg').read_text().strip()}")
    results: dict[str, list[dict[str, float]]] = {
        "plain": [], "controls": [], "panel-ws": [], "panel": []
    }  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="bench-panel-") as tmp:
        for r in range(args.rounds):
            for way in results:
                facts = _one(way, Path(tmp) / f"{way}-{r}", args.seconds, args.browsers)
                results[way].append(facts)
                print(f"round {r + 1} {way:8s} " + "  ".join(
                    f"{k} {v:.1f}" for k, v in facts.items()), flush=True)  # fmt: skip
    print(f"load after: {Path('/proc/loadavg').read_text().strip()}")
    print("\nway       lateness p50/p99 us   loop work p50/p99 us   overruns   "
          "feed / panel / browsers CPU %")  # fmt: skip
    for way, rows in results.items():
        if not rows:
            continue

        def mean(key: str, rows: list[dict[str, float]] = rows) -> float:
            return statistics.fmean(r.get(key, float("nan")) for r in rows)

        cpu = (f"{mean('feed_cpu_pct'):.1f} / {mean('panel_cpu_pct'):.1f} / "
               f"{mean('browsers_cpu_pct'):.0f}" if way.startswith("panel") else "-")  # fmt: skip
        print(f"{way:9s} {mean('late_p50'):8.0f} / {mean('late_p99'):7.0f}"
              f"      {mean('work_p50'):7.1f} / {mean('work_p99'):7.1f}"
              f"     {mean('overruns'):6.0f}     {cpu}")  # fmt: skip


if __name__ == "__main__":
    main()
