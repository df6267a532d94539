"""Which reliability the bridge reads a camera with: what its publishers offer decides (ROS-free, so it is tested
without ROS; bridge/ros/video.py turns it into an rclpy profile).

Why reliable where it can be: a 640×480 picture is ~0.9 MB, some fifteen DDS fragments; a best-effort reader loses
the whole picture with any one of them, a reliable reader has the fragment sent again. Measured with the sim's
camera at 30 Hz and one subscriber on this machine: 22.6 pictures a second arrive best effort, 30.0 reliable
(beside a CPU hog: 26.3 and 30.0). The reader keeps the newest picture only (depth 1), so a reliable writer of
depth 1 replaces a picture rather than wait for a slow reader. A reliable reader would not match a best-effort
publisher at all, so one such publisher (or none known yet) makes the reader best effort: that matches either kind.
"""

from __future__ import annotations

from collections.abc import Iterable


def reads_reliably(publishers_reliable: Iterable[bool]) -> bool:
    """True when there is a publisher and every one offers reliable delivery."""
    offered = list(publishers_reliable)
    return bool(offered) and all(offered)
