"""``declare/<node>`` and ``param_result/<node>``: parameters of SDK nodes, held as ROS parameters. ROS-free.

An SDK node (a program without ROS) announces its parameters with a retained ``from/<user>/declare/<node>``
naming its presence client (an empty one withdraws them); the bridge then keeps a ROS node of that name holding
them. A ROS ``set_parameters`` goes to the SDK as ``to/<user>/param_set/<node>`` and its answer comes back on
``from/<user>/param_result/<node>``. Operators only. The port (:class:`SdkParameterPort`,
:mod:`roslink_mqtt.bridge.ros.sdk_params` with rclpy) keeps the proxy nodes (docs/protocol.md, "Parameters of SDK
nodes").
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

from ....authorize import refusal
from ....protocol.node_params import ParamDeclaration, ParamSetResult, check_node_name
from ....topics import Verb
from .base import Gates, Refusal, Report, Request
from .ports import PortKey

if TYPE_CHECKING:
    from .registry import Wiring
from .offers import Offers


class SdkParameterPort(Protocol):
    def offer(self, user: str, node: str, declaration: ParamDeclaration) -> str | None:
        """``user``'s program holds ``node``'s parameters; why not instead (another user declared it)."""
        ...

    def withdraw(self, user: str, node: str, reason: str) -> None:
        """``user``'s ``node`` is gone: its ROS node goes, waiting ROS sets fail with ``reason``."""
        ...

    def result(self, user: str, node: str, answer: ParamSetResult) -> str | None:
        """The SDK's answer to a forwarded set; why not instead (no such set waiting)."""
        ...


SDK_PARAMETER_PORT = PortKey[SdkParameterPort]("sdk_parameters", "SDK nodes' parameters as ROS nodes'")


class DeclareParameters(Offers[ParamDeclaration]):
    verb = Verb.DECLARE

    @classmethod
    def build(cls, wiring: Wiring) -> DeclareParameters:
        """From the bridge's wiring (capabilities/registry.py)."""
        port: SdkParameterPort = wiring.ports.get(SDK_PARAMETER_PORT)
        return cls(wiring.robot.name, port, wiring.report)

    def read(self, name: str, payload: bytes) -> ParamDeclaration:
        check_node_name(name)
        return ParamDeclaration.from_json(payload)

    def withdrawn(self, user: str, name: str) -> str:
        return f"{name} withdrawn by {user}"


class ParameterSetResult:
    verb = Verb.PARAM_RESULT

    @classmethod
    def build(cls, wiring: Wiring) -> ParameterSetResult:
        """From the bridge's wiring (capabilities/registry.py)."""
        port: SdkParameterPort = wiring.ports.get(SDK_PARAMETER_PORT)
        return cls(wiring.robot.name, port, wiring.report)

    def __init__(self, robot: str, port: SdkParameterPort, report: Report) -> None:
        self.robot, self.port, self.report = robot, port, report

    def parse(self, name: str, payload: bytes) -> ParamSetResult:
        return ParamSetResult.from_json(payload)

    def gate(self, request: Request[ParamSetResult], gates: Gates) -> Refusal | None:
        why = refusal(request.user, request.role, Verb.PARAM_RESULT, request.name, robot=self.robot)
        return Refusal(why) if why else None

    def run(self, request: Request[ParamSetResult]) -> None:
        assert request.body is not None
        why = self.port.result(request.user, request.name, request.body)
        if why:
            self.refuse(request, Refusal(why))

    def refuse(self, request: Request[ParamSetResult], refusal: Refusal) -> None:
        body = request.body
        self.report(request.user, request.topic, refusal.reason,
                    client_id=body.client_id if body is not None else refusal.client_id)


# the operations this module serves (capabilities/registry.py gathers them)
SERVES = (DeclareParameters, ParameterSetResult,)
