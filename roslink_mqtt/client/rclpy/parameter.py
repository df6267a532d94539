"""``rclpy.parameter``'s ``Parameter``, and the two ``rcl_interfaces.msg`` types a node's parameter callbacks use."""

from .parameters import Parameter, ParameterDescriptor, SetParametersResult

__all__ = ["Parameter", "ParameterDescriptor", "SetParametersResult"]
