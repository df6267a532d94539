"""When a VDA 5050 order takes the robot's ROSLink lease, and when it gives it back.

Pure logic. The master control sends no ROSLink presence, so the lease it drives an order under is one the order
took: the bridge takes the free lease when an order starts and gives back **that** lease when the order ends. A lease
the master already held (its own teleop session, say) is not the order's to give back: releasing it whenever no
order runs would take the master's joystick away twice a second.
"""

from __future__ import annotations

from enum import Enum


class LeaseStep(Enum):
    NONE = "none"
    HOLD = "hold"  # take the free lease for the order
    RELEASE = "release"  # give back the lease the order took


class OrderLease:
    """Decides, each tick, whether the order takes or gives back the lease (:meth:`step`); remembers whether the
    lease the master holds is the order's (:attr:`taken`)."""

    def __init__(self, master: str) -> None:
        self.master = master
        self.taken = False  # the master holds the lease because an order took it

    def step(self, executing: bool, holder: str | None) -> LeaseStep:
        if holder != self.master:
            self.taken = False  # released, expired, stopped or taken over: nothing of the order's is left to give
        if executing and holder is None:
            return LeaseStep.HOLD
        if not executing and self.taken:
            return LeaseStep.RELEASE
        return LeaseStep.NONE

    def held(self, ok: bool) -> None:
        """:meth:`step` said HOLD and the endpoint answered (``ok``: the lease is the master's now)."""
        self.taken = self.taken or ok

    def released(self) -> None:
        self.taken = False
