"""ROSLink presets: standard ROS types ↔ ROSLink messages.

``STATE_PRESETS`` turn a ROS message into a ROSLink payload (robot → users);
``COMMAND_PRESETS`` turn a validated ROSLink payload into the ROS message a
rule publishes (users → robot). Each lists the ROS types it accepts so a
preset/type mismatch is caught when the bridge starts.
"""

from .command import COMMAND_PRESETS, ORDINARY, CommandBehaviour, CommandPreset, CommandRefused
from .state import STATE_PRESETS, StatePreset

__all__ = ["COMMAND_PRESETS", "ORDINARY", "STATE_PRESETS", "CommandBehaviour", "CommandPreset", "CommandRefused",
           "StatePreset"]
