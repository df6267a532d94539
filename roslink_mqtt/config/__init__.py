"""Fleet configuration (robots.yaml): robots, keys, users, grants, mapping rules.

Core install only (pyyaml); the broker and the bridge both read it.
"""

from .loader import load_fleet, parse_fleet
from .model import (
    ActionRule,
    BridgeSettings,
    BrokerSettings,
    Direction,
    FailsafeAction,
    Fleet,
    Grant,
    ParameterRule,
    Priority,
    Robot,
    Role,
    RosQos,
    Rule,
    ServiceRule,
    SnapshotSettings,
    SnapshotTopic,
    TlsSettings,
    User,
    VelocityLimits,
    VideoStream,
)
from .passwords import PasswordHashError, hash_password, verify_password
from .yamlsource import ConfigError

__all__ = [
    "ActionRule", "BridgeSettings", "BrokerSettings", "ConfigError", "Direction", "FailsafeAction", "Fleet", "Grant",
    "ParameterRule", "PasswordHashError", "Priority",
    "Robot", "Role", "RosQos", "Rule", "ServiceRule", "SnapshotSettings", "SnapshotTopic", "TlsSettings", "User",
    "VelocityLimits", "VideoStream",
    "hash_password", "load_fleet", "parse_fleet", "verify_password",
]
