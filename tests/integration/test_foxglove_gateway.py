"""``roslink-mqtt foxglove``: the demo robot served over the Foxglove WebSocket protocol, checked with
``@foxglove/ws-protocol``'s client from npm (run with node, tests/js/foxglove_probe.js), as Foxglove would use it.

turtle1 (sim + bridge from its robot file) runs against the embedded broker; alice (an operator) and bob (a viewer)
each run a gateway. The client sees channels with JSON schemas, messages at the robot's rates, the reset service
and the sim's parameters; alice's twists move the sim, bob's are refused with a status message; killing alice's
gateway while she drives stops the robot (her presence goes, the bridge's failsafe stops it).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from roslink_mqtt.localproc import LocalProcess, free_port
from tests.support.browser import CHROMIUM, browser, wait_until
from tests.support.measure import record_measurement
from tests.support.mqtt_client import TestClient
from tests.support.procs import ROOT
from tests.support.robot_stack import turtle1_online

pytestmark = [pytest.mark.timeout(150), pytest.mark.skipif(shutil.which("node") is None, reason="node missing")]

PROBE = ROOT / "tests" / "js" / "foxglove_probe.js"
MOTION = "roslink/turtle1/state/global_motion"
STOPPED_WITHIN = 3.0  # s from the gateway's death to a still robot: operator_timeout 1.5 s, with room for CI


@pytest.fixture(scope="module")
def broker_port(tmp_path_factory) -> Iterator[int]:
    with turtle1_online(tmp_path_factory.mktemp("foxglove")) as port:
        yield port


def _gateway(work: Path, broker_port: int, user: str) -> LocalProcess:
    port = free_port()
    proc = LocalProcess([sys.executable, "-m", "roslink_mqtt.cli.main", "foxglove", "turtle1", "--port", str(port),
                         "--url", f"mqtt://127.0.0.1:{broker_port}", "-u", user], work / f"gateway-{user}.log",
                        env={**os.environ, "ROSLINK_PASSWORD": f"{user}-demo", "PYTHONUNBUFFERED": "1"}, cwd=ROOT,
                        port=port, what=f"{user}'s gateway", stop_signal=2)
    proc.start()
    return proc


def _probe(port: int, plan: dict, timeout: float = 60, subprotocol: str = "foxglove.sdk.v1") -> dict:
    done = subprocess.run(["node", str(PROBE), f"ws://127.0.0.1:{port}", json.dumps(plan)], capture_output=True,
                          text=True, cwd=ROOT, timeout=timeout, env={**os.environ, "FOXGLOVE_SUBPROTOCOL": subprotocol})
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_channels_services_and_parameters_as_foxglove_sees_them(tmp_path, broker_port: int) -> None:
    gateway = _gateway(tmp_path, broker_port, "alice")
    try:
        seen = _probe(gateway.port or 0, {"subscribe": [MOTION, "roslink/turtle1/heartbeat"], "seconds": 3,
                                          "call": {"service": "roslink/turtle1/call/reset", "request": {}},
                                          "parameters": True})
    finally:
        gateway.stop()
    assert seen["serverInfo"]["name"] == "roslink-mqtt (alice)", seen["serverInfo"]
    assert {"clientPublish", "services", "parameters"} <= set(seen["serverInfo"]["capabilities"])
    assert not seen["errors"], seen["errors"]
    for topic, channel in seen["channels"].items():
        assert channel["encoding"] == "json" and channel["schemaEncoding"] == "jsonschema", topic
        assert json.loads(channel["schema"])["type"] == "object", topic
    motion_schema = json.loads(seen["channels"][MOTION]["schema"])
    assert motion_schema["properties"]["payload"]["properties"]["x"]["type"] == "number"
    assert seen["channels"][MOTION]["schemaName"] == "roslink.global_motion"
    # 10 Hz for the ≥ 3 s after the subscription (the service call and the parameters come before the wait)
    assert seen["messages"].get(MOTION, 0) >= 25, seen["messages"]
    assert "x" in seen["firstMessage"][MOTION]["payload"]
    assert seen["messages"].get("roslink/turtle1/heartbeat", 0) >= 2
    assert "roslink/turtle1/state/control" in seen["channels"]  # the bridge's own state, beside the description's
    assert {"roslink/turtle1/call/reset", "roslink/turtle1/cmd/emergency_stop"} <= set(seen["services"])
    assert seen["callFailure"] is None and seen["callResponse"]["success"] is True, seen
    names = {p["name"] for p in seen["parameters"] or []}
    assert any(n.startswith("roslink/turtle1/param/sim_robot/") for n in names), names


def test_an_operators_twist_moves_the_robot_and_a_viewers_is_refused(tmp_path, broker_port: int) -> None:
    twist = {"topic": "roslink/turtle1/cmd/twist", "linear": 0.3, "angular": 0.0, "hz": 10, "seconds": 2.5}
    with TestClient(broker_port, "bob", "bob-demo") as watcher:
        assert watcher.connect() == 0
        watcher.subscribe(MOTION, qos=0)
        bobs = _gateway(tmp_path, broker_port, "bob")
        try:  # bob's client names the protocol as older clients do (Lichtblick before 2025-12, ws-protocol's default)
            seen = _probe(bobs.port or 0, {"twist": twist, "seconds": 0.5}, subprotocol="foxglove.websocket.v1")
        finally:
            bobs.stop()
        refusals = [s for s in seen["status"] if "user 'bob' may not send 'cmd/twist'" in s]
        assert len(refusals) == 1, seen["status"]  # 25 twists refused, said once
        assert "roslink/turtle1/call/reset" not in seen["services"]  # not bob's to call: not offered
        assert "roslink/turtle1/cmd/emergency_stop" in seen["services"]  # every granted user may stop it
        assert all(abs(m.json()["payload"]["vx"]) < 0.05 for m in watcher.drain(0.1)), "bob's twists moved it"
        alices = _gateway(tmp_path, broker_port, "alice")
        try:
            _probe(alices.port or 0, {"twist": twist})
            moving = watcher.wait_for(lambda m: m.json()["payload"]["vx"] > 0.25, timeout=5).json()["payload"]
            assert moving["vx"] == pytest.approx(0.3, abs=0.03)
        finally:
            alices.stop()


def test_killing_the_gateway_while_driving_stops_the_robot(tmp_path, broker_port: int) -> None:
    gateway = _gateway(tmp_path, broker_port, "alice")
    plan = {"twist": {"topic": "roslink/turtle1/cmd/twist", "linear": 0.2, "angular": 0.0, "hz": 10, "seconds": 0,
                      "hold": True}}
    driver = subprocess.Popen(["node", str(PROBE), f"ws://127.0.0.1:{gateway.port}", json.dumps(plan)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        with TestClient(broker_port, "bob", "bob-demo") as watcher:
            assert watcher.connect() == 0
            watcher.subscribe(MOTION, qos=0)
            watcher.wait_for(lambda m: m.json()["payload"]["vx"] > 0.15, timeout=10)
            gateway.kill()  # SIGKILL: no goodbye, only the broker's last will for alice's presence
            killed = time.monotonic()
            watcher.wait_for(lambda m: abs(m.json()["payload"]["vx"]) < 0.01, timeout=STOPPED_WITHIN + 5)
            stopped = time.monotonic() - killed
    finally:
        driver.kill()
        driver.wait(5)
        gateway.stop()
    record_measurement("foxglove gateway killed while driving → robot still", stopped, STOPPED_WITHIN)
    assert stopped < STOPPED_WITHIN


@CHROMIUM
def test_a_page_shows_what_the_gateway_serves(tmp_path, broker_port: int) -> None:
    """tools/foxglove-view.html in headless Chromium, against alice's gateway while she drives an arc through it:
    every channel counted, global_motion at the robot's rate, the path drawn. ``FOXGLOVE_SCREENSHOT=path.png``
    also saves the page there (docs/foxglove.png comes from such a run)."""
    gateway = _gateway(tmp_path, broker_port, "alice")
    try:
        with browser(tmp_path, "foxglove-view") as driver:
            driver.get(f"file://{ROOT / 'tools' / 'foxglove-view.html'}?url=ws://127.0.0.1:{gateway.port}")
            wait_until("the server info", lambda: driver.execute_script("return window.gatewayView.server"))
            _probe(gateway.port or 0, {"twist": {"topic": "roslink/turtle1/cmd/twist", "linear": 0.4,
                                                 "angular": 0.8, "hz": 10, "seconds": 4}})
            counts = wait_until("global_motion in the page", lambda: driver.execute_script(
                "const out = {}; for (const c of window.gatewayView.channels.values()) out[c.topic] = c.count;"
                "return out[arguments[0]] > 30 ? out : null;", MOTION))
            assert counts.get("roslink/turtle1/heartbeat", 0) >= 3, counts
            path = driver.execute_script("return window.gatewayView.paths.get('turtle1')")
            xs, ys = [p[0] for p in path], [p[1] for p in path]
            assert max(xs) - min(xs) > 0.3 and max(ys) - min(ys) > 0.3, "the arc is not in the page"
            driver.set_window_size(1280, 600)
            time.sleep(0.5)  # the next redraw
            shot = Path(os.environ.get("FOXGLOVE_SCREENSHOT") or tmp_path / "foxglove-view.png")
            driver.save_screenshot(str(shot))
            print(f"screenshot: {shot}")
    finally:
        gateway.stop()
