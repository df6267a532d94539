"""The benchmarks share bench/_support.py, and each of them still imports after a change to the package."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BENCH = ROOT / "bench"


def test_every_benchmark_imports() -> None:
    """A renamed function of the package breaks a benchmark here, in seconds, not in the next `make bench`."""
    names = sorted(p.stem for p in BENCH.glob("*.py"))
    code = ("import importlib, sys\n"
            f"for name in {names!r}:\n"
            "    importlib.import_module(name)\n"
            "assert 'rclpy' not in sys.modules, 'a benchmark imports ROS at import time'\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=BENCH, capture_output=True, text=True, timeout=60,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 0, done.stderr[-2000:]


def test_cpu_and_memory_of_a_process() -> None:
    sys.path.insert(0, str(BENCH))
    try:
        from _support import cpu_seconds, rss_bytes
    finally:
        sys.path.remove(str(BENCH))
    mine = os.getpid()
    assert cpu_seconds(mine) > 0 and rss_bytes(mine) > 1 << 20
    assert math.isnan(cpu_seconds(None))
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    assert math.isnan(cpu_seconds(gone.pid)) and rss_bytes(gone.pid) == 0
