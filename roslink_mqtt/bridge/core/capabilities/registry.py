"""Every operation, built the same way: the ROS adapter hands the core its ports once (:class:`Ports`), and each
capability builds itself from them (``build``, one signature for all). ROS-free.

Why: with each capability constructed by hand in the bridge, with a constructor shape of its own, adding an
operation meant editing the bridge's wiring too. Now the bridge wires ports, not operations; a new operation is its
capability module, its line in :data:`OPERATIONS` and, when it needs ROS, its port (docs/architecture.md).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from .advertise import Advertise, AdvertisePort
from .base import Capability, Report
from .call import CallService, ServicePort
from .goals import ActionPort, CancelGoal, SendGoal
from .logs import LogLines, RosoutPort
from .params import ParameterPort, Parameters
from .provide import ProviderPort, ProvideService, RespondToCall
from .provide_action import ActionProviderPort, ProvideAction, UpdateProvidedGoal
from .sdk_params import DeclareParameters, ParameterSetResult, SdkParameterPort
from .snapshot import ChunkLink, SnapshotPort, Snapshots
from .watch import Watch, WatchPort

if TYPE_CHECKING:
    from ....config import Robot
    from ....topics import TopicTree
    from ..budget import RequestBudget
    from ..routes import Inbound
    from ..snapshot_buffer import SnapshotFile


@dataclass(frozen=True, slots=True)
class Ports:
    """What the ROS adapter (bridge/ros/) implements for the core: one typed port per kind of operation."""

    services: ServicePort  # call/*: the robot's ROS services
    parameters: ParameterPort  # param/*: ROS nodes' parameters
    actions: ActionPort  # goal/*, cancel/*: ROS action servers
    rosout: RosoutPort  # log/*: lines onto /rosout
    advertise: AdvertisePort  # advertise/*: on-demand ROS publishers
    provider: ProviderPort  # provide/*, response/*: services MQTT clients provide to ROS
    action_provider: ActionProviderPort  # provide_action/*, action_update/*: actions they provide
    sdk_parameters: SdkParameterPort  # declare/*, param_result/*: SDK nodes' parameters as ROS nodes
    video: WatchPort  # watch/*: cameras encoded while watched
    snapshots: SnapshotPort | None = None  # snapshot/*: the ring buffer (None: the robot keeps none)
    chunks: ChunkLink | None = None  # … and the uplink its chunks leave on
    save_failsafe: Callable[[SnapshotFile, str], None] | None = None  # a failsafe stop's snapshot, kept on disk


@dataclass(frozen=True, slots=True)
class Wiring:
    """Everything a capability may be built from."""

    robot: Robot
    topics: TopicTree
    routes: Mapping[str, Inbound]  # the robot's MQTT→ROS rules by name
    ports: Ports
    report: Report  # an error report on to/<user>/error (the endpoint's refuse)
    publish_reliable: Callable[[str, bytes], None]  # the command link, QoS 1
    publish: Callable[[str, bytes, int], None]  # the command link, at the QoS given
    budget: RequestBudget  # requests one user may have unanswered (calls and parameters together)


C = TypeVar("C", covariant=True)


class Operation(Protocol[C]):
    """A capability class: it builds itself from the wiring."""

    @classmethod
    def build(cls, wiring: Wiring) -> C: ...


# Every operation the bridge serves besides ``cmd/*`` and ``control/*`` (the endpoint's own: the motion path and the
# control lease). The order is irrelevant: each has a verb of its own.
OPERATIONS: tuple[Operation[Capability[Any]], ...] = (
    CallService, Parameters, SendGoal, CancelGoal, LogLines, Advertise, ProvideService, RespondToCall,
    ProvideAction, UpdateProvidedGoal, DeclareParameters, ParameterSetResult, Snapshots, Watch,
)


def build_all(wiring: Wiring, operations: Sequence[Operation[Capability[Any]]] = OPERATIONS) -> list[Capability[Any]]:
    """Every registered operation (``operations``: these instead), built from ``wiring``."""
    return [operation.build(wiring) for operation in operations]
