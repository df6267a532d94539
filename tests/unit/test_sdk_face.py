"""The SDK's face (issue 44, step 4): a small package namespace that exports everything RobotClient returns, the
rclpy-shaped API in ``roslink_mqtt.client.rclpy`` with rclpy's module names, and every name that moved still
working for one release with a warning that gives its new import."""

from __future__ import annotations

import ast
import importlib
import inspect
import subprocess
import sys
import typing
import warnings
from typing import Any

import pytest

import roslink_mqtt.client as sdk
from roslink_mqtt.client import RobotClient
from roslink_mqtt.protocol.json_value import JsonValue
from tests.support.procs import ROOT

MOST_NAMES = 30  # aiomqtt, the model, has about 14; ours carries the errors a program catches


def _hints(function: Any) -> dict[str, Any]:
    """Its annotations, evaluated (the JSON alias is recursive: its forward reference names itself)."""
    return typing.get_type_hints(function, localns={"JsonValue": JsonValue})


def test_the_package_exports_few_names_each_once() -> None:
    assert len(sdk.__all__) <= MOST_NAMES, sorted(sdk.__all__)
    assert len(set(sdk.__all__)) == len(sdk.__all__)
    assert not set(sdk.__all__) & set(sdk._MOVED), "a name both exported and deprecated"


def _classes(hint: Any) -> set[type]:
    found = {hint} if isinstance(hint, type) else set()
    for arg in typing.get_args(hint):
        found |= _classes(arg)
    return found


def test_everything_robotclient_returns_is_exported() -> None:
    """A program can name (annotate, isinstance) whatever RobotClient hands it, from the package."""
    missing = {}
    for name, method in inspect.getmembers(RobotClient, callable):
        if name.startswith("_"):
            continue
        for cls in _classes(_hints(method).get("return")):
            if cls.__module__.startswith("roslink_mqtt") and cls is not RobotClient and \
                    cls.__name__ not in sdk.__all__ and not typing.is_typeddict(cls):  # a dict: nothing to import
                missing[name] = f"{cls.__module__}.{cls.__name__}"
    assert not missing, missing


def _has_any(hint: Any) -> bool:
    return hint is Any or any(_has_any(arg) for arg in typing.get_args(hint))


def test_no_public_return_of_the_sdk_is_any() -> None:
    """What the exported classes return is typed to the end: JSON values, parameter values, TypedDicts."""
    untyped = {}
    for exported in sdk.__all__:
        cls = getattr(sdk, exported)
        if not isinstance(cls, type) or issubclass(cls, BaseException):
            continue
        for name, member in vars(cls).items():
            function = member.fget if isinstance(member, property) else member
            if name.startswith("_") or not callable(function):
                continue
            if _has_any(_hints(function).get("return")):
                untyped[f"{exported}.{name}"] = _hints(function)["return"]
    assert not untyped, untyped


@pytest.mark.parametrize("name", sorted(sdk._MOVED))
def test_a_moved_name_still_works_with_a_warning_that_gives_its_new_import(name: str) -> None:
    where = sdk._MOVED[name]
    with pytest.warns(DeprecationWarning, match=f"from {where} import {name}"):
        old = getattr(sdk, name)
    assert old is getattr(importlib.import_module(where), name)


def test_an_unknown_name_is_still_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no attribute 'Nonexistent'"):
        sdk.Nonexistent  # noqa: B018


def test_the_rclpy_shaped_api_mirrors_rclpys_modules() -> None:
    from roslink_mqtt.client import rclpy
    from roslink_mqtt.client.rclpy import action, exceptions, node, parameter, qos

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the new spellings warn about nothing
        assert callable(rclpy.init) and callable(rclpy.create_node) and callable(rclpy.spin_until_future_complete)
        assert node.Node and node.Client and qos.QoSProfile and action.ActionClient and action.ActionServer
        assert parameter.Parameter and exceptions.ParameterNotDeclaredException


@pytest.mark.parametrize(("old", "new"), [("qos", "rclpy.qos"), ("actions", "rclpy.action"), ("node", "rclpy.node")])
def test_a_moved_module_imports_with_a_warning(old: str, new: str) -> None:
    """A fresh interpreter: here the module may be loaded already (its warning said once)."""
    code = (f"import warnings; warnings.simplefilter('always')\n"
            f"with warnings.catch_warnings(record=True) as seen:\n"
            f"    import roslink_mqtt.client.{old} as old\n"
            f"import roslink_mqtt.client.{new} as new\n"
            f"assert any('moved to roslink_mqtt.client.{new}' in str(w.message) for w in seen), seen\n"
            f"assert all(getattr(old, n) is getattr(new, n) for n in dir(new) if not n.startswith('_'))\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def test_a_robotclient_program_does_not_load_the_rclpy_shaped_api() -> None:
    code = ("import sys, roslink_mqtt.client\n"
            "loaded = sorted(m for m in sys.modules if m.startswith('roslink_mqtt.client.rclpy'))\n"
            "assert not loaded, loaded\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def _privates_defined(tree: ast.Module) -> set[str]:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            names.add(node.attr)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
        elif isinstance(node, ast.Assign):
            names.update(t.id for t in node.targets if isinstance(t, ast.Name))
    return {name for name in names if name.startswith("_")}


def test_no_module_of_the_sdk_reaches_into_another_ones_privates() -> None:
    """A private (``x._name``) is used only in the module that defines it: what another module needs is handed to it
    (control requests get the client's refusal and send) or public (``RobotClient.refusal``)."""
    reached = []
    for path in sorted((ROOT / "roslink_mqtt" / "client").rglob("*.py")):
        tree = ast.parse(path.read_text())
        own = _privates_defined(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__") and \
                    node.attr not in own and ast.unparse(node) != "sys._getframe":
                reached.append(f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)}")
    assert not reached, reached
