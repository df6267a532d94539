"""The demo fleet has what the docs use (issue 13 item 9), and the sim does something visible with it.

The docs' examples send ``set_mode``, ``takeoff``, ``lights`` (advertised, on demand) … to turtle1 of
config/robots.yaml. First, without ROS: every command, service and state an example names on turtle1 is
mapped in the demo fleet. Then against the real stack (embedded broker, sim, bridge): the documented calls
are accepted, reach the simulated robot (its log says what it got) or come back on ``state/ack``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from roslink_mqtt.client import CommandRefused, RobotClient
from roslink_mqtt.config import Direction, load_fleet
from roslink_mqtt.protocol.messages import SPECS_BY_NAME
from roslink_mqtt.protocol.messages import Direction as MsgDirection
from tests.support.procs import CONFIG, ROOT
from tests.support.robot_stack import turtle1_online
from tests.support.waits import wait_until

pytestmark = pytest.mark.timeout(180)

DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "broker" / "README.md",
        ROOT / "bridge" / "README.md"]
COMMANDS = {name for name, spec in SPECS_BY_NAME.items() if spec.direction is MsgDirection.COMMAND}
SDK_METHODS = {"twist": "twist", "go_to_waypoint": "go_to_waypoint", "emergency_stop": "emergency_stop",
               "arm": "arm", "disarm": "disarm"}
NOT_MAPPED_HERE = {"ack"}  # acknowledgements: the bridge's own state, no rule needed


def doc_examples() -> dict[str, set[str]]:
    """What the docs do to turtle1: {"commands": leaves under from/<user>/, "advertised", "services", "states"}."""
    found: dict[str, set[str]] = {"commands": set(), "advertised": set(), "services": set(), "states": set()}

    def command(name: str) -> str:
        return f"cmd/{name}" if name in COMMANDS else name

    for path in DOCS:
        text = path.read_text()
        found["commands"] |= {command(n) for n in re.findall(r'\.command\("turtle1", "([\w/]+)"', text)}
        found["commands"] |= {command(n) for n in re.findall(r"roslink-mqtt pub turtle1 ([\w/]+)", text)}
        found["commands"] |= {f"cmd/{SDK_METHODS[n]}" for n in re.findall(r"\.(\w+)\(\"turtle1\"", text)
                              if n in SDK_METHODS}
        found["commands"] |= {f"cmd/{n}" for n in re.findall(r"from/<user>/cmd/(\w+)", text)}
        found["commands"] |= {f"cmd/{n}" for n in re.findall(r"`cmd/(\w+)`", text)}
        found["advertised"] |= set(re.findall(r'\.advertise\("turtle1", "([\w/]+)"', text))
        found["services"] |= set(re.findall(r'\.call(?:_async)?\("turtle1", "(\w+)"', text))
        found["services"] |= set(re.findall(r"roslink-mqtt call turtle1 (\w+)", text))
        found["states"] |= set(re.findall(r'\.subscribe\("turtle1", "(\w+)"', text))
        found["states"] |= set(re.findall(r"roslink-mqtt echo turtle1 (\w+)", text))
    return found


def test_docs_name_only_what_the_demo_fleet_maps() -> None:
    examples = doc_examples()
    assert {"cmd/set_mode", "cmd/takeoff", "lights"} <= examples["commands"]  # the scan finds what the issue names
    turtle1 = load_fleet(CONFIG).robots["turtle1"]
    inbound = {r.mqtt_topic: r for r in turtle1.rules if r.direction is Direction.MQTT_TO_ROS}
    outbound = {r.mqtt_topic.removeprefix("state/") for r in turtle1.rules if r.direction is Direction.ROS_TO_MQTT}
    missing = sorted(examples["commands"] - set(inbound))
    assert not missing, f"docs send these to turtle1 but config/robots.yaml does not map them: {missing}"
    not_on_demand = sorted(a for a in examples["advertised"] if not (a in inbound and inbound[a].on_demand))
    assert not not_on_demand, f"docs advertise these, which the demo fleet has no on_demand rule for: {not_on_demand}"
    services = {s.name for s in turtle1.services}
    assert examples["services"] <= services, sorted(examples["services"] - services)
    states = examples["states"] - NOT_MAPPED_HERE - {"heartbeat"}
    assert states <= outbound, sorted(states - outbound)
    assert set(inbound) >= {f"cmd/{c}" for c in COMMANDS}, "every ROSLink command runs on the demo fleet"


def _wait_log(log: Path, needle: str, timeout: float = 10, again=None) -> None:
    """Until the sim's log says ``needle``, calling ``again`` between looks (a message DDS may have dropped)."""
    def logged() -> bool:
        if needle in log.read_text(errors="replace"):
            return True
        if again is not None:
            again()
        return False

    try:
        wait_until(f"{needle!r} in the sim's log", logged, timeout=timeout, period=0.5)
    except AssertionError as e:
        raise AssertionError(f"{e}:\n{log.read_text()[-3000:]}") from None


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    work = tmp_path_factory.mktemp("demo-docs")
    with turtle1_online(work) as port:
        yield port, work / "sim.log"


def test_sdk_examples_reach_the_sim(stack) -> None:
    port, sim_log = stack
    with RobotClient("alice", "alice-demo", url=f"mqtt://127.0.0.1:{port}", robots=["turtle1"]) as client:
        client.wait_for_robot("turtle1", timeout=10)
        acks = client.subscribe("turtle1", "ack")
        client.command("turtle1", "set_mode", {"mode": "GUIDED"}, check=1.0)  # docs/sdk.md, verbatim
        # the bridge's ROS publisher may not have matched the sim's subscriber yet (DDS discovery): send again
        _wait_log(sim_log, "mode: GUIDED", again=lambda: client.command("turtle1", "set_mode", {"mode": "GUIDED"}))
        client.advertise("turtle1", "lights", "std_msgs/msg/Bool")  # docs/sdk.md: ahead of the messages
        # a new ROS publisher takes a moment to match (the docs say so): sent again until the sim has it
        client.command("turtle1", "lights", {"data": True}, check=1.0)
        _wait_log(sim_log, "lights on", timeout=15, again=lambda: client.command("turtle1", "lights", {"data": True}))
        client.unadvertise("turtle1", "lights")
        client.command("turtle1", "get_map", {}, check=1.0)
        ack = acks.get(timeout=10)
        assert "room" in ack.text, ack
        with pytest.raises(CommandRefused, match="no mapping"):  # still refused: what no rule maps
            client.command("turtle1", "cmd/fly", {}, check=2.0)


def test_cli_examples_reach_the_sim(stack) -> None:
    port, sim_log = stack
    env = {**os.environ, "ROSLINK_PASSWORD": "alice-demo"}

    def pub(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "pub", "turtle1", *args, "--url",
                               f"mqtt://127.0.0.1:{port}", "-u", "alice"], capture_output=True, text=True, env=env,
                              cwd=ROOT, timeout=30, stdin=subprocess.DEVNULL)

    for args, seen in ((("takeoff", '{"altitude": 1.5}'), "takeoff to 1.5 m"), (("land",), "land requested"),
                       (("set_mode", '{"mode": "AUTO"}'), "mode: AUTO")):
        out = pub(*args)
        assert out.returncode == 0, out.stdout + out.stderr
        _wait_log(sim_log, seen)
