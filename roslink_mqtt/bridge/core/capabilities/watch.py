"""``watch/<stream>``: a user keeps one of the robot's video streams coming (docs/video.md). ROS-free.

Any granted user may watch, a viewer too (the frames are state, which every granted user reads). A watch is a
lease the client renews (:class:`~roslink_mqtt.protocol.video.WatchRequest`); the port (:class:`WatchPort`,
:mod:`roslink_mqtt.bridge.ros.video` with rclpy) encodes the camera while any watch is fresh, once for every
watcher, and refuses a user who watches from too many clients at once.
"""

from __future__ import annotations

from collections.abc import Collection
from typing import TYPE_CHECKING, Protocol

from ....authorize import refusal
from ....protocol.video import WatchRequest
from ....topics import Verb
from .base import Gates, Refusal, Report, Request
from .ports import PortKey

if TYPE_CHECKING:
    from .registry import Wiring


class WatchPort(Protocol):
    def watch(self, stream: str, user: str, client_id: str, key: bool) -> str | None:
        """Start or renew a watch (``key``: send a keyframe now); a refusal's reason, or None."""
        ...

    def leave(self, stream: str, user: str, client_id: str) -> None:
        ...


VIDEO_PORT = PortKey[WatchPort]("video", "cameras encoded while watched")


class Watch:
    verb = Verb.WATCH

    @classmethod
    def build(cls, wiring: Wiring) -> Watch:
        """From the bridge's wiring (capabilities/registry.py)."""
        return cls(wiring.robot.name, [stream.name for stream in wiring.robot.video], wiring.ports.get(VIDEO_PORT),
                   wiring.report)

    def __init__(self, robot: str, streams: Collection[str], port: WatchPort, report: Report) -> None:
        self.robot, self.streams, self.port, self.report = robot, tuple(streams), port, report

    def parse(self, name: str, payload: bytes) -> WatchRequest:
        return WatchRequest.from_json(payload)

    def gate(self, request: Request[WatchRequest], gates: Gates) -> Refusal | None:
        if request.name not in self.streams:
            known = ", ".join(self.streams) or "none (robots.yaml `video:`)"
            return Refusal(f"no video stream '{request.name}' on {self.robot} (streams: {known})")
        why = refusal(request.user, request.role, Verb.WATCH, request.name, robot=self.robot, read_only=True)
        return Refusal(why) if why else None

    def run(self, request: Request[WatchRequest]) -> None:
        body = request.body
        assert body is not None
        if body.leave:
            self.port.leave(request.name, request.user, body.client_id)
            return
        why = self.port.watch(request.name, request.user, body.client_id, body.key)
        if why is not None:
            self.report(request.user, request.topic, why, client_id=body.client_id)

    def refuse(self, request: Request[WatchRequest], refusal: Refusal) -> None:
        client_id = request.body.client_id if request.body is not None else refusal.client_id
        self.report(request.user, request.topic, refusal.reason, client_id=client_id)


# the operations this module serves (capabilities/registry.py gathers them)
SERVES = (Watch,)
