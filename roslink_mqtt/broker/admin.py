"""The embedded broker's control topic: ``roslink-mqtt fleet apply`` asks it, as an administrator, over MQTT.

Modelled on Mosquitto's dynamic-security plugin (``$CONTROL/dynamic-security/v1``), so one client drives both:
an admin publishes ``{"commands": [{"command": …}, …], "id": …}`` on ``$CONTROL/roslink/v1`` and reads
``{"responses": [{"command": …, "data": …} | {"command": …, "error": …}], "id": …}`` on its ``/response``.

* ``getFleet``: what the broker enforces (config/plan.py's :class:`FleetState`) and the fleet file it read
  (path and SHA-256 of its bytes, so ``fleet apply`` can tell a copy that differs from the admin's).
* ``reload``: re-read that file, exactly as SIGHUP does (removed logins and reduced grants are disconnected, the
  robots' grants republished), then report the new state.

Only an administrator's PUBLISH is obeyed; anyone else's is dropped and logged (the ACL gives nobody else the
topic either). Nothing here changes the file: the broker applies the file it was started with, which the admin
edits (``fleet user add``, ``fleet grant`` …) on the broker host, or copies there.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from ..config import Fleet
from ..config.plan import FleetState
from ..protocol.errors import ProtocolError
from ..protocol.fleet_control import CommandAnswer, ControlRequest, ControlResponse
from ..topics import FLEET_CONTROL as CONTROL_TOPIC

log = logging.getLogger("roslink_mqtt.broker")


def file_sha256(path: str) -> str:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return ""


class FleetControl:
    """Answers ``$CONTROL/roslink/v1`` for :class:`~roslink_mqtt.broker.server.EmbeddedBroker`."""

    def __init__(self, fleet: Callable[[], Fleet], config_path: str, reload: Callable[[], Awaitable[bool]]) -> None:
        self._fleet, self.config_path, self._reload = fleet, config_path, reload

    def is_admin(self, login: str | None) -> bool:
        user = self._fleet().users.get(login or "")
        return user is not None and user.admin

    def _state(self) -> dict[str, Any]:
        return {"file": self.config_path, "sha256": file_sha256(self.config_path),
                **FleetState.of(self._fleet()).to_data()}

    async def handle(self, login: str | None, payload: bytes) -> bytes | None:
        """The response to one request, or None when ``login`` may not ask (the broker checks before: a login
        can lose its admin rights between the two)."""
        if not self.is_admin(login):
            return None
        try:
            request = ControlRequest.from_json(payload)
        except ProtocolError as err:
            return ControlResponse((CommandAnswer("", error=str(err)).to_body(),)).to_json()
        responses = []
        for command in request.commands:
            name, echo = str(command.get("command")), command.get("correlationData")
            if name == "getFleet":
                answer = CommandAnswer(name, echo, data=self._state())
            elif name == "reload":
                log.info("%s: %s asks to reload %s", CONTROL_TOPIC, login, self.config_path)
                answer = CommandAnswer(name, echo, data=self._state()) if await self._reload() else CommandAnswer(
                    name, echo, error=f"{self.config_path} was refused; the broker still enforces the previous "
                                      "fleet (its log says why)")
            else:
                answer = CommandAnswer(name, echo, error="unknown command (getFleet, reload)")
            responses.append(answer.to_body())
        return ControlResponse(tuple(responses), request.id).to_json()
