"""``roslink-mqtt record``: the demo robot recorded as MCAP, read back by two independent readers.

turtle1 (sim + bridge, from its robot file) runs against the embedded broker; bob (a viewer) records it for a few
seconds with the CLI. The Python ``mcap`` reader and ``@mcap/core`` from npm (run with node) both open the file:
every channel has a JSON schema, counts match each stream's rate over the time it was recorded within 10 %, log
times never go back on a channel, every payload is JSON. What bob may not read is not in it.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

from tests.support.procs import ROOT
from tests.support.robot_stack import turtle1_online

pytestmark = pytest.mark.timeout(120)

NODE = shutil.which("node")
RATES = {"roslink/turtle1/state/global_motion": 10.0, "roslink/turtle1/state/range_finder_data": 5.0}
DURATION = 6.0


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    work = tmp_path_factory.mktemp("record")
    out = work / "turtle1.mcap"
    with turtle1_online(work) as port:
        done = subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "record", "turtle1", "-o", str(out),
                               "--duration", str(DURATION), "--url", f"mqtt://127.0.0.1:{port}", "-u", "bob"],
                              capture_output=True, text=True, cwd=ROOT, timeout=60,
                              env={**os.environ, "ROSLINK_PASSWORD": "bob-demo"}, stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stderr
    assert "recorded" in done.stderr and str(out) in done.stderr, done.stderr
    return out


def test_every_channel_has_a_schema_and_the_rates_hold(recording: Path) -> None:
    from mcap.reader import make_reader

    with recording.open("rb") as f:
        reader = make_reader(f)
        times: dict[str, list[int]] = defaultdict(list)
        schemas = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert schema is not None and schema.encoding == "jsonschema", channel.topic
            assert channel.message_encoding == "json"
            json.loads(message.data)
            schemas[channel.topic] = json.loads(schema.data)
            times[channel.topic].append(message.log_time)
    for topic, stamps in times.items():
        assert stamps == sorted(stamps), f"{topic}: log times go back"
    assert "roslink/turtle1/heartbeat" in times
    assert len(times["roslink/turtle1/state/description"]) == 1  # retained, matched by two filters: recorded once
    assert not [t for t in times if "/to/" in t and "/to/bob/" not in t], "another user's replies were recorded"
    for topic, rate in RATES.items():
        stamps = times[topic]
        span = (stamps[-1] - stamps[0]) / 1e9
        assert span > DURATION / 2, (topic, span)
        measured = (len(stamps) - 1) / span
        assert abs(measured - rate) <= 0.1 * rate, f"{topic}: {measured:.2f}/s, expected {rate}/s"
    motion = schemas["roslink/turtle1/state/global_motion"]
    assert motion["title"] == "roslink.global_motion"
    assert motion["properties"]["payload"]["properties"]["x"]["type"] == "number"
    assert schemas["roslink/turtle1/heartbeat"]["title"] == "roslink.heartbeat"
    assert schemas["roslink/turtle1/state/description"]["title"] == "RobotDescription"


@pytest.mark.skipif(NODE is None, reason="node not installed")
def test_an_independent_reader_agrees(recording: Path) -> None:
    from mcap.reader import make_reader

    done = subprocess.run([NODE, str(ROOT / "tests" / "js" / "read_mcap.js"), str(recording)], capture_output=True,
                          text=True, cwd=ROOT, timeout=60)
    assert done.returncode == 0, done.stderr
    found = json.loads(done.stdout)
    assert found["library"] == "roslink-mqtt"
    with recording.open("rb") as f:
        counts: dict[str, int] = defaultdict(int)
        for _, channel, _ in make_reader(f).iter_messages():
            counts[channel.topic] += 1
    assert {c["topic"]: c["count"] for c in found["channels"] if c["count"]} == counts
    for channel in found["channels"]:
        assert channel["monotonic"] and channel["encoding"] == "json", channel
        assert channel["schema"]["encoding"] == "jsonschema" and channel["schema"]["parsed"]["type"] == "object"


def test_play_publishes_the_recording_again_as_its_robot(recording: Path, tmp_path: Path) -> None:
    """``roslink-mqtt play`` at twice the speed into a broker with no robot: a viewer sees turtle1's motion as
    recorded (same messages, same order, half the time), and the robot offline once the recording ends."""
    from mcap.reader import make_reader

    from tests.support.embedded_broker import EmbeddedBrokerProcess
    from tests.support.mqtt_client import TestClient

    motion_topic = "roslink/turtle1/state/global_motion"
    with recording.open("rb") as f:
        recorded = [(m.log_time, bytes(m.data)) for _, c, m in make_reader(f).iter_messages()
                    if c.topic == motion_topic]
    span = (recorded[-1][0] - recorded[0][0]) / 1e9
    with EmbeddedBrokerProcess(tmp_path) as broker, TestClient(broker.port, "bob", "bob-demo") as bob:
        assert bob.connect() == 0
        bob.subscribe(motion_topic)
        bob.subscribe("roslink/turtle1/heartbeat")
        done = subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "play", str(recording), "--rate", "2",
                               "--url", f"mqtt://127.0.0.1:{broker.port}", "-u", "turtle1"], capture_output=True,
                              text=True, cwd=ROOT, timeout=60, stdin=subprocess.DEVNULL,
                              env={**os.environ, "ROSLINK_PASSWORD": "turtle1-demo"})
        assert done.returncode == 0 and "played" in done.stderr, done.stderr
        got = bob.drain(1.0)
    motion = [m for m in got if m.topic == motion_topic]
    assert [m.payload for m in motion] == [payload for _, payload in recorded]
    played_span = motion[-1].at - motion[0].at
    assert span / 2 * 0.75 < played_span < span / 2 * 1.25, (played_span, span)
    heartbeats = [m.json()["payload"]["system_status"] for m in got if m.topic.endswith("/heartbeat")]
    assert heartbeats and heartbeats[-1] == 8  # offline: the recording is over
