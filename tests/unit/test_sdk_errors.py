"""Every exception the SDK raises is a RoslinkError (issue 14, SDK surface).

The scan reads the source, not behaviour: a new ``raise ValueError(...)`` in
roslink_mqtt/client is caught the day it is written, not the day a user's
``except RoslinkError`` misses it. Re-raising an exception object held in a
variable (``raise self.failure``, bare ``raise``) is allowed: its class was
chosen where it was made.
"""

from __future__ import annotations

import ast
import builtins
from pathlib import Path

import pytest

import roslink_mqtt.client as sdk
from roslink_mqtt.client import errors
from roslink_mqtt.client.rclpy import exceptions as rclpy_exceptions
from roslink_mqtt.client.rclpy.qos import mqtt_qos

CLIENT = Path(sdk.__file__).parent
# (file, builtin): raises that are Python protocol, not SDK errors
ALLOWED = {("__init__.py", "AttributeError")}  # PEP 562 module __getattr__ must raise AttributeError


def _builtin_exception(name: str) -> bool:
    value = getattr(builtins, name, None)
    return isinstance(value, type) and issubclass(value, BaseException)


def _raised_builtins(path: Path) -> list[tuple[int, str]]:
    """(line, name) of each ``raise`` whose exception is a builtin class, called or bare, anywhere in it."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if not isinstance(node, ast.Raise) or node.exc is None:
            continue
        names = {part.id for part in ast.walk(node.exc)  # also `raise a or ValueError(...)`
                 if isinstance(part, ast.Name) and _builtin_exception(part.id)}
        found.extend((node.lineno, name) for name in names)
    return sorted(found)


def test_no_bare_builtin_raised_in_the_sdk() -> None:
    offenders = [f"{path.name}:{line}: raise {name}"
                 for path in sorted(CLIENT.glob("*.py"))
                 for line, name in _raised_builtins(path)
                 if (path.name, name) not in ALLOWED]
    assert not offenders, "raise a RoslinkError subclass (roslink_mqtt/client/errors.py) instead:\n" + \
        "\n".join(offenders)


def test_the_scan_sees_a_bare_builtin(tmp_path: Path) -> None:
    sample = tmp_path / "sample.py"
    sample.write_text("def f(x):\n    if x:\n        raise ValueError('x')\n    raise x or TimeoutError\n")
    assert _raised_builtins(sample) == [(3, "ValueError"), (4, "TimeoutError")]


@pytest.mark.parametrize(("cls", "builtin"), [
    (errors.InvalidArgument, ValueError), (errors.InvalidType, TypeError), (errors.WaitTimeout, TimeoutError),
    (errors.NodeDestroyed, RuntimeError), (errors.SubscriptionFailed, ConnectionError),
])
def test_each_sdk_error_is_also_the_builtin_it_replaced(cls: type[Exception], builtin: type[Exception]) -> None:
    assert issubclass(cls, errors.RoslinkError) and issubclass(cls, builtin)
    # NodeDestroyed: raised by the rclpy-shaped node only; InvalidType: caught as the TypeError it is
    home = rclpy_exceptions if cls is errors.NodeDestroyed else errors if cls is errors.InvalidType else sdk
    assert getattr(home, cls.__name__) is cls


def test_old_except_clauses_still_catch() -> None:
    with pytest.raises(ValueError) as bad_value:
        mqtt_qos(-1)
    assert isinstance(bad_value.value, errors.RoslinkError)
    with pytest.raises(TypeError) as bad_type:
        mqtt_qos("ten")
    assert isinstance(bad_type.value, errors.RoslinkError)


def test_an_invalid_command_payload_is_a_roslink_error_too() -> None:
    """The SDK validates commands with the protocol's rules; what it raises then is still a RoslinkError."""
    from roslink_mqtt.client.commands import CommandStreams
    from roslink_mqtt.protocol import ProtocolError
    from roslink_mqtt.topics import TopicTree

    with pytest.raises(errors.RoslinkError) as bad:
        CommandStreams(TopicTree(), "alice").build("turtle1", "twist", {"lx": "fast"})
    assert isinstance(bad.value, ProtocolError) and isinstance(bad.value, ValueError)
    assert "payload.lx: expected number" in str(bad.value)
