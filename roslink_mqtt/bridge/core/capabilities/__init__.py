"""One module per operation a user sends the robot (as rosbridge_suite's ``capabilities/``). ROS-free.

Each capability owns its body type, its gate (role, presence, control lease, budget: a decision) and its port
to ROS (a typed Protocol the ROS adapter implements). The command endpoint runs every registered verb the
same way (:mod:`.base`). docs/architecture.md says how to add one. Every verb a user sends is one of them.
"""

from __future__ import annotations

from .advertise import Advertise, AdvertisePort
from .base import Capability, Gates, Refusal, Report, Request, Withdrawal
from .call import CallService, ServicePort
from .control import Control, LeaseDesk
from .goals import ActionPort, CancelGoal, SendGoal
from .logs import LogLines, RosoutPort
from .params import ParameterPort, Parameters
from .provide import ProviderPort, ProvideService, RespondToCall
from .provide_action import ActionProviderPort, ProvideAction, UpdateProvidedGoal
from .sdk_params import DeclareParameters, ParameterSetResult, SdkParameterPort
from .snapshot import ChunkLink, SnapshotPort, Snapshots
from .watch import Watch, WatchPort

__all__ = [
    "ActionPort", "ActionProviderPort", "Advertise", "AdvertisePort", "CallService", "CancelGoal", "Capability",
    "Control", "DeclareParameters", "Gates", "LeaseDesk", "LogLines", "ParameterPort", "ParameterSetResult",
    "Parameters", "ProvideAction", "ProvideService", "ProviderPort", "Refusal", "Report", "Request", "RespondToCall",
    "RosoutPort", "SdkParameterPort", "SendGoal", "ServicePort", "UpdateProvidedGoal", "Withdrawal", "ChunkLink",
    "SnapshotPort", "Snapshots", "Watch", "WatchPort",
]
