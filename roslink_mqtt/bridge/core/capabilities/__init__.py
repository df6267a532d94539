"""One module per operation a user sends the robot (as rosbridge_suite's ``capabilities/``). ROS-free.

Each capability owns its body type, its gate (role, presence, control lease, budget: a decision) and its port
to ROS (a typed Protocol the ROS adapter implements). The command endpoint runs every registered verb the
same way (:mod:`.base`). docs/architecture.md says how to add one. Every verb a user sends is one of them.
"""

from __future__ import annotations

from .advertise import ADVERTISE_PORT, Advertise, AdvertisePort
from .base import Capability, Gates, Refusal, Report, Request, Withdrawal
from .call import SERVICE_PORT, CallService, ServicePort
from .control import Control, LeaseDesk
from .goals import ACTION_PORT, ActionPort, CancelGoal, SendGoal
from .logs import ROSOUT_PORT, LogLines, RosoutPort
from .params import PARAMETER_PORT, ParameterPort, Parameters
from .ports import MissingPort, PortKey, Ports
from .provide import PROVIDER_PORT, ProviderPort, ProvideService, RespondToCall
from .provide_action import ACTION_PROVIDER_PORT, ActionProviderPort, ProvideAction, UpdateProvidedGoal
from .sdk_params import SDK_PARAMETER_PORT, DeclareParameters, ParameterSetResult, SdkParameterPort
from .snapshot import CHUNK_PORT, FAILSAFE_FILE_PORT, SNAPSHOT_PORT, ChunkLink, SnapshotPort, Snapshots
from .watch import VIDEO_PORT, Watch, WatchPort

__all__ = [
    "ACTION_PORT", "ACTION_PROVIDER_PORT", "ADVERTISE_PORT", "CHUNK_PORT", "FAILSAFE_FILE_PORT", "PARAMETER_PORT",
    "PROVIDER_PORT", "ROSOUT_PORT", "SDK_PARAMETER_PORT", "SERVICE_PORT", "SNAPSHOT_PORT", "VIDEO_PORT", "MissingPort",
    "PortKey", "Ports",
    "ActionPort", "ActionProviderPort", "Advertise", "AdvertisePort", "CallService", "CancelGoal", "Capability",
    "Control", "DeclareParameters", "Gates", "LeaseDesk", "LogLines", "ParameterPort", "ParameterSetResult",
    "Parameters", "ProvideAction", "ProvideService", "ProviderPort", "Refusal", "Report", "Request", "RespondToCall",
    "RosoutPort", "SdkParameterPort", "SendGoal", "ServicePort", "UpdateProvidedGoal", "Withdrawal", "ChunkLink",
    "SnapshotPort", "Snapshots", "Watch", "WatchPort",
]
