"""What the benchmarks share: the CPU and memory of processes, read from /proc.

Every bench runs as a script (``python bench/<name>.py``), so this folder is on ``sys.path`` and
``from _support import cpu_seconds`` works without path tricks.
"""

from __future__ import annotations

import os
from pathlib import Path

TICKS = os.sysconf("SC_CLK_TCK")
PAGE = os.sysconf("SC_PAGE_SIZE")
PROC = Path("/proc")


def cpu_seconds(pid: int | None) -> float:
    """User + system CPU of process ``pid`` so far (all its threads); NaN when there is none or it is gone, so a
    difference of two readings is NaN, never a wrong number."""
    if pid is None:
        return float("nan")
    try:
        # the command name in field 2 may hold spaces and ')': count the fields after its last ')'
        fields = (PROC / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / TICKS  # utime, stime (fields 14, 15 of the full line)
    except (OSError, IndexError, ValueError):
        return float("nan")


def rss_bytes(pid: int) -> int:
    """Resident memory of process ``pid`` in bytes; 0 when it is gone."""
    try:
        return int((PROC / str(pid) / "statm").read_text().split()[1]) * PAGE
    except (OSError, IndexError, ValueError):
        return 0
