"""Benchmark: the web dashboard watching ten robots for ten minutes — does the page stay level, and what does it cost?

    .venv/bin/python bench/dashboard_soak.py [--robots 10] [--seconds 120] [--every 30] [--plot PATH] [--quick]

``make bench`` runs it for two minutes; the figures in docs/dashboard.md come from ``--seconds 600``.

One embedded broker with a WebSocket listener, ``--robots`` simulated robots (tests/support/sim_fleet.py: MQTT only,
each its own login; heartbeat, battery, link and — for three — GPS at 1 Hz, positions at 10 Hz) and the dashboard
in headless Chromium logged in as ``ops`` (operator of all), its fleet view shown (map, attention list, alerts).
Two windows, one after the other, in one run:

* **reference**: 60 s with the robots sending only their 1 Hz messages (no positions): the page's floor;
* **soak**: ``--seconds`` with the full stream.

Every ``--every`` s a sample after a forced garbage collection: heap, DOM elements and nodes, JS listeners, and the
page's main-thread CPU (DevTools' TaskDuration) since the last sample. The summary says how the heap and DOM moved
after the soak's first minute and the average CPU of the page and of the broker. Never asserts on timing.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

from _support import cpu_seconds

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # tests/support: the simulated fleet and the page sampler the fleet test uses too

from roslink_mqtt.dashboard import DashboardServer  # noqa: E402
from roslink_mqtt.localproc import free_port, start_embedded_broker  # noqa: E402
from tests.support.browser import browser, logged_in, login, robot_row, wait_until  # noqa: E402
from tests.support.page_soak import PageSample, cpu_share, soak, table  # noqa: E402
from tests.support.sim_fleet import PASSWORD, SimulatedFleet, robot_name, write_sim_fleet  # noqa: E402

DEFAULT_PLOT = ROOT / "docs" / "performance" / "dashboard_soak.png"
REFERENCE_SECONDS = 60.0


def window(name: str, samples: list[PageSample], broker_cpu: float) -> str:
    first, last = samples[0], samples[-1]
    after_minute = next((s for s in samples if s.t >= 60), first)
    return (f"{name:<10} {last.t:7.0f}   {cpu_share(first, last) * 100:9.1f}   {broker_cpu * 100:10.1f}   "
            f"{first.heap_mb:8.2f}   {after_minute.heap_mb:12.2f}   {last.heap_mb:8.2f}   "
            f"{last.heap_mb - after_minute.heap_mb:+11.2f}   {first.elements:5d} → {last.elements:<5d}   "
            f"{first.nodes:5d} → {last.nodes:<5d}")


def plot(samples: list[PageSample], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot([s.t / 60 for s in samples], [s.heap_mb for s in samples], marker="o", label="heap (MB, after GC)")
    cpu = [cpu_share(a, b) * 100 for a, b in zip(samples, samples[1:], strict=False)]
    ax.plot([s.t / 60 for s in samples[1:]], cpu, marker=".", label="page CPU (% of a core)")
    ax.set_xlabel("minutes of ten robots streaming")
    ax.set_ylim(bottom=0)
    ax.set_title("the dashboard's fleet view over time")
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", type=int, default=10)
    p.add_argument("--seconds", type=float, default=120.0, help="the soak window (docs: 600)")
    p.add_argument("--every", type=float, default=30.0)
    p.add_argument("--plot", type=Path, default=DEFAULT_PLOT)
    p.add_argument("--no-plot", action="store_true")
    p.add_argument("--quick", action="store_true", help="20 s windows, a sample every 5 s (a smoke run)")
    args = p.parse_args()
    reference_s = REFERENCE_SECONDS
    if args.quick:
        args.seconds, args.every, reference_s = 20.0, 5.0, 20.0
    with ExitStack() as stack, tempfile.TemporaryDirectory(prefix="dashboard-soak-") as tmp:
        work = Path(tmp)
        port, ws_port = free_port(), free_port()
        fleet_file = write_sim_fleet(work / "fleet.yaml", args.robots, port, ws_port)
        broker = start_embedded_broker(stack, fleet_file, port, work / "broker.log", ws_port=ws_port)
        sim = SimulatedFleet(port, args.robots)
        sim.motion = False
        sim.start(seconds=reference_s + args.seconds + 120)
        stack.callback(sim.stop)
        server = DashboardServer("127.0.0.1", 0, ws_port=ws_port).start()
        stack.callback(server.stop)
        driver = stack.enter_context(browser(work, "soak", precise_memory=True))
        driver.set_window_size(1280, 800)
        login(driver, server.url, "ops", PASSWORD)
        logged_in(driver, "ops")
        for i in range(args.robots):
            wait_until(f"{robot_name(i)} seen", lambda i=i: robot_row(driver, robot_name(i)), timeout=30)
        driver.find_element("id", "tab-fleet").click()
        print(f"{args.robots} robots; reference {reference_s:.0f} s (1 Hz messages only), then "
              f"{args.seconds:.0f} s of the full stream; a sample every {args.every:.0f} s", flush=True)
        rows = []
        for name, seconds, motion in (("reference", reference_s, False), ("soak", args.seconds, True)):
            sim.motion = motion
            c0, t0 = cpu_seconds(broker.proc.pid), time.monotonic()
            samples = soak(driver, seconds, args.every)
            broker_cpu = (cpu_seconds(broker.proc.pid) - c0) / (time.monotonic() - t0)
            print(f"\n{name}:\n{table(samples)}", flush=True)
            rows.append(window(name, samples, broker_cpu))
            if name == "soak" and not args.no_plot:
                plot(samples, args.plot)
        print("\nwindow     seconds   page CPU %   broker CPU %   heap MB: start   after 1 min   end   "
              "growth after 1 min   elements   DOM nodes")
        print("\n".join(rows))
        if not args.no_plot:
            print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
