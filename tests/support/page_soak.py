"""How a dashboard page holds up over time: heap after a forced collection, DOM size, main-thread CPU.

Shared by the fleet browser test (a short soak) and ``bench/dashboard_soak.py`` (ten minutes). Samples come from
Chromium's DevTools protocol: ``HeapProfiler.collectGarbage`` first, so the heap is what the page keeps, not what
it has not collected yet; ``Performance.getMetrics``' TaskDuration is the main thread's busy time, so its growth
over a window is the page's CPU share of one core.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from tests.support.waits import paced


@dataclass(frozen=True)
class PageSample:
    t: float           # s since the soak began
    heap_mb: float     # used JS heap after a forced garbage collection
    elements: int      # elements in the document
    nodes: int         # DOM nodes Chromium counts (detached ones included)
    listeners: int     # JS event listeners
    task_s: float      # main-thread busy time so far (s)


def sample(driver: Any, t0: float) -> PageSample:
    driver.execute_cdp_cmd("HeapProfiler.collectGarbage", {})
    heap = driver.execute_script("return performance.memory.usedJSHeapSize")
    elements = driver.execute_script("return document.getElementsByTagName('*').length")
    metrics = {m["name"]: m["value"] for m in driver.execute_cdp_cmd("Performance.getMetrics", {})["metrics"]}
    return PageSample(time.monotonic() - t0, heap / 1e6, int(elements), int(metrics.get("Nodes", -1)),
                      int(metrics.get("JSEventListeners", -1)), float(metrics.get("TaskDuration", 0.0)))


def soak(driver: Any, seconds: float, every: float) -> list[PageSample]:
    """Sample the page every ``every`` s for ``seconds`` s (bounded), the first at once."""
    driver.execute_cdp_cmd("Performance.enable", {})
    t0 = time.monotonic()
    # a sample each tick, up to and including the first tick at or past ``seconds``
    return [sample(driver, t0) for _ in paced(every, within=seconds + every)]


def cpu_share(a: PageSample, b: PageSample) -> float:
    """The page's main-thread busy share of one core between two samples (sampling itself included)."""
    return (b.task_s - a.task_s) / (b.t - a.t) if b.t > a.t else float("nan")


def table(samples: list[PageSample]) -> str:
    lines = ["    t s   heap MB   elements   DOM nodes   listeners   page CPU % (since last)"]
    for prev, s in zip([samples[0], *samples], samples, strict=False):
        cpu = cpu_share(prev, s) * 100 if s is not prev else float("nan")
        lines.append(f"{s.t:7.1f}   {s.heap_mb:7.2f}   {s.elements:8d}   {s.nodes:9d}   {s.listeners:9d}   {cpu:8.1f}")
    return "\n".join(lines)
