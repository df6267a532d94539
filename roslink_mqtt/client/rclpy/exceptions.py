"""``rclpy.exceptions``' parameter errors, raised by an SDK node's parameters as rclpy raises them; and
:class:`NodeDestroyed`, what a destroyed SDK node raises where rclpy would raise its own error."""

from ..errors import NodeDestroyed
from .parameters import (
    InvalidParameterValueException,
    ParameterAlreadyDeclaredException,
    ParameterNotDeclaredException,
)

__all__ = ["InvalidParameterValueException", "NodeDestroyed", "ParameterAlreadyDeclaredException",
           "ParameterNotDeclaredException"]
